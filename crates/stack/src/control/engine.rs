//! The engine's side of control: what the ECU says, the limits, and the
//! operator's commands decide how much of the law's throttle reaches the
//! engine. Plain code that never touches the bus; [`super::ControlService`]
//! feeds it and publishes what it decides.
//!
//! - Throttle above idle only while the ECU says run, no trip is latched, no
//!   stop is under way and the operator has not said idle (or hold, which
//!   caps it).
//! - An ECU that leaves run on its own ends the test: the throttle goes to
//!   idle, the law is reset, and a `SHUTDOWN` and a `TEST_ENDED` event name
//!   the ECU's reason.
//! - A trip is latched until `CLEAR_TRIPS`; a `shutdown` trip also shuts the
//!   engine down through the ECU and ends the test.
//! - Operator commands follow one rule: anyone may make the engine safer;
//!   only an authenticated operator may make it run harder.
//! - With the config's `[operator]` section, control is a lease
//!   ([`jetbench_control::operator::Lease`]): one operator at a time holds it
//!   (taken, released, handed over, each recorded), and only the holder's
//!   raising commands are accepted; the bench PC's own commands raise only
//!   while no operator in the control room holds control. The deadman idles
//!   the engine when the holder's heartbeats lapse for the window while it
//!   runs above idle, latched until the holder raises it again, with a
//!   `DEADMAN` event naming who went silent and for how long.
//! - A stop idles the engine for `[engine] stop_idle_s`, then asks the ECU to
//!   shut it down; the test ends then (an emergency stop ends it at once), so
//!   the set stays up until the ECU has been asked.

use jetbench_control::operator::{Identity, Lease, LeaseChange, LeaseRefusal, LeaseSettings};
use jetbench_io::ecu::state::{EcuState, OffCondition};
use jetbench_model::THROTTLE_MIN_PCT;
use jetbench_msgs::{
    authorities, command_flags, ecu_flags, end_reasons, event_kinds, identity, operator_commands as op, origins,
    refusals, EcuTelemetry, Event, OperatorCommand, ServiceId,
};

use crate::config::{EngineReference, EngineSection};
use crate::limits::{LimitMonitor, Limits, Response, Trip};

/// What the operator asked the throttle to do.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mode {
    /// The reference profile (the config's, or one an operator chose).
    Profile,
    /// Idle until told otherwise.
    Idle,
    /// The law's throttle, capped at this, %.
    Hold(f64),
}

/// A stop under way: idle, then the ECU shuts the engine down.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stopping {
    since_ns: u64,
    /// At once (`STOP_NOW`, a `shutdown` trip) or after the idle time.
    now: bool,
    /// The operator's command (`STOP`, `STOP_NOW`), or 0 for a trip.
    command: i32,
}

/// What the control step should do about the law this cycle.
#[derive(Clone, Debug, PartialEq)]
pub enum LawChange {
    /// Nothing.
    None,
    /// Reset it (integral, shaper, profile time).
    Reset,
    /// Track this profile from now on (an operator's choice).
    Profile(jetbench_control::Profile),
}

/// The engine supervisor of the control service.
#[derive(Debug)]
pub struct EngineSupervisor {
    monitor: LimitMonitor,
    stop_idle_ns: u64,
    mode: Mode,
    ecu: Option<EcuTelemetry>,
    state: Option<EcuState>,
    running: bool,
    /// A start requested: ask the ECU until it starts (or this deadline).
    start_until_ns: Option<u64>,
    stopping: Option<Stopping>,
    ended: bool,
    /// The ECU left run on its own at this time: its reason is awaited.
    left_run: Option<(u64, EcuTelemetry)>,
    gated: bool,
    /// The last estimate's rate was still settling (`state_flags::SETTLING`): the law's
    /// output is not used, the throttle stays where it was.
    settling: bool,
    law_change: LawChange,
    /// The throttle last commanded, % (what HOLD and SET_REFERENCE compare with).
    last_throttle_pct: f64,
    last_reference_n: f64,
    events: Vec<Event>,
    /// Builds the profile of `RUN_PROFILE` (index) or `SET_REFERENCE` (N); `None` if invalid.
    profiles: ProfileSource,
    /// Who holds control, with `[operator]`; without it any operator authority raises.
    lease: Option<Lease>,
}

/// Where operator-chosen profiles come from.
#[derive(Clone, Debug)]
pub struct ProfileSource {
    /// The config's `[reference]`.
    pub configured: jetbench_control::Profile,
    /// The model's idle and full thrust, N, to scale the built-in profiles to.
    pub idle_n: f64,
    /// The model's thrust at full throttle, N.
    pub max_n: f64,
}

impl ProfileSource {
    fn by_index(&self, index: f64) -> Option<(String, jetbench_control::Profile)> {
        if index < 0.0 {
            return Some(("the configured [reference]".into(), self.configured.clone()));
        }
        let name = *jetbench_control::BUILTIN_PROFILES.get(index as usize).filter(|_| index.fract() == 0.0)?;
        jetbench_control::Profile::builtin(name, self.idle_n, self.max_n).map(|p| (name.to_string(), p))
    }

    fn constant(&self, thrust_n: f64) -> Option<jetbench_control::Profile> {
        (thrust_n.is_finite() && (0.0..=self.max_n).contains(&thrust_n)).then(|| {
            jetbench_control::Profile::from(jetbench_control::ProfileSpec::Steps {
                levels_n: vec![thrust_n],
                hold_s: 1.0,
                smoothing_s: 0.3,
            })
        })
    }
}

/// How long the reason of a shutdown the ECU made is awaited before the test
/// ends without it (the `RSS` reply follows the state by a poll or two).
const REASON_WAIT_NS: u64 = 400_000_000;
/// How long a start is asked for before it is given up.
const START_ASK_NS: u64 = 5_000_000_000;

impl EngineSupervisor {
    /// A supervisor with the config's `[engine]` settings and `[limits]`, the profiles it
    /// may run, nobody holding control (no lease until [`Self::with_lease`]).
    pub fn new(settings: &EngineSection, limits: Limits, profiles: ProfileSource) -> Self {
        EngineSupervisor {
            monitor: LimitMonitor::new(limits),
            stop_idle_ns: (settings.stop_idle_s * 1e9) as u64,
            mode: match settings.reference {
                EngineReference::Profile => Mode::Profile,
                EngineReference::Idle => Mode::Idle,
            },
            ecu: None,
            state: None,
            running: false,
            start_until_ns: None,
            stopping: None,
            ended: false,
            left_run: None,
            gated: true,
            settling: false,
            law_change: LawChange::None,
            last_throttle_pct: THROTTLE_MIN_PCT,
            last_reference_n: 0.0,
            events: Vec::new(),
            profiles,
            lease: None,
        }
    }

    /// With the config's `[operator]` section: control is a lease held by one
    /// operator at a time, and the deadman watches the holder's heartbeats.
    pub fn with_lease(mut self, settings: LeaseSettings) -> Self {
        self.lease = Some(Lease::new(settings));
        self
    }

    /// Who holds control (alive or lapsed), with `[operator]`.
    pub fn holder(&self) -> Option<Identity> {
        self.lease.as_ref().and_then(Lease::holder)
    }

    /// What the engine is told to do now: follow the profile, hold, or idle.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// True once the test has ended (the engine is being brought down).
    pub fn ended(&self) -> bool {
        self.ended
    }

    /// The events that happened since the last call, oldest first.
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }

    /// How the law must change before this cycle's step.
    pub fn take_law_change(&mut self) -> LawChange {
        std::mem::replace(&mut self.law_change, LawChange::None)
    }

    fn event(&mut self, now_ns: u64, kind: u32, code: i32) -> &mut Event {
        self.events.push(Event {
            stamp_ns: now_ns,
            kind,
            code,
            source_id: ServiceId::Control as u32,
            identity: identity(ServiceId::Control.name()),
            ..Event::default()
        });
        self.events.last_mut().expect("just pushed")
    }

    fn end(&mut self, now_ns: u64, reason: i32, previous: i32, value: f64, limit: f64) {
        if self.ended {
            return;
        }
        self.ended = true;
        let e = self.event(now_ns, event_kinds::TEST_ENDED, reason);
        (e.previous, e.value, e.limit) = (previous, value, limit);
    }

    /// An ECU sample.
    pub fn on_ecu(&mut self, now_ns: u64, t: &EcuTelemetry) {
        self.monitor.on_ecu(now_ns, t);
        if t.flags & (ecu_flags::STALE | ecu_flags::SILENT) != 0 {
            return;
        }
        self.ecu = Some(*t);
        let state = EcuState::from_code(t.state);
        if state != self.state {
            let previous = self.state.map_or(-1, |s| i32::from(s.code()));
            let e = self.event(t.stamp_ns, event_kinds::ECU_STATE, t.state as i32);
            e.previous = previous;
            if let Some(s) = state {
                tracing::info!(
                    "ECU: {} -> {s}",
                    self.state.map_or_else(|| "(first reading)".to_string(), |p| p.to_string())
                );
            } else {
                tracing::warn!("ECU reports an unknown state {}", t.state);
            }
            self.state = state;
        }
        let running = state.is_some_and(EcuState::is_running);
        if self.running && !running && self.stopping.is_none() && !self.ended {
            // Left run, and nobody here asked: the ECU shut the engine down.
            self.left_run = Some((t.stamp_ns, *t));
        }
        if running || state.is_some_and(EcuState::is_starting) {
            self.start_until_ns = None;
        }
        self.running = running;
    }

    /// A thrust estimate.
    pub fn on_thrust(&mut self, now_ns: u64, thrust_n: f64) {
        self.monitor.on_thrust(now_ns, thrust_n);
    }

    /// Whether the estimate the next [`Self::gate`] acts on has a rate still settling
    /// after the estimator started or restarted (`state_flags::SETTLING`), for a law that
    /// acts on it. A law about to start (or start afresh) waits for a settled estimate:
    /// the throttle stays where it was, idle at a start, whatever the law asks, since the
    /// law would act on first differences of the sensor's noise. A law already running
    /// free is not held by a restart of the estimator: holding it would bring a reset of
    /// its profile with it.
    pub fn on_settling(&mut self, settling: bool) {
        self.settling = settling;
    }

    /// True when the law's output reaches the engine at the next [`Self::gate`]: the
    /// engine is [`Self::free`], and the estimate has settled or the law already runs free.
    pub fn passes(&self) -> bool {
        self.free() && !(self.settling && self.gated)
    }

    /// The limits and the ECU's shutdowns at `now_ns`, every thrust estimate
    /// that has arrived taken ([`EngineSupervisor::on_thrust`]).
    pub fn check(&mut self, now_ns: u64) {
        self.check_with(now_ns, true);
    }

    /// As [`EngineSupervisor::check`], before the waiting thrust estimates are
    /// taken: everything but the sensor's silence, which the check after them
    /// judges (a cycle woken late must not count its lateness as the sensor's).
    pub fn check_before_estimates(&mut self, now_ns: u64) {
        self.check_with(now_ns, false);
    }

    fn check_with(&mut self, now_ns: u64, estimates_taken: bool) {
        if let Some((at, t)) = self.left_run {
            // Name the ECU's reason once its status arrives (or give up waiting).
            let off = self.ecu.map_or(0, |e| e.off_condition);
            if off != 0 || now_ns.saturating_sub(at) >= REASON_WAIT_NS {
                self.left_run = None;
                let reason = OffCondition::from_code(off).unwrap_or(OffCondition::None);
                tracing::error!(
                    "the ECU shut the engine down: {reason} (RPM {:.0}, EGT {:.0} °C); the test ends",
                    t.rpm,
                    t.egt_c
                );
                let e = self.event(at, event_kinds::SHUTDOWN, off as i32);
                (e.value, e.limit) = (t.egt_c, t.rpm);
                self.end(at, end_reasons::ECU_SHUTDOWN, off as i32, t.egt_c, t.rpm);
            }
        }
        let trips = if estimates_taken {
            self.monitor.check(now_ns, self.running)
        } else {
            self.monitor.check_before_samples(now_ns, self.running)
        };
        for trip in trips {
            self.on_trip(&trip);
        }
        if let Some(s) = self.stopping {
            if s.command != 0 && (s.now || now_ns.saturating_sub(s.since_ns) >= self.stop_idle_ns) {
                // The ECU is asked to shut down from this cycle on: the test is over.
                self.end(now_ns, end_reasons::OPERATOR, s.command, 0.0, 0.0);
            }
        }
        self.deadman(now_ns);
    }

    /// The deadman: the holder silent longer than the window while the engine
    /// runs above idle idles it, latched (until the holder raises it again),
    /// with a `DEADMAN` event naming who and for how long.
    fn deadman(&mut self, now_ns: u64) {
        let above_idle = self.free() && self.last_throttle_pct > THROTTLE_MIN_PCT + 1e-6;
        let Some(reason) = self.lease.as_mut().and_then(|l| l.deadman(now_ns, above_idle)) else { return };
        tracing::error!("deadman: {reason}; the engine goes to idle until the operator in control raises it again");
        self.mode = Mode::Idle;
        let e = self.event(now_ns, event_kinds::DEADMAN, 0);
        (e.value, e.limit) = (reason.silent_ns as f64 * 1e-9, reason.window_ns as f64 * 1e-9);
        e.identity = reason.holder.field();
    }

    fn on_trip(&mut self, trip: &Trip) {
        tracing::error!("limit tripped: {trip}");
        let e = self.event(trip.at_ns, event_kinds::TRIP, trip.kind.code());
        (e.value, e.limit) = (trip.value, trip.limit);
        e.previous = match trip.response {
            Response::Idle => 0,
            Response::Shutdown => 1,
        };
        if trip.response == Response::Shutdown && !self.ended {
            self.stopping = Some(Stopping { since_ns: trip.at_ns, now: true, command: 0 });
            self.end(trip.at_ns, end_reasons::TRIP, trip.kind.code(), trip.value, trip.limit);
        }
    }

    /// An operator command: accepted or refused by the authority rule and the
    /// engine's state, with an event either way.
    pub fn on_command(&mut self, now_ns: u64, c: &OperatorCommand) {
        if let (Some(lease), Some(who)) = (self.lease.as_mut(), Identity::from_field(c.identity)) {
            // Any command from the holder is a sign of their link's life (of a live
            // link only: after a lapse, even their own late commands do not revive it).
            if c.authority == authorities::OPERATOR && lease.holder() == Some(who) && c.command != op::RELEASE_CONTROL {
                let _ = lease.heartbeat(now_ns, who);
            }
        }
        let result = self.apply(now_ns, c);
        let who = jetbench_msgs::identity_text(&c.identity);
        let name = op::name(c.command).unwrap_or("unknown command");
        let (kind, previous) = match &result {
            Ok(note) => {
                // A heartbeat comes ten times a second: logged at debug only
                // (its event is recorded like every command's).
                if c.command == op::HEARTBEAT {
                    tracing::debug!("{name} from {who}: accepted{note}");
                } else {
                    tracing::info!("{name} from {who}: accepted{note}");
                }
                (event_kinds::COMMAND_ACCEPTED, 0)
            }
            Err((code, why)) => {
                tracing::warn!("{name} from {who}: refused, {why}");
                (event_kinds::COMMAND_REFUSED, *code)
            }
        };
        let e = self.event(now_ns, kind, c.command);
        e.previous = previous;
        e.value = c.value;
        e.source_id = c.client_id;
        e.origin = c.origin;
        e.authority = c.authority;
        e.identity = c.identity;
    }

    fn apply(&mut self, now_ns: u64, c: &OperatorCommand) -> Result<String, (i32, String)> {
        let operator = c.authority == authorities::OPERATOR;
        let need_operator = |what: &str| -> Result<(), (i32, String)> {
            if operator {
                Ok(())
            } else {
                Err((refusals::NOT_AUTHORISED, format!("{what} needs an authenticated operator")))
            }
        };
        let ended = |s: &Self| -> Result<(), (i32, String)> {
            if s.ended || s.stopping.is_some() {
                Err((refusals::TEST_ENDED, "the test has ended; the engine is being brought down".into()))
            } else {
                Ok(())
            }
        };
        let who = Identity::from_field(c.identity);
        // With a lease, a raising command needs control on top of the authority:
        // the holder's (with a live link), or the bench PC's while nobody holds it.
        let in_control = |s: &Self, what: &str| -> Result<(), (i32, String)> {
            let Some(lease) = &s.lease else { return Ok(()) };
            let live_holder = lease.holder().filter(|_| !lease.lapsed(now_ns));
            match (live_holder, who) {
                (Some(h), Some(w)) if h == w && c.origin != origins::LOCAL => Ok(()),
                (None, _) if c.origin == origins::LOCAL => Ok(()),
                (Some(h), _) => Err((refusals::HELD_BY_ANOTHER, format!("{what}: {h} holds control"))),
                (None, _) => Err((refusals::NOT_IN_CONTROL, format!("{what} needs control: take it first"))),
            }
        };
        let raise = |s: &Self, what: &str| -> Result<(), (i32, String)> {
            need_operator(what)?;
            in_control(s, what)
        };
        match c.command {
            op::STOP | op::STOP_NOW => {
                let now = c.command == op::STOP_NOW;
                match self.stopping {
                    Some(s) if s.now || !now => {}
                    _ => self.stopping = Some(Stopping { since_ns: now_ns, now, command: c.command }),
                }
                if now {
                    self.end(now_ns, end_reasons::OPERATOR, c.command, 0.0, 0.0);
                }
                Ok(if now { ": shutting down now".into() } else { ": idle, then shutdown".into() })
            }
            op::IDLE => {
                self.mode = Mode::Idle;
                Ok(String::new())
            }
            op::HOLD => {
                let cap = if c.value > 0.0 { c.value } else { self.last_throttle_pct };
                if !cap.is_finite() {
                    return Err((refusals::BAD_VALUE, format!("hold at {cap} %")));
                }
                if cap > self.last_throttle_pct + 1e-9 {
                    raise(self, "a hold above the current throttle")?;
                }
                self.mode = Mode::Hold(cap.max(THROTTLE_MIN_PCT));
                Ok(format!(": throttle at most {cap:.1} %"))
            }
            op::HEARTBEAT | op::RELEASE_CONTROL | op::TAKE_CONTROL | op::HANDOVER => self.lease_command(now_ns, c, who),
            op::CLEAR_TRIPS => {
                raise(self, "clearing trips")?;
                ended(self)?;
                self.monitor.clear();
                let _ = self.event(now_ns, event_kinds::TRIP_CLEARED, 0);
                Ok(String::new())
            }
            op::START => {
                raise(self, "a start")?;
                ended(self)?;
                if self.monitor.tripped() {
                    return Err((refusals::TRIPPED, "a trip is latched; clear it first".into()));
                }
                match self.state {
                    Some(EcuState::Standby) => {
                        self.start_until_ns = Some(now_ns + START_ASK_NS);
                        Ok(": starting through the ECU".into())
                    }
                    Some(s) if s.is_burning() => Ok(format!(": the engine is already {s}")),
                    s => Err((
                        refusals::NOT_NOW,
                        format!(
                            "the ECU is {} (a start needs standby)",
                            s.map_or("not heard yet".into(), |s| s.to_string())
                        ),
                    )),
                }
            }
            op::RUN_PROFILE => {
                raise(self, "a profile")?;
                ended(self)?;
                let (name, profile) = self
                    .profiles
                    .by_index(c.value)
                    .ok_or_else(|| (refusals::BAD_VALUE, format!("no profile {}", c.value)))?;
                self.mode = Mode::Profile;
                self.law_change = LawChange::Profile(profile);
                Ok(format!(": {name}"))
            }
            op::SET_REFERENCE => {
                if c.value > self.last_reference_n + 1e-9 || self.mode == Mode::Idle {
                    // From idle any reference raises the engine.
                    raise(self, "a higher reference")?;
                }
                ended(self)?;
                let profile = self.profiles.constant(c.value).ok_or_else(|| {
                    (refusals::BAD_VALUE, format!("{} N is outside 0..{:.0} N", c.value, self.profiles.max_n))
                })?;
                self.mode = Mode::Profile;
                self.law_change = LawChange::Profile(profile);
                Ok(format!(": {:.1} N", c.value))
            }
            other => Err((refusals::UNKNOWN, format!("unknown command {other}"))),
        }
    }

    /// `TAKE_CONTROL`, `RELEASE_CONTROL`, `HANDOVER`, `HEARTBEAT` on the lease,
    /// with a `CONTROL` event when control moved.
    fn lease_command(
        &mut self,
        now_ns: u64,
        c: &OperatorCommand,
        who: Option<Identity>,
    ) -> Result<String, (i32, String)> {
        let Some(lease) = self.lease.as_mut() else {
            return Ok(": recorded (control is not leased on a bench without [operator])".into());
        };
        if c.command != op::HEARTBEAT && c.command != op::RELEASE_CONTROL && c.authority != authorities::OPERATOR {
            return Err((refusals::NOT_AUTHORISED, "control needs an authenticated operator".into()));
        }
        let Some(who) = who else {
            return Err((refusals::BAD_VALUE, "the command names nobody (empty identity)".into()));
        };
        let change = match c.command {
            op::TAKE_CONTROL => lease.take(now_ns, who),
            op::RELEASE_CONTROL => lease.release(now_ns, who),
            op::HANDOVER => lease.handover(now_ns, who),
            _ => lease.heartbeat(now_ns, who),
        }
        .map_err(|refusal| {
            let code = match refusal {
                LeaseRefusal::HeldBy { .. } => refusals::HELD_BY_ANOTHER,
                LeaseRefusal::NotHolder { .. } | LeaseRefusal::Lapsed { .. } => refusals::NOT_IN_CONTROL,
                LeaseRefusal::NoOffer { .. } => refusals::NO_HANDOVER_OFFER,
            };
            (code, refusal.to_string())
        })?;
        let (holder, lapsed_from, note) = match change {
            LeaseChange::Taken { by, from } => (
                Some(by),
                from.is_some(),
                match from {
                    Some(f) if f == by => format!(": {by} took control again, their link had lapsed"),
                    Some(f) => format!(": {by} took control from {f}, whose link had lapsed"),
                    None => format!(": {by} holds control"),
                },
            ),
            LeaseChange::Released { by } => (None, false, format!(": {by} released control")),
            LeaseChange::Offered { by } => {
                (Some(by), false, format!(": {by} offers control to the next operator who accepts"))
            }
            LeaseChange::HandedOver { from, to } => (Some(to), false, format!(": {from} handed control over to {to}")),
            LeaseChange::AlreadyHeld | LeaseChange::Heartbeat => return Ok(String::new()),
        };
        let e = self.event(now_ns, event_kinds::CONTROL, c.command);
        e.identity = holder.map_or([0; jetbench_msgs::IDENTITY_LEN], |h| h.field());
        e.previous = i32::from(lapsed_from);
        e.origin = c.origin;
        Ok(note)
    }

    /// The throttle the engine gets this cycle from the law's `law_pct` (and
    /// the reference it tracked), with the command flags that say why it was
    /// gated and what the ECU is asked.
    pub fn gate(&mut self, now_ns: u64, law_pct: f64, reference_n: f64) -> (f64, u64) {
        let mut flags = self.ecu_asks(now_ns);
        let free = self.free();
        let held = free && self.settling && self.gated;
        let wanted = if held { self.last_throttle_pct } else { law_pct };
        let throttle = match (free, self.mode) {
            (false, _) => THROTTLE_MIN_PCT,
            (true, Mode::Hold(cap)) => wanted.min(cap),
            (true, _) => wanted,
        };
        if throttle < law_pct || held {
            flags |= command_flags::GATED;
        }
        self.gated = !free || held;
        self.last_throttle_pct = throttle;
        if free {
            self.last_reference_n = reference_n;
        }
        (throttle, flags)
    }

    /// Idle for a cycle in which no law ran (no estimate came), with the flags
    /// that say what the ECU is asked. The law's output did not reach the
    /// engine, so it counts as held: the first estimate to find the engine free
    /// resets the law ([`Self::is_free`] is false until a law's output passes).
    pub fn gate_idle(&mut self, now_ns: u64) -> (f64, u64) {
        let flags = self.ecu_asks(now_ns) | command_flags::GATED;
        self.gated = true;
        self.last_throttle_pct = THROTTLE_MIN_PCT;
        (THROTTLE_MIN_PCT, flags)
    }

    /// The command flags that ask the ECU to start or stop the engine at `now_ns`.
    fn ecu_asks(&mut self, now_ns: u64) -> u64 {
        let stop_due = self.stopping.map(|s| s.now || now_ns.saturating_sub(s.since_ns) >= self.stop_idle_ns);
        let burning = self.state.is_some_and(EcuState::is_burning);
        let mut flags = 0;
        if stop_due == Some(true) && burning {
            flags |= command_flags::ECU_STOP;
        }
        match self.start_until_ns {
            Some(until) if now_ns < until && self.stopping.is_none() => flags |= command_flags::ECU_START,
            Some(_) => {
                tracing::warn!("the ECU did not start the engine within {} s", START_ASK_NS / 1_000_000_000);
                self.start_until_ns = None;
            }
            None => {}
        }
        flags
    }

    /// True while the law ran free last cycle (its output reached the engine).
    pub fn is_free(&self) -> bool {
        !self.gated
    }

    /// True when the law's output may reach the engine now: the ECU says run, no
    /// trip is latched, no stop is under way, the test has not ended and no
    /// operator holds the engine at idle. The control step resets the law when
    /// this turns true while [`Self::is_free`] is false, so the law never brings
    /// to the engine what it integrated while its output was held at idle.
    pub fn free(&self) -> bool {
        self.running
            && !self.monitor.tripped()
            && self.stopping.is_none()
            && !self.ended
            && self.left_run.is_none()
            && self.mode != Mode::Idle
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_msgs::{ecu_states, origins};

    const MS: u64 = 1_000_000;

    fn supervisor(reference: EngineReference, limits: Limits) -> EngineSupervisor {
        let settings = EngineSection { reference, ..EngineSection::default() };
        let profiles = ProfileSource { configured: Default::default(), idle_n: 5.0, max_n: 100.0 };
        EngineSupervisor::new(&settings, limits, profiles)
    }

    fn ecu(state: i32, off: u32, at_ns: u64) -> EcuTelemetry {
        EcuTelemetry {
            stamp_ns: at_ns,
            state: state as u32,
            off_condition: off,
            rpm: 60_000.0,
            egt_c: 600.0,
            ..Default::default()
        }
    }

    fn command(command: i32, value: f64, authority: u32) -> OperatorCommand {
        OperatorCommand {
            command,
            value,
            authority,
            origin: origins::ZENOH,
            identity: identity("tester"),
            ..Default::default()
        }
    }

    #[test]
    fn a_cycle_woken_late_does_not_count_its_lateness_as_the_sensors_silence() {
        use crate::limits::{Limit, LimitKind};
        let mut limits = Limits::default();
        limits.set(LimitKind::SensorSilent, Some(Limit { limit: 0.1, response: Response::Idle, hold_s: 0.0 }));
        let mut s = supervisor(EngineReference::Profile, limits);
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        s.on_thrust(0, 10.0);
        s.check(0);
        // Control wakes 150 ms late, the estimates of those 150 ms waiting for it:
        // the check before they are taken leaves the sensor's silence alone ...
        s.check_before_estimates(150 * MS);
        assert!(s.free(), "{:?}", s.take_events());
        // ... nor do the checks after each of them while newer ones wait ...
        for k in 1..=15 {
            s.on_thrust(k * 10 * MS, 10.0);
            s.check_before_estimates(150 * MS);
        }
        // ... and with all of them taken, the sensor was never silent for 0.1 s.
        s.check(150 * MS);
        assert!(s.free(), "{:?}", s.take_events());
        // A sensor that really stops: no check before estimates ever judges it,
        // the first check with every estimate taken does.
        s.check_before_estimates(400 * MS);
        assert!(s.free());
        s.check(400 * MS);
        assert!(!s.free());
        let events = s.take_events();
        assert!(
            events.iter().any(|e| e.kind == event_kinds::TRIP && e.code == LimitKind::SensorSilent.code()),
            "{events:?}"
        );
    }

    #[test]
    fn idle_sent_with_no_estimate_leaves_the_law_held_so_its_first_output_starts_afresh() {
        let mut s = supervisor(EngineReference::Profile, Limits::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        // The engine runs before the sensor is heard: cycles with no estimate send idle ...
        assert!(s.free() && !s.is_free());
        assert_eq!(s.gate_idle(MS), (THROTTLE_MIN_PCT, command_flags::GATED));
        // ... and the law is still held, so the control step resets it at the first
        // estimate (before, that idle counted as the law running free, and a law
        // that had integrated while held brought it to the engine).
        assert!(s.free() && !s.is_free());
        assert_eq!(s.gate(10 * MS, 60.0, 50.0), (60.0, 0));
        assert!(s.is_free());
    }

    #[test]
    fn while_the_estimate_settles_the_throttle_stays_where_it_was_and_the_law_starts_afresh_after() {
        let mut s = supervisor(EngineReference::Profile, Limits::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        // The estimator has just started: its rate is a first difference of the noise.
        s.on_settling(true);
        assert!(s.free() && !s.passes());
        let (u, flags) = s.gate(10 * MS, 100.0, 50.0);
        assert_eq!(u, THROTTLE_MIN_PCT, "held where it was: idle");
        assert_ne!(flags & command_flags::GATED, 0);
        assert!(!s.is_free(), "the law's output did not reach the engine");
        assert_eq!(s.gate(20 * MS, 25.0, 50.0).0, THROTTLE_MIN_PCT);
        // Settled: the output passes, and the control step resets the law first.
        s.on_settling(false);
        assert!(s.passes() && !s.is_free());
        assert_eq!(s.gate(30 * MS, 60.0, 50.0), (60.0, 0));
        assert!(s.is_free());
        // The filter restarts mid-run: a law running free is not held (holding it would
        // restart its profile) ...
        s.on_settling(true);
        assert!(s.passes());
        assert_eq!(s.gate(40 * MS, 70.0, 50.0), (70.0, 0));
        // ... but one about to start afresh is: after an operator's hold at idle, the
        // throttle stays at idle until the estimate has settled.
        s.on_command(50 * MS, &command(op::IDLE, 0.0, authorities::ANYONE));
        assert_eq!(s.gate(60 * MS, 100.0, 50.0).0, THROTTLE_MIN_PCT);
        assert!(!s.is_free());
    }

    #[test]
    fn throttle_passes_only_in_run_and_an_ecu_shutdown_ends_the_test_with_its_reason() {
        let mut s = supervisor(EngineReference::Profile, Limits::default());
        s.on_ecu(0, &ecu(ecu_states::STANDBY, 0, 0));
        assert_eq!(s.gate(0, 60.0, 50.0).0, THROTTLE_MIN_PCT);
        s.on_ecu(10 * MS, &ecu(ecu_states::RUN, 0, 10 * MS));
        assert_eq!(s.gate(10 * MS, 60.0, 50.0), (60.0, 0));
        // Over-temperature: slow-down, the reason one poll later.
        s.on_ecu(20 * MS, &ecu(ecu_states::SLOW_DOWN, 0, 20 * MS));
        s.check(20 * MS);
        let (u, flags) = s.gate(20 * MS, 60.0, 50.0);
        assert_eq!(u, THROTTLE_MIN_PCT);
        assert_ne!(flags & command_flags::GATED, 0);
        // Held: the law's output no longer reaches the engine, and it will start
        // afresh (the control step resets it) once it may again.
        assert!(!s.free() && !s.is_free());
        assert!(!s.ended());
        s.on_ecu(80 * MS, &ecu(ecu_states::SLOW_DOWN, 2, 80 * MS));
        s.check(80 * MS);
        assert!(s.ended());
        let events = s.take_events();
        let shutdown = events.iter().find(|e| e.kind == event_kinds::SHUTDOWN).expect("a shutdown event");
        assert_eq!((shutdown.code, shutdown.stamp_ns), (2, 20 * MS));
        let ended = events.iter().find(|e| e.kind == event_kinds::TEST_ENDED).expect("the test ends");
        assert_eq!((ended.code, ended.previous), (end_reasons::ECU_SHUTDOWN, 2));
    }

    #[test]
    fn anyone_may_make_it_safer_only_an_operator_may_raise_it() {
        let mut s = supervisor(EngineReference::Idle, Limits::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        // Idle by default at the bench until a profile is chosen.
        assert_eq!(s.gate(0, 60.0, 50.0).0, THROTTLE_MIN_PCT);
        s.on_command(MS, &command(op::RUN_PROFILE, 0.0, authorities::ANYONE));
        assert_eq!(s.mode(), Mode::Idle);
        s.on_command(MS, &command(op::RUN_PROFILE, 0.0, authorities::OPERATOR));
        assert!(matches!(s.take_law_change(), LawChange::Profile(_)));
        assert_eq!(s.gate(2 * MS, 60.0, 50.0).0, 60.0);
        s.on_command(3 * MS, &command(op::HOLD, 80.0, authorities::ANYONE));
        s.on_command(3 * MS, &command(op::HOLD, 40.0, authorities::ANYONE));
        assert_eq!(s.gate(4 * MS, 60.0, 50.0).0, 40.0);
        s.on_command(5 * MS, &command(op::SET_REFERENCE, 70.0, authorities::ANYONE));
        s.on_command(5 * MS, &command(op::SET_REFERENCE, 30.0, authorities::ANYONE));
        s.on_command(5 * MS, &command(op::CLEAR_TRIPS, 0.0, authorities::ANYONE));
        s.on_command(6 * MS, &command(op::STOP_NOW, 0.0, authorities::ANYONE));
        let (u, flags) = s.gate(7 * MS, 60.0, 50.0);
        assert_eq!(u, THROTTLE_MIN_PCT);
        assert_ne!(flags & command_flags::ECU_STOP, 0);
        s.on_command(8 * MS, &command(op::START, 0.0, authorities::OPERATOR));
        let verdicts: Vec<(u32, i32, i32)> = s
            .take_events()
            .iter()
            .filter(|e| e.kind == event_kinds::COMMAND_ACCEPTED || e.kind == event_kinds::COMMAND_REFUSED)
            .map(|e| (e.kind, e.code, e.previous))
            .collect();
        let (ok, no) = (event_kinds::COMMAND_ACCEPTED, event_kinds::COMMAND_REFUSED);
        assert_eq!(
            verdicts,
            vec![
                (no, op::RUN_PROFILE, refusals::NOT_AUTHORISED),
                (ok, op::RUN_PROFILE, 0),
                (no, op::HOLD, refusals::NOT_AUTHORISED),
                (ok, op::HOLD, 0),
                (no, op::SET_REFERENCE, refusals::NOT_AUTHORISED),
                (ok, op::SET_REFERENCE, 0),
                (no, op::CLEAR_TRIPS, refusals::NOT_AUTHORISED),
                (ok, op::STOP_NOW, 0),
                (no, op::START, refusals::TEST_ENDED),
            ]
        );
    }

    #[test]
    fn a_stop_idles_first_then_asks_the_ecu() {
        let mut s = supervisor(EngineReference::Profile, Limits::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        s.on_command(0, &command(op::STOP, 0.0, authorities::ANYONE));
        let (u, flags) = s.gate(MS, 60.0, 50.0);
        assert_eq!((u, flags & command_flags::ECU_STOP), (THROTTLE_MIN_PCT, 0));
        let (_, flags) = s.gate(3_000 * MS, 60.0, 50.0);
        assert_ne!(flags & command_flags::ECU_STOP, 0);
        // The ECU obeys: slow-down is no shutdown of its own.
        s.on_ecu(3_100 * MS, &ecu(ecu_states::SLOW_DOWN, 15, 3_100 * MS));
        s.check(3_100 * MS);
        assert!(!s.take_events().iter().any(|e| e.kind == event_kinds::SHUTDOWN));
    }

    fn from(who: &str, command: i32, value: f64) -> OperatorCommand {
        OperatorCommand { identity: identity(who), ..self::command(command, value, authorities::OPERATOR) }
    }

    fn verdicts(s: &mut EngineSupervisor) -> Vec<(u32, i32, String, i32)> {
        s.take_events()
            .iter()
            .filter(|e| e.kind != event_kinds::ECU_STATE)
            .map(|e| (e.kind, e.code, jetbench_msgs::identity_text(&e.identity), e.previous))
            .collect()
    }

    #[test]
    fn one_operator_holds_control_and_hands_it_over_only_by_accepting_an_offer() {
        let mut s = supervisor(EngineReference::Idle, Limits::default()).with_lease(LeaseSettings::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        let (ok, no, moved) = (event_kinds::COMMAND_ACCEPTED, event_kinds::COMMAND_REFUSED, event_kinds::CONTROL);
        // An operator's raise without control is refused; so is the bench PC's while alice holds it.
        s.on_command(MS, &from("alice", op::RUN_PROFILE, 0.0));
        s.on_command(2 * MS, &from("alice", op::TAKE_CONTROL, 0.0));
        s.on_command(3 * MS, &from("bob", op::TAKE_CONTROL, 0.0));
        s.on_command(4 * MS, &from("bob", op::RUN_PROFILE, 0.0));
        s.on_command(5 * MS, &OperatorCommand { origin: origins::LOCAL, ..from("local:root", op::RUN_PROFILE, 0.0) });
        s.on_command(6 * MS, &from("alice", op::RUN_PROFILE, 0.0));
        assert_eq!(s.mode(), Mode::Profile);
        // bob accepts with no offer open; alice offers; bob accepts; alice is out.
        s.on_command(7 * MS, &from("bob", op::HANDOVER, 0.0));
        s.on_command(8 * MS, &from("alice", op::HANDOVER, 0.0));
        s.on_command(9 * MS, &from("bob", op::HANDOVER, 0.0));
        s.on_command(10 * MS, &from("alice", op::SET_REFERENCE, 90.0));
        s.on_command(11 * MS, &from("bob", op::RELEASE_CONTROL, 0.0));
        // Anyone may not take control; a heartbeat from who does not hold it is refused.
        s.on_command(12 * MS, &command(op::TAKE_CONTROL, 0.0, authorities::ANYONE));
        s.on_command(13 * MS, &from("alice", op::HEARTBEAT, 0.0));
        let r = refusals::NOT_AUTHORISED;
        assert_eq!(
            verdicts(&mut s),
            vec![
                (no, op::RUN_PROFILE, "alice".into(), refusals::NOT_IN_CONTROL),
                (moved, op::TAKE_CONTROL, "alice".into(), 0),
                (ok, op::TAKE_CONTROL, "alice".into(), 0),
                (no, op::TAKE_CONTROL, "bob".into(), refusals::HELD_BY_ANOTHER),
                (no, op::RUN_PROFILE, "bob".into(), refusals::HELD_BY_ANOTHER),
                (no, op::RUN_PROFILE, "local:root".into(), refusals::HELD_BY_ANOTHER),
                (ok, op::RUN_PROFILE, "alice".into(), 0),
                (no, op::HANDOVER, "bob".into(), refusals::NO_HANDOVER_OFFER),
                (moved, op::HANDOVER, "alice".into(), 0),
                (ok, op::HANDOVER, "alice".into(), 0),
                (moved, op::HANDOVER, "bob".into(), 0),
                (ok, op::HANDOVER, "bob".into(), 0),
                (no, op::SET_REFERENCE, "alice".into(), refusals::HELD_BY_ANOTHER),
                (moved, op::RELEASE_CONTROL, "".into(), 0),
                (ok, op::RELEASE_CONTROL, "bob".into(), 0),
                (no, op::TAKE_CONTROL, "tester".into(), r),
                (no, op::HEARTBEAT, "alice".into(), refusals::NOT_IN_CONTROL),
            ]
        );
    }

    #[test]
    fn the_deadman_idles_the_engine_when_the_holders_link_lapses_above_idle_and_latches() {
        let mut s = supervisor(EngineReference::Idle, Limits::default()).with_lease(LeaseSettings::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        s.on_command(0, &from("alice", op::TAKE_CONTROL, 0.0));
        s.on_command(0, &from("alice", op::RUN_PROFILE, 0.0));
        let _ = s.take_events();
        let mut t = 0;
        // Heartbeats every 100 ms for 3 s: the engine follows the law.
        while t < 3_000 * MS {
            if t % (100 * MS) == 0 {
                s.on_command(t, &from("alice", op::HEARTBEAT, 0.0));
            }
            s.check(t);
            assert_eq!(s.gate(t, 70.0, 80.0).0, 70.0, "at {t} ns");
            t += 10 * MS;
        }
        let last_heard = t - 10 * MS - (t - 10 * MS) % (100 * MS);
        // The link goes: the first tick past the window idles the engine.
        let mut idled_at = None;
        while t < 6_000 * MS {
            s.check(t);
            if s.gate(t, 70.0, 80.0).0 == THROTTLE_MIN_PCT && idled_at.is_none() {
                idled_at = Some(t);
            }
            t += 10 * MS;
        }
        let idled_at = idled_at.expect("the deadman idled the engine");
        assert!(idled_at > last_heard + 1_000 * MS && idled_at <= last_heard + 1_010 * MS + 10 * MS, "{idled_at}");
        let events: Vec<Event> =
            s.take_events().into_iter().filter(|e| e.kind != event_kinds::COMMAND_ACCEPTED).collect();
        assert_eq!(events.len(), 1, "{events:?}");
        let e = &events[0];
        assert_eq!((e.kind, jetbench_msgs::identity_text(&e.identity)), (event_kinds::DEADMAN, "alice".to_string()));
        assert!(e.value > 1.0 && e.value < 1.02 && (e.limit - 1.0).abs() < 1e-9, "{e:?}");
        // Latched: alice's late heartbeats (an outage's backlog) do not renew her lease
        // nor raise the engine, nor does her profile until she takes control again.
        for late in 0..3 {
            s.on_command(t + late * MS, &from("alice", op::HEARTBEAT, 0.0));
        }
        s.on_command(t + 3 * MS, &from("alice", op::RUN_PROFILE, 0.0));
        s.check(t + 3 * MS);
        assert_eq!(s.gate(t + 3 * MS, 70.0, 80.0).0, THROTTLE_MIN_PCT);
        // Anyone's lower reference does not bring it out of idle either.
        s.on_command(t + 4 * MS, &command(op::SET_REFERENCE, 10.0, authorities::ANYONE));
        assert_eq!(s.mode(), Mode::Idle);
        s.on_command(t + 5 * MS, &from("alice", op::TAKE_CONTROL, 0.0));
        s.on_command(t + 6 * MS, &from("alice", op::RUN_PROFILE, 0.0));
        t += 6 * MS;
        assert_eq!(s.gate(t, 70.0, 80.0).0, 70.0);
        let (ok, no) = (event_kinds::COMMAND_ACCEPTED, event_kinds::COMMAND_REFUSED);
        let heartbeat_refused = (no, op::HEARTBEAT, "alice".to_string(), refusals::NOT_IN_CONTROL);
        assert_eq!(
            verdicts(&mut s),
            vec![
                heartbeat_refused.clone(),
                heartbeat_refused.clone(),
                heartbeat_refused,
                (no, op::RUN_PROFILE, "alice".into(), refusals::NOT_IN_CONTROL),
                (no, op::SET_REFERENCE, "tester".into(), refusals::NOT_AUTHORISED),
                // Taken again, recorded as a take from the lapsed link (previous = 1).
                (event_kinds::CONTROL, op::TAKE_CONTROL, "alice".into(), 1),
                (ok, op::TAKE_CONTROL, "alice".into(), 0),
                (ok, op::RUN_PROFILE, "alice".into(), 0),
            ]
        );
        // At idle the deadman does not fire: silence is harmless there.
        s.on_command(t, &from("alice", op::IDLE, 0.0));
        let _ = s.take_events();
        for _ in 0..300 {
            t += 10 * MS;
            s.check(t);
            s.gate(t, 70.0, 80.0);
        }
        assert!(s.take_events().iter().all(|e| e.kind != event_kinds::DEADMAN));
    }

    #[test]
    fn a_stop_ends_the_test_when_the_ecu_is_asked_an_emergency_stop_at_once() {
        let mut s = supervisor(EngineReference::Profile, Limits::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        s.on_command(0, &command(op::STOP, 0.0, authorities::ANYONE));
        s.check(MS);
        assert!(!s.ended(), "idling: the set stays up until the ECU is asked");
        s.on_command(2 * MS, &command(op::RUN_PROFILE, 0.0, authorities::OPERATOR));
        s.check(2_999 * MS);
        assert!(!s.ended());
        s.check(3_000 * MS);
        assert!(s.ended());
        let ended: Vec<(i32, i32)> = s
            .take_events()
            .iter()
            .filter(|e| e.kind == event_kinds::TEST_ENDED || e.kind == event_kinds::COMMAND_REFUSED)
            .map(|e| (e.code, e.previous))
            .collect();
        assert_eq!(ended, vec![(op::RUN_PROFILE, refusals::TEST_ENDED), (end_reasons::OPERATOR, op::STOP)]);
        let mut s = supervisor(EngineReference::Profile, Limits::default());
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        s.on_command(0, &command(op::STOP_NOW, 0.0, authorities::ANYONE));
        assert!(s.ended());
    }

    #[test]
    fn a_latched_trip_holds_idle_until_cleared() {
        let mut limits = Limits::default();
        limits.set(
            crate::limits::LimitKind::MaxThrust,
            Some(crate::limits::Limit { limit: 80.0, response: Response::Idle, hold_s: 0.0 }),
        );
        let mut s = supervisor(EngineReference::Profile, limits);
        s.on_ecu(0, &ecu(ecu_states::RUN, 0, 0));
        s.on_thrust(MS, 90.0);
        s.check(MS);
        assert_eq!(s.gate(MS, 60.0, 50.0).0, THROTTLE_MIN_PCT);
        s.on_thrust(2 * MS, 40.0);
        s.check(2 * MS);
        assert_eq!(s.gate(2 * MS, 60.0, 50.0).0, THROTTLE_MIN_PCT, "latched");
        s.on_command(3 * MS, &command(op::CLEAR_TRIPS, 0.0, authorities::OPERATOR));
        s.check(3 * MS);
        assert_eq!(s.gate(3 * MS, 60.0, 50.0).0, 60.0);
        assert!(!s.ended(), "an idle trip does not end the test");
    }
}
