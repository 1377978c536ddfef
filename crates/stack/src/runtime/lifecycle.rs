//! The engine's lifecycle as the launcher follows it: operator commands given
//! on this machine, the ECU's states and the events of a run, the wait for
//! run (and the start through the ECU), and the cool-down at the end.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use jetbench_bus::{Bus, BusError, Publisher, Subscriber};
use jetbench_io::ecu::state::{EcuState, OffCondition};
use jetbench_msgs::{
    authorities, channels, end_reasons, event_kinds, identity, identity_text, operator_commands, origins, refusals,
    EcuTelemetry, Event, OperatorCommand,
};

use crate::limits::LimitKind;
use crate::runtime::clock::monotonic_ns;

/// Who a command given on this machine comes from: `local:<user>`.
pub fn local_identity() -> String {
    let user = std::env::var("USER").or_else(|_| std::env::var("LOGNAME")).unwrap_or_else(|_| "unknown".into());
    format!("local:{user}")
}

/// A command given on this machine's command line: origin local, authority
/// operator (whoever can run commands on the bench PC operates the bench).
pub fn local_command(command: i32, value: f64) -> OperatorCommand {
    OperatorCommand {
        stamp_ns: monotonic_ns(),
        value,
        command,
        origin: origins::LOCAL,
        client_id: 0,
        authority: authorities::OPERATOR,
        identity: identity(&local_identity()),
        ..OperatorCommand::default()
    }
}

/// An event in words, for the launcher's log and `jetbench stop`'s answer.
pub fn describe_event(e: &Event) -> String {
    let who = identity_text(&e.identity);
    let command = || operator_commands::name(e.code).unwrap_or("unknown command");
    match e.kind {
        event_kinds::TRIP => {
            let kind = LimitKind::from_code(e.code);
            let unit = kind.map_or("", LimitKind::unit);
            format!(
                "TRIP {} ({}): {:.1} {unit} against {:.1} {unit}, response {}",
                kind.map_or("unknown limit", LimitKind::key),
                kind.map_or("?", LimitKind::describe),
                e.value,
                e.limit,
                if e.previous == 1 { "shutdown" } else { "idle" }
            )
        }
        event_kinds::TRIP_CLEARED => "trips cleared".into(),
        event_kinds::ECU_STATE => format!("ECU {} -> {}", state_name(e.previous), state_name(e.code)),
        event_kinds::SHUTDOWN => format!("ECU shut the engine down: {}", off_name(e.code)),
        event_kinds::COMMAND_ACCEPTED => format!("{} from {who}: accepted", command()),
        event_kinds::COMMAND_REFUSED => format!("{} from {who}: refused ({})", command(), refusal_name(e.previous)),
        event_kinds::TEST_ENDED => format!("test ended: {}", end_reason(e)),
        event_kinds::DEADMAN => {
            format!("DEADMAN: operator {who} silent for {:.2} s (window {:.2} s); engine at idle", e.value, e.limit)
        }
        event_kinds::CONTROL if who.is_empty() => format!("control released ({})", command()),
        event_kinds::CONTROL => format!("control: {who} ({})", command()),
        other => format!("event of kind {other}"),
    }
}

/// Why a test ended, from its `TEST_ENDED` event.
pub fn end_reason(e: &Event) -> String {
    match e.code {
        end_reasons::OPERATOR => "stopped by an operator".into(),
        end_reasons::ECU_SHUTDOWN => format!(
            "the ECU shut the engine down: {} (EGT {:.0} °C, RPM {:.0})",
            off_name(e.previous),
            e.value,
            e.limit
        ),
        end_reasons::TRIP => {
            let kind = LimitKind::from_code(e.previous);
            let unit = kind.map_or("", LimitKind::unit);
            format!(
                "limit {} tripped ({}: {:.1} {unit} against {:.1} {unit}); engine shut down",
                kind.map_or("unknown", LimitKind::key),
                kind.map_or("?", LimitKind::describe),
                e.value,
                e.limit
            )
        }
        other => format!("reason {other}"),
    }
}

fn state_name(code: i32) -> String {
    u32::try_from(code).ok().and_then(EcuState::from_code).map_or_else(|| format!("state {code}"), |s| s.to_string())
}

fn off_name(code: i32) -> String {
    u32::try_from(code)
        .ok()
        .and_then(OffCondition::from_code)
        .map_or_else(|| format!("off condition {code}"), |o| o.to_string())
}

fn refusal_name(code: i32) -> &'static str {
    match code {
        refusals::NOT_AUTHORISED => "not authorised",
        refusals::NOT_NOW => "not possible in the engine's state",
        refusals::TEST_ENDED => "the test has ended",
        refusals::BAD_VALUE => "value out of range",
        refusals::UNKNOWN => "unknown command",
        refusals::TRIPPED => "a trip is latched",
        refusals::HELD_BY_ANOTHER => "another operator holds control",
        refusals::NOT_IN_CONTROL => "not in control",
        refusals::NO_HANDOVER_OFFER => "no handover offered",
        _ => "no reason given",
    }
}

/// Ctrl-C and SIGTERM counted (the bus's own flag says only whether one came).
#[derive(Clone)]
pub struct Interrupts(Arc<AtomicUsize>);

impl Interrupts {
    /// Counts SIGINT and SIGTERM from now on, on a thread of its own.
    pub fn install() -> std::io::Result<Self> {
        let count = Arc::new(AtomicUsize::new(0));
        let mut signals =
            signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])?;
        let c = count.clone();
        std::thread::Builder::new().name("interrupts".into()).spawn(move || {
            for _ in signals.forever() {
                c.fetch_add(1, Ordering::Relaxed);
            }
        })?;
        Ok(Interrupts(count))
    }

    /// SIGINT and SIGTERM received so far.
    pub fn count(&self) -> usize {
        self.0.load(Ordering::Relaxed)
    }
}

/// The launcher's view of the engine: the ECU's state, the run's events, and
/// its own operator commands (Ctrl-C, the start of `[engine] start = "auto"`).
pub struct EngineWatch {
    ecu: Subscriber<EcuTelemetry>,
    events: Subscriber<Event>,
    operator: Publisher<OperatorCommand>,
    /// The newest fresh ECU reading.
    pub latest: Option<EcuTelemetry>,
    state: Option<EcuState>,
    /// Why the test ended, once it has (`TEST_ENDED`), and whether that was a fault.
    pub ended: Option<(String, bool)>,
    /// The newest trip, in words.
    pub last_trip: Option<String>,
    /// The keys of the limits that tripped during the run, in order (a trip
    /// cleared by an operator is still counted).
    pub tripped: Vec<&'static str>,
}

impl EngineWatch {
    /// Watches the ECU telemetry and events on `bus`.
    pub fn new(bus: &Bus) -> Result<Self, BusError> {
        Ok(EngineWatch {
            ecu: bus.polled_subscriber(channels::ECU, 64)?,
            events: bus.polled_subscriber(channels::EVENTS, 256)?,
            operator: bus.publisher(channels::OPERATOR)?,
            latest: None,
            state: None,
            ended: None,
            last_trip: None,
            tripped: Vec::new(),
        })
    }

    /// Sends a command as this machine's operator.
    pub fn command(&mut self, command: i32) -> Result<(), BusError> {
        self.operator.publish(local_command(command, 0.0))?;
        Ok(())
    }

    /// The ECU's state by its newest reading.
    pub fn state(&self) -> Option<EcuState> {
        self.state
    }

    /// Takes what came since the last call; logs each event and state change.
    pub fn poll(&mut self) -> Result<(), BusError> {
        while let Some(t) = self.ecu.try_recv()? {
            if t.flags & (jetbench_msgs::ecu_flags::STALE | jetbench_msgs::ecu_flags::SILENT) == 0 {
                self.latest = Some(t);
                self.state = EcuState::from_code(t.state);
            }
        }
        while let Some(e) = self.events.try_recv()? {
            let text = describe_event(&e);
            // Above the status line, never through it; an accepted heartbeat
            // (ten a second from an operator in control) only in the recording.
            let heartbeat = e.kind == event_kinds::COMMAND_ACCEPTED && e.code == operator_commands::HEARTBEAT;
            if !heartbeat {
                crate::runtime::status::say(&format!("event: {text}"));
            }
            match e.kind {
                event_kinds::TRIP => {
                    self.last_trip = Some(text);
                    self.tripped.push(LimitKind::from_code(e.code).map_or("unknown limit", LimitKind::key));
                }
                event_kinds::TEST_ENDED => {
                    let fault = e.code != end_reasons::OPERATOR;
                    self.ended.get_or_insert((end_reason(&e), fault));
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// How the run ended: why the test ended early (and whether that was a
    /// fault), or else the limits that tripped while it ran (a fault too: the
    /// launcher exits non-zero naming them), or `None` for a clean run.
    pub fn outcome(&mut self) -> Option<(String, bool)> {
        if let Some(ended) = self.ended.take() {
            return Some(ended);
        }
        if self.tripped.is_empty() {
            return None;
        }
        Some((format!("limits tripped during the run: {}", self.tripped.join(", ")), true))
    }

    /// True while the engine burns fuel or cools down (not yet off or standby).
    pub fn engine_busy(&self) -> bool {
        self.state.is_some_and(|s| s.is_burning() || s.is_stopping())
    }

    /// The ECU reports the engine running.
    pub fn running(&self) -> bool {
        self.state.is_some_and(EcuState::is_running)
    }
}

/// On a terminal, returns the cursor to the line start and clears the line
/// (where the status line was), so a log line replaces it rather than runs
/// into it; nothing in a log file.
pub fn clear_line() -> &'static str {
    use std::io::IsTerminal;
    if std::io::stderr().is_terminal() && std::io::stdout().is_terminal() {
        "\r\x1b[K"
    } else {
        ""
    }
}

/// Sleeps one launcher tick (20 ms).
pub fn tick() {
    std::thread::sleep(Duration::from_millis(20));
}

/// Seconds since `t`.
pub fn since_s(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}
