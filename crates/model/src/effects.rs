//! Physics the ten-parameter model leaves out (docs/model/README.md, "Effects the ten
//! parameters leave out"), each a small extension with few parameters.
//!
//! The effects act on the way in (the throttle the engine follows), in the engine
//! (extra acceleration) or on the way out (the force the sensor reads), in a fixed
//! physical order ([`crate::Plant`] simulates them):
//!
//! ```text
//! u ─ input_delay ─ rate_limit ─ actuator_lag ─ v(u)·(1 − gain_drift·t) (+ discrepancy) ─ engine T
//!                                                         (Ṫ within accel_schedule's bounds)
//! T ─ bearing_friction (play band) ─ stand_resonance ─ + sensor_drift bias ─ measured thrust
//! ```
//!
//! Every effect has wide bounds a model file must respect (a typo like `delay_s = 80`
//! is an error) and a narrower *physical range* with a sign ([`EffectKind::physical`]):
//! what a bench can have. A fit outside the physical range is evidence that something
//! is there, not a claim that this physics is.
//!
//! ```
//! use jetbench_model::{Effect, EffectKind};
//!
//! let drift: Effect = "sensor_drift:gain=0.03,time_constant_s=40".parse()?;
//! assert!(drift.unphysical().is_none());
//! let cooling: Effect = "sensor_drift:gain=-0.03,time_constant_s=1.8".parse()?;
//! assert!(cooling.unphysical().unwrap().contains("gain"));
//! assert_eq!(EffectKind::CATALOGUE.len(), 7);
//! # Ok::<(), jetbench_model::ModelError>(())
//! ```

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use crate::discrepancy::{
    discrepancy_key_active, DISCREPANCY_BOUNDS, DISCREPANCY_DEFAULTS, DISCREPANCY_KEYS, DISCREPANCY_TERMS,
};
use crate::ModelError;

/// Which physics an [`Effect`] adds. Names and parameter keys are part of the model-file
/// and JSON contract.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum EffectKind {
    /// The engine follows `u(t − delay_s)`: ECU processing and fuel transport.
    InputDelay,
    /// First-order lag on the throttle: fuel-pump dynamics.
    ActuatorLag,
    /// The throttle the engine follows changes no faster than the ECU's schedule.
    RateLimit,
    /// Measured thrust `T + b`, `ḃ = (gain·T − b)/time_constant_s`: the sensor heats.
    SensorDrift,
    /// `v(u)` scaled by `1 − per_minute·t/60`: fuel pressure or pump voltage sags.
    GainDrift,
    /// The measured force follows `T` only once they differ by more than `force_n`.
    BearingFriction,
    /// The sensor reads the frame through a mass-spring: `ẍ = ω²(F − x) − 2ζω·ẋ`.
    StandResonance,
    /// Extra acceleration from named terms (see [`crate::discrepancy`]): physics outside
    /// the catalogue.
    Discrepancy,
    /// The thrust rate stays within bounds that grow with the thrust: the ECU's fuel
    /// schedule pacing the spool, which a throttle rate limit does not describe. Model
    /// structure that `identify` may choose; not one of the catalogue's hypotheses.
    AccelSchedule,
}

impl EffectKind {
    /// Every kind, in the order of the signal path (and of model files).
    pub const ALL: [EffectKind; 9] = [
        EffectKind::InputDelay,
        EffectKind::RateLimit,
        EffectKind::ActuatorLag,
        EffectKind::GainDrift,
        EffectKind::Discrepancy,
        EffectKind::AccelSchedule,
        EffectKind::BearingFriction,
        EffectKind::StandResonance,
        EffectKind::SensorDrift,
    ];

    /// The named physics a diagnosis weighs: every kind but the generic
    /// [`EffectKind::Discrepancy`] and the structure [`EffectKind::AccelSchedule`].
    pub const CATALOGUE: [EffectKind; 7] = [
        EffectKind::InputDelay,
        EffectKind::RateLimit,
        EffectKind::ActuatorLag,
        EffectKind::GainDrift,
        EffectKind::BearingFriction,
        EffectKind::StandResonance,
        EffectKind::SensorDrift,
    ];

    /// True for an effect on the reading alone (the bearing's play, the stand, the
    /// sensor's drift): the engine runs the same with or without it, so a simulation may
    /// keep the engine's path and run only the sensor side again ([`crate::Plant::replay_sensor`]).
    pub fn is_sensor_side(self) -> bool {
        matches!(self, EffectKind::SensorDrift | EffectKind::BearingFriction | EffectKind::StandResonance)
    }

    /// Name in model files (`[effects.<name>]`), on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            EffectKind::InputDelay => "input_delay",
            EffectKind::ActuatorLag => "actuator_lag",
            EffectKind::RateLimit => "rate_limit",
            EffectKind::SensorDrift => "sensor_drift",
            EffectKind::GainDrift => "gain_drift",
            EffectKind::BearingFriction => "bearing_friction",
            EffectKind::StandResonance => "stand_resonance",
            EffectKind::Discrepancy => "discrepancy",
            EffectKind::AccelSchedule => "accel_schedule",
        }
    }

    /// Parameter keys, in the order of [`Effect::values`].
    pub fn keys(self) -> &'static [&'static str] {
        match self {
            EffectKind::InputDelay => &["delay_s"],
            EffectKind::ActuatorLag => &["time_constant_s"],
            EffectKind::RateLimit => &["up_pct_per_s", "down_pct_per_s"],
            EffectKind::SensorDrift => &["gain", "time_constant_s"],
            EffectKind::GainDrift => &["per_minute"],
            EffectKind::BearingFriction => &["force_n"],
            EffectKind::StandResonance => &["frequency_hz", "damping_ratio"],
            EffectKind::Discrepancy => &DISCREPANCY_KEYS,
            EffectKind::AccelSchedule => &["up_n_per_s", "down_n_per_s", "exponent", "offset_n"],
        }
    }

    /// The range each parameter may take in a model file (inclusive), in the order of
    /// [`EffectKind::keys`]: wide, so a typo like `delay_s = 80` is caught.
    pub fn bounds(self) -> &'static [(f64, f64)] {
        match self {
            EffectKind::InputDelay => &[(0.0, 2.0)],
            EffectKind::ActuatorLag => &[(0.0, 10.0)],
            EffectKind::RateLimit => &[(0.1, 10_000.0), (0.1, 10_000.0)],
            EffectKind::SensorDrift => &[(-1.0, 1.0), (0.1, 3600.0)],
            EffectKind::GainDrift => &[(-0.2, 0.2)],
            EffectKind::BearingFriction => &[(0.0, 50.0)],
            EffectKind::StandResonance => &[(0.05, 200.0), (0.001, 10.0)],
            EffectKind::Discrepancy => &DISCREPANCY_BOUNDS,
            EffectKind::AccelSchedule => &[(0.1, 100_000.0), (0.1, 100_000.0), (0.0, 4.0), (0.0, 200.0)],
        }
    }

    /// What a bench can have (inclusive ranges, in the order of [`EffectKind::keys`]),
    /// with the sign the physics gives:
    ///
    /// - `input_delay`: 5–500 ms (ECU processing and fuel transport, tens of ms).
    /// - `actuator_lag`: 0.02–2 s (fuel pump, 0.1–0.5 s typical).
    /// - `rate_limit`: 2–1000 %/s each way (slower than that is no ECU schedule, faster
    ///   is no limit at 100 Hz).
    /// - `sensor_drift`: gain 0–0.2 (a sensor that heats reads high under load),
    ///   time constant 5–1800 s (thermal, never seconds).
    /// - `gain_drift`: 0–0.05 per minute (a gain that sags over a run).
    /// - `bearing_friction`: 0–10 N.
    /// - `stand_resonance`: 0.5–45 Hz (below the 50 Hz Nyquist limit), damping 0.005–0.3
    ///   (lightly damped: it rings; a heavily damped one is a lag, not a resonance).
    /// - `discrepancy`: knots within the throttle range 25–100 %, history 2–1800 s,
    ///   coefficients as in files.
    /// - `accel_schedule`: 5–20 000 N/s each way at 100 N (a full step of a model jet
    ///   takes tenths of a second to seconds), exponent 0–3 (a spool's acceleration margin
    ///   grows with its speed), offset 0–100 N.
    pub fn physical(self) -> &'static [(f64, f64)] {
        match self {
            EffectKind::InputDelay => &[(0.005, 0.5)],
            EffectKind::ActuatorLag => &[(0.02, 2.0)],
            EffectKind::RateLimit => &[(2.0, 1000.0), (2.0, 1000.0)],
            EffectKind::SensorDrift => &[(0.0, 0.2), (5.0, 1800.0)],
            EffectKind::GainDrift => &[(0.0, 0.05)],
            EffectKind::BearingFriction => &[(0.0, 10.0)],
            EffectKind::StandResonance => &[(0.5, 45.0), (0.005, 0.3)],
            EffectKind::Discrepancy => &[
                (-5.0, 5.0),
                (25.0, 100.0),
                (-5.0, 5.0),
                (25.0, 100.0),
                (-0.1, 0.1),
                (2.0, 1800.0),
                (-0.01, 0.01),
                (-0.01, 0.01),
                (-0.01, 0.01),
                // A run-down from a tenth to three times the run-up's pace.
                (-0.9, 2.0),
                (-0.1, 0.1),
                (2.0, 1800.0),
            ],
            EffectKind::AccelSchedule => &[(5.0, 20_000.0), (5.0, 20_000.0), (0.0, 3.0), (0.0, 100.0)],
        }
    }

    /// One line of physics, for help texts and reports.
    pub fn physics(self) -> &'static str {
        match self {
            EffectKind::InputDelay => "ECU processing and fuel transport delay the throttle",
            EffectKind::ActuatorLag => "fuel-pump dynamics smear the throttle (first-order lag)",
            EffectKind::RateLimit => "the ECU's acceleration/deceleration schedule limits how fast the throttle moves",
            EffectKind::SensorDrift => "the force sensor heats with the exhaust: a bias follows thrust slowly",
            EffectKind::GainDrift => {
                "fuel pressure or pump voltage sags: the same throttle gives less thrust over the run"
            }
            EffectKind::BearingFriction => "Coulomb friction of the frame's linear bearings: a play band on the force",
            EffectKind::StandResonance => "frame and sensor form a lightly damped mass-spring: the reading rings",
            EffectKind::Discrepancy => {
                "physics outside the catalogue as extra thrust acceleration from named terms (throttle-map hinges, \
                 gain following thrust history, input gain in T², Ṫ², T·Ṫ, spool-down slower or faster than spool-up)"
            }
            EffectKind::AccelSchedule => {
                "the ECU's fuel schedule paces the spool: the thrust may rise or fall only so fast, more slowly at \
                 low thrust"
            }
        }
    }

    /// What the effect does to the model, as a formula in words.
    pub fn formula(self) -> &'static str {
        match self {
            EffectKind::InputDelay => "the engine follows u(t − delay_s)",
            EffectKind::ActuatorLag => "first-order lag on u",
            EffectKind::RateLimit => "the throttle moves no faster than up/down_pct_per_s",
            EffectKind::SensorDrift => "measured = T + b, ḃ = (gain·T − b)/time_constant_s",
            EffectKind::GainDrift => "v(u) scaled by (1 − per_minute·t/60)",
            EffectKind::BearingFriction => "the measured force follows T only beyond a play band of ±force_n",
            EffectKind::StandResonance => "the sensor reads the frame through ẍ = ω²(F − x) − 2ζω·ẋ",
            EffectKind::Discrepancy => "extra thrust acceleration from named terms",
            EffectKind::AccelSchedule => {
                "Ṫ kept within ±up/down_n_per_s·s^exponent, s = max((T + offset_n)/100 N, 0.05)"
            }
        }
    }

    /// The physical range ([`EffectKind::physical`]) in words: `key lo–hi` per parameter
    /// (the discrepancy's knots only: its coefficients are as in files).
    pub fn physical_text(self) -> String {
        let ranges = self.keys().iter().zip(self.physical());
        let shown: Vec<String> = match self {
            EffectKind::Discrepancy => ranges
                .filter(|(key, _)| key.starts_with("knot_"))
                .map(|(key, (lo, hi))| format!("{key} {lo}–{hi}"))
                .collect(),
            _ => ranges.map(|(key, (lo, hi))| format!("{key} {lo}–{hi}")).collect(),
        };
        shown.join(", ")
    }

    /// The catalogue as the Markdown table of docs/model/README.md: name, parameters with the bounds a
    /// model file must respect, what the effect does, the physics, the physical range.
    /// A test fails when that table differs.
    pub fn catalogue_markdown() -> String {
        let mut table = String::from(
            "| name | parameters (bounds in a model file) | what it does | physics | physical range |\n|---|---|---|---|---|\n",
        );
        for kind in Self::ALL {
            let params = match kind {
                EffectKind::Discrepancy => "terms below".to_string(),
                _ => Self::keys_with_bounds(kind).join(", "),
            };
            table.push_str(&format!(
                "| `{}` | {params} | {} | {} | {} |\n",
                kind.name(),
                kind.formula(),
                kind.physics(),
                kind.physical_text()
            ));
        }
        table
    }

    fn keys_with_bounds(kind: EffectKind) -> Vec<String> {
        kind.keys().iter().zip(kind.bounds()).map(|(key, (lo, hi))| format!("`{key}` [{lo}, {hi}]")).collect()
    }

    /// Every kind with its keys, their bounds, what it does, its physics and its physical
    /// range, the discrepancy's terms too: the catalogue as `sim-record --help` and
    /// `diagnose --help` show it.
    pub fn catalogue_help() -> String {
        let mut help = String::new();
        for kind in Self::ALL {
            let keys: Vec<String> =
                kind.keys().iter().zip(kind.bounds()).map(|(key, (lo, hi))| format!("{key}=[{lo}, {hi}]")).collect();
            help.push_str(&format!(
                "  {}:{}\n      {}; {}\n      physical: {}\n",
                kind.name(),
                keys.join(","),
                kind.formula(),
                kind.physics(),
                kind.physical_text()
            ));
        }
        help.push_str("  discrepancy terms (each with its shape key; absent terms are 0):\n");
        for term in DISCREPANCY_TERMS {
            help.push_str(&format!("      {}: {}\n", DISCREPANCY_KEYS[term.coefficient], term.meaning));
        }
        help
    }

    /// Comma-separated valid names, for error messages.
    pub fn valid_names() -> String {
        Self::ALL.iter().map(|k| k.name()).collect::<Vec<_>>().join(", ")
    }
}

impl fmt::Display for EffectKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for EffectKind {
    type Err = ModelError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| ModelError::UnknownEffect { name: s.to_owned(), valid: Self::valid_names() })
    }
}

/// Most values an effect has (the discrepancy's).
const MAX_VALUES: usize = DISCREPANCY_KEYS.len();

/// One effect with its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Effect {
    kind: EffectKind,
    values: [f64; MAX_VALUES],
}

impl Effect {
    /// Checks the number of values and their ranges ([`EffectKind::bounds`]).
    pub fn new(kind: EffectKind, values: &[f64]) -> Result<Self, ModelError> {
        let keys = kind.keys();
        if values.len() != keys.len() {
            return Err(ModelError::EffectParam {
                effect: kind.name(),
                message: format!("expects {} value(s) ({}), got {}", keys.len(), keys.join(", "), values.len()),
            });
        }
        let mut stored = [0.0; MAX_VALUES];
        for ((key, &(lo, hi)), (slot, &value)) in keys.iter().zip(kind.bounds()).zip(stored.iter_mut().zip(values)) {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(ModelError::EffectParam {
                    effect: kind.name(),
                    message: format!("{key} = {value} is out of range: expected a number in [{lo}, {hi}]"),
                });
            }
            *slot = value;
        }
        Ok(Self { kind, values: stored })
    }

    /// Which physics.
    pub fn kind(&self) -> EffectKind {
        self.kind
    }

    /// Parameter values in the order of [`EffectKind::keys`] (every key, for a
    /// discrepancy the absent terms as 0).
    pub fn values(&self) -> &[f64] {
        &self.values[..self.kind.keys().len()]
    }

    /// `(key, value)` pairs that matter: every key, but only the terms present (and
    /// their shape keys) of a discrepancy.
    pub fn params(&self) -> impl Iterator<Item = (&'static str, f64)> + '_ {
        let values = self.values();
        self.kind
            .keys()
            .iter()
            .copied()
            .zip(values.iter().copied())
            .enumerate()
            .filter(move |(i, _)| self.kind != EffectKind::Discrepancy || discrepancy_key_active(values, *i))
            .map(|(_, kv)| kv)
    }

    /// `None` when every parameter that matters lies in its physical range
    /// ([`EffectKind::physical`]); otherwise what does not, in words.
    pub fn unphysical(&self) -> Option<String> {
        let problems: Vec<String> = self
            .params()
            .filter_map(|(key, value)| {
                let i = self.kind.keys().iter().position(|k| *k == key)?;
                let (lo, hi) = self.kind.physical()[i];
                (!(lo..=hi).contains(&value)).then(|| format!("{key} = {value:.4} outside [{lo}, {hi}]"))
            })
            .collect();
        (!problems.is_empty()).then(|| problems.join(", "))
    }

    /// Reads an effect from its model-file table (every key required and no others; a
    /// discrepancy holds only the terms present, each with its shape key).
    pub fn from_table(kind: EffectKind, table: &toml::Table) -> Result<Self, ModelError> {
        let keys = kind.keys();
        let error = |message: String| ModelError::EffectParam { effect: kind.name(), message };
        if let Some(unknown) = table.keys().find(|k| !keys.contains(&k.as_str())) {
            return Err(error(format!("unknown key `{unknown}`; expected {}", keys.join(", "))));
        }
        let discrepancy = kind == EffectKind::Discrepancy;
        let mut values = Vec::with_capacity(keys.len());
        for (i, key) in keys.iter().enumerate() {
            let value = match table.get(*key) {
                Some(toml::Value::Float(x)) => *x,
                Some(toml::Value::Integer(i)) => *i as f64,
                Some(other) => return Err(error(format!("{key} must be a number, not {}", other.type_str()))),
                None if discrepancy => DISCREPANCY_DEFAULTS[i],
                None => return Err(error(format!("missing key {key}"))),
            };
            values.push(value);
        }
        if discrepancy {
            for term in DISCREPANCY_TERMS {
                if let Some(shape) = term.shape {
                    if values[term.coefficient] != 0.0 && !table.contains_key(keys[shape]) {
                        return Err(error(format!("{} needs {}", keys[term.coefficient], keys[shape])));
                    }
                }
            }
        }
        Self::new(kind, &values)
    }

    fn to_table(self) -> toml::Table {
        self.params().map(|(k, v)| (k.to_owned(), toml::Value::Float(v))).collect()
    }
}

/// `name:key=value,key=value`, as `jetbench sim-record --effect` takes it.
impl FromStr for Effect {
    type Err = ModelError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (name, rest) = s.split_once(':').unwrap_or((s, ""));
        let kind: EffectKind = name.trim().parse()?;
        let mut table = toml::Table::new();
        for pair in rest.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let Some((key, value)) = pair.split_once('=') else {
                return Err(ModelError::EffectParam {
                    effect: kind.name(),
                    message: format!("`{pair}` is not KEY=VALUE (expected {})", kind.keys().join(", ")),
                });
            };
            let value: f64 = value.trim().parse().map_err(|_| ModelError::EffectParam {
                effect: kind.name(),
                message: format!("{} = `{}` is not a number", key.trim(), value.trim()),
            })?;
            table.insert(key.trim().to_owned(), toml::Value::Float(value));
        }
        Effect::from_table(kind, &table)
    }
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:", self.kind)?;
        for (i, (k, v)) in self.params().enumerate() {
            write!(f, "{}{k}={v}", if i > 0 { "," } else { "" })?;
        }
        Ok(())
    }
}

/// A set of effects, at most one of each kind, kept in signal-path order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Effects {
    list: Vec<Effect>,
}

impl Effects {
    /// No effect: the plain ten-parameter model.
    pub fn none() -> Self {
        Self::default()
    }

    /// Fails when a kind appears twice.
    pub fn new(effects: impl IntoIterator<Item = Effect>) -> Result<Self, ModelError> {
        let mut list: Vec<Effect> = effects.into_iter().collect();
        list.sort_by_key(|e| EffectKind::ALL.iter().position(|k| *k == e.kind));
        if let Some(w) = list.windows(2).find(|w| w[0].kind == w[1].kind) {
            return Err(ModelError::EffectParam { effect: w[0].kind.name(), message: "given more than once".into() });
        }
        Ok(Self { list })
    }

    /// The effect of this kind, if present.
    pub fn get(&self, kind: EffectKind) -> Option<&Effect> {
        self.list.iter().find(|e| e.kind == kind)
    }

    /// The input delay, s: what the engine's throttle lags the applied one by (0 without
    /// an `input_delay` effect).
    pub fn input_delay_s(&self) -> f64 {
        self.get(EffectKind::InputDelay).map_or(0.0, |e| e.values()[0])
    }

    /// The bounds an `accel_schedule` puts on the thrust rate (`None`: the model is not paced).
    pub fn rate_schedule(&self) -> Option<crate::RateSchedule> {
        self.get(EffectKind::AccelSchedule).map(|e| crate::RateSchedule::new(e.values()))
    }

    /// Effects in signal-path order.
    pub fn iter(&self) -> impl Iterator<Item = &Effect> {
        self.list.iter()
    }

    /// True when the model is the ten parameters alone (no effect).
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// How many effects the model has (at most one of each kind).
    pub fn len(&self) -> usize {
        self.list.len()
    }

    /// Adds `effect`, replacing one of the same kind.
    pub fn with(&self, effect: Effect) -> Self {
        let mut list: Vec<Effect> = self.list.iter().copied().filter(|e| e.kind != effect.kind).collect();
        list.push(effect);
        list.sort_by_key(|e| EffectKind::ALL.iter().position(|k| *k == e.kind));
        Self { list }
    }

    /// Without the effect of this kind.
    pub fn without(&self, kind: EffectKind) -> Self {
        Self { list: self.list.iter().copied().filter(|e| e.kind != kind).collect() }
    }

    /// From the `[effects.<name>]` tables of a model file.
    pub fn from_tables(tables: &BTreeMap<String, toml::Table>) -> Result<Self, ModelError> {
        let mut list = Vec::with_capacity(tables.len());
        for (name, table) in tables {
            list.push(Effect::from_table(name.parse()?, table)?);
        }
        Self::new(list)
    }

    /// The `[effects.<name>]` tables of a model file.
    pub fn to_tables(&self) -> BTreeMap<String, toml::Table> {
        self.list.iter().map(|e| (e.kind.name().to_owned(), e.to_table())).collect()
    }
}

impl fmt::Display for Effects {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.list.is_empty() {
            return f.write_str("none");
        }
        for (i, e) in self.list.iter().enumerate() {
            write!(f, "{}{e}", if i > 0 { " " } else { "" })?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn effect(s: &str) -> Effect {
        s.parse().unwrap()
    }

    #[test]
    fn effects_parse_check_and_print() {
        let e = effect("rate_limit:up_pct_per_s=60,down_pct_per_s=120");
        assert_eq!(e.to_string(), "rate_limit:up_pct_per_s=60,down_pct_per_s=120");
        assert_eq!(e.to_string().parse::<Effect>().unwrap(), e);
        for bad in [
            "input_dealy:delay_s=0.1",
            "input_delay:delay=0.1",
            "input_delay",
            "input_delay:delay_s=nan",
            "input_delay:delay_s=80",
            "rate_limit:up_pct_per_s=60",
            "input_delay:delay_s",
            "stand_resonance:frequency_hz=3",
            "discrepancy:map_below=1",
            "discrepancy:B_TT=0.5",
            "discrepancy:knot=40",
        ] {
            let err = bad.parse::<Effect>().unwrap_err();
            assert!(!err.to_string().is_empty(), "{bad}");
        }
        let twice = Effects::new([effect("input_delay:delay_s=0.1"), effect("input_delay:delay_s=0.2")]);
        assert!(twice.is_err());
    }

    #[test]
    fn a_discrepancy_holds_only_its_terms() {
        let e = effect("discrepancy:gain_history_per_n=-0.0005,history_time_constant_s=40,B_TT=1e-5");
        assert_eq!(
            e.params().collect::<Vec<_>>(),
            vec![("gain_history_per_n", -0.0005), ("history_time_constant_s", 40.0), ("B_TT", 1e-5)]
        );
        assert_eq!(e.values().len(), DISCREPANCY_KEYS.len());
        assert_eq!(e.to_string().parse::<Effect>().unwrap(), e);
        assert!(e.unphysical().is_none());
        let far = effect("discrepancy:map_below=1,knot_below_pct=10");
        assert!(far.unphysical().unwrap().contains("knot_below_pct"), "a knot below the throttle range");
    }

    #[test]
    fn physical_ranges_hold_the_bounds_and_the_sign() {
        for kind in EffectKind::ALL {
            assert_eq!(kind.physical().len(), kind.keys().len(), "{kind}");
            for (&(lo, hi), &(blo, bhi)) in kind.physical().iter().zip(kind.bounds()) {
                assert!(blo <= lo && lo < hi && hi <= bhi, "{kind}: [{lo}, {hi}] within [{blo}, {bhi}]");
            }
        }
        assert!(effect("gain_drift:per_minute=-0.01").unphysical().is_some(), "a gain that rises");
        assert!(effect("gain_drift:per_minute=0.01").unphysical().is_none());
        assert!(effect("stand_resonance:frequency_hz=3,damping_ratio=0.05").unphysical().is_none());
    }
}
