//! A physically based single-spool turbojet with its ECU: an engine that is *not* the
//! ten-parameter model, so that identification and diagnosis are tested out of class.
//!
//! ```
//! use jetbench_model::turbojet::{Turbojet, TurbojetParams};
//!
//! let params = TurbojetParams::p100();
//! let mut engine = Turbojet::at_rest(params, 25.0);
//! assert!((engine.sample().thrust_n - 1.5).abs() < 0.1, "idle thrust");
//! // A full step: the fuel schedule lets the spool accelerate, the governor holds 100 %.
//! for _ in 0..300 {
//!     engine.step(100.0);
//! }
//! let s = engine.sample();
//! assert!((s.thrust_n - 100.0).abs() < 1.0);
//! assert!((s.rpm - 154_000.0).abs() < 2_000.0);
//! ```
//!
//! The physics, per unit of the spool's maximum speed `n = rpm / rpm_max`:
//!
//! - **Spool.** `I·ṅ = τ_turbine − τ_compressor` with the turbine torque proportional to the
//!   fuel flow that reaches the burner, `w` (per unit of the fuel flow that holds full
//!   speed), and the compressor's load growing with the square of the speed (its power with
//!   the cube): `ṅ = (η·w − n²)/τ₀`, where `τ₀` (s) is the spool's inertia over its load at
//!   full speed and `η` the combustion efficiency (1 unless a gain drift sags it). Small
//!   deviations settle with `τ₀/(2n)`: slow at idle, fast at full speed, as real engines do.
//! - **Thrust** grows with the square of the spool speed (mass flow and jet velocity both
//!   grow with it), less what the intake and nozzle lose at low speed:
//!   `T = T_max·(n² − n_z²)/(1 − n_z²)`, with `n_z` set so the engine gives `idle_thrust_n`
//!   at idle.
//! - **Governor.** The ECU maps the throttle linearly onto a speed between idle and full,
//!   `n_ref = n_idle + (1 − n_idle)·(u − 25)/75`, and holds it with a PI law on the speed
//!   error around the fuel flow that would hold `n_ref` (`n_ref²`).
//! - **Fuel schedule.** The fuel flow the governor may ask for is bounded around the one that
//!   holds the present speed: at most `(1 + accel_margin)·n²` (more would surge the compressor
//!   or overheat the turbine), at least `(1 − decel_margin)·n²` (less would blow the flame out).
//!   These bounds, not the governor, set how fast full steps go; the pump follows the request
//!   with a first-order lag `pump_time_constant_s`.
//! - **Exhaust gas temperature** settles at `egt_idle_c` at idle and `egt_full_c` at full
//!   speed, linearly in `n`, plus `egt_overfuel_c` per unit of fuel beyond what holds the
//!   present speed (an accelerating engine runs hot), through a first-order lag
//!   `egt_time_constant_s`.
//!
//! Integration: classic RK4 at 1 kHz with the throttle held over each 10 ms step; the fuel
//! schedule's bounds are a clamp inside the right-hand side, so RK4 sees a continuous
//! (piecewise smooth) field. A throttle that is not a number holds the previous one; one
//! outside 25–100 % is clamped to it, as the ECU does.

use crate::{STEP_S, SUBSTEPS, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};

/// The constants of a turbojet and its ECU (see the [module docs](self) for the physics).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TurbojetParams {
    /// Spool speed at full throttle, rpm.
    pub rpm_max: f64,
    /// Spool speed the governor holds at 25 %, rpm.
    pub rpm_idle: f64,
    /// Thrust at full speed, N.
    pub max_thrust_n: f64,
    /// Thrust at idle speed, N.
    pub idle_thrust_n: f64,
    /// Spool inertia over its load at full speed, s (`τ₀`).
    pub spool_time_constant_s: f64,
    /// Fuel beyond the steady-state flow the schedule allows while accelerating (fraction).
    pub accel_margin: f64,
    /// Fuel below the steady-state flow the schedule allows while decelerating (fraction).
    pub decel_margin: f64,
    /// Governor's proportional gain, fuel flow per unit of speed error.
    pub governor_kp: f64,
    /// Governor's integral gain, fuel flow per unit of speed error per second.
    pub governor_ki_per_s: f64,
    /// Fuel pump lag, s.
    pub pump_time_constant_s: f64,
    /// Ambient (and cold-engine) temperature, °C.
    pub ambient_c: f64,
    /// Exhaust gas temperature settled at idle, °C.
    pub egt_idle_c: f64,
    /// Exhaust gas temperature settled at full speed, °C.
    pub egt_full_c: f64,
    /// Exhaust gas temperature added per unit of fuel beyond the steady-state flow, °C.
    pub egt_overfuel_c: f64,
    /// Thermal lag of the exhaust gas temperature reading, s.
    pub egt_time_constant_s: f64,
}

impl TurbojetParams {
    /// A JetCat P100-RX-like engine: 100 N at 154 000 rpm, 1.5 N at a 33 000 rpm idle, a full
    /// step settling in about a second.
    pub const fn p100() -> Self {
        Self {
            rpm_max: 154_000.0,
            rpm_idle: 33_000.0,
            max_thrust_n: 100.0,
            idle_thrust_n: 1.5,
            spool_time_constant_s: 0.12,
            accel_margin: 0.45,
            decel_margin: 0.5,
            governor_kp: 4.0,
            governor_ki_per_s: 8.0,
            pump_time_constant_s: 0.04,
            ambient_c: 20.0,
            egt_idle_c: 520.0,
            egt_full_c: 680.0,
            egt_overfuel_c: 500.0,
            egt_time_constant_s: 0.7,
        }
    }

    /// A JetCat P220-RXi-like engine: 220 N at 117 000 rpm, 5 N at a 35 000 rpm idle; the
    /// heavier spool makes it slower than the P100.
    pub const fn p220() -> Self {
        Self {
            rpm_max: 117_000.0,
            rpm_idle: 35_000.0,
            max_thrust_n: 220.0,
            idle_thrust_n: 5.0,
            spool_time_constant_s: 0.2,
            accel_margin: 0.4,
            decel_margin: 0.45,
            governor_kp: 4.0,
            governor_ki_per_s: 6.0,
            pump_time_constant_s: 0.05,
            ambient_c: 20.0,
            egt_idle_c: 540.0,
            egt_full_c: 700.0,
            egt_overfuel_c: 500.0,
            egt_time_constant_s: 1.0,
        }
    }

    /// The names of the constants as a plant file's `[turbojet]` table spells them.
    pub const NAMES: [&'static str; 15] = [
        "rpm_max",
        "rpm_idle",
        "max_thrust_n",
        "idle_thrust_n",
        "spool_time_constant_s",
        "accel_margin",
        "decel_margin",
        "governor_kp",
        "governor_ki_per_s",
        "pump_time_constant_s",
        "ambient_c",
        "egt_idle_c",
        "egt_full_c",
        "egt_overfuel_c",
        "egt_time_constant_s",
    ];

    /// The constant called `name` (one of [`TurbojetParams::NAMES`]), to read or set.
    pub fn field_mut(&mut self, name: &str) -> Option<&mut f64> {
        Some(match name {
            "rpm_max" => &mut self.rpm_max,
            "rpm_idle" => &mut self.rpm_idle,
            "max_thrust_n" => &mut self.max_thrust_n,
            "idle_thrust_n" => &mut self.idle_thrust_n,
            "spool_time_constant_s" => &mut self.spool_time_constant_s,
            "accel_margin" => &mut self.accel_margin,
            "decel_margin" => &mut self.decel_margin,
            "governor_kp" => &mut self.governor_kp,
            "governor_ki_per_s" => &mut self.governor_ki_per_s,
            "pump_time_constant_s" => &mut self.pump_time_constant_s,
            "ambient_c" => &mut self.ambient_c,
            "egt_idle_c" => &mut self.egt_idle_c,
            "egt_full_c" => &mut self.egt_full_c,
            "egt_overfuel_c" => &mut self.egt_overfuel_c,
            "egt_time_constant_s" => &mut self.egt_time_constant_s,
            _ => return None,
        })
    }

    /// A preset by name: `p100` or `p220` (ASCII case ignored).
    pub fn preset(name: &str) -> Option<Self> {
        match name.trim().to_ascii_lowercase().as_str() {
            "p100" => Some(Self::p100()),
            "p220" => Some(Self::p220()),
            _ => None,
        }
    }

    /// The constants of a plant file's `[turbojet]` table: `base = "p100"` (the default)
    /// or `"p220"`, then any constant of [`TurbojetParams::NAMES`] overriding the base's;
    /// an unknown key, a value that is not a number or constants that fail
    /// [`TurbojetParams::check`] are an error naming the key.
    pub fn from_table(table: &toml::Table) -> Result<Self, String> {
        let mut params = match table.get("base") {
            None => Self::p100(),
            Some(toml::Value::String(name)) => {
                Self::preset(name).ok_or_else(|| format!("base = \"{name}\" is not a turbojet (p100, p220)"))?
            }
            Some(other) => return Err(format!("base = {other} must be \"p100\" or \"p220\"")),
        };
        for (key, value) in table {
            if key == "base" {
                continue;
            }
            let number = match value {
                toml::Value::Float(x) => *x,
                toml::Value::Integer(i) => *i as f64,
                other => return Err(format!("{key} = {other} must be a number")),
            };
            let slot = params
                .field_mut(key)
                .ok_or_else(|| format!("unknown key `{key}`; valid keys: base, {}", Self::NAMES.join(", ")))?;
            *slot = number;
        }
        params.check()?;
        Ok(params)
    }

    /// What is wrong with these constants, in words naming the field, if anything.
    pub fn check(&self) -> Result<(), String> {
        let positive = [
            ("rpm_max", self.rpm_max),
            ("rpm_idle", self.rpm_idle),
            ("max_thrust_n", self.max_thrust_n),
            ("idle_thrust_n", self.idle_thrust_n),
            ("spool_time_constant_s", self.spool_time_constant_s),
            ("accel_margin", self.accel_margin),
            ("decel_margin", self.decel_margin),
            ("governor_kp", self.governor_kp),
            ("pump_time_constant_s", self.pump_time_constant_s),
            ("egt_time_constant_s", self.egt_time_constant_s),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(format!("{name} = {value} must be a positive number"));
            }
        }
        let finite = [
            ("governor_ki_per_s", self.governor_ki_per_s),
            ("ambient_c", self.ambient_c),
            ("egt_idle_c", self.egt_idle_c),
            ("egt_full_c", self.egt_full_c),
            ("egt_overfuel_c", self.egt_overfuel_c),
        ];
        if let Some((name, value)) = finite.into_iter().find(|(_, v)| !v.is_finite()) {
            return Err(format!("{name} = {value} must be a number"));
        }
        if self.governor_ki_per_s < 0.0 {
            return Err(format!("governor_ki_per_s = {} must be 0 or more", self.governor_ki_per_s));
        }
        if self.rpm_idle >= self.rpm_max {
            return Err(format!("rpm_idle = {} must be below rpm_max = {}", self.rpm_idle, self.rpm_max));
        }
        if self.idle_thrust_n >= self.max_thrust_n {
            return Err(format!(
                "idle_thrust_n = {} must be below max_thrust_n = {}",
                self.idle_thrust_n, self.max_thrust_n
            ));
        }
        if self.idle_speed().powi(2) <= self.idle_thrust_n / self.max_thrust_n {
            return Err(format!(
                "idle_thrust_n = {} N is more than a thrust growing with the square of the speed gives at \
                 rpm_idle = {} (at most {:.2} N)",
                self.idle_thrust_n,
                self.rpm_idle,
                self.max_thrust_n * self.idle_speed().powi(2)
            ));
        }
        if self.decel_margin >= 1.0 {
            return Err(format!("decel_margin = {} must be below 1 (no fuel at all)", self.decel_margin));
        }
        Ok(())
    }

    /// Idle speed per unit of full speed.
    pub fn idle_speed(&self) -> f64 {
        self.rpm_idle / self.rpm_max
    }

    /// `n_z²`: the squared speed at which the thrust formula gives zero.
    fn zero_thrust_speed_sq(&self) -> f64 {
        let n2 = self.idle_speed().powi(2);
        let f = self.idle_thrust_n / self.max_thrust_n;
        (n2 - f) / (1.0 - f)
    }

    /// The speed the governor holds at `throttle_pct` (clamped to 25–100 %), per unit.
    pub fn governed_speed(&self, throttle_pct: f64) -> f64 {
        let u = throttle_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT);
        let n_idle = self.idle_speed();
        n_idle + (1.0 - n_idle) * (u - THROTTLE_MIN_PCT) / (THROTTLE_MAX_PCT - THROTTLE_MIN_PCT)
    }

    /// The spool speed (per unit) at which the engine gives `thrust_n` (clamped to zero
    /// speed below the thrust formula's zero): the inverse of
    /// [`TurbojetParams::thrust_at_speed_n`].
    pub fn speed_at_thrust(&self, thrust_n: f64) -> f64 {
        let nz2 = self.zero_thrust_speed_sq();
        (nz2 + thrust_n * (1.0 - nz2) / self.max_thrust_n).max(1e-6).sqrt()
    }

    /// Thrust at spool speed `n` (per unit), N.
    pub fn thrust_at_speed_n(&self, n: f64) -> f64 {
        let nz2 = self.zero_thrust_speed_sq();
        self.max_thrust_n * (n * n - nz2) / (1.0 - nz2)
    }

    /// The settled thrust at `throttle_pct`, N.
    pub fn rest_thrust_n(&self, throttle_pct: f64) -> f64 {
        self.thrust_at_speed_n(self.governed_speed(throttle_pct))
    }

    /// The settled exhaust gas temperature at spool speed `n` with fuel flow `w`, °C.
    fn egt_target_c(&self, n: f64, w: f64) -> f64 {
        let n_idle = self.idle_speed();
        let steady = self.egt_idle_c + (self.egt_full_c - self.egt_idle_c) * (n - n_idle) / (1.0 - n_idle);
        steady + self.egt_overfuel_c * (w - n * n).max(0.0) / (n * n).max(1e-6)
    }
}

/// The turbojet's state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TurbojetState {
    /// Spool speed per unit of `rpm_max`.
    pub speed: f64,
    /// Fuel flow reaching the burner per unit of the flow that holds full speed.
    pub fuel: f64,
    /// The governor's integral term (fuel flow).
    pub integral: f64,
    /// Exhaust gas temperature, °C.
    pub egt_c: f64,
}

/// What the engine does after one 10 ms step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TurbojetSample {
    /// Thrust, N.
    pub thrust_n: f64,
    /// Thrust rate, N/s.
    pub thrust_rate_n_per_s: f64,
    /// Spool speed, rpm (what the ECU reports).
    pub rpm: f64,
    /// Exhaust gas temperature, °C (what the ECU reports).
    pub egt_c: f64,
    /// Fuel flow per unit of the flow at full speed.
    pub fuel: f64,
    /// The throttle the ECU acted on (clamped to 25–100 %), %.
    pub throttle_pct: f64,
}

/// The simulated turbojet: RK4 at 1 kHz, 10 ms per [`Turbojet::step`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Turbojet {
    params: TurbojetParams,
    state: TurbojetState,
    throttle_pct: f64,
    /// Combustion efficiency (1: as built); a gain drift lowers it.
    efficiency: f64,
}

impl Turbojet {
    /// The engine settled at `throttle_pct` (clamped to 25–100 %; a throttle that is not a
    /// number idles).
    pub fn at_rest(params: TurbojetParams, throttle_pct: f64) -> Self {
        let u = if throttle_pct.is_finite() { throttle_pct } else { THROTTLE_MIN_PCT };
        let u = u.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT);
        let n = params.governed_speed(u);
        let state = TurbojetState { speed: n, fuel: n * n, integral: 0.0, egt_c: params.egt_target_c(n, n * n) };
        Self { params, state, throttle_pct: u, efficiency: 1.0 }
    }

    /// The engine spinning at the speed that gives `thrust_n`, with the fuel flow that
    /// holds that speed and the governor's integral set so that, at `throttle_pct`, the
    /// governor asks for that flow: at rest if `thrust_n` is the rest thrust of the
    /// throttle, otherwise on its way there. A thrust or throttle that is not a number
    /// gives the engine at rest at idle.
    pub fn at_thrust(params: TurbojetParams, thrust_n: f64, throttle_pct: f64) -> Self {
        let mut engine = Self::at_rest(params, throttle_pct);
        if thrust_n.is_finite() && thrust_n != engine.sample().thrust_n {
            engine.set_thrust(thrust_n);
        }
        engine
    }

    /// Moves the spool to the speed that gives `thrust_n` (see [`Turbojet::at_thrust`]),
    /// keeping the throttle: how a predictor re-anchors the engine on a measured thrust.
    /// Not a number leaves the engine as it is.
    pub fn set_thrust(&mut self, thrust_n: f64) {
        if !thrust_n.is_finite() {
            return;
        }
        let p = self.params;
        let n = p.speed_at_thrust(thrust_n);
        let n_ref = p.governed_speed(self.throttle_pct);
        self.state.speed = n;
        self.state.fuel = n * n;
        self.state.integral = n * n - n_ref * n_ref - p.governor_kp * (n_ref - n);
        self.state.egt_c = p.egt_target_c(n, n * n);
    }

    /// The constants.
    pub fn params(&self) -> &TurbojetParams {
        &self.params
    }

    /// The state.
    pub fn state(&self) -> TurbojetState {
        self.state
    }

    /// Sets the combustion efficiency (1: as built; 0.97: 3 % less torque per fuel flow).
    /// Not a number or not positive leaves it unchanged.
    pub fn set_efficiency(&mut self, efficiency: f64) {
        if efficiency.is_finite() && efficiency > 0.0 {
            self.efficiency = efficiency;
        }
    }

    /// What the engine does now.
    pub fn sample(&self) -> TurbojetSample {
        let p = &self.params;
        let s = self.state;
        let n_dot = self.derivative(&s)[0];
        TurbojetSample {
            thrust_n: p.thrust_at_speed_n(s.speed),
            thrust_rate_n_per_s: p.max_thrust_n * 2.0 * s.speed * n_dot / (1.0 - p.zero_thrust_speed_sq()),
            rpm: s.speed * p.rpm_max,
            egt_c: s.egt_c,
            fuel: s.fuel,
            throttle_pct: self.throttle_pct,
        }
    }

    /// One 10 ms step with `throttle_pct` held (clamped to 25–100 %; not a number holds the
    /// previous throttle).
    pub fn step(&mut self, throttle_pct: f64) -> TurbojetSample {
        let h = STEP_S / SUBSTEPS as f64;
        for _ in 0..SUBSTEPS {
            self.substep(throttle_pct, h);
        }
        self.sample()
    }

    /// One classic RK4 step of `h` seconds with `throttle_pct` held (clamped to 25–100 %;
    /// not a number holds the previous throttle): what [`Turbojet::step`] does ten times,
    /// and what a plant whose throttle path moves within a step calls once per tick.
    pub fn substep(&mut self, throttle_pct: f64, h: f64) {
        if throttle_pct.is_finite() {
            self.throttle_pct = throttle_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT);
        }
        {
            let x = self.to_array();
            let k1 = self.derivative_of(&x);
            let k2 = self.derivative_of(&add(&x, &k1, h / 2.0));
            let k3 = self.derivative_of(&add(&x, &k2, h / 2.0));
            let k4 = self.derivative_of(&add(&x, &k3, h));
            let mut next = x;
            for i in 0..4 {
                next[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
            // A spool never turns backwards; the burner never burns negative fuel.
            next[0] = next[0].max(1e-3);
            next[1] = next[1].max(0.0);
            self.state = TurbojetState { speed: next[0], fuel: next[1], integral: next[2], egt_c: next[3] };
        }
    }

    fn to_array(self) -> [f64; 4] {
        [self.state.speed, self.state.fuel, self.state.integral, self.state.egt_c]
    }

    fn derivative(&self, s: &TurbojetState) -> [f64; 4] {
        self.derivative_of(&[s.speed, s.fuel, s.integral, s.egt_c])
    }

    /// `d/dt [n, w, i, egt]` at the held throttle.
    fn derivative_of(&self, x: &[f64; 4]) -> [f64; 4] {
        let p = &self.params;
        let [n, w, integral, egt] = *x;
        let n_ref = p.governed_speed(self.throttle_pct);
        let error = n_ref - n;
        let request = n_ref * n_ref + p.governor_kp * error + integral;
        let (lo, hi) = ((1.0 - p.decel_margin) * n * n, (1.0 + p.accel_margin) * n * n);
        let scheduled = request.clamp(lo, hi);
        // Anti-windup: the integral stops while the schedule, not the governor, sets the fuel.
        let integral_rate = if (request > hi && error > 0.0) || (request < lo && error < 0.0) {
            0.0
        } else {
            p.governor_ki_per_s * error
        };
        [
            (self.efficiency * w - n * n) / p.spool_time_constant_s,
            (scheduled - w) / p.pump_time_constant_s,
            integral_rate,
            (p.egt_target_c(n, w) - egt) / p.egt_time_constant_s,
        ]
    }
}

fn add(x: &[f64; 4], k: &[f64; 4], h: f64) -> [f64; 4] {
    [x[0] + h * k[0], x[1] + h * k[1], x[2] + h * k[2], x[3] + h * k[3]]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(engine: &mut Turbojet, throttle_pct: f64, seconds: f64) -> Vec<TurbojetSample> {
        (0..(seconds / STEP_S).round() as usize).map(|_| engine.step(throttle_pct)).collect()
    }

    /// 10–90 % rise (or fall) time of a step from `from` to `to`, s.
    fn transition_s(params: TurbojetParams, from: f64, to: f64) -> f64 {
        let mut e = Turbojet::at_rest(params, from);
        let (a, b) = (params.rest_thrust_n(from), params.rest_thrust_n(to));
        let trace = run(&mut e, to, 6.0);
        let at = |frac: f64| {
            let level = a + frac * (b - a);
            trace.iter().position(|s| (s.thrust_n - level) * (b - a).signum() >= 0.0).map(|i| (i + 1) as f64 * STEP_S)
        };
        at(0.9).unwrap_or(f64::INFINITY) - at(0.1).unwrap_or(0.0)
    }

    #[test]
    fn the_presets_are_valid_and_span_their_thrust_range() {
        for (params, idle, full) in [(TurbojetParams::p100(), 1.5, 100.0), (TurbojetParams::p220(), 5.0, 220.0)] {
            params.check().expect("preset");
            assert!((params.rest_thrust_n(25.0) - idle).abs() < 1e-9);
            assert!((params.rest_thrust_n(100.0) - full).abs() < 1e-9);
            let mut last = f64::NEG_INFINITY;
            for u in (25..=100).map(f64::from) {
                let t = params.rest_thrust_n(u);
                assert!(t > last, "thrust rises with the throttle at {u} %");
                last = t;
            }
        }
    }

    #[test]
    fn it_rests_where_its_governor_says() {
        let p = TurbojetParams::p100();
        for u in [25.0, 40.0, 60.0, 85.0, 100.0] {
            let mut e = Turbojet::at_rest(p, 30.0);
            let last = *run(&mut e, u, 10.0).last().expect("samples");
            assert!((last.thrust_n - p.rest_thrust_n(u)).abs() < 0.02, "{u} %: {} N", last.thrust_n);
            assert!(last.thrust_rate_n_per_s.abs() < 0.05);
            assert!((last.rpm - p.governed_speed(u) * p.rpm_max).abs() < 50.0);
        }
    }

    #[test]
    fn full_steps_settle_in_about_a_second_both_ways_and_stay_bounded() {
        for p in [TurbojetParams::p100(), TurbojetParams::p220()] {
            let up = transition_s(p, 25.0, 100.0);
            let down = transition_s(p, 100.0, 25.0);
            assert!((0.3..2.0).contains(&up), "25 -> 100 %: {up} s");
            assert!((0.3..2.0).contains(&down), "100 -> 25 %: {down} s");
            let mut e = Turbojet::at_rest(p, 100.0);
            let trace = run(&mut e, 25.0, 5.0);
            let lowest = trace.iter().map(|s| s.thrust_n).fold(f64::INFINITY, f64::min);
            assert!(lowest > 0.0, "no flame-out on a full step down: lowest {lowest} N");
            let mut e = Turbojet::at_rest(p, 25.0);
            let highest = run(&mut e, 100.0, 5.0).iter().map(|s| s.thrust_n).fold(0.0, f64::max);
            assert!(highest < 1.05 * p.max_thrust_n, "overshoot bounded: {highest} N");
        }
    }

    #[test]
    fn small_steps_are_faster_at_high_speed_than_near_idle() {
        let p = TurbojetParams::p100();
        let low = transition_s(p, 27.0, 32.0);
        let high = transition_s(p, 90.0, 95.0);
        assert!(high < low, "near full {high} s, near idle {low} s");
    }

    #[test]
    fn the_exhaust_runs_hot_while_the_engine_accelerates() {
        let p = TurbojetParams::p100();
        let mut e = Turbojet::at_rest(p, 25.0);
        assert!((e.sample().egt_c - p.egt_idle_c).abs() < 1e-9);
        let trace = run(&mut e, 100.0, 8.0);
        let peak = trace.iter().map(|s| s.egt_c).fold(0.0, f64::max);
        let settled = trace.last().map_or(0.0, |s| s.egt_c);
        assert!((settled - p.egt_full_c).abs() < 5.0, "settled {settled} °C");
        assert!(peak > settled + 10.0, "an acceleration overheats for a while: peak {peak} °C");
    }

    #[test]
    fn a_sagging_efficiency_loses_thrust_the_governor_wins_back() {
        let p = TurbojetParams::p100();
        let mut e = Turbojet::at_rest(p, 60.0);
        e.set_efficiency(0.9);
        let trace = run(&mut e, 60.0, 10.0);
        let dip = trace.iter().map(|s| s.thrust_n).fold(f64::INFINITY, f64::min);
        assert!(dip < p.rest_thrust_n(60.0) - 0.5, "the speed sags first: {dip} N");
        let last = trace.last().map_or(0.0, |s| s.thrust_n);
        assert!((last - p.rest_thrust_n(60.0)).abs() < 0.1, "the governor's integral wins it back: {last} N");
    }

    #[test]
    fn bad_throttles_are_held_or_clamped_never_nan() {
        let p = TurbojetParams::p100();
        let mut e = Turbojet::at_rest(p, f64::NAN);
        assert_eq!(e.sample().throttle_pct, 25.0);
        let s = e.step(70.0);
        assert_eq!(s.throttle_pct, 70.0);
        for u in [f64::NAN, f64::INFINITY, -1e9, 1e9, 0.7] {
            let s = e.step(u);
            assert!(s.thrust_n.is_finite() && s.egt_c.is_finite() && s.rpm.is_finite(), "{u}");
        }
        assert_eq!(e.step(f64::NAN).throttle_pct, 25.0, "NaN holds the last one: 0.7 % was clamped to 25 %");
    }

    #[test]
    fn bad_constants_are_named() {
        let mut p = TurbojetParams::p100();
        p.rpm_idle = 200_000.0;
        assert!(p.check().unwrap_err().contains("rpm_idle"));
        let mut p = TurbojetParams::p100();
        p.spool_time_constant_s = f64::NAN;
        assert!(p.check().unwrap_err().contains("spool_time_constant_s"));
        let mut p = TurbojetParams::p100();
        p.idle_thrust_n = 20.0;
        assert!(p.check().unwrap_err().contains("idle_thrust_n"));
    }
}
