//! Physics the ten-parameter model leaves out (plant.md, "Effects the second-order
//! model leaves out"), each a small extension with few parameters, and the plant
//! that simulates the model with them.
//!
//! The effects act on the way in (the throttle the engine follows) or on the way out
//! (the force the sensor reads), in a fixed physical order:
//!
//! ```text
//! u ─ input_delay ─ rate_limit ─ actuator_lag ─ v(u)·(1 − gain_drift·t) ─ engine T
//! T ─ bearing_friction (play band) ─ + sensor_drift bias ─ measured thrust
//! ```

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use crate::{rk4_step, ModelError, Params, State, DIVERGENCE_RATE_N_PER_S, DIVERGENCE_THRUST_N, STEP_S, SUBSTEPS};

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
}

impl EffectKind {
    /// Every kind, in the order of the signal path (and of model files).
    pub const ALL: [EffectKind; 6] = [
        EffectKind::InputDelay,
        EffectKind::RateLimit,
        EffectKind::ActuatorLag,
        EffectKind::GainDrift,
        EffectKind::BearingFriction,
        EffectKind::SensorDrift,
    ];

    /// Name in model files (`[effects.<name>]`), on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            EffectKind::InputDelay => "input_delay",
            EffectKind::ActuatorLag => "actuator_lag",
            EffectKind::RateLimit => "rate_limit",
            EffectKind::SensorDrift => "sensor_drift",
            EffectKind::GainDrift => "gain_drift",
            EffectKind::BearingFriction => "bearing_friction",
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
        }
    }

    /// The range each parameter may take (inclusive), in the order of [`EffectKind::keys`]:
    /// wide physical bounds, so a typo like `delay_s = 80` is caught.
    pub fn bounds(self) -> &'static [(f64, f64)] {
        match self {
            EffectKind::InputDelay => &[(0.0, 2.0)],
            EffectKind::ActuatorLag => &[(0.0, 10.0)],
            EffectKind::RateLimit => &[(0.1, 10_000.0), (0.1, 10_000.0)],
            EffectKind::SensorDrift => &[(-1.0, 1.0), (0.1, 3600.0)],
            EffectKind::GainDrift => &[(-0.2, 0.2)],
            EffectKind::BearingFriction => &[(0.0, 50.0)],
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
        }
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

/// One effect with its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Effect {
    kind: EffectKind,
    values: [f64; 2],
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
        let mut stored = [0.0; 2];
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

    /// Parameter values in the order of [`EffectKind::keys`].
    pub fn values(&self) -> &[f64] {
        &self.values[..self.kind.keys().len()]
    }

    /// `(key, value)` pairs.
    pub fn params(&self) -> impl Iterator<Item = (&'static str, f64)> + '_ {
        self.kind.keys().iter().copied().zip(self.values().iter().copied())
    }

    /// Reads an effect from its model-file table (every key required, no others).
    pub fn from_table(kind: EffectKind, table: &toml::Table) -> Result<Self, ModelError> {
        let keys = kind.keys();
        if let Some(unknown) = table.keys().find(|k| !keys.contains(&k.as_str())) {
            return Err(ModelError::EffectParam {
                effect: kind.name(),
                message: format!("unknown key `{unknown}`; expected {}", keys.join(", ")),
            });
        }
        let mut values = Vec::with_capacity(keys.len());
        for key in keys {
            let value = match table.get(*key) {
                Some(toml::Value::Float(x)) => *x,
                Some(toml::Value::Integer(i)) => *i as f64,
                Some(other) => {
                    return Err(ModelError::EffectParam {
                        effect: kind.name(),
                        message: format!("{key} must be a number, not {}", other.type_str()),
                    })
                }
                None => {
                    return Err(ModelError::EffectParam { effect: kind.name(), message: format!("missing key {key}") })
                }
            };
            values.push(value);
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

    /// Effects in signal-path order.
    pub fn iter(&self) -> impl Iterator<Item = &Effect> {
        self.list.iter()
    }

    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

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

/// The engine model with its effects: what a bench recording is a measurement of.
#[derive(Clone, Debug, PartialEq)]
pub struct Plant {
    /// The ten coefficients.
    pub params: Params,
    /// What the ten coefficients leave out.
    pub effects: Effects,
}

/// One 10 ms step of a [`PlantEngine`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantSample {
    /// The engine's state after the step.
    pub state: State,
    /// The force the sensor reads (before noise), N.
    pub measured_n: f64,
    /// The throttle the engine followed at the end of the step, %.
    pub engine_throttle_pct: f64,
}

impl Plant {
    pub fn new(params: Params, effects: Effects) -> Self {
        Self { params, effects }
    }

    /// A stepping simulator started at `initial` with every effect at rest for the
    /// throttle `u0_pct` (delay line full of it, lag settled, sensor bias zero, as just
    /// after a tare), `t0_s` seconds after the start of the recording.
    pub fn engine(&self, initial: State, u0_pct: f64, t0_s: f64) -> PlantEngine {
        PlantEngine::new(self, initial, u0_pct, t0_s, SUBSTEPS)
    }

    /// Like [`Plant::engine`], integrating with `substeps` RK4 steps per [`STEP_S`]
    /// (at least 1) instead of 10: a cheaper predictor for a controller, accurate to a
    /// fraction of a newton on this model with 2.
    pub fn coarse_engine(&self, initial: State, u0_pct: f64, t0_s: f64, substeps: usize) -> PlantEngine {
        PlantEngine::new(self, initial, u0_pct, t0_s, substeps.max(1))
    }

    /// A stepping simulator at rest at the stable equilibrium for `u0_pct`, at time 0.
    pub fn at_equilibrium(&self, u0_pct: f64) -> PlantEngine {
        let thrust_n = self.params.stable_equilibrium(u0_pct).unwrap_or(0.0);
        self.engine(State { thrust_n, thrust_rate_n_per_s: 0.0 }, u0_pct, 0.0)
    }

    /// Free run: `out[0]` is the measured force at `initial`, `out[k + 1]` follows with
    /// `u_pct[k]` held for [`STEP_S`]. On divergence the rest is NaN and the time of
    /// divergence (s from the run start) is returned.
    pub fn free_run(&self, t0_s: f64, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        let mut engine = self.engine(initial, u_pct.first().copied().unwrap_or(0.0), t0_s);
        out.clear();
        out.push(engine.measured_n());
        for (k, &u) in u_pct.iter().enumerate().take(u_pct.len().saturating_sub(1)) {
            match engine.step(u) {
                Ok(s) => out.push(s.measured_n),
                Err(_) => {
                    out.resize(u_pct.len(), f64::NAN);
                    return Some((k + 1) as f64 * STEP_S);
                }
            }
        }
        None
    }
}

/// The plant stepped 10 ms at a time (RK4 at 1 kHz, like [`crate::Engine`], which it
/// reproduces bit for bit when there is no effect).
#[derive(Debug)]
pub struct PlantEngine {
    params: Params,
    state: State,
    substeps: usize,
    t0_s: f64,
    steps: u64,
    failed: bool,
    // Effect parameters, flattened for the inner loop (None: effect absent).
    delay_s: Option<f64>,
    rate_limit: Option<(f64, f64)>,
    lag_alpha: Option<f64>,
    gain_per_s: f64,
    play_n: Option<f64>,
    drift: Option<(f64, f64)>,
    // Effect states.
    history: std::collections::VecDeque<f64>,
    rate_limited_pct: f64,
    lagged_pct: f64,
    engine_throttle_pct: f64,
    frame_n: f64,
    bias_n: f64,
}

impl Clone for PlantEngine {
    fn clone(&self) -> Self {
        Self { history: self.history.clone(), ..*self }
    }

    /// Reuses the throttle history's memory: a controller copies its model every cycle.
    fn clone_from(&mut self, source: &Self) {
        let mut history = std::mem::take(&mut self.history);
        history.clone_from(&source.history);
        *self = Self { history, ..*source };
    }
}

impl PlantEngine {
    fn new(plant: &Plant, initial: State, u0_pct: f64, t0_s: f64, substeps: usize) -> Self {
        let h = STEP_S / substeps as f64;
        let fx = plant.effects.get(EffectKind::InputDelay).map(|e| e.values()[0]).filter(|d| *d > 0.0);
        let history_len = fx.map_or(1, |d| (d / STEP_S).ceil() as usize + 2);
        Self {
            params: plant.params,
            state: initial,
            substeps,
            t0_s,
            steps: 0,
            failed: false,
            delay_s: fx,
            rate_limit: plant.effects.get(EffectKind::RateLimit).map(|e| (e.values()[0] * h, e.values()[1] * h)),
            lag_alpha: plant
                .effects
                .get(EffectKind::ActuatorLag)
                .map(|e| e.values()[0])
                .filter(|tau| *tau > 0.0)
                .map(|tau| 1.0 - (-h / tau).exp()),
            gain_per_s: plant.effects.get(EffectKind::GainDrift).map_or(0.0, |e| e.values()[0] / 60.0),
            play_n: plant.effects.get(EffectKind::BearingFriction).map(|e| e.values()[0]),
            drift: plant
                .effects
                .get(EffectKind::SensorDrift)
                .map(|e| (e.values()[0], 1.0 - (-h / e.values()[1]).exp())),
            history: std::iter::repeat_n(u0_pct, history_len).collect(),
            rate_limited_pct: u0_pct,
            lagged_pct: u0_pct,
            engine_throttle_pct: u0_pct,
            frame_n: initial.thrust_n,
            bias_n: 0.0,
        }
    }

    /// The engine's state.
    pub fn state(&self) -> State {
        self.state
    }

    /// The force the sensor reads now (before noise), N.
    pub fn measured_n(&self) -> f64 {
        self.frame_n + self.bias_n
    }

    /// Replaces the engine's thrust and rate, keeping the throttle history and the
    /// effects' states: how a controller re-anchors its model on a fresh state estimate.
    /// Clears a divergence.
    pub fn set_state(&mut self, state: State) {
        self.state = state;
        self.frame_n = state.thrust_n;
        self.failed = false;
    }

    /// Time since the start of the recording, s.
    pub fn time_s(&self) -> f64 {
        self.t0_s + self.steps as f64 * STEP_S
    }

    /// Advances one [`STEP_S`] with `throttle_pct` commanded; fails like
    /// [`crate::Engine::step`] on divergence or a non-finite throttle.
    pub fn step(&mut self, throttle_pct: f64) -> Result<PlantSample, ModelError> {
        if !throttle_pct.is_finite() {
            return Err(ModelError::InvalidThrottle { throttle_pct });
        }
        if self.failed {
            return Err(self.diverged(self.time_s()));
        }
        let h = STEP_S / self.substeps as f64;
        if self.delay_s.is_some() {
            self.history.pop_front();
            self.history.push_back(throttle_pct);
        }
        let p = self.params;
        let (mut t, mut d) = (self.state.thrust_n, self.state.thrust_rate_n_per_s);
        for i in 0..self.substeps {
            // The throttle the engine follows over this substep.
            let mut u = match self.delay_s {
                None => throttle_pct,
                Some(delay) => self.delayed_pct(i as f64 * h - delay, h),
            };
            if let Some((up, down)) = self.rate_limit {
                self.rate_limited_pct += (u - self.rate_limited_pct).clamp(-down, up);
                u = self.rate_limited_pct;
            }
            if let Some(alpha) = self.lag_alpha {
                self.lagged_pct += (u - self.lagged_pct) * alpha;
                u = self.lagged_pct;
            }
            self.engine_throttle_pct = u;
            let mut v = p.v(u);
            if self.gain_per_s != 0.0 {
                let t_mid = self.t0_s + self.steps as f64 * STEP_S + (i as f64 + 0.5) * h;
                v *= 1.0 - self.gain_per_s * t_mid;
            }
            (t, d) = rk4_step(t, d, h, |t, d| p.f(t, d) + p.g(t, d) * v);
            if !(t.is_finite() && d.is_finite() && t.abs() <= DIVERGENCE_THRUST_N && d.abs() <= DIVERGENCE_RATE_N_PER_S)
            {
                self.failed = true;
                let at = self.time_s() + (i + 1) as f64 * h;
                return Err(self.diverged(at));
            }
            match self.play_n {
                Some(play) => self.frame_n = self.frame_n.clamp(t - play, t + play),
                None => self.frame_n = t,
            }
            if let Some((gain, alpha)) = self.drift {
                self.bias_n += (gain * t - self.bias_n) * alpha;
            }
        }
        self.state = State { thrust_n: t, thrust_rate_n_per_s: d };
        self.steps += 1;
        Ok(PlantSample {
            state: self.state,
            measured_n: self.measured_n(),
            engine_throttle_pct: self.engine_throttle_pct,
        })
    }

    /// The commanded throttle averaged over `[from_s, from_s + h]`, times relative to
    /// the start of the current row (negative: earlier rows). Averaging over the
    /// substep makes the response a smooth function of the delay, which a fit needs.
    fn delayed_pct(&self, from_s: f64, h: f64) -> f64 {
        let n = self.history.len() as i64;
        let row = |j: i64| self.history[(n - 1 + j.clamp(1 - n, 0)) as usize];
        // Row holding the end of the interval (a tolerance keeps an end exactly on a
        // row boundary in the earlier row).
        let j_end = ((from_s + h) / STEP_S - 1e-9).floor().min(0.0) as i64;
        let boundary_s = j_end as f64 * STEP_S;
        if from_s < boundary_s {
            let w = ((boundary_s - from_s) / h).min(1.0);
            w * row(j_end - 1) + (1.0 - w) * row(j_end)
        } else {
            row(j_end)
        }
    }

    fn diverged(&self, time_s: f64) -> ModelError {
        ModelError::Diverged {
            time_s,
            thrust_n: self.state.thrust_n,
            thrust_rate_n_per_s: self.state.thrust_rate_n_per_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Engine, Preset};

    fn effect(s: &str) -> Effect {
        s.parse().unwrap()
    }

    fn step_input() -> Vec<f64> {
        (0..1600)
            .map(|k| {
                if k < 100 {
                    30.0
                } else if k < 800 {
                    90.0
                } else {
                    40.0
                }
            })
            .collect()
    }

    fn run(plant: &Plant, u: &[f64]) -> Vec<f64> {
        let initial = State { thrust_n: plant.params.stable_equilibrium(u[0]).unwrap(), thrust_rate_n_per_s: 0.0 };
        let mut out = Vec::new();
        assert!(plant.free_run(0.0, initial, u, &mut out).is_none());
        out
    }

    #[test]
    fn without_effects_the_plant_is_the_engine_bit_for_bit() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let sim = run(&Plant::new(p, Effects::none()), &u);
        let mut engine = Engine::at_equilibrium(p, u[0]);
        for (k, &uk) in u.iter().enumerate().take(u.len() - 1) {
            assert_eq!(engine.step(uk).unwrap().thrust_n.to_bits(), sim[k + 1].to_bits(), "row {k}");
        }
    }

    #[test]
    fn a_coarse_engine_follows_the_fine_one_and_a_copy_reanchors() {
        let plant =
            Plant::new(Preset::P100Diesel.params(), Effects::new([effect("input_delay:delay_s=0.05")]).unwrap());
        let u = step_input();
        let mut fine = plant.at_equilibrium(u[0]);
        let mut coarse = plant.coarse_engine(fine.state(), u[0], 0.0, 2);
        for &u in &u {
            let (a, b) = (fine.step(u).unwrap(), coarse.step(u).unwrap());
            assert!((a.state.thrust_n - b.state.thrust_n).abs() < 0.05, "{:?} vs {:?}", a.state, b.state);
        }
        // A copy keeps the throttle history; a new state replaces thrust and rate only.
        let mut copy = plant.at_equilibrium(25.0);
        copy.clone_from(&fine);
        let state = State { thrust_n: 30.0, thrust_rate_n_per_s: 5.0 };
        copy.set_state(state);
        fine.set_state(state);
        for _ in 0..20 {
            assert_eq!(copy.step(40.0).unwrap(), fine.step(40.0).unwrap());
        }
    }

    #[test]
    fn a_delay_of_whole_rows_shifts_the_response() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        let delayed = run(&Plant::new(p, Effects::new([effect("input_delay:delay_s=0.07")]).unwrap()), &u);
        for k in 0..u.len() - 7 {
            assert!((delayed[k + 7] - nominal[k]).abs() < 1e-9, "row {k}: {} vs {}", delayed[k + 7], nominal[k]);
        }
    }

    #[test]
    fn lag_and_rate_limit_slow_the_step_and_friction_holds_a_band() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        for spec in ["actuator_lag:time_constant_s=0.3", "rate_limit:up_pct_per_s=40,down_pct_per_s=80"] {
            let slow = run(&Plant::new(p, Effects::new([effect(spec)]).unwrap()), &u);
            assert!(slow[150] < nominal[150] - 1.0, "{spec}: {} vs {}", slow[150], nominal[150]);
            assert!(
                (slow[799] - nominal[799]).abs() < 0.5,
                "{spec} settles to the same thrust: {} vs {}",
                slow[799],
                nominal[799]
            );
        }
        let friction = run(&Plant::new(p, Effects::new([effect("bearing_friction:force_n=2")]).unwrap()), &u);
        let gaps: Vec<f64> = friction.iter().zip(&nominal).map(|(m, t)| m - t).collect();
        assert!(gaps.iter().all(|g| g.abs() <= 2.0 + 1e-9));
        assert!((gaps[150] + 2.0).abs() < 1e-9, "rising: the frame trails by the band ({})", gaps[150]);
        assert!((gaps[850] - 2.0).abs() < 1e-9, "falling: it trails from above ({})", gaps[850]);
    }

    #[test]
    fn sensor_drift_settles_to_its_gain_and_gain_drift_sags() {
        let p = Preset::P100Diesel.params();
        let u = vec![90.0; 30_000];
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        let drift = Effects::new([effect("sensor_drift:gain=0.05,time_constant_s=20")]).unwrap();
        let warm = run(&Plant::new(p, drift), &u);
        let bias = warm[29_999] - nominal[29_999];
        assert!((bias - 0.05 * nominal[29_999]).abs() < 0.01, "{bias}");
        let sag = run(&Plant::new(p, Effects::new([effect("gain_drift:per_minute=0.01")]).unwrap()), &u);
        assert!(sag[29_999] < nominal[29_999] - 1.0 && (sag[100] - nominal[100]).abs() < 0.1);
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
        ] {
            let err = bad.parse::<Effect>().unwrap_err();
            assert!(!err.to_string().is_empty(), "{bad}");
        }
        let twice = Effects::new([effect("input_delay:delay_s=0.1"), effect("input_delay:delay_s=0.2")]);
        assert!(twice.is_err());
    }
}
