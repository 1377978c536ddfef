//! An emulated JetCat-like ECU with its lifecycle: a plain struct clocked by
//! the time its owner passes in (seconds on any monotonic clock), no I/O, so
//! the same code runs in sim-bench, behind a pseudo-terminal and in tests.
//!
//! ```text
//! off --1 s--> standby --start--> ignite -> preheat 1 -> preheat 2 -> kerosene full on
//!     -> accelerate -> stabilise -> run --stop or fault--> slow-down --EGT < cool--> off
//! ```
//!
//! Each start phase lasts [`EcuParams::phases`] (about 14 s in all, a
//! kerosene start); RPM, EGT and pump voltage approach each phase's targets
//! with first-order lags, so the exhaust warms through ignition and preheat,
//! peaks while accelerating and settles at idle. In run they follow the
//! engine's thrust as [`EcuModel`](crate::emulate::EcuModel) maps it. A stop
//! (or a fault) cuts the fuel: slow-down, the starter turning the rotor to
//! cool it, until the exhaust is below [`EcuParams::cool_egt_c`], then off.
//!
//! The ECU shuts the engine down on its own, naming the reason
//! ([`OffCondition`]), as JetCat's ECU documents it: over-temperature (EGT
//! above `max_egt_c` for `over_temp_hold_s`), over-RPM (5 % above `max_rpm`
//! for 0.5 s), low RPM (10 % below idle for 3 s: a flame-out), low battery
//! (below `low_battery_v` for 1 s) and fail-safe (no throttle signal for
//! `failsafe_s` while burning). [`EcuFaults`] makes each happen on request.
//!
//! ```
//! use jetbench_io::ecu::emulator::{EcuCommand, EcuEmulator, EcuFaults, EcuParams};
//! use jetbench_io::ecu::state::{EcuState, OffCondition};
//!
//! let faults: EcuFaults = "ecu:overtemp_at_s=30".parse().unwrap();
//! let mut ecu = EcuEmulator::new(EcuParams::default(), faults, 0.0);
//! ecu.step(1.5, 0.0);
//! assert_eq!(ecu.state(), EcuState::Standby);
//! ecu.command(EcuCommand::Start, 2.0).unwrap();
//! let mut t = 2.0;
//! while ecu.state() != EcuState::Run { t += 0.01; ecu.throttle(0.0, t); ecu.step(t, 5.0); }
//! assert!(t > 15.0 && t < 17.0, "{t}");
//! while ecu.state() == EcuState::Run { t += 0.01; ecu.throttle(20.0, t); ecu.step(t, 10.0); }
//! assert_eq!((ecu.state(), ecu.off_condition()), (EcuState::SlowDown, OffCondition::OverTemperature));
//! ```

use std::fmt;
use std::str::FromStr;

use super::state::{EcuState, OffCondition};
use super::EcuReading;
use crate::emulate::{EGT_IDLE_C, EGT_PER_N, IDLE_RPM, PUMP_IDLE_V, PUMP_PER_PCT, RPM_PER_SQRT_N};

/// What the PC (or the radio) asks of the ECU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EcuCommand {
    /// Start the engine (JetCat `TCO,1`); accepted in standby only.
    Start,
    /// Stop: fuel off, slow-down, cool-down (JetCat `TCO,0`); always accepted.
    Stop,
    /// The throttle, % (JetCat `WPE`); it also keeps the fail-safe timer fed.
    Throttle(f64),
}

impl fmt::Display for EcuCommand {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EcuCommand::Start => f.write_str("start"),
            EcuCommand::Stop => f.write_str("stop"),
            EcuCommand::Throttle(pct) => write!(f, "throttle {pct} %"),
        }
    }
}

/// Why a command was refused, with JetCat's error number.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Refused {
    /// The command is not allowed in the ECU's current state (e.g. a start
    /// while already running), which it names.
    #[error("not allowed in state {0}")]
    NotInState(EcuState),
    /// The parameter is outside what the command takes (a throttle above 100 %).
    #[error("parameter out of range")]
    OutOfRange,
}

impl Refused {
    /// JetCat's error number (3: not allowed in this state, 4: out of range).
    pub fn code(self) -> u8 {
        match self {
            Refused::NotInState(_) => 3,
            Refused::OutOfRange => 4,
        }
    }
}

/// One start phase: its state, how long it lasts and where it takes the engine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phase {
    /// The state the ECU reports through this phase.
    pub state: EcuState,
    /// How long the phase lasts, s.
    pub duration_s: f64,
    /// The shaft speed the phase brings the engine to, rev/min.
    pub rpm: f64,
    /// The exhaust gas temperature the phase brings the engine to, °C.
    pub egt_c: f64,
    /// The fuel pump voltage through the phase, V.
    pub pump_v: f64,
}

/// The emulated engine and its ECU's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct EcuParams {
    /// The start sequence, in order; run follows the last phase.
    pub phases: Vec<Phase>,
    /// Idle shaft speed, rev/min: run at idle throttle.
    pub idle_rpm: f64,
    /// Maximum shaft speed, rev/min: run at full throttle.
    pub max_rpm: f64,
    /// Over-temperature limit, °C: the ECU shuts down above it.
    pub max_egt_c: f64,
    /// How long the exhaust may be above `max_egt_c` before the ECU shuts down, s.
    pub over_temp_hold_s: f64,
    /// Over-RPM: 5 % above `max_rpm` for this long.
    pub over_rpm_hold_s: f64,
    /// Low RPM: 10 % below idle while running for this long (a flame-out).
    pub low_rpm_hold_s: f64,
    /// The battery's nominal voltage, V (what `RFI` reports when healthy).
    pub battery_v: f64,
    /// The battery voltage below which the ECU shuts down, V.
    pub low_battery_v: f64,
    /// How long the battery may be below `low_battery_v` before the ECU shuts down, s.
    pub low_battery_hold_s: f64,
    /// Fail-safe: the longest the throttle signal may be missing while burning.
    pub failsafe_s: f64,
    /// Slow-down ends (off) once the exhaust is below this, °C.
    pub cool_egt_c: f64,
    /// Rotor speed the starter holds while cooling, rev/min.
    pub cooling_rpm: f64,
    /// The air around the engine, °C: the exhaust of a cold engine.
    pub ambient_c: f64,
    /// From off to standby (the ECU's self-test, or re-arming after a stop).
    pub arm_s: f64,
    /// In run, RPM is `idle_rpm + rpm_per_sqrt_n · √thrust` and the exhaust
    /// settles at `idle_egt_c + egt_per_n · thrust`.
    pub rpm_per_sqrt_n: f64,
    /// The exhaust's settled temperature at idle, °C.
    pub idle_egt_c: f64,
    /// The exhaust's settled rise per newton of thrust in run, °C/N.
    pub egt_per_n: f64,
}

impl Default for EcuParams {
    fn default() -> Self {
        let phase = |state, duration_s, rpm, egt_c, pump_v| Phase { state, duration_s, rpm, egt_c, pump_v };
        EcuParams {
            phases: vec![
                phase(EcuState::Ignite, 3.0, 6_000.0, 180.0, 0.0),
                phase(EcuState::Preheat1, 2.0, 7_000.0, 320.0, 0.15),
                phase(EcuState::Preheat2, 2.0, 8_500.0, 420.0, 0.25),
                phase(EcuState::KeroseneFullOn, 2.0, 16_000.0, 560.0, 0.45),
                phase(EcuState::Accelerate, 3.0, IDLE_RPM, 640.0, PUMP_IDLE_V),
                phase(EcuState::Stabilise, 2.0, IDLE_RPM, EGT_IDLE_C, PUMP_IDLE_V),
            ],
            idle_rpm: IDLE_RPM,
            max_rpm: 125_000.0,
            max_egt_c: 800.0,
            over_temp_hold_s: 1.0,
            over_rpm_hold_s: 0.5,
            low_rpm_hold_s: 3.0,
            battery_v: 7.4,
            low_battery_v: 6.4,
            low_battery_hold_s: 1.0,
            failsafe_s: 1.0,
            cool_egt_c: 100.0,
            cooling_rpm: 4_000.0,
            ambient_c: 20.0,
            arm_s: 1.0,
            rpm_per_sqrt_n: RPM_PER_SQRT_N,
            idle_egt_c: EGT_IDLE_C,
            egt_per_n: EGT_PER_N,
        }
    }
}

/// Time constant of the emulated RPM's first-order lag behind its target, s.
pub const RPM_TAU_S: f64 = 0.6;
const EGT_TAU_S: f64 = 1.5;
const EGT_COOL_TAU_S: f64 = 4.0;
const PUMP_TAU_S: f64 = 0.2;
const BATTERY_TAU_S: f64 = 1.0;
/// Time constant of the exhaust's rise in a surge, s.
const SURGE_TAU_S: f64 = 0.3;

/// Faults the emulated ECU produces on request, each at a time on the
/// emulator's clock (seconds since it was created): `ecu:KEY=SECONDS,...`
/// with keys `overtemp_at_s`, `overrpm_at_s`, `flameout_at_s`,
/// `lowbattery_at_s`, `failsafe_at_s`, `surge_at_s`, `silent_at_s` (the
/// kinds compose).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EcuFaults {
    /// The exhaust heats past the over-temperature limit.
    pub overtemp_at_s: Option<f64>,
    /// The rotor overspeeds.
    pub overrpm_at_s: Option<f64>,
    /// The flame goes out: RPM and EGT fall.
    pub flameout_at_s: Option<f64>,
    /// The ECU's battery sags below its limit.
    pub lowbattery_at_s: Option<f64>,
    /// The throttle signal is lost (commands no longer arrive).
    pub failsafe_at_s: Option<f64>,
    /// A surge (a compressor stall, or fuel rushing in): the exhaust heats
    /// fast, towards 300 °C above the over-temperature limit within a few
    /// tenths of a second.
    pub surge_at_s: Option<f64>,
    /// The ECU falls silent on its serial line (its cable or supply lost) and
    /// answers no poll; the engine runs on.
    pub silent_at_s: Option<f64>,
}

/// Why an ECU fault specification was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("--inject {spec:?}: {reason} (ecu:KEY=SECONDS,... with keys {keys})")]
pub struct EcuFaultError {
    /// The specification as given, e.g. `ecu:overtemp_at_s=x`.
    pub spec: String,
    /// What is wrong with it.
    pub reason: String,
    /// The keys an ECU fault may have, for the message.
    pub keys: &'static str,
}

const FAULT_KEYS: &str =
    "overtemp_at_s, overrpm_at_s, flameout_at_s, lowbattery_at_s, failsafe_at_s, surge_at_s, silent_at_s";

impl EcuFaults {
    /// True if `spec` is meant for the ECU (`ecu:...`), so a caller can route it here.
    pub fn is_ecu_spec(spec: &str) -> bool {
        spec.trim().split(':').next() == Some("ecu")
    }

    /// True if no fault is asked for: the ECU runs healthy.
    pub fn is_empty(&self) -> bool {
        *self == EcuFaults::default()
    }

    /// Adds the faults of `other` (a key given twice is refused by the parser, not here).
    pub fn merge(&mut self, other: EcuFaults) {
        let pick = |a: Option<f64>, b: Option<f64>| b.or(a);
        self.overtemp_at_s = pick(self.overtemp_at_s, other.overtemp_at_s);
        self.overrpm_at_s = pick(self.overrpm_at_s, other.overrpm_at_s);
        self.flameout_at_s = pick(self.flameout_at_s, other.flameout_at_s);
        self.lowbattery_at_s = pick(self.lowbattery_at_s, other.lowbattery_at_s);
        self.failsafe_at_s = pick(self.failsafe_at_s, other.failsafe_at_s);
        self.surge_at_s = pick(self.surge_at_s, other.surge_at_s);
        self.silent_at_s = pick(self.silent_at_s, other.silent_at_s);
    }

    /// True once an injected silence has begun at `now_s` (the ECU answers no poll).
    pub fn silent(&self, now_s: f64) -> bool {
        self.silent_at_s.is_some_and(|t| now_s >= t)
    }
}

impl FromStr for EcuFaults {
    type Err = EcuFaultError;

    fn from_str(spec: &str) -> Result<Self, EcuFaultError> {
        let err = |reason: String| EcuFaultError { spec: spec.into(), reason, keys: FAULT_KEYS };
        let Some(rest) = spec.trim().strip_prefix("ecu:") else {
            return Err(err("not an ECU fault (they start with `ecu:`)".into()));
        };
        let mut faults = EcuFaults::default();
        let mut any = false;
        for pair in rest.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (key, value) = pair.split_once('=').ok_or_else(|| err(format!("`{pair}` is not KEY=VALUE")))?;
            let value: f64 = value
                .trim()
                .parse()
                .map_err(|_| err(format!("{} = `{}` is not a number", key.trim(), value.trim())))?;
            if !(value.is_finite() && value >= 0.0) {
                return Err(err(format!("{} = {value} must be a number of seconds >= 0", key.trim())));
            }
            let slot = match key.trim() {
                "overtemp_at_s" => &mut faults.overtemp_at_s,
                "overrpm_at_s" => &mut faults.overrpm_at_s,
                "flameout_at_s" => &mut faults.flameout_at_s,
                "lowbattery_at_s" => &mut faults.lowbattery_at_s,
                "failsafe_at_s" => &mut faults.failsafe_at_s,
                "surge_at_s" => &mut faults.surge_at_s,
                "silent_at_s" => &mut faults.silent_at_s,
                other => return Err(err(format!("unknown key `{other}`"))),
            };
            if slot.replace(value).is_some() {
                return Err(err(format!("{} given twice", key.trim())));
            }
            any = true;
        }
        if !any {
            return Err(err("no fault given".into()));
        }
        Ok(faults)
    }
}

/// The emulated ECU and the engine it sees.
#[derive(Clone, Debug)]
pub struct EcuEmulator {
    params: EcuParams,
    faults: EcuFaults,
    state: EcuState,
    off: OffCondition,
    /// When the current state (or start phase) began.
    entered_s: f64,
    phase: usize,
    last_s: f64,
    rpm: f64,
    egt_c: f64,
    pump_v: f64,
    battery_v: f64,
    throttle_pct: f64,
    /// The last throttle signal, for the fail-safe.
    throttle_seen_s: f64,
    /// Since when each limit has been exceeded.
    over_temp_since: Option<f64>,
    over_rpm_since: Option<f64>,
    low_rpm_since: Option<f64>,
    low_battery_since: Option<f64>,
    /// State changes so far, in order: (time, state, off condition).
    transitions: Vec<(f64, EcuState, OffCondition)>,
}

fn lag(value: f64, target: f64, dt_s: f64, tau_s: f64) -> f64 {
    value + (1.0 - (-dt_s / tau_s).exp()) * (target - value)
}

impl EcuEmulator {
    /// Powered up at `now_s`, off; standby after [`EcuParams::arm_s`].
    pub fn new(params: EcuParams, faults: EcuFaults, now_s: f64) -> Self {
        let ambient = params.ambient_c;
        let battery_v = params.battery_v;
        EcuEmulator {
            params,
            faults,
            state: EcuState::Off,
            off: OffCondition::None,
            entered_s: now_s,
            phase: 0,
            last_s: now_s,
            rpm: 0.0,
            egt_c: ambient,
            pump_v: 0.0,
            battery_v,
            throttle_pct: 0.0,
            throttle_seen_s: now_s,
            over_temp_since: None,
            over_rpm_since: None,
            low_rpm_since: None,
            low_battery_since: None,
            transitions: Vec::new(),
        }
    }

    /// Powered up at `now_s` with the engine already running at idle (a
    /// simulated bench that starts where a test begins; [`EcuEmulator::new`]
    /// starts from off).
    pub fn running(params: EcuParams, faults: EcuFaults, now_s: f64) -> Self {
        let mut ecu = EcuEmulator::new(params, faults, now_s);
        ecu.rpm = ecu.params.idle_rpm;
        ecu.egt_c = ecu.params.idle_egt_c;
        ecu.pump_v = PUMP_IDLE_V;
        ecu.phase = ecu.params.phases.len();
        ecu.enter(EcuState::Run, now_s);
        ecu
    }

    /// The state the ECU reports now.
    pub fn state(&self) -> EcuState {
        self.state
    }

    /// Why the engine last stopped ([`OffCondition::None`] until it has, and again after a start).
    pub fn off_condition(&self) -> OffCondition {
        self.off
    }

    /// The engine and ECU settings this emulator runs with.
    pub fn params(&self) -> &EcuParams {
        &self.params
    }

    /// Every state change so far: (time, new state, off condition).
    pub fn transitions(&self) -> &[(f64, EcuState, OffCondition)] {
        &self.transitions
    }

    fn enter(&mut self, state: EcuState, now_s: f64) {
        self.state = state;
        self.entered_s = now_s;
        self.transitions.push((now_s, state, self.off));
    }

    fn shut_down(&mut self, reason: OffCondition, now_s: f64) {
        self.off = reason;
        self.over_temp_since = None;
        self.over_rpm_since = None;
        self.low_rpm_since = None;
        self.low_battery_since = None;
        self.enter(EcuState::SlowDown, now_s);
    }

    /// A command from the PC at `now_s`.
    pub fn command(&mut self, command: EcuCommand, now_s: f64) -> Result<(), Refused> {
        match command {
            EcuCommand::Start if self.state == EcuState::Standby => {
                self.off = OffCondition::None;
                self.phase = 0;
                self.throttle_seen_s = now_s;
                let first = self.params.phases.first().map_or(EcuState::Run, |p| p.state);
                self.enter(first, now_s);
                Ok(())
            }
            EcuCommand::Start => Err(Refused::NotInState(self.state)),
            EcuCommand::Stop => {
                if self.state.is_burning() {
                    self.shut_down(OffCondition::ManualOff, now_s);
                }
                Ok(())
            }
            EcuCommand::Throttle(pct) => self.throttle(pct, now_s),
        }
    }

    /// The throttle signal at `now_s` (the PWM the board sends, or `WPE`).
    /// After an injected fail-safe fault the signal no longer arrives.
    pub fn throttle(&mut self, pct: f64, now_s: f64) -> Result<(), Refused> {
        if !(pct.is_finite() && (0.0..=100.0).contains(&pct)) {
            return Err(Refused::OutOfRange);
        }
        if self.faults.failsafe_at_s.is_some_and(|t| now_s >= t) {
            return Ok(()); // lost on the way: the ECU never sees it
        }
        self.throttle_pct = pct;
        self.throttle_seen_s = now_s;
        Ok(())
    }

    fn fault_on(at: Option<f64>, now_s: f64) -> bool {
        at.is_some_and(|t| now_s >= t)
    }

    /// Advances to `now_s`; `thrust_n` is the engine's thrust (what RPM and
    /// EGT follow in run). Non-finite inputs or time going back are ignored.
    pub fn step(&mut self, now_s: f64, thrust_n: f64) {
        self.step_with_engine(now_s, thrust_n, None);
    }

    /// Like [`EcuEmulator::step`], for an engine simulated with its own spool and
    /// exhaust: in run, the ECU reports `engine`'s `(rpm, egt_c)` as they are (the
    /// engine's model holds their lags), not the RPM and EGT it derives from the
    /// thrust; injected faults still override them. `None` is [`EcuEmulator::step`].
    pub fn step_with_engine(&mut self, now_s: f64, thrust_n: f64, engine: Option<(f64, f64)>) {
        if !now_s.is_finite() || now_s < self.last_s {
            return;
        }
        let thrust_n = if thrust_n.is_finite() { thrust_n.max(0.0) } else { 0.0 };
        let dt = now_s - self.last_s;
        self.last_s = now_s;
        let p = &self.params;
        let in_state_s = now_s - self.entered_s;

        // Where the engine is heading in this state.
        let (mut rpm_to, mut egt_to, mut pump_to) = match self.state {
            EcuState::Off | EcuState::Standby => (0.0, p.ambient_c, 0.0),
            s if s.is_stopping() => {
                let rpm = if self.egt_c > p.cool_egt_c { p.cooling_rpm } else { 0.0 };
                (rpm, p.ambient_c, 0.0)
            }
            s if s.is_running() => {
                let u = self.throttle_pct;
                (
                    p.idle_rpm + p.rpm_per_sqrt_n * thrust_n.sqrt(),
                    p.idle_egt_c + p.egt_per_n * thrust_n,
                    PUMP_IDLE_V + PUMP_PER_PCT * (u - 25.0),
                )
            }
            _ => {
                let ph = p.phases[self.phase.min(p.phases.len() - 1)];
                (ph.rpm, ph.egt_c, ph.pump_v)
            }
        };
        // The engine's own spool and exhaust, in run: reported as they are.
        let (mut rpm_now, mut egt_now) = match engine {
            Some((rpm, egt_c)) if self.state.is_running() && rpm.is_finite() && egt_c.is_finite() => {
                (rpm_to, egt_to) = (rpm, egt_c);
                (true, true)
            }
            _ => (false, false),
        };
        let burning = self.state.is_burning();
        if burning && Self::fault_on(self.faults.overtemp_at_s, now_s) {
            egt_to = p.max_egt_c + 200.0;
            egt_now = false;
        }
        let surge = burning && Self::fault_on(self.faults.surge_at_s, now_s);
        if surge {
            egt_to = p.max_egt_c + 300.0;
            egt_now = false;
        }
        if burning && Self::fault_on(self.faults.overrpm_at_s, now_s) {
            rpm_to = p.max_rpm * 1.15;
            rpm_now = false;
        }
        if burning && Self::fault_on(self.faults.flameout_at_s, now_s) {
            (rpm_to, egt_to, pump_to) = (0.0, p.ambient_c, pump_to);
            (rpm_now, egt_now) = (false, false);
        }
        let battery_to =
            if Self::fault_on(self.faults.lowbattery_at_s, now_s) { p.low_battery_v - 1.0 } else { p.battery_v };
        let egt_tau = if surge {
            SURGE_TAU_S
        } else if egt_to < self.egt_c && !burning {
            EGT_COOL_TAU_S
        } else {
            EGT_TAU_S
        };
        self.rpm = if rpm_now { rpm_to } else { lag(self.rpm, rpm_to, dt, RPM_TAU_S) };
        self.egt_c = if egt_now { egt_to } else { lag(self.egt_c, egt_to, dt, egt_tau) };
        self.pump_v = lag(self.pump_v, pump_to.max(0.0), dt, PUMP_TAU_S);
        self.battery_v = lag(self.battery_v, battery_to, dt, BATTERY_TAU_S);

        // The ECU's own checks, while the engine burns fuel.
        if burning {
            let since = |slot: &mut Option<f64>, exceeded: bool| {
                if exceeded {
                    now_s - *slot.get_or_insert(now_s)
                } else {
                    *slot = None;
                    -1.0
                }
            };
            let p = self.params.clone();
            let checks = [
                (
                    since(&mut self.over_temp_since, self.egt_c > p.max_egt_c),
                    p.over_temp_hold_s,
                    OffCondition::OverTemperature,
                ),
                (
                    since(&mut self.over_rpm_since, self.rpm > 1.05 * p.max_rpm),
                    p.over_rpm_hold_s,
                    OffCondition::OverRpm,
                ),
                (
                    since(&mut self.low_rpm_since, self.state.is_running() && self.rpm < 0.9 * p.idle_rpm),
                    p.low_rpm_hold_s,
                    OffCondition::LowRpm,
                ),
                (
                    since(&mut self.low_battery_since, self.battery_v < p.low_battery_v),
                    p.low_battery_hold_s,
                    OffCondition::LowBattery,
                ),
                (now_s - self.throttle_seen_s, p.failsafe_s, OffCondition::FailSafe),
            ];
            if let Some(&(_, _, reason)) = checks.iter().find(|(held, hold, _)| *held >= *hold) {
                self.shut_down(reason, now_s);
                return;
            }
        }

        // The sequence.
        match self.state {
            EcuState::Off if in_state_s >= self.params.arm_s => self.enter(EcuState::Standby, now_s),
            s if s.is_stopping() && self.egt_c < self.params.cool_egt_c => self.enter(EcuState::Off, now_s),
            s if s.is_starting() && in_state_s >= self.params.phases[self.phase].duration_s => {
                self.phase += 1;
                let next = self.params.phases.get(self.phase).map_or(EcuState::Run, |ph| ph.state);
                self.enter(next, now_s);
            }
            _ => {}
        }
    }

    /// The telemetry as the ECU reports it (`RAC`), rounded as JetCat's ECU
    /// rounds it: whole RPM, EGT to 0.1 °C, volts to 0.01 V, throttle to 0.1 %.
    pub fn reading(&self) -> EcuReading {
        let throttle = if self.state.is_running() { self.throttle_pct } else { 0.0 };
        EcuReading {
            rpm: self.rpm.clamp(0.0, super::RPM_MAX).round(),
            egt_c: ((self.egt_c * 10.0).round() / 10.0).clamp(super::EGT_MIN_C, super::EGT_MAX_C),
            pump_v: ((self.pump_v * 100.0).round() / 100.0).clamp(0.0, super::PUMP_MAX_V),
            state: u32::from(self.state.code()),
            throttle_pct: (throttle * 10.0).round() / 10.0,
        }
    }

    /// The injected faults.
    pub fn faults(&self) -> &EcuFaults {
        &self.faults
    }

    /// The ECU's battery voltage, V, to 0.01 V (what `RFI` reports).
    pub fn battery_v(&self) -> f64 {
        (self.battery_v * 100.0).round() / 100.0
    }
}
