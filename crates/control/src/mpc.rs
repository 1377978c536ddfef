//! Model predictive control that knows the throttle limits and the model's effects.

use std::time::Instant;

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus};
use jetbench_model::{Params, Plant, PlantEngine, State, STEP_S, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use serde::{Deserialize, Serialize};

use crate::throttle::{clamp_throttle, resting_throttle};
use crate::{ControlError, Fbl, FblGains, Profile, ThrottleCommand};

/// Settings of the [`Mpc`].
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct MpcSettings {
    /// Prediction horizon, s (at 10 ms steps). Keep it longer than the model's input
    /// delay plus the engine's rise time.
    pub horizon_s: f64,
    /// Free throttle moves over the horizon (move blocking): short blocks first, longer
    /// ones later, so the first move is 10 ms and the problem stays small.
    pub moves: usize,
    /// Weight of the squared thrust error, per N² and per 10 ms step.
    pub thrust_weight: f64,
    /// Weight of the squared throttle change between moves, per %².
    pub move_weight: f64,
    /// Gauss–Newton passes per cycle (each re-linearises the model about the plan).
    pub iterations: usize,
    /// Time budget of one cycle's optimisation, s: no further pass starts once it is
    /// spent, and the plan of the passes so far is used (the first pass always runs).
    pub time_budget_s: f64,
    /// Use the reference profile's future over the horizon (it is a known function of
    /// time); off, the reference is held at its present value.
    pub preview: bool,
    /// Bandwidth ω with which the controller's model state follows the state estimate,
    /// rad/s: the model-to-engine error decays like `s² + 2ω·s + ω²` (critically damped),
    /// with the integral's pole beside it.
    /// It is the MPC's feedback bandwidth to estimate noise and model error; the default
    /// `√10` gives the error dynamics of FBL with the study's gains (`kp = 10`,
    /// `kd = 2√10`). See [`Mpc`].
    pub correction_rad_per_s: f64,
    /// Bandwidth of the correction's integral, rad/s: how fast the controller's model
    /// learns an acceleration it lacks, the third pole of the model-to-engine error,
    /// `(s² + 2ω·s + ω²)(s + ω_i)`. A model that is off (a gain, an offset) then leaves no
    /// offset at steady state. 0 turns it off (for a model that is the engine itself, as
    /// on the simulated bench); at most `correction_rad_per_s`. See [`Mpc`].
    pub integral_rad_per_s: f64,
}

impl Default for MpcSettings {
    fn default() -> Self {
        Self {
            horizon_s: 0.8,
            moves: 10,
            thrust_weight: 1.0,
            move_weight: 0.05,
            iterations: 2,
            time_budget_s: 0.004,
            preview: true,
            correction_rad_per_s: 10.0_f64.sqrt(),
            integral_rad_per_s: INTEGRAL_RAD_PER_S,
        }
    }
}

impl MpcSettings {
    /// Checks the settings; the error names the first bad one.
    pub fn validate(&self) -> Result<(), ControlError> {
        let bad = |name: &'static str, value: f64, requirement: &'static str| {
            Err(ControlError::SettingOutOfRange { name, value, requirement })
        };
        let steps = self.horizon_s / STEP_S;
        if !(steps.is_finite() && (1.0..=1000.0).contains(&steps.round())) {
            return bad("horizon_s", self.horizon_s, "between 0.01 and 10 s");
        }
        if self.moves == 0 || self.moves > 50 || self.moves as f64 > steps.round() {
            return bad("moves", self.moves as f64, "1 to 50, and at most one per 10 ms of horizon");
        }
        if !(self.thrust_weight.is_finite() && self.thrust_weight > 0.0) {
            return bad("thrust_weight", self.thrust_weight, "a positive number");
        }
        if !(self.move_weight.is_finite() && self.move_weight >= 0.0) {
            return bad("move_weight", self.move_weight, "a number >= 0");
        }
        if self.iterations == 0 || self.iterations > 10 {
            return bad("iterations", self.iterations as f64, "1 to 10");
        }
        if !(self.time_budget_s > 0.0 && self.time_budget_s <= 0.01) {
            return bad("time_budget_s", self.time_budget_s, "in (0, 0.01] s, inside the 10 ms cycle");
        }
        if !(self.correction_rad_per_s > 0.0 && self.correction_rad_per_s <= MAX_CORRECTION_RAD_PER_S) {
            return bad(
                "correction_rad_per_s",
                self.correction_rad_per_s,
                "in (0, 20] rad/s, slow against the 10 ms cycle",
            );
        }
        if !(self.integral_rad_per_s >= 0.0 && self.integral_rad_per_s <= self.correction_rad_per_s) {
            return bad("integral_rad_per_s", self.integral_rad_per_s, "in [0, correction_rad_per_s] rad/s (0: off)");
        }
        Ok(())
    }
}

/// One MPC cycle's result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MpcOutput {
    /// The command applied.
    pub command: ThrottleCommand,
    /// True when the optimisation failed this cycle and FBL computed the command.
    pub fallback: bool,
    /// Time the cycle's optimisation took, s.
    pub solve_s: f64,
}

/// Default [`MpcSettings::integral_rad_per_s`].
const INTEGRAL_RAD_PER_S: f64 = 2.0;
/// Throttle change used for finite-difference sensitivities, %.
const PERTURBATION_PCT: f64 = 0.5;
/// RK4 steps per 10 ms in the prediction: 5 ms steps are accurate to well under the
/// sensor's resolution on this model, at a fifth of the simulator's cost.
pub(crate) const PREDICTION_SUBSTEPS: usize = 2;
/// Interior-point iterations per QP; a 10-variable box QP takes about a dozen.
const MAX_SOLVER_ITERATIONS: u32 = 40;
/// Levenberg damping of a Gauss–Newton pass, per %², keeps the QP strictly convex.
const DAMPING: f64 = 1e-4;
/// Fastest correction of the model state, rad/s: the correction is applied once per
/// 10 ms cycle, which stays close to its continuous-time design while `ω·Δt ≤ 0.2`.
const MAX_CORRECTION_RAD_PER_S: f64 = 20.0;

/// Model predictive control by sequential quadratic programming on the identified
/// model, effects included:
///
/// ```text
/// min over u_0..u_{M-1}   Σ_k q·(T_k(u) − r_k)²  +  λ·Σ_j (u_j − u_{j−1})²
/// subject to              25 % ≤ u_j ≤ 100 %
/// ```
///
/// `T_k(u)` is the model stepped over the horizon with the plan held on each move's
/// block, `r_k` the reference profile ahead. The model is the controller's own
/// [`PlantEngine`], fed with every command the controller sends, so its throttle history
/// holds what the engine has yet to see through an input delay, and its rate limiter and
/// actuator lag are where the commands have put them: the controller predicts through the
/// delay instead of fighting it. Each pass linearises `T(u)` about the plan by finite
/// differences and solves the box-constrained QP with Clarabel (an interior-point
/// solver); the plan is warm-started from the previous cycle's, and no pass starts once
/// the cycle's time budget is spent. When a pass fails (the solver does not converge in
/// its iterations, the model diverges, the numbers are not finite) the cycle's command
/// comes from feedback linearisation instead and is flagged, so the loop never stalls.
///
/// # Two degrees of freedom: plan on the model, correct it slowly
///
/// The plan starts from the model's own state `(T_m, Ṫ_m)`, not from the state estimate
/// `(T̂, Ṫ̂)`. The model runs alongside the engine on the same commands, and each cycle
/// its state is pulled towards the estimated thrust:
///
/// ```text
/// ε = T̂ − T_m        T_m += Δt·l₁·ε        Ṫ_m += Δt·l₂·ε
/// l₁ = 2ω + b        l₂ = ω² + a + l₁·b     (a = ∂T̈/∂T, b = ∂T̈/∂Ṫ of the model, here)
/// ```
///
/// which puts the poles of the model-to-engine error `e = T − T_m` at `(s + ω)²`,
/// whatever the model's own stiffness and damping at the operating point. So the two
/// jobs of a tracking controller are split:
///
/// - Feed-forward: the optimisation is fast and sees the reference ahead and the limits,
///   on a state free of estimate noise. On a reference the engine can follow, the model
///   follows it too and there is nothing to feed back; on a saturating step the model
///   knows how far the engine lags, because it was fed the same saturated throttle.
/// - Feedback: estimate noise and model error reach the throttle only through the
///   correction, at the bandwidth `ω` ([`MpcSettings::correction_rad_per_s`]). The
///   default `√10` makes the error dynamics `s² + 2√10·s + 10`, those of FBL with the
///   study's gains, so the MPC passes estimate noise to the thrust about as FBL does,
///   and a constant acceleration error `Δa` of the model would leave FBL's offset,
///   `Δa/ω²` (the study's FBL has no integral), were it not for the integral below.
///
/// # The integral: what the model lacks
///
/// The correction also integrates the innovation into a bias, an acceleration the model
/// lacks, which the model then carries on the commands sent and over the whole horizon
/// ([`MpcSettings::integral_rad_per_s`], `ω_i`; the error dynamics become
/// `(s² + 2ω·s + ω²)(s + ω_i)`):
///
/// ```text
/// b += Δt·l₃·ε      l₃ = ω²·ω_i      (l₁ and l₂ as above, for the third pole)
/// ```
///
/// A model is never the engine. Without the integral, what the model has wrong reaches
/// the throttle only through the plan's starting state; a stiff model (one that settles
/// within the horizon) forgets that state within the horizon, so the plan holds the
/// model's own equilibrium and the engine sits off the reference by the model's error
/// there. Worse, where the model is much stiffer than `ω²`, the correction cancels most of
/// its stiffness, and the corrected model can settle in a state of its own, off the
/// estimate, held there by the correction: with the ten parameters identified from the
/// turbojet plant, 3.6 N above the estimate and rising at 7 N/s while the engine held 15 %
/// under the reference. With the integral, the only state that holds is the estimate's
/// (the innovation, the integral's input, must vanish), whatever the model's stiffness. Its
/// price is on a model that is right: the bias follows the estimate's slow noise, and the
/// holds at low thrust wander more (on the study's P100 with sensor noise, the worst hold
/// of four draws 2.3 % off with `ω_i = 2`, 1.3 % without). config/sim.toml, whose engine
/// is the model, turns it off.
///
/// Re-anchoring the plan on the estimate every cycle (`ω → ∞`) makes the optimisation's
/// own bandwidth, far above FBL's, the feedback bandwidth: it chased the observer's noise
/// (sensor noise 7 N²) and the thrust wandered beyond ±1 N at steady state, so small
/// steps did not settle. The estimated rate `Ṫ̂` is not used: it is the observer's
/// noisiest output, and the model's own rate, anchored on the thrust, is smoother.
pub struct Mpc {
    plant: Plant,
    settings: MpcSettings,
    invalid: Option<ControlError>,
    /// Block boundaries in steps: move `j` is held on steps `bounds[j]..bounds[j + 1]`.
    bounds: Vec<usize>,
    fallback_law: Fbl,
    /// The model run on the commands sent, its state corrected towards the estimate.
    shadow: Option<PlantEngine>,
    /// The acceleration the model lacks, N/s²: the correction's integral, added to the
    /// model's own on the commands sent and over the horizon (see [`Mpc`]).
    bias_n_per_s2: f64,
    scratch: Option<PlantEngine>,
    last_pct: f64,
    /// Throttle the model's engine followed in its last step (after delay, rate limit,
    /// lag), %: where the correction linearises it.
    engine_pct: f64,
    plan_pct: Vec<f64>,
    shifted_pct: Vec<f64>,
    reference_n: Vec<f64>,
    nominal_n: Vec<f64>,
    perturbed_n: Vec<f64>,
    /// Sensitivities `∂T_k/∂u_j`, row-major `k·M + j`, N/%.
    sensitivity: Vec<f64>,
    qp: Option<Qp>,
    fallbacks: u64,
}

impl std::fmt::Debug for Mpc {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mpc").field("settings", &self.settings).field("fallbacks", &self.fallbacks).finish()
    }
}

impl Mpc {
    /// A controller for `plant` (the ten parameters and any effects), falling back to FBL
    /// with `fallback_gains`. Bad settings do not panic: every step returns the reason.
    pub fn new(plant: Plant, settings: MpcSettings, fallback_gains: FblGains) -> Self {
        let invalid = settings.validate().err().or_else(|| crate::non_finite_setting(&[], &plant.params));
        let steps = ((settings.horizon_s / STEP_S).round() as usize).max(1);
        let moves = settings.moves.clamp(1, steps);
        Self {
            fallback_law: Fbl::new(plant.params, fallback_gains),
            plant,
            settings,
            invalid,
            bounds: block_bounds(steps, moves),
            shadow: None,
            bias_n_per_s2: 0.0,
            scratch: None,
            last_pct: THROTTLE_MIN_PCT,
            engine_pct: THROTTLE_MIN_PCT,
            plan_pct: vec![THROTTLE_MIN_PCT; moves],
            shifted_pct: vec![THROTTLE_MIN_PCT; moves],
            reference_n: vec![0.0; steps],
            nominal_n: vec![0.0; steps],
            perturbed_n: vec![0.0; steps],
            sensitivity: vec![0.0; steps * moves],
            qp: None,
            fallbacks: 0,
        }
    }

    /// The settings.
    pub fn settings(&self) -> &MpcSettings {
        &self.settings
    }

    /// Cycles so far whose command came from the fallback law.
    pub fn fallbacks(&self) -> u64 {
        self.fallbacks
    }

    /// The current plan, one throttle per move, %.
    pub fn plan_pct(&self) -> &[f64] {
        &self.plan_pct
    }

    /// Throttle for the state estimate at `t_s` seconds into `profile`.
    pub fn step(&mut self, state: State, t_s: f64, profile: &Profile) -> Result<MpcOutput, ControlError> {
        let now = profile.at(t_s);
        crate::check_step(self.invalid, state, &now)?;
        let started = Instant::now();
        let planned = self.plan(state, t_s, profile, started);
        let solve_s = started.elapsed().as_secs_f64();
        let (command, fallback) = match planned {
            Some(u_pct) => {
                let throttle_pct = clamp_throttle(u_pct);
                let at_limit = throttle_pct <= THROTTLE_MIN_PCT + 1e-6 || throttle_pct >= THROTTLE_MAX_PCT - 1e-6;
                let command = ThrottleCommand {
                    throttle_pct,
                    unclamped_pct: u_pct,
                    virtual_input: self.plant.params.v(throttle_pct),
                    saturated: at_limit,
                };
                (command, false)
            }
            None => {
                self.fallbacks += 1;
                (self.fallback_law.step(state, &now)?, true)
            }
        };
        self.last_pct = command.throttle_pct;
        if let Some(shadow) = self.shadow.as_mut() {
            // The engine sees this command (after any delay): so must the model.
            match advance(shadow, command.throttle_pct, self.bias_n_per_s2) {
                Some(engine_pct) => self.engine_pct = engine_pct,
                None => self.shadow = None,
            }
        }
        Ok(MpcOutput { command, fallback, solve_s })
    }

    /// The first move of the optimal plan, or `None` when the optimisation failed.
    fn plan(&mut self, state: State, t_s: f64, profile: &Profile, started: Instant) -> Option<f64> {
        match self.shadow.as_mut() {
            Some(shadow) => {
                let model = ModelEstimate { state: shadow.state(), bias_n_per_s2: self.bias_n_per_s2 };
                let next = corrected(&self.plant.params, model, self.engine_pct, state, &self.settings);
                shadow.set_state(next.state);
                self.bias_n_per_s2 = next.bias_n_per_s2;
            }
            None => {
                // First cycle (or after the model diverged): start on the estimate, and
                // assume the engine has been resting at the throttle that holds its thrust.
                let u0 = resting_throttle(&self.plant.params, state.thrust_n);
                self.last_pct = u0;
                self.engine_pct = u0;
                self.plan_pct.iter_mut().for_each(|u| *u = u0);
                self.bias_n_per_s2 = 0.0;
                self.shadow = Some(self.plant.coarse_engine(state, u0, t_s, PREDICTION_SUBSTEPS));
            }
        }
        let preview = self.settings.preview;
        let held = profile.at(t_s).thrust_n;
        for (k, r) in self.reference_n.iter_mut().enumerate() {
            *r = if preview { profile.at(t_s + (k + 1) as f64 * STEP_S).thrust_n } else { held };
        }
        self.warm_start();
        for pass in 0..self.settings.iterations {
            if pass > 0 && started.elapsed().as_secs_f64() > self.settings.time_budget_s {
                break;
            }
            if self.linearise().and_then(|()| self.solve_pass()).is_none() {
                // Start the next cycle afresh: a plan held at the last command, a new solver.
                self.qp = None;
                let last = self.last_pct;
                self.plan_pct.iter_mut().for_each(|u| *u = last);
                return None;
            }
        }
        Some(self.plan_pct[0])
    }

    /// Shifts last cycle's plan one step forward in time.
    fn warm_start(&mut self) {
        let moves = self.plan_pct.len();
        for j in 0..moves {
            let step = self.bounds[j] + 1;
            let from = (0..moves).rev().find(|&i| self.bounds[i] <= step).unwrap_or(0);
            self.shifted_pct[j] = self.plan_pct[from];
        }
        self.plan_pct.copy_from_slice(&self.shifted_pct);
    }

    /// Nominal prediction and finite-difference sensitivities about the plan.
    fn linearise(&mut self) -> Option<()> {
        let moves = self.plan_pct.len();
        let shadow = self.shadow.as_ref()?;
        let scratch = self.scratch.get_or_insert_with(|| shadow.clone());
        let bias = self.bias_n_per_s2;
        rollout(shadow, scratch, bias, &self.bounds, &self.plan_pct, &mut self.nominal_n)?;
        for j in 0..moves {
            let saved = self.plan_pct[j];
            // Perturb inward, so the model is never run far outside the throttle range.
            let du =
                if saved > 0.5 * (THROTTLE_MIN_PCT + THROTTLE_MAX_PCT) { -PERTURBATION_PCT } else { PERTURBATION_PCT };
            self.plan_pct[j] = saved + du;
            let ok = rollout(shadow, scratch, bias, &self.bounds, &self.plan_pct, &mut self.perturbed_n);
            self.plan_pct[j] = saved;
            ok?;
            for (k, (p, n)) in self.perturbed_n.iter().zip(&self.nominal_n).enumerate() {
                self.sensitivity[k * moves + j] = (p - n) / du;
            }
        }
        Some(())
    }

    /// One QP in the plan change; applies it.
    fn solve_pass(&mut self) -> Option<()> {
        let moves = self.plan_pct.len();
        let qp = match self.qp.as_mut() {
            Some(qp) => qp,
            None => self.qp.insert(Qp::new(moves)?),
        };
        let (w, lambda) = (self.settings.thrust_weight, self.settings.move_weight);
        // P = w·SᵀS + λ·DᵀD + μI (upper triangle, column by column), q = w·Sᵀ(T̄ − r) + λ·Dᵀ(Dū − e₀·u₋₁).
        let mut at = 0;
        for col in 0..moves {
            for row in 0..=col {
                let mut sum = 0.0;
                for k in 0..self.nominal_n.len() {
                    sum += self.sensitivity[k * moves + row] * self.sensitivity[k * moves + col];
                }
                let dtd = match col - row {
                    0 => {
                        if col + 1 < moves {
                            2.0
                        } else {
                            1.0
                        }
                    }
                    1 => -1.0,
                    _ => 0.0,
                };
                qp.p[at] = w * sum + lambda * dtd + if row == col { DAMPING } else { 0.0 };
                at += 1;
            }
        }
        for j in 0..moves {
            let mut grad = 0.0;
            for (k, (n, r)) in self.nominal_n.iter().zip(&self.reference_n).enumerate() {
                grad += self.sensitivity[k * moves + j] * (n - r);
            }
            // (Dū − e₀·u₋₁)_i = ū_i − ū_{i−1} with ū_{−1} = the last command.
            let diff = |i: usize| self.plan_pct[i] - if i == 0 { self.last_pct } else { self.plan_pct[i - 1] };
            let mut dt_diff = diff(j);
            if j + 1 < moves {
                dt_diff -= diff(j + 1);
            }
            qp.q[j] = w * grad + lambda * dt_diff;
            qp.b[j] = THROTTLE_MAX_PCT - self.plan_pct[j];
            qp.b[moves + j] = self.plan_pct[j] - THROTTLE_MIN_PCT;
        }
        let delta = qp.solve()?;
        for (u, d) in self.plan_pct.iter_mut().zip(delta) {
            *u = (*u + d).clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT);
        }
        Some(())
    }
}

/// The controller's model: its state, and the acceleration it lacks.
#[derive(Clone, Copy, Debug, PartialEq)]
struct ModelEstimate {
    state: State,
    bias_n_per_s2: f64,
}

/// The model `model` pulled one cycle towards the `estimate`'s thrust, so that the error
/// between engine and model, a constant acceleration the model lacks included, decays like
/// `(s² + 2ω·s + ω²)(s + ω_i)` (see [`Mpc`]); the estimate itself, with no bias, where the
/// model's slopes are not finite.
fn corrected(
    params: &Params,
    model: ModelEstimate,
    engine_pct: f64,
    estimate: State,
    settings: &MpcSettings,
) -> ModelEstimate {
    let (omega, omega_i) = (settings.correction_rad_per_s, settings.integral_rad_per_s);
    let State { thrust_n, thrust_rate_n_per_s } = model.state;
    let slopes = params.accel_partials(thrust_n, thrust_rate_n_per_s, engine_pct);
    let (a, b) = (slopes.d_thrust_per_s2, slopes.d_rate_per_s);
    // The error's characteristic polynomial, s³ + (l₁ − b)s² + (l₂ − a − l₁b)s + l₃, set to
    // (s² + 2ω·s + ω²)(s + ω_i); with ω_i = 0 the two-state correction (s + ω)².
    let l1 = 2.0 * omega + omega_i + b;
    let l2 = omega * omega + 2.0 * omega * omega_i + a + l1 * b;
    let l3 = omega * omega * omega_i;
    let innovation_n = estimate.thrust_n - thrust_n;
    let next = ModelEstimate {
        state: State {
            thrust_n: thrust_n + STEP_S * l1 * innovation_n,
            thrust_rate_n_per_s: thrust_rate_n_per_s + STEP_S * l2 * innovation_n,
        },
        bias_n_per_s2: model.bias_n_per_s2 + STEP_S * l3 * innovation_n,
    };
    if [next.state.thrust_n, next.state.thrust_rate_n_per_s, next.bias_n_per_s2].iter().all(|x| x.is_finite()) {
        next
    } else {
        ModelEstimate { state: estimate, bias_n_per_s2: 0.0 }
    }
}

/// One 10 ms step of the controller's model on `throttle_pct`, with the acceleration
/// `bias_n_per_s2` it lacks added over the step; the throttle the engine followed (after
/// any delay, rate limit or lag), or `None` when the model diverges.
fn advance(engine: &mut PlantEngine, throttle_pct: f64, bias_n_per_s2: f64) -> Option<f64> {
    let sample = engine.step(throttle_pct).ok()?;
    if bias_n_per_s2 != 0.0 {
        let State { thrust_n, thrust_rate_n_per_s } = sample.state;
        engine.set_state(State {
            thrust_n: thrust_n + 0.5 * bias_n_per_s2 * STEP_S * STEP_S,
            thrust_rate_n_per_s: thrust_rate_n_per_s + bias_n_per_s2 * STEP_S,
        });
    }
    Some(sample.engine_throttle_pct)
}

/// Steps the model over the horizon with the plan, the bias held; `None` if it diverges.
fn rollout(
    shadow: &PlantEngine,
    scratch: &mut PlantEngine,
    bias_n_per_s2: f64,
    bounds: &[usize],
    plan_pct: &[f64],
    out_n: &mut [f64],
) -> Option<()> {
    scratch.clone_from(shadow);
    for (j, &u) in plan_pct.iter().enumerate() {
        for out in &mut out_n[bounds[j]..bounds[j + 1]] {
            advance(scratch, u, bias_n_per_s2)?;
            *out = scratch.state().thrust_n;
        }
    }
    Some(())
}

/// Move-blocking boundaries: quadratic spacing, so early moves are short.
fn block_bounds(steps: usize, moves: usize) -> Vec<usize> {
    let mut bounds = Vec::with_capacity(moves + 1);
    bounds.push(0);
    for j in 1..moves {
        let b = ((steps as f64) * (j as f64 / moves as f64).powi(2)).round() as usize;
        let prev = *bounds.last().unwrap_or(&0);
        // At least one step per block, and room left for the blocks still to come.
        bounds.push(b.max(prev + 1).min(steps - (moves - j)));
    }
    bounds.push(steps);
    bounds
}

/// The box-constrained QP `min ½δᵀPδ + qᵀδ  s.t.  δ ≤ b_hi, −δ ≤ b_lo`, with a dense upper
/// triangle of `P`, kept between cycles so only the numbers change.
struct Qp {
    solver: DefaultSolver<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
    b: Vec<f64>,
}

impl Qp {
    fn new(moves: usize) -> Option<Self> {
        let mut colptr = vec![0];
        let mut rowval = Vec::new();
        for col in 0..moves {
            rowval.extend(0..=col);
            colptr.push(rowval.len());
        }
        // Start from P = I, so the solver's scaling sees a well-posed problem; every
        // position of the upper triangle is stored, so later updates keep the pattern.
        let p: Vec<f64> =
            (0..moves).flat_map(|col| (0..=col).map(move |row| if row == col { 1.0 } else { 0.0 })).collect();
        let p_matrix = CscMatrix::new(moves, moves, colptr, rowval, p.clone());
        let a_matrix = CscMatrix::new(
            2 * moves,
            moves,
            (0..=moves).map(|j| 2 * j).collect(),
            (0..moves).flat_map(|j| [j, moves + j]).collect(),
            (0..moves).flat_map(|_| [1.0, -1.0]).collect(),
        );
        let settings = DefaultSettingsBuilder::default()
            .verbose(false)
            .presolve_enable(false)
            // Bounded by iterations, not the solver's clock: its clock includes the setup
            // time of the first cycle, which would fail every later solve after a slow start.
            .max_iter(MAX_SOLVER_ITERATIONS)
            .build()
            .ok()?;
        let q = vec![0.0; moves];
        let b = vec![1.0; 2 * moves];
        let solver = DefaultSolver::new(&p_matrix, &q, &a_matrix, &b, &[NonnegativeConeT(2 * moves)], settings).ok()?;
        Some(Self { solver, p, q, b })
    }

    fn solve(&mut self) -> Option<&[f64]> {
        self.solver.update_P(&self.p).ok()?;
        self.solver.update_q(&self.q).ok()?;
        self.solver.update_b(&self.b).ok()?;
        self.solver.solve();
        let ok = matches!(self.solver.solution.status, SolverStatus::Solved | SolverStatus::AlmostSolved);
        let x = &self.solver.solution.x;
        (ok && x.iter().all(|v| v.is_finite())).then_some(x.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_model::{Effects, Preset};

    /// Mean |reference − thrust| of the MPC on `model` driving `truth` through the built-in steps.
    fn tracking_mae_n(truth: &Plant, model: &Plant, settings: MpcSettings, seconds: f64) -> f64 {
        let params = truth.params;
        let (idle, max) = (params.stable_equilibrium(25.0).unwrap(), params.stable_equilibrium(100.0).unwrap());
        let profile = Profile::builtin("steps", idle, max).unwrap();
        let mut mpc = Mpc::new(model.clone(), settings, FblGains::default());
        let mut engine = truth.at_equilibrium(25.0);
        let steps = (seconds / STEP_S) as usize;
        let mut sum = 0.0;
        for k in 0..steps {
            let t_s = k as f64 * STEP_S;
            let state = engine.state();
            let out = mpc.step(state, t_s, &profile).unwrap();
            engine.step(out.command.throttle_pct).unwrap();
            sum += (profile.at(t_s).thrust_n - state.thrust_n).abs();
        }
        sum / steps as f64
    }

    #[test]
    fn the_mpc_predicts_with_a_diagnosed_discrepancy() {
        // An engine that loses input gain as it heat-soaks (a discrepancy term): with the
        // term in its model the MPC plans for the sag instead of correcting it afterwards.
        // The comparison is made with the correction's integral off, which would otherwise
        // learn part of the sag as it comes; with it on, the model without the term does
        // better than without the integral, and still not as well as the model with it.
        let soak = "discrepancy:gain_history_per_n=-0.0008,history_time_constant_s=20".parse().unwrap();
        let truth = Plant::new(Preset::P100Diesel.params(), Effects::new([soak]).unwrap());
        let blind = Plant::new(truth.params, Effects::none());
        let off = MpcSettings { integral_rad_per_s: 0.0, ..MpcSettings::default() };
        let (aware, unaware) = (tracking_mae_n(&truth, &truth, off, 40.0), tracking_mae_n(&truth, &blind, off, 40.0));
        assert!(aware < 0.8 * unaware, "MAE {aware:.2} N with the discrepancy vs {unaware:.2} N without");
        let learning = tracking_mae_n(&truth, &blind, MpcSettings::default(), 40.0);
        assert!(learning < unaware && aware < learning, "MAE {learning:.2} N without the term, the integral on");
    }
}
