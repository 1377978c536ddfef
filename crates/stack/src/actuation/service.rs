//! Actuation: `bench/command` in; throttle board, `bench/actuation` and `bench/ecu` out.

use jetbench_bus::{Publisher, Wake};
use jetbench_io::ecu::PcCommand;
use jetbench_io::serial::{EcuPoller, ThrottleBoard, SILENT_AFTER};
use jetbench_io::ThrottleOutput;
use jetbench_msgs::{actuation_flags, channels, command_flags, ecu_flags, Command, EcuTelemetry, ServiceId};

use super::ActuationStep;
use crate::runtime::clock::{monotonic_ns, COMMAND_DEADLINE};
use crate::runtime::{Context, Input, Service, ServiceError, Setup};

/// Actuation: applies each command ([`ActuationStep`]); without fresh commands it
/// holds, then idles after the configured cycles. The board and the ECU are
/// serial devices opened by path (sim-bench's ptys with `devices = "sim"`); the
/// ECU is polled on its own thread and its samples are published here without
/// waiting.
pub struct ActuationService {
    step: ActuationStep,
    board: ThrottleBoard,
    ecu: EcuPoller,
    actuation: Publisher<jetbench_msgs::Actuation>,
    telemetry: Publisher<EcuTelemetry>,
    links: LinkLog,
    was_idle: bool,
    /// The ECU's state by its newest fresh sample (`None` before the first).
    ecu_state: Option<u32>,
    /// What was last asked of the ECU (start or stop) and when (monotonic ns).
    ecu_asked: Option<(PcCommand, u64)>,
}

/// How often a start or stop is repeated while control keeps asking, ns.
const ECU_ASK_EVERY_NS: u64 = 1_000_000_000;

impl Service for ActuationService {
    const ID: ServiceId = ServiceId::Actuation;
    type Inputs = Input<Command>;

    fn new(setup: &Setup<'_>) -> Result<(Self, Self::Inputs), ServiceError> {
        let (bus, config) = (setup.bus, setup.config);
        let command = Input::new(bus.subscriber(channels::COMMAND, 16)?, COMMAND_DEADLINE);
        let board = ThrottleBoard::new(config.board_port(), config.actuation.board_baud, monotonic_ns);
        tracing::info!("driving the {}", board.describe());
        let ecu = EcuPoller::spawn(config.ecu_port(), config.ecu.baud, config.ecu.poll_hz, monotonic_ns)?;
        tracing::info!("polling the {} at {} Hz", ecu.describe(), config.ecu.poll_hz);
        if config.rt.enabled {
            // It inherited actuation's priority, the highest of the control path.
            let priority = config.rt.ecu_priority;
            match ecu.pthread().map(|t| crate::runtime::rt::set_thread_fifo(t, priority)) {
                Some(Ok(())) => tracing::info!("ECU poller at SCHED_FIFO {priority}"),
                Some(Err(e)) => tracing::warn!("cannot set the ECU poller to SCHED_FIFO {priority}: {e}"),
                None => {}
            }
        }
        let actuation = ActuationService {
            step: ActuationStep::new(config.actuation.idle_after_missed_cycles),
            board,
            ecu,
            actuation: bus.publisher(channels::ACTUATION)?,
            telemetry: bus.publisher(channels::ECU)?,
            links: LinkLog::default(),
            was_idle: false,
            ecu_state: None,
            ecu_asked: None,
        };
        Ok((actuation, command))
    }

    fn process(&mut self, wake: Wake, command: &Input<Command>, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        // Before the first command the board is kept at idle; that is the
        // expected start, not a missed deadline.
        let (mut output, late) = match wake {
            Wake::Input(_) => match command.latest()? {
                Some(command) => {
                    self.ask_ecu(command.flags);
                    (self.step.on_command(&command), false)
                }
                None => return Ok(()),
            },
            Wake::Missed(_) => (self.step.on_missed(ctx.wake_ns()), command.started()),
            Wake::Tick => return Ok(()),
        };
        // A second guard behind control's: above idle only while the ECU says run.
        let running = |code: u32| jetbench_io::ecu::state::EcuState::from_code(code).is_some_and(|s| s.is_running());
        if self.ecu_state.is_some_and(|s| !running(s)) && output.applied_pct > jetbench_model::THROTTLE_MIN_PCT {
            output.applied_pct = jetbench_model::THROTTLE_MIN_PCT;
        }
        if let Err(e) = self.board.write(output.applied_pct) {
            ctx.reject("throttle write", &e);
        }
        let board = &self.board;
        let mut output =
            self.step.with_board(output, board.acknowledged(), board.unacked_writes(), board.silent_writes());
        output.written_ns = board.written_ns().unwrap_or(0);
        ctx.publish(&mut self.actuation, output, |a, ns| a.publish_ns = ns)?;
        let board_silent = board.silent_writes() >= SILENT_AFTER;
        if self.links.board(board_silent, board) {
            ctx.health().error();
        }
        for telemetry in self.ecu.try_iter() {
            if self.links.ecu(telemetry.flags, &self.ecu) {
                ctx.health().error();
            }
            if telemetry.flags & (ecu_flags::STALE | ecu_flags::SILENT) == 0 {
                self.ecu_state = Some(telemetry.state);
            }
            ctx.publish(&mut self.telemetry, telemetry, |t, ns| t.publish_ns = ns)?;
        }
        let idle = self.step.is_idle_fallback();
        if idle != self.was_idle {
            if !command.started() {
                tracing::info!("no controller yet: throttle held at idle");
            } else if idle {
                tracing::warn!("no command for {} cycles: throttle to idle", output.missed_cycles);
            } else {
                tracing::info!("commands are back: leaving idle");
            }
            self.was_idle = idle;
        }
        ctx.health().set_fallback(idle || board_silent);
        ctx.health().set_input_gaps(command.subscriber.gaps());
        ctx.cycle(late)?;
        Ok(())
    }

    fn stop(&mut self, _command: &Input<Command>, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        // Disarm, whatever ended the loop, and say so in a last sample.
        self.board.stop();
        // Idle, as the engine is once disarmed (the board then drives no signal,
        // which the ECU takes as idle).
        let mut last = self.step.on_stop();
        match self.board.acknowledged() {
            Some(ack) if !ack.armed => {
                tracing::info!("throttle board disarmed (acknowledged): engine at idle");
                last.flags |= actuation_flags::DISARMED;
                last.round_trip_ns = ack.round_trip_ns;
            }
            _ => {
                tracing::warn!(
                    "the throttle board did not acknowledge the disarm; its own watchdog idles it in 100 ms"
                );
                last.flags |= actuation_flags::UNACKED;
            }
        }
        ctx.publish(&mut self.actuation, last, |a, ns| a.publish_ns = ns)?;
        let c = self.board.counters();
        tracing::info!(
            "throttle board: {} acknowledged frames, {} rejected from the board ({} CRC, {} truncated), {} late \
             acks, opened {} times; ECU: {:?}, {} late replies dropped",
            c.frames,
            c.rejected(),
            c.crc_errors,
            c.truncated,
            self.board.late_acks(),
            self.board.opens(),
            self.ecu.shared().counters,
            self.ecu.shared().late_replies
        );
        Ok(())
    }
}

impl ActuationService {
    /// Passes control's start or stop request to the ECU: at once when it is
    /// new, again every [`ECU_ASK_EVERY_NS`] while control keeps asking.
    fn ask_ecu(&mut self, flags: u64) {
        let wanted = if flags & command_flags::ECU_STOP != 0 {
            Some(PcCommand::Stop)
        } else if flags & command_flags::ECU_START != 0 {
            Some(PcCommand::Start)
        } else {
            None
        };
        let Some(wanted) = wanted else {
            self.ecu_asked = None;
            return;
        };
        let now = monotonic_ns();
        let due = match self.ecu_asked {
            Some((asked, at)) => asked != wanted || now.saturating_sub(at) >= ECU_ASK_EVERY_NS,
            None => true,
        };
        if due {
            if self.ecu.send(wanted) {
                tracing::info!("asking the ECU: {}", if wanted == PcCommand::Stop { "stop" } else { "start" });
            }
            self.ecu_asked = Some((wanted, now));
        }
    }
}

/// Logs each serial device going silent and coming back, once per change.
#[derive(Default)]
struct LinkLog {
    board_seen: bool,
    board_silent: bool,
    ecu_seen: bool,
    ecu_silent: bool,
}

impl LinkLog {
    /// Returns true when the board has just gone silent after answering.
    fn board(&mut self, silent: bool, board: &ThrottleBoard) -> bool {
        let changed = silent != self.board_silent;
        self.board_silent = silent;
        match (changed, silent, self.board_seen) {
            (true, true, true) => {
                let why = board.link_error().unwrap_or("no acknowledgement");
                tracing::warn!("{} is silent ({why}); reopening it", board.describe());
                true
            }
            (_, false, false) if board.acknowledged().is_some() => {
                self.board_seen = true;
                tracing::info!("{} answers", board.describe());
                false
            }
            (true, false, true) => {
                tracing::info!("{} answers again (port opened {} times)", board.describe(), board.opens());
                false
            }
            _ => false,
        }
    }

    /// One ECU sample's flags; returns true when the ECU has just gone silent after answering.
    fn ecu(&mut self, flags: u32, ecu: &EcuPoller) -> bool {
        let fresh = flags & jetbench_msgs::ecu_flags::STALE == 0;
        let silent = flags & jetbench_msgs::ecu_flags::SILENT != 0;
        let mut went_silent = false;
        if fresh && !self.ecu_seen {
            self.ecu_seen = true;
            tracing::info!("{} answers", ecu.describe());
        } else if fresh && self.ecu_silent {
            tracing::info!("{} answers again", ecu.describe());
        } else if silent && !self.ecu_silent && self.ecu_seen {
            let why = ecu.shared().link_error.unwrap_or_else(|| "no valid reply".into());
            tracing::warn!("{} is silent ({why}); reopening it", ecu.describe());
            went_silent = true;
        }
        if fresh || silent {
            self.ecu_silent = silent;
        }
        went_silent
    }
}
