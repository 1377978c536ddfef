//! Time integration of the model: the simulated engine.

use crate::{ModelError, Params, STEP_S, SUBSTEPS};

/// Beyond this thrust magnitude (N) the model has left any range it was fitted on.
pub const DIVERGENCE_THRUST_N: f64 = 1e4;
/// Beyond this thrust-rate magnitude (N/s) the model has left any range it was fitted on.
pub const DIVERGENCE_RATE_N_PER_S: f64 = 1e6;
/// Longest run [`settling_time_s`] accepts, s; bounds its cost.
pub const MAX_SETTLING_RUN_S: f64 = 3600.0;

/// Model state.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct State {
    /// Thrust, N.
    pub thrust_n: f64,
    /// Thrust rate, N/s.
    pub thrust_rate_n_per_s: f64,
}

impl State {
    /// Thrust `thrust_n` (N) rising at `thrust_rate_n_per_s` (N/s).
    pub const fn new(thrust_n: f64, thrust_rate_n_per_s: f64) -> Self {
        State { thrust_n, thrust_rate_n_per_s }
    }

    fn is_sane(&self) -> bool {
        self.thrust_n.is_finite()
            && self.thrust_rate_n_per_s.is_finite()
            && self.thrust_n.abs() <= DIVERGENCE_THRUST_N
            && self.thrust_rate_n_per_s.abs() <= DIVERGENCE_RATE_N_PER_S
    }
}

/// Where and when a run left the valid range; kept so a failed engine keeps failing.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Divergence {
    time_s: f64,
    last_finite: State,
}

impl Divergence {
    fn to_error(self) -> ModelError {
        ModelError::Diverged {
            time_s: self.time_s,
            thrust_n: self.last_finite.thrust_n,
            thrust_rate_n_per_s: self.last_finite.thrust_rate_n_per_s,
        }
    }
}

/// The simulated engine: RK4 at 1 kHz ([`SUBSTEPS`] per [`STEP_S`]) with the throttle
/// held over each step, as a PWM command is between controller cycles.
///
/// The throttle is applied as given (no clamp to 25-100 %), so what-if runs can go
/// outside the ECU range; clamping is the controller's job.
#[derive(Clone, Debug, PartialEq)]
pub struct Engine {
    params: Params,
    state: State,
    steps: u64,
    failure: Option<Divergence>,
}

impl Engine {
    /// An engine at `initial`, time 0.
    pub fn new(params: Params, initial: State) -> Self {
        Self { params, state: initial, steps: 0, failure: None }
    }

    /// An engine at rest at the stable equilibrium for `throttle_pct` (the highest-thrust
    /// one if several), or at zero thrust when there is none.
    pub fn at_equilibrium(params: Params, throttle_pct: f64) -> Self {
        let thrust_n = params.stable_equilibrium(throttle_pct).unwrap_or(0.0);
        Self::new(params, State { thrust_n, thrust_rate_n_per_s: 0.0 })
    }

    /// Current state; after a divergence, the state at the start of the failed step.
    pub fn state(&self) -> State {
        self.state
    }

    /// Simulated time, s (exactly `steps · STEP_S`, so it never drifts).
    pub fn time_s(&self) -> f64 {
        self.steps as f64 * STEP_S
    }

    /// The coefficients this engine runs on.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// True once a step has diverged; every later step returns the same error.
    pub fn has_diverged(&self) -> bool {
        self.failure.is_some()
    }

    /// Advances one [`STEP_S`] with the throttle held at `throttle_pct`.
    ///
    /// Fails with [`ModelError::Diverged`] when `|T| > DIVERGENCE_THRUST_N`,
    /// `|Ṫ| > DIVERGENCE_RATE_N_PER_S` or any value becomes non-finite, so it never
    /// returns NaN. A non-finite throttle fails with [`ModelError::InvalidThrottle`] and
    /// changes nothing.
    pub fn step(&mut self, throttle_pct: f64) -> Result<State, ModelError> {
        if let Some(failure) = self.failure {
            return Err(failure.to_error());
        }
        if !throttle_pct.is_finite() {
            return Err(ModelError::InvalidThrottle { throttle_pct });
        }
        let h = STEP_S / SUBSTEPS as f64;
        let first_substep = self.steps * SUBSTEPS as u64;
        let mut x = self.state;
        if !x.is_sane() {
            return Err(self.fail(self.time_s(), x));
        }
        for i in 0..SUBSTEPS as u64 {
            let next = rk4(&self.params, x, throttle_pct, h);
            if !next.is_sane() {
                let time_s = (first_substep + i + 1) as f64 * h;
                let last_finite =
                    if next.thrust_n.is_finite() && next.thrust_rate_n_per_s.is_finite() { next } else { x };
                return Err(self.fail(time_s, last_finite));
            }
            x = next;
        }
        self.state = x;
        self.steps += 1;
        Ok(x)
    }

    fn fail(&mut self, time_s: f64, last_finite: State) -> ModelError {
        let failure = Divergence { time_s, last_finite };
        self.failure = Some(failure);
        failure.to_error()
    }
}

/// One classic Runge-Kutta step of `[Ṫ, T̈]` with the throttle held.
fn rk4(p: &Params, x: State, throttle_pct: f64, h: f64) -> State {
    let (thrust_n, thrust_rate_n_per_s) =
        rk4_step(x.thrust_n, x.thrust_rate_n_per_s, h, |t, d| p.accel(t, d, throttle_pct));
    State { thrust_n, thrust_rate_n_per_s }
}

/// One classic Runge–Kutta step of length `h` of `Ṫ = d, ḋ = accel(T, d)` from
/// `(t, d)`: the integrator of every simulator in the project. Always inlined: a free run
/// is this step and little else, and left to itself the compiler calls it out of the
/// larger run loops, which costs a tenth of a diagnosis.
#[inline(always)]
pub fn rk4_step(t: f64, d: f64, h: f64, accel: impl Fn(f64, f64) -> f64) -> (f64, f64) {
    let k1 = (d, accel(t, d));
    let k2 = (d + 0.5 * h * k1.1, accel(t + 0.5 * h * k1.0, d + 0.5 * h * k1.1));
    let k3 = (d + 0.5 * h * k2.1, accel(t + 0.5 * h * k2.0, d + 0.5 * h * k2.1));
    let k4 = (d + h * k3.1, accel(t + h * k3.0, d + h * k3.1));
    (t + h / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0), d + h / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1))
}

/// [`rk4_step`] of `N` independent states at once, stage by stage, with `accel(lane, t, d)`:
/// each lane's operations are those of [`rk4_step`], in its order (the same values bit for
/// bit), and the lanes' chains of dependent operations sit side by side for the core to
/// overlap.
#[inline(always)]
pub(crate) fn rk4_step_lanes<const N: usize>(
    t: [f64; N],
    d: [f64; N],
    h: f64,
    accel: impl Fn(usize, f64, f64) -> f64,
) -> ([f64; N], [f64; N]) {
    let (mut k1, mut k2, mut k3, mut k4) = ([(0.0, 0.0); N], [(0.0, 0.0); N], [(0.0, 0.0); N], [(0.0, 0.0); N]);
    for l in 0..N {
        k1[l] = (d[l], accel(l, t[l], d[l]));
    }
    for l in 0..N {
        k2[l] = (d[l] + 0.5 * h * k1[l].1, accel(l, t[l] + 0.5 * h * k1[l].0, d[l] + 0.5 * h * k1[l].1));
    }
    for l in 0..N {
        k3[l] = (d[l] + 0.5 * h * k2[l].1, accel(l, t[l] + 0.5 * h * k2[l].0, d[l] + 0.5 * h * k2[l].1));
    }
    for l in 0..N {
        k4[l] = (d[l] + h * k3[l].1, accel(l, t[l] + h * k3[l].0, d[l] + h * k3[l].1));
    }
    let (mut t_next, mut d_next) = ([0.0; N], [0.0; N]);
    for l in 0..N {
        t_next[l] = t[l] + h / 6.0 * (k1[l].0 + 2.0 * k2[l].0 + 2.0 * k3[l].0 + k4[l].0);
        d_next[l] = d[l] + h / 6.0 * (k1[l].1 + 2.0 * k2[l].1 + 2.0 * k3[l].1 + k4[l].1);
    }
    (t_next, d_next)
}

/// Free run: one throttle value per [`STEP_S`]; returns the state after each step.
pub fn simulate(params: &Params, initial: State, throttle_pct: &[f64]) -> Result<Vec<State>, ModelError> {
    let mut engine = Engine::new(*params, initial);
    throttle_pct.iter().map(|&u| engine.step(u)).collect()
}

/// 10-90 % rise time (s) of a throttle step `from_pct -> to_pct`, starting at rest at the
/// stable equilibrium for `from_pct`, for plausibility checks of identified models.
///
/// The run lasts `max_s`; the final value is the thrust at its end. `None` when the
/// response has not settled by then (it still moves by more than 2 % of the step, or
/// 0.05 N, over the last second or last quarter of the run). `Some(0.0)` when the step
/// does not change the thrust. Divergence is returned as an error.
pub fn settling_time_s(params: &Params, from_pct: f64, to_pct: f64, max_s: f64) -> Result<Option<f64>, ModelError> {
    for throttle_pct in [from_pct, to_pct] {
        if !throttle_pct.is_finite() {
            return Err(ModelError::InvalidThrottle { throttle_pct });
        }
    }
    if !(max_s > 0.0 && max_s <= MAX_SETTLING_RUN_S) {
        return Err(ModelError::InvalidArgument { name: "max_s", value: max_s, expected: "a duration in (0, 3600] s" });
    }
    let steps = (max_s / STEP_S).round().max(1.0) as usize;
    let mut engine = Engine::at_equilibrium(*params, from_pct);
    let start_n = engine.state().thrust_n;
    let mut thrust_n = Vec::with_capacity(steps + 1);
    thrust_n.push(start_n);
    for _ in 0..steps {
        thrust_n.push(engine.step(to_pct)?.thrust_n);
    }
    let end_n = thrust_n.last().copied().unwrap_or(start_n);
    let change_n = end_n - start_n;
    let window = ((1.0 / STEP_S) as usize).min(steps / 4).max(1);
    let band_n = (0.02 * change_n.abs()).max(0.05);
    let tail = &thrust_n[thrust_n.len() - window..];
    if tail.iter().any(|t| (t - end_n).abs() > band_n) {
        return Ok(None);
    }
    if change_n.abs() < 1e-9 {
        return Ok(Some(0.0));
    }
    let crossing_s = |fraction: f64| -> Option<f64> {
        let level = |t: f64| (t - start_n) / change_n;
        thrust_n.windows(2).enumerate().find_map(|(k, w)| {
            let (a, b) = (level(w[0]), level(w[1]));
            (b >= fraction && a < fraction).then(|| (k as f64 + (fraction - a) / (b - a)) * STEP_S)
        })
    };
    Ok(match (crossing_s(0.1), crossing_s(0.9)) {
        (Some(t10), Some(t90)) => Some(t90 - t10),
        _ => None,
    })
}
