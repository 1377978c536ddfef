//! The operating envelope (`[limits]` of the bench config) and the monitor
//! that trips on it.
//!
//! ```toml
//! [limits]
//! preset = "p100"                     # defaults for a JetCat P100 (or "p220")
//! max_egt_c = { limit = 780.0, response = "shutdown", hold_s = 0.3 }
//! sensor_silent_s = "off"             # an entry can be switched off
//! ```
//!
//! Each entry has a `limit`, a `response` (`idle`: the throttle goes to idle
//! and stays there; `shutdown`: the engine is shut down through the ECU) and a
//! `hold_s` (how long the limit must be exceeded before it trips). A trip is
//! latched: nothing raises the throttle again until an operator clears the
//! trips (`jetbench clear`). [`LimitMonitor`] is plain code, fed the state
//! estimates and the ECU's telemetry by the control service.

use std::collections::VecDeque;
use std::fmt;

use jetbench_msgs::{ecu_flags, trip_limits, EcuTelemetry};

/// What the stack does when a limit trips.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Response {
    /// Throttle to idle, held there until the trips are cleared.
    Idle,
    /// Shut the engine down through the ECU (it cools down), and end the test.
    Shutdown,
}

impl fmt::Display for Response {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Response::Idle => "idle",
            Response::Shutdown => "shutdown",
        })
    }
}

/// The limits of `[limits]`, by their key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LimitKind {
    /// `max_thrust_n`: the stand's rating, N.
    MaxThrust,
    /// `max_egt_c`: the exhaust gas temperature, °C.
    MaxEgt,
    /// `max_egt_rise_c_per_s`: how fast the exhaust heats, °C/s.
    MaxEgtRise,
    /// `max_rpm`: shaft overspeed.
    MaxRpm,
    /// `min_rpm`: the shaft too slow while the engine runs (a flame-out).
    MinRpm,
    /// `thrust_rpm_band_n`: thrust and RPM disagree by more than this, N.
    ThrustRpmBand,
    /// `ecu_silent_s`: no ECU telemetry for this long, s.
    EcuSilent,
    /// `sensor_silent_s`: no force sample for this long, s.
    SensorSilent,
}

impl LimitKind {
    /// Every limit, in the order of `[limits]`' documentation.
    pub const ALL: [LimitKind; 8] = [
        LimitKind::MaxThrust,
        LimitKind::MaxEgt,
        LimitKind::MaxEgtRise,
        LimitKind::MaxRpm,
        LimitKind::MinRpm,
        LimitKind::ThrustRpmBand,
        LimitKind::EcuSilent,
        LimitKind::SensorSilent,
    ];

    /// Its key in `[limits]`.
    pub fn key(self) -> &'static str {
        match self {
            LimitKind::MaxThrust => "max_thrust_n",
            LimitKind::MaxEgt => "max_egt_c",
            LimitKind::MaxEgtRise => "max_egt_rise_c_per_s",
            LimitKind::MaxRpm => "max_rpm",
            LimitKind::MinRpm => "min_rpm",
            LimitKind::ThrustRpmBand => "thrust_rpm_band_n",
            LimitKind::EcuSilent => "ecu_silent_s",
            LimitKind::SensorSilent => "sensor_silent_s",
        }
    }

    /// What it watches, in words.
    pub fn describe(self) -> &'static str {
        match self {
            LimitKind::MaxThrust => "thrust above the stand's rating",
            LimitKind::MaxEgt => "exhaust too hot",
            LimitKind::MaxEgtRise => "exhaust heating too fast",
            LimitKind::MaxRpm => "shaft overspeed",
            LimitKind::MinRpm => "shaft too slow while running (flame-out)",
            LimitKind::ThrustRpmBand => "thrust disagrees with RPM (sensor or mount fault)",
            LimitKind::EcuSilent => "ECU silent",
            LimitKind::SensorSilent => "force sensor silent",
        }
    }

    /// Its unit, for messages.
    pub fn unit(self) -> &'static str {
        match self {
            LimitKind::MaxThrust | LimitKind::ThrustRpmBand => "N",
            LimitKind::MaxEgt => "°C",
            LimitKind::MaxEgtRise => "°C/s",
            LimitKind::MaxRpm | LimitKind::MinRpm => "rpm",
            LimitKind::EcuSilent | LimitKind::SensorSilent => "s",
        }
    }

    /// Its code in `bench/events` ([`trip_limits`]).
    pub fn code(self) -> i32 {
        match self {
            LimitKind::MaxThrust => trip_limits::MAX_THRUST,
            LimitKind::MaxEgt => trip_limits::MAX_EGT,
            LimitKind::MaxEgtRise => trip_limits::MAX_EGT_RISE,
            LimitKind::MaxRpm => trip_limits::MAX_RPM,
            LimitKind::MinRpm => trip_limits::MIN_RPM,
            LimitKind::ThrustRpmBand => trip_limits::THRUST_RPM_MISMATCH,
            LimitKind::EcuSilent => trip_limits::ECU_SILENT,
            LimitKind::SensorSilent => trip_limits::SENSOR_SILENT,
        }
    }

    /// The limit with this code in `bench/events`.
    pub fn from_code(code: i32) -> Option<LimitKind> {
        Self::ALL.into_iter().find(|k| k.code() == code)
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// One limit: its threshold, its response and how long it must be exceeded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limit {
    /// The threshold, in the limit's [`LimitKind::unit`].
    pub limit: f64,
    /// What a trip does.
    pub response: Response,
    /// How long the threshold must be passed before it trips, s.
    pub hold_s: f64,
}

/// How thrust follows RPM, for the thrust-against-RPM check: a turbojet's
/// thrust grows with the square of its shaft speed above idle,
/// `thrust ≈ ((rpm − idle_rpm) / rpm_per_sqrt_n)²`, the RPM reading lagging
/// the thrust by a first-order lag of `lag_s` in `√thrust` (the ECU's
/// filtering and its poll; the emulated P100's RPM lags by 0.6 s). The
/// check compares the RPM's thrust with the thrust passed through the same
/// lag ([`ThrustLag`]), so a step of the engine is no disagreement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RpmMap {
    /// Shaft speed at zero thrust, rpm.
    pub idle_rpm: f64,
    /// RPM above idle per √N of thrust.
    pub rpm_per_sqrt_n: f64,
    /// The RPM reading's lag behind the thrust, s.
    pub lag_s: f64,
}

impl RpmMap {
    /// The thrust `rpm` stands for, N.
    pub fn thrust_n(&self, rpm: f64) -> f64 {
        let above = ((rpm - self.idle_rpm) / self.rpm_per_sqrt_n).max(0.0);
        above * above
    }
}

/// The thrust as the RPM reading would show it: `√thrust` through a
/// first-order lag of [`RpmMap::lag_s`], squared. Fed each thrust estimate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ThrustLag {
    lag_s: f64,
    last: Option<(u64, f64)>,
}

impl ThrustLag {
    /// A lag of `lag_s` (0: none), starting at the first thrust it is fed.
    pub fn new(lag_s: f64) -> Self {
        ThrustLag { lag_s, last: None }
    }

    /// The lagged thrust after a thrust estimate at `now_ns`, N.
    pub fn step(&mut self, now_ns: u64, thrust_n: f64) -> f64 {
        let x = thrust_n.max(0.0).sqrt();
        let lagged = match self.last {
            Some((t0, y)) if self.lag_s > 0.0 => {
                let dt = now_ns.saturating_sub(t0) as f64 * 1e-9;
                y + (1.0 - (-dt / self.lag_s).exp()) * (x - y)
            }
            _ => x,
        };
        self.last = Some((now_ns, lagged));
        lagged * lagged
    }
}

/// How the emulated engine's RPM lags its thrust (its ECU's
/// [`jetbench_io::ecu::emulator::RPM_TAU_S`]), the presets' `lag_s`.
pub const EMULATED_RPM_LAG_S: f64 = jetbench_io::ecu::emulator::RPM_TAU_S;

/// The checked `[limits]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Limits {
    entries: [Option<Limit>; 8],
    /// The engine's thrust–RPM relation, needed by `thrust_rpm_band_n`.
    pub rpm_map: Option<RpmMap>,
}

/// A `[limits]` that cannot be used: which key, and why.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LimitsError {
    /// A key `[limits]` does not have (a typo, usually).
    #[error("[limits] unknown key `{key}`{}; the keys are preset, {}", suggest(.suggestion), keys())]
    UnknownKey {
        /// The key as written.
        key: String,
        /// The nearest key there is.
        suggestion: Option<&'static str>,
    },
    /// A key a limit's table does not have.
    #[error("[limits] {entry}: unknown key `{key}`{}; an entry has limit, response and hold_s{}", suggest(.suggestion), if *.entry == "thrust_rpm_band_n" { " (and idle_rpm, rpm_per_sqrt_n, lag_s)" } else { "" })]
    UnknownEntryKey {
        /// The limit's key.
        entry: &'static str,
        /// The key as written inside it.
        key: String,
        /// The nearest key there is.
        suggestion: Option<&'static str>,
    },
    /// A value out of range or of the wrong type.
    #[error("[limits] {key}: {message}")]
    Invalid {
        /// The key concerned.
        key: String,
        /// What is wrong and what is allowed.
        message: String,
    },
    /// `preset` names no preset.
    #[error("[limits] preset = {0:?} is not a preset; the presets are \"p100\" and \"p220\"")]
    UnknownPreset(String),
}

fn suggest(s: &Option<&'static str>) -> String {
    s.map_or_else(String::new, |s| format!(" (did you mean `{s}`?)"))
}

fn keys() -> String {
    LimitKind::ALL.iter().map(|k| k.key()).collect::<Vec<_>>().join(", ")
}

/// The closest of `candidates` to `key`, if it is close (a typo).
fn closest(key: &str, candidates: &[&'static str]) -> Option<&'static str> {
    candidates
        .iter()
        .map(|c| (strsim::levenshtein(key, c), *c))
        .filter(|(d, c)| *d <= (c.len() / 3).max(2))
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

const ENTRY_KEYS: [&str; 3] = ["limit", "response", "hold_s"];
const MAP_KEYS: [&str; 3] = ["idle_rpm", "rpm_per_sqrt_n", "lag_s"];

impl Limits {
    /// The defaults for a JetCat P100 or P220 (`preset`), with the emulated
    /// engine's RPM map. EGT and RPM limits sit below the ECU's own, so the
    /// stack acts first.
    pub fn preset(name: &str) -> Option<Limits> {
        let (max_thrust_n, band_n, full_n) = match name {
            "p100" => (115.0, 25.0, 100.0),
            "p220" => (250.0, 45.0, 220.0),
            _ => return None,
        };
        let l = |limit, response, hold_s| Some(Limit { limit, response, hold_s });
        use Response::{Idle, Shutdown};
        let idle_rpm = 35_000.0;
        Some(Limits {
            entries: [
                l(max_thrust_n, Idle, 0.1),
                l(780.0, Shutdown, 0.3),
                l(400.0, Idle, 0.3),
                l(122_000.0, Shutdown, 0.2),
                l(30_000.0, Shutdown, 0.5),
                l(band_n, Idle, 1.0),
                l(0.5, Idle, 0.0),
                l(0.1, Idle, 0.0),
            ],
            rpm_map: Some(RpmMap {
                idle_rpm,
                rpm_per_sqrt_n: (115_000.0 - idle_rpm) / f64::sqrt(full_n),
                lag_s: EMULATED_RPM_LAG_S,
            }),
        })
    }

    /// True when no limit is set.
    pub fn is_empty(&self) -> bool {
        self.entries.iter().all(Option::is_none)
    }

    /// The limit of `kind`, if set.
    pub fn get(&self, kind: LimitKind) -> Option<Limit> {
        self.entries[kind.index()]
    }

    /// Sets (or, with `None`, clears) the limit of `kind`.
    pub fn set(&mut self, kind: LimitKind, limit: Option<Limit>) {
        self.entries[kind.index()] = limit;
    }

    /// Parses `[limits]`: an optional `preset`, then entries that override it.
    pub fn from_table(table: &toml::Table) -> Result<Limits, LimitsError> {
        let mut limits = match table.get("preset") {
            None => Limits::default(),
            Some(toml::Value::String(name)) => {
                Limits::preset(name).ok_or_else(|| LimitsError::UnknownPreset(name.clone()))?
            }
            Some(other) => return Err(LimitsError::UnknownPreset(other.to_string())),
        };
        let names: Vec<&'static str> =
            std::iter::once("preset").chain(LimitKind::ALL.iter().map(|k| k.key())).collect();
        for (key, value) in table {
            if key == "preset" {
                continue;
            }
            let Some(kind) = LimitKind::ALL.into_iter().find(|k| k.key() == key) else {
                return Err(LimitsError::UnknownKey { key: key.clone(), suggestion: closest(key, &names) });
            };
            let entry = kind.key();
            let invalid = |message: String| LimitsError::Invalid { key: entry.into(), message };
            let t = match value {
                toml::Value::String(s) if s == "off" => {
                    limits.set(kind, None);
                    continue;
                }
                toml::Value::Table(t) => t,
                other => {
                    return Err(invalid(format!(
                        "{other} is neither a table {{ limit = ..., response = \"idle\"|\"shutdown\", hold_s = ... }} nor \"off\""
                    )))
                }
            };
            let allowed: Vec<&'static str> = if kind == LimitKind::ThrustRpmBand {
                ENTRY_KEYS.iter().chain(MAP_KEYS.iter()).copied().collect()
            } else {
                ENTRY_KEYS.to_vec()
            };
            for k in t.keys() {
                if !allowed.contains(&k.as_str()) {
                    return Err(LimitsError::UnknownEntryKey {
                        entry,
                        key: k.clone(),
                        suggestion: closest(k, &allowed),
                    });
                }
            }
            let number = |k: &str| -> Result<Option<f64>, LimitsError> {
                match t.get(k) {
                    None => Ok(None),
                    Some(toml::Value::Float(v)) => Ok(Some(*v)),
                    Some(toml::Value::Integer(v)) => Ok(Some(*v as f64)),
                    Some(other) => Err(invalid(format!("{k} = {other} is not a number"))),
                }
            };
            let base = limits.get(kind);
            let limit = number("limit")?
                .or(base.map(|b| b.limit))
                .ok_or_else(|| invalid("needs `limit` (no preset gives it)".into()))?;
            let hold_s = number("hold_s")?.or(base.map(|b| b.hold_s)).unwrap_or(0.0);
            let response = match t.get("response") {
                None => base.map_or(Response::Idle, |b| b.response),
                Some(toml::Value::String(r)) if r == "idle" => Response::Idle,
                Some(toml::Value::String(r)) if r == "shutdown" => Response::Shutdown,
                Some(other) => return Err(invalid(format!("response = {other}: it is \"idle\" or \"shutdown\""))),
            };
            if !(limit.is_finite() && limit > 0.0) {
                return Err(invalid(format!("limit = {limit} must be a positive number ({})", kind.unit())));
            }
            if !(hold_s.is_finite() && (0.0..=60.0).contains(&hold_s)) {
                return Err(invalid(format!("hold_s = {hold_s} must be within 0..60 s")));
            }
            limits.set(kind, Some(Limit { limit, response, hold_s }));
            if kind == LimitKind::ThrustRpmBand {
                let base = limits.rpm_map;
                let idle_rpm = number("idle_rpm")?.or(base.map(|m| m.idle_rpm));
                let per = number("rpm_per_sqrt_n")?.or(base.map(|m| m.rpm_per_sqrt_n));
                let lag_s = number("lag_s")?.or(base.map(|m| m.lag_s)).unwrap_or(0.0);
                if !(lag_s.is_finite() && (0.0..=10.0).contains(&lag_s)) {
                    return Err(invalid(format!("lag_s = {lag_s} must be within 0..10 s")));
                }
                match (idle_rpm, per) {
                    (Some(idle_rpm), Some(rpm_per_sqrt_n))
                        if idle_rpm.is_finite()
                            && idle_rpm >= 0.0
                            && rpm_per_sqrt_n.is_finite()
                            && rpm_per_sqrt_n > 0.0 =>
                    {
                        limits.rpm_map = Some(RpmMap { idle_rpm, rpm_per_sqrt_n, lag_s });
                    }
                    (Some(_), Some(_)) => {
                        return Err(invalid("idle_rpm must be >= 0 and rpm_per_sqrt_n > 0".into()));
                    }
                    _ => return Err(invalid("needs idle_rpm and rpm_per_sqrt_n (how thrust follows RPM)".into())),
                }
            }
        }
        if let (Some(max), Some(min)) = (limits.get(LimitKind::MaxRpm), limits.get(LimitKind::MinRpm)) {
            if min.limit >= max.limit {
                return Err(LimitsError::Invalid {
                    key: "min_rpm".into(),
                    message: format!("limit = {} must be below max_rpm's {}", min.limit, max.limit),
                });
            }
        }
        Ok(limits)
    }
}

/// A limit that tripped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trip {
    /// Which limit.
    pub kind: LimitKind,
    /// What the trip does.
    pub response: Response,
    /// The value past the limit, in the limit's unit.
    pub value: f64,
    /// The limit it passed.
    pub limit: f64,
    /// When the limit was first exceeded, monotonic ns.
    pub since_ns: u64,
    /// When it tripped (after its hold), monotonic ns.
    pub at_ns: u64,
}

impl fmt::Display for Trip {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let unit = self.kind.unit();
        write!(
            f,
            "{} ({}): {:.1} {unit} against {:.1} {unit}, response {}",
            self.kind.key(),
            self.kind.describe(),
            self.value,
            self.limit,
            self.response
        )
    }
}

/// Checks the limits cycle after cycle; each trip is reported once and
/// latched until [`LimitMonitor::clear`].
#[derive(Clone, Debug)]
pub struct LimitMonitor {
    limits: Limits,
    /// Since when each limit has been exceeded (monotonic ns).
    since: [Option<u64>; 8],
    latched: [bool; 8],
    /// The newest thrust estimate and when it came.
    thrust: Option<(u64, f64)>,
    /// The thrust as the RPM would show it (the map's lag), and the newest.
    lag: ThrustLag,
    lagged_n: Option<f64>,
    /// The newest fresh ECU reading and when it came.
    ecu: Option<(u64, EcuTelemetry)>,
    /// The fresh EGT readings of the last [`EGT_RATE_WINDOW_NS`] (and the one
    /// before), the rise rate is measured over.
    egt_history: VecDeque<(u64, f64)>,
    egt_rate: f64,
    started_ns: Option<u64>,
}

/// The window an EGT rise rate is measured over, ns: the rate is the slope
/// from the newest reading at least this old to the newest reading, so it is
/// fresh at every reading and a single noisy reading cannot make it.
pub const EGT_RATE_WINDOW_NS: u64 = 250_000_000;

/// How long the monitor waits for the first sample of the sensor and the ECU
/// before their silence counts, ns: the services of a set start in any order.
pub const STARTUP_GRACE_NS: u64 = 2_000_000_000;

impl LimitMonitor {
    /// A monitor of `limits`, nothing seen yet.
    pub fn new(limits: Limits) -> Self {
        let lag = ThrustLag::new(limits.rpm_map.map_or(0.0, |m| m.lag_s));
        LimitMonitor {
            limits,
            since: [None; 8],
            latched: [false; 8],
            thrust: None,
            lag,
            lagged_n: None,
            ecu: None,
            egt_history: VecDeque::new(),
            egt_rate: 0.0,
            started_ns: None,
        }
    }

    /// The limits it watches.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// A thrust estimate at `now_ns`.
    pub fn on_thrust(&mut self, now_ns: u64, thrust_n: f64) {
        if thrust_n.is_finite() {
            self.thrust = Some((now_ns, thrust_n));
            self.lagged_n = Some(self.lag.step(now_ns, thrust_n));
        }
    }

    /// An ECU sample (stale ones only count as silence).
    pub fn on_ecu(&mut self, now_ns: u64, t: &EcuTelemetry) {
        if t.flags & (ecu_flags::STALE | ecu_flags::SILENT) != 0 {
            return;
        }
        self.ecu = Some((now_ns, *t));
        let h = &mut self.egt_history;
        h.push_back((now_ns, t.egt_c));
        // Keep the newest reading at least a window old, and everything after it.
        while h.len() > 2 && h[1].0.saturating_add(EGT_RATE_WINDOW_NS) <= now_ns {
            h.pop_front();
        }
        self.egt_rate = match h.front() {
            Some(&(t0, egt0)) if now_ns.saturating_sub(t0) >= EGT_RATE_WINDOW_NS => {
                (t.egt_c - egt0) / (now_ns - t0) as f64 * 1e9
            }
            _ => 0.0,
        };
    }

    /// Any limit latched.
    pub fn tripped(&self) -> bool {
        self.latched.iter().any(|l| *l)
    }

    /// Clears the latched trips; a limit still exceeded trips again after its hold.
    pub fn clear(&mut self) {
        self.latched = [false; 8];
        self.since = [None; 8];
    }

    /// The limits at `now_ns`, `running` while the ECU says run: the trips
    /// that happened now (each once until cleared). Made where every force
    /// sample that has arrived has been taken ([`LimitMonitor::on_thrust`]),
    /// so the sensor's silence is what it seems.
    pub fn check(&mut self, now_ns: u64, running: bool) -> Vec<Trip> {
        self.check_with(now_ns, running, true)
    }

    /// The limits at `now_ns` except the sensor's silence, for a check made
    /// before the samples waiting for the caller are taken: the age of the
    /// newest sample is not known yet, and a caller woken late would count its
    /// own lateness as the sensor's silence. Its clock keeps running: the next
    /// [`LimitMonitor::check`] judges it.
    pub fn check_before_samples(&mut self, now_ns: u64, running: bool) -> Vec<Trip> {
        self.check_with(now_ns, running, false)
    }

    fn check_with(&mut self, now_ns: u64, running: bool, sensor_known: bool) -> Vec<Trip> {
        let started = *self.started_ns.get_or_insert(now_ns);
        let mut trips = Vec::new();
        let ecu = self.ecu.map(|(at, t)| (at, t.rpm, t.egt_c));
        let thrust = self.thrust;
        // A silence counts from the last sample; before the first, from the
        // monitor's start plus the time a set takes to bring its services up
        // (a sensor never heard still trips, [`STARTUP_GRACE_NS`] late).
        let age_s = |at: Option<u64>| {
            now_ns.saturating_sub(at.unwrap_or(started.saturating_add(STARTUP_GRACE_NS))) as f64 * 1e-9
        };
        for kind in LimitKind::ALL {
            let Some(limit) = self.limits.get(kind) else { continue };
            if kind == LimitKind::SensorSilent && !sensor_known {
                continue;
            }
            let value = match kind {
                LimitKind::MaxThrust => thrust.map(|(_, t)| t).filter(|t| *t > limit.limit),
                LimitKind::MaxEgt => ecu.map(|(_, _, egt)| egt).filter(|e| *e > limit.limit),
                LimitKind::MaxEgtRise => Some(self.egt_rate).filter(|r| ecu.is_some() && *r > limit.limit),
                LimitKind::MaxRpm => ecu.map(|(_, rpm, _)| rpm).filter(|r| *r > limit.limit),
                LimitKind::MinRpm => ecu.map(|(_, rpm, _)| rpm).filter(|r| running && *r < limit.limit),
                LimitKind::ThrustRpmBand => match (self.limits.rpm_map, ecu, self.lagged_n, running) {
                    (Some(map), Some((_, rpm, _)), Some(t), true) => {
                        Some((t - map.thrust_n(rpm)).abs()).filter(|d| *d > limit.limit)
                    }
                    _ => None,
                },
                LimitKind::EcuSilent => Some(age_s(ecu.map(|e| e.0))).filter(|s| *s > limit.limit),
                LimitKind::SensorSilent => Some(age_s(thrust.map(|t| t.0))).filter(|s| *s > limit.limit),
            };
            let i = kind.index();
            match value {
                None => self.since[i] = None,
                Some(value) => {
                    let since = *self.since[i].get_or_insert(now_ns);
                    if !self.latched[i] && now_ns.saturating_sub(since) as f64 * 1e-9 >= limit.hold_s {
                        self.latched[i] = true;
                        trips.push(Trip {
                            kind,
                            response: limit.response,
                            value,
                            limit: limit.limit,
                            since_ns: since,
                            at_ns: now_ns,
                        });
                    }
                }
            }
        }
        trips
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(text: &str) -> toml::Table {
        toml::from_str(text).unwrap()
    }

    #[test]
    fn a_preset_loads_and_an_entry_overrides_it() {
        let l = Limits::from_table(&table(
            "preset = \"p100\"\nmax_egt_c = { limit = 700, hold_s = 0.5 }\nsensor_silent_s = \"off\"",
        ))
        .unwrap();
        assert_eq!(l.get(LimitKind::MaxEgt), Some(Limit { limit: 700.0, response: Response::Shutdown, hold_s: 0.5 }));
        assert_eq!(l.get(LimitKind::SensorSilent), None);
        assert_eq!(l.get(LimitKind::MaxThrust).unwrap().limit, 115.0);
        assert!(Limits::from_table(&table("")).unwrap().is_empty());
    }

    #[test]
    fn typos_and_bad_values_name_the_key() {
        let e = Limits::from_table(&table("max_egt = { limit = 700 }")).unwrap_err().to_string();
        assert!(e.contains("`max_egt`") && e.contains("did you mean `max_egt_c`"), "{e}");
        let e = Limits::from_table(&table("max_rpm = { limit = 1e5, hold = 1 }")).unwrap_err().to_string();
        assert!(e.contains("[limits] max_rpm") && e.contains("did you mean `hold_s`"), "{e}");
        let e = Limits::from_table(&table("max_rpm = { limit = 1e5, response = \"stop\" }")).unwrap_err().to_string();
        assert!(e.contains("[limits] max_rpm") && e.contains("\"idle\" or \"shutdown\""), "{e}");
        let e = Limits::from_table(&table("max_thrust_n = { limit = -5 }")).unwrap_err().to_string();
        assert!(e.contains("max_thrust_n") && e.contains("positive"), "{e}");
        let e = Limits::from_table(&table("preset = \"p300\"")).unwrap_err().to_string();
        assert!(e.contains("p100"), "{e}");
        let e = Limits::from_table(&table("thrust_rpm_band_n = { limit = 20 }")).unwrap_err().to_string();
        assert!(e.contains("idle_rpm"), "{e}");
        let e = Limits::from_table(&table("preset = \"p100\"\nmin_rpm = { limit = 130000 }")).unwrap_err().to_string();
        assert!(e.contains("min_rpm") && e.contains("below max_rpm"), "{e}");
    }

    fn ecu(rpm: f64, egt_c: f64) -> EcuTelemetry {
        EcuTelemetry { rpm, egt_c, state: 11, ..Default::default() }
    }

    /// Feeds cycles `ks` (10 ms apart) with `feed` and checks after each: the first trip of `kind`.
    fn first_trip(
        m: &mut LimitMonitor,
        ks: std::ops::Range<u64>,
        kind: LimitKind,
        mut feed: impl FnMut(&mut LimitMonitor, u64),
    ) -> Option<Trip> {
        let mut first = None;
        for k in ks {
            let t = k * 10_000_000;
            feed(m, t);
            first = first.or(m.check(t, true).into_iter().find(|trip| trip.kind == kind));
        }
        first
    }

    #[test]
    fn a_limit_trips_after_its_hold_once_and_latches_until_cleared() {
        let mut m = LimitMonitor::new(Limits::preset("p100").unwrap());
        let ms = 1_000_000u64;
        let mut trips = Vec::new();
        for k in 0..100u64 {
            let t = k * 10 * ms;
            m.on_thrust(t, 50.0);
            let egt = if k >= 20 { 790.0 } else { 700.0 };
            m.on_ecu(t, &ecu(91_000.0, egt));
            trips.extend(m.check(t, true));
        }
        let egt: Vec<_> = trips.iter().filter(|t| t.kind == LimitKind::MaxEgt).collect();
        assert_eq!(egt.len(), 1, "{trips:?}");
        // Exceeded from 200 ms, hold 0.3 s: trips at 500 ms.
        assert_eq!((egt[0].since_ns, egt[0].at_ns), (200 * ms, 500 * ms));
        assert_eq!(egt[0].response, Response::Shutdown);
        assert!(m.tripped());
        m.clear();
        assert!(!m.tripped());
    }

    #[test]
    fn silence_and_thrust_against_rpm_trip_and_a_healthy_engine_does_not() {
        // RPM that follows thrust at once: no lag in the map.
        let mut limits = Limits::preset("p100").unwrap();
        limits.rpm_map = limits.rpm_map.map(|m| RpmMap { lag_s: 0.0, ..m });
        let map = limits.rpm_map.unwrap();
        let mut m = LimitMonitor::new(limits);
        let ms = 1_000_000u64;
        // Healthy: thrust and RPM agree.
        for k in 0..300u64 {
            let t = k * 10 * ms;
            let thrust = 20.0 + 60.0 * ((k as f64) * 0.01).sin().abs();
            m.on_thrust(t, thrust);
            m.on_ecu(t, &ecu(map.idle_rpm + map.rpm_per_sqrt_n * thrust.sqrt(), 600.0));
            assert_eq!(m.check(t, true), vec![], "at {k}");
        }
        // The sensor reads 40 N too much: the band trips after its 1 s hold.
        let band = first_trip(&mut m, 300..500, LimitKind::ThrustRpmBand, |m, t| {
            m.on_thrust(t, 80.0);
            m.on_ecu(t, &ecu(map.idle_rpm + map.rpm_per_sqrt_n * 40f64.sqrt(), 600.0));
        });
        let band = band.expect("the band trips");
        assert_eq!(band.at_ns - band.since_ns, 1000 * ms);
        // Then the sensor falls silent: 0.1 s later it trips.
        let silent = first_trip(&mut m, 500..600, LimitKind::SensorSilent, |m, t| m.on_ecu(t, &ecu(90_000.0, 600.0)));
        let silent = silent.expect("sensor silence trips");
        assert!(silent.value > 0.1 && silent.value < 0.12, "{silent}");
    }

    #[test]
    fn the_egt_rise_is_a_slope_over_a_quarter_second_fresh_at_every_reading() {
        let mut m = LimitMonitor::new(Limits::preset("p100").unwrap());
        let ms = 1_000_000u64;
        let mut rise = None;
        // 15 Hz readings (66 ms): steady at 400 °C with one reading 60 °C off
        // (noise, 230 °C/s over the window: no trip), then from 2 s a rise of
        // 800 °C/s, levelling off at 770 °C (below max_egt_c).
        for k in 0..60u64 {
            let t = k * 66 * ms;
            let egt = match k {
                10 => 460.0,
                _ if t >= 2000 * ms => 400.0 + 0.8 * (t - 2000 * ms) as f64 / ms as f64,
                _ => 400.0,
            };
            m.on_ecu(t, &ecu(90_000.0, egt.min(770.0)));
            m.on_thrust(t, 50.0);
            for trip in m.check(t, true) {
                assert_eq!(trip.kind, LimitKind::MaxEgtRise, "{trip}");
                rise = rise.or(Some(trip));
            }
        }
        let rise = rise.expect("the rise trips");
        // Exceeded from the first reading whose window holds the rise long enough, tripped 0.3 s later.
        assert!(rise.since_ns > 2000 * ms && rise.since_ns < 2300 * ms, "{rise:?}");
        assert!(rise.at_ns - rise.since_ns >= 300 * ms && rise.at_ns - rise.since_ns < 370 * ms, "{rise:?}");
    }

    #[test]
    fn a_sensor_not_yet_heard_trips_only_after_the_startup_grace() {
        let mut m = LimitMonitor::new(Limits::preset("p100").unwrap());
        let ms = 1_000_000u64;
        let mut silent = None;
        for k in 0..300u64 {
            let t = k * 10 * ms;
            m.on_ecu(t, &ecu(40_000.0, 500.0));
            for trip in m.check(t, true) {
                silent = silent.or(Some(trip));
            }
        }
        let silent = silent.expect("a sensor never heard trips");
        assert_eq!(silent.kind, LimitKind::SensorSilent, "{silent}");
        // The grace (2 s) and the limit (0.1 s): not before 2.1 s.
        assert!(silent.at_ns > 2100 * ms && silent.at_ns <= 2120 * ms, "{silent:?}");
    }
}
