//! The extended Kalman filter of thrust, thrust rate and unexplained acceleration.

use jetbench_model::{Params, DIVERGENCE_RATE_N_PER_S, DIVERGENCE_THRUST_N, STEP_S};
use nalgebra::{Matrix3, Vector3};

use crate::gate::{Gate, GateConfig, Verdict};
use jetbench_model::{RateSchedule, ThrottlePath, MAX_INPUT_DELAY_S};

type Mat3 = Matrix3<f64>;
type Vec3 = Vector3<f64>;

/// The rate estimate has settled once its variance is within this factor of the filter's
/// steady value ([`ThrustObserver::settling`]): its standard deviation within twice the
/// steady one.
pub const SETTLED_RATE_VAR_FACTOR: f64 = 4.0;

/// Measurements after a start or a restart by which the rate counts as settled whatever its
/// variance, 1 s at 100 Hz: a filter that never reaches [`SETTLED_RATE_VAR_FACTOR`] of the
/// steady value computed for it never holds a law back for longer.
pub const MAX_SETTLING_STEPS: u32 = 100;

/// Errors of the observer; `Copy` so a rejected configuration can be reported on every step.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum EstimError {
    /// A measurement or throttle is NaN or infinite; the sample was dropped.
    #[error("{what} is not finite ({value}); sample ignored, observer state unchanged")]
    NonFiniteInput {
        /// Which input.
        what: &'static str,
        /// The offending value.
        value: f64,
    },
    /// The configuration cannot describe a filter.
    #[error("observer setting {name} = {value} is invalid: it must be finite and {requirement}")]
    InvalidConfig {
        /// Field of [`ObserverConfig`].
        name: &'static str,
        /// The offending value.
        value: f64,
        /// What is accepted.
        requirement: &'static str,
    },
    /// A model parameter is not finite, so no prediction is possible.
    #[error("model parameter {name} is not finite ({value}); fix the model before estimating")]
    InvalidParams {
        /// Parameter name (`K_T`, ...).
        name: &'static str,
        /// The offending value.
        value: f64,
    },
}

/// Noise levels of the observer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObserverConfig {
    /// Variance of the thrust measurement, N² (about 7 on the P100 bench, 9 on the P220).
    pub measurement_var_n2: f64,
    /// Standard deviation of the acceleration the model does not explain, white from one
    /// 10 ms step to the next, N/s²: the process noise. Larger trusts the model less and
    /// follows real steps faster, and passes more sensor noise into the rate.
    pub accel_noise_n_per_s2: f64,
    /// How fast the persistent part of the unexplained acceleration (the disturbance: a
    /// slightly wrong model, a slow drift) may change: the standard deviation of its
    /// change over one second, N/s² (a random walk). The filter estimates it as a third
    /// state and FBL cancels it. 0 turns the state off: the disturbance stays 0 and the
    /// filter is the plain 2-state EKF of `[T, Ṫ]`, bit for bit.
    pub disturbance_drift_n_per_s2: f64,
    /// The model's input delay, s (its `input_delay` effect; 0: none): the engine
    /// follows the throttle applied that long ago, so the filter predicts with that one.
    /// At most [`MAX_INPUT_DELAY_S`]. At 0 the filter predicts with the throttle just
    /// applied, bit for bit as before delays were modelled.
    pub input_delay_s: f64,
    /// The model's acceleration schedule (its `accel_schedule` effect; `None`: the model
    /// is not paced): the predicted thrust rate is held within the schedule's bounds, as
    /// the engine holds its own. A paced model's ten parameters alone run faster than the
    /// engine wherever the schedule binds, so without it the prediction runs away on every
    /// large step.
    pub rate_schedule: Option<RateSchedule>,
    /// Thrust variance right after the first measurement, N².
    pub initial_thrust_var_n2: f64,
    /// Thrust-rate variance right after the first measurement, (N/s)².
    pub initial_rate_var: f64,
    /// Which measurements are plausible enough to use (spikes, a stuck sensor).
    pub gate: GateConfig,
}

impl Default for ObserverConfig {
    /// P100 bench noise, 200 N/s² of unmodelled acceleration and no disturbance state:
    /// a filter that assumes little of the model. With the study's P100 sets (off by 4-7
    /// N) on simulated diesel data it keeps the worst thrust error near 4-5 N on full
    /// steps, while the rate stays far smoother than a first difference. 10 N/s² with a
    /// disturbance drift of 1.5 N/s² is the calm tuning of the bench: one measurement
    /// then moves the FBL throttle by under 1 % (crates/stack/tests/injected.rs; the
    /// trade in crates/estim/README.md). No input delay.
    fn default() -> Self {
        Self {
            measurement_var_n2: 7.0,
            accel_noise_n_per_s2: 200.0,
            disturbance_drift_n_per_s2: 0.0,
            input_delay_s: 0.0,
            rate_schedule: None,
            initial_thrust_var_n2: 7.0,
            initial_rate_var: 1.0e4,
            gate: GateConfig::default(),
        }
    }
}

impl ObserverConfig {
    /// Checks every field is finite and in range.
    pub fn validate(&self) -> Result<(), EstimError> {
        let checks = [
            ("measurement_var_n2", self.measurement_var_n2, true),
            // Zero would make the filter trust the model forever and stop hearing the sensor.
            ("accel_noise_n_per_s2", self.accel_noise_n_per_s2, true),
            ("disturbance_drift_n_per_s2", self.disturbance_drift_n_per_s2, false),
            ("initial_thrust_var_n2", self.initial_thrust_var_n2, false),
            ("initial_rate_var", self.initial_rate_var, false),
        ];
        if !(0.0..=MAX_INPUT_DELAY_S).contains(&self.input_delay_s) {
            return Err(EstimError::InvalidConfig {
                name: "input_delay_s",
                value: self.input_delay_s,
                requirement: "in [0, 2] s",
            });
        }
        for (name, value, strictly_positive) in checks {
            let ok = value.is_finite() && if strictly_positive { value > 0.0 } else { value >= 0.0 };
            if !ok {
                return Err(EstimError::InvalidConfig {
                    name,
                    value,
                    requirement: if strictly_positive { "> 0" } else { ">= 0" },
                });
            }
        }
        self.gate.validate()
    }
}

/// One observer output.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Estimate {
    /// Estimated thrust, N.
    pub thrust_n: f64,
    /// Estimated thrust rate, N/s.
    pub thrust_rate_n_per_s: f64,
    /// Estimated acceleration: the model's `f + g·v` at the estimate and the last
    /// throttle applied, plus the disturbance, N/s² (with an input delay the engine
    /// still follows an earlier throttle: this is the acceleration once it follows
    /// the last one). Where a paced model's rate runs on its schedule
    /// ([`ObserverConfig::rate_schedule`]), the rate at which that bound moves.
    pub thrust_accel_n_per_s2: f64,
    /// The disturbance: acceleration the model does not explain, estimated, N/s² (0 with
    /// [`ObserverConfig::disturbance_drift_n_per_s2`] = 0).
    pub disturbance_n_per_s2: f64,
    /// Measurement minus predicted thrust, N (0 on the first sample).
    pub innovation_n: f64,
    /// The throttle the prediction assumed the engine followed: the one applied an
    /// input delay ago ([`ObserverConfig::input_delay_s`]; with none, the one just
    /// applied), %.
    pub engine_throttle_pct: f64,
    /// Variance of the thrust estimate, N².
    pub thrust_var_n2: f64,
    /// Variance of the rate estimate, (N/s)².
    pub thrust_rate_var: f64,
    /// Whether the measurement was used ([`crate::gate`]).
    pub verdict: Verdict,
}

/// EKF of `[T, Ṫ, d]` at [`STEP_S`], `d` the disturbance ([`ObserverConfig`]), predicting
/// through the model's input delay. Fixed-size algebra only, so a step never allocates;
/// plain `f64` arithmetic in a fixed order, so equal inputs give bit-identical outputs.
#[derive(Clone, Debug)]
pub struct ThrustObserver {
    params: Params,
    config: ObserverConfig,
    process_noise: Mat3,
    /// Why the observer cannot run, found once at construction.
    invalid: Option<EstimError>,
    /// `None` until the first measurement.
    state: Option<(Vec3, Mat3)>,
    fallbacks: u64,
    gate: Gate,
    gated: Gated,
    /// The throttle path to the engine (`None` when it leaves the throttle as applied).
    path: Option<ThrottlePath>,
    /// The rate variance the rate has settled at ([`SETTLED_RATE_VAR_FACTOR`] times the
    /// filter's steady value), (N/s)².
    settled_rate_var: f64,
    /// Measurements left before the rate counts as settled whatever its variance; `None`
    /// once it has settled (or before the first measurement).
    settling_left: Option<u32>,
}

impl ThrustObserver {
    /// An observer for `params`. Bad parameters or settings do not panic: every
    /// [`ThrustObserver::step`] then returns the reason as an error.
    pub fn new(params: Params, config: ObserverConfig) -> Self {
        let invalid = Params::NAMES
            .iter()
            .zip(params.to_array())
            .find(|(_, value)| !value.is_finite())
            .map(|(&name, value)| EstimError::InvalidParams { name, value })
            .or_else(|| config.validate().err());
        // White unmodelled acceleration a enters as [Δt²/2, Δt, 0]·a; the disturbance
        // walks by its drift's variance per second, times Δt.
        let dt = STEP_S;
        let gain = Vec3::new(0.5 * dt * dt, dt, 0.0);
        let sigma = config.accel_noise_n_per_s2;
        let mut process_noise = gain * gain.transpose() * (sigma * sigma);
        process_noise[(2, 2)] = config.disturbance_drift_n_per_s2.powi(2) * dt;
        Self {
            params,
            config,
            process_noise,
            invalid,
            state: None,
            fallbacks: 0,
            gate: Gate::default(),
            gated: Gated::default(),
            path: (config.input_delay_s > 0.0).then(|| ThrottlePath::delay_only(config.input_delay_s)),
            settled_rate_var: SETTLED_RATE_VAR_FACTOR * steady_rate_var(&process_noise, config.measurement_var_n2),
            settling_left: None,
        }
    }

    /// One 10 ms cycle: predict over the last interval with `throttle_pct`, the throttle
    /// that was applied during it (or, with an input delay, the one applied that long
    /// before), then correct with `thrust_meas_n`.
    ///
    /// The first call initialises the thrust from the measurement (rate 0). A non-finite
    /// input returns [`EstimError::NonFiniteInput`] and changes nothing. A measurement the
    /// gate finds implausible ([`crate::gate`]: a spike, a stuck sensor) is not used: the
    /// estimate is the prediction, and [`Estimate::verdict`] says why. When the model
    /// prediction is non-finite or leaves the model's range (a bad or locally valid model),
    /// that step uses a constant-rate prediction instead and [`ThrustObserver::fallbacks`]
    /// counts it, so the output is never NaN.
    pub fn step(&mut self, thrust_meas_n: f64, throttle_pct: f64) -> Result<Estimate, EstimError> {
        if let Some(e) = self.invalid {
            return Err(e);
        }
        if !thrust_meas_n.is_finite() {
            return Err(EstimError::NonFiniteInput { what: "thrust measurement", value: thrust_meas_n });
        }
        if !throttle_pct.is_finite() {
            return Err(EstimError::NonFiniteInput { what: "throttle", value: throttle_pct });
        }
        let engine_pct = self.path.as_mut().map_or(throttle_pct, |path| path.cycle_mean(throttle_pct));
        let Some((x, p)) = self.state else {
            let (x, p) = self.initial(thrust_meas_n);
            self.state = Some((x, p));
            self.gate.first(thrust_meas_n);
            self.settling_left = Some(MAX_SETTLING_STEPS);
            return Ok(self.estimate(&x, &p, [throttle_pct, engine_pct], 0.0, Verdict::Accepted));
        };

        let (x_pred, f) = match self.predict(&x, engine_pct) {
            Some(prediction) => prediction,
            None => {
                self.fallbacks += 1;
                constant_rate(&x)
            }
        };
        let p_pred = f * p * f.transpose() + self.process_noise;

        // Scalar measurement y = T, so the gain is a column of P over a scalar.
        let innovation_n = thrust_meas_n - x_pred[0];
        let s = p_pred[(0, 0)] + self.config.measurement_var_n2;
        let verdict = self.gate.judge(&self.config.gate, thrust_meas_n, innovation_n * innovation_n / s);
        let (x_new, p_new) = match verdict {
            Verdict::Accepted => {
                let k = Vec3::new(p_pred[(0, 0)] / s, p_pred[(1, 0)] / s, p_pred[(2, 0)] / s);
                let x_new = x_pred + k * innovation_n;
                // Joseph form keeps P symmetric positive semi-definite under rounding.
                let i_kh = Mat3::new(1.0 - k[0], 0.0, 0.0, -k[1], 1.0, 0.0, -k[2], 0.0, 1.0);
                let r = self.config.measurement_var_n2;
                let p_new = i_kh * p_pred * i_kh.transpose() + k * k.transpose() * r;
                (x_new, (p_new + p_new.transpose()) * 0.5)
            }
            // The measurement is not used: the prediction stands, and its growing
            // variance widens the gate for the measurements that follow.
            Verdict::Rejected | Verdict::Stuck => (x_pred, (p_pred + p_pred.transpose()) * 0.5),
            // The thrust is where the sensor says, however far from the model; the
            // rate and the disturbance are kept, with the variances of a fresh start.
            Verdict::Restarted => (Vec3::new(thrust_meas_n, x_pred[1], x_pred[2]), self.initial(thrust_meas_n).1),
        };
        match verdict {
            Verdict::Accepted => {}
            Verdict::Rejected => self.gated.rejected += 1,
            Verdict::Stuck => self.gated.stuck += 1,
            Verdict::Restarted => self.gated.restarts += 1,
        }

        let (x_new, p_new, innovation_n) = if x_new.iter().chain(p_new.iter()).all(|v| v.is_finite()) {
            (x_new, p_new, innovation_n)
        } else {
            // Only reachable with absurd (finite) inputs; restart rather than emit NaN.
            self.fallbacks += 1;
            let (x0, p0) = self.initial(thrust_meas_n);
            (x0, p0, 0.0)
        };
        self.state = Some((x_new, p_new));
        self.settle(verdict, p_new[(1, 1)]);
        Ok(self.estimate(&x_new, &p_new, [throttle_pct, engine_pct], innovation_n, verdict))
    }

    /// Whether the rate estimate is still settling after the filter started or restarted:
    /// its variance not yet down to [`SETTLED_RATE_VAR_FACTOR`] times the steady value, for
    /// at most [`MAX_SETTLING_STEPS`] measurements. Until then the rate follows the first
    /// differences of the measurements more than the model, as noisy as they are (at 7 N²
    /// of sensor noise, tens of N/s), and a law acting on it throws the throttle about.
    /// Once settled it stays settled until the next restart: measurements rejected or a
    /// stuck sensor widen the variance without making the rate a first difference again.
    pub fn settling(&self) -> bool {
        self.settling_left.is_some()
    }

    /// Counts one measurement towards the rate's settling; a restart settles afresh.
    fn settle(&mut self, verdict: Verdict, rate_var: f64) {
        if verdict == Verdict::Restarted {
            self.settling_left = Some(MAX_SETTLING_STEPS);
            return;
        }
        self.settling_left = match self.settling_left {
            Some(left) if left > 1 && rate_var > self.settled_rate_var => Some(left - 1),
            _ => None,
        };
    }

    /// The observer predicting through a model's whole throttle path (input delay, rate
    /// limit and actuator lag: [`ThrottlePath::new`] of the model's effects) instead of
    /// the delay alone of [`ObserverConfig::input_delay_s`]: it predicts each cycle with
    /// the mean throttle the engine follows over it ([`ThrottlePath::cycle_mean`]). A
    /// path of a delay alone predicts exactly as that delay in the config does.
    pub fn with_throttle_path(mut self, path: ThrottlePath) -> Self {
        self.path = path.shapes().then_some(path);
        self
    }

    /// Forgets the estimate and the fallback count; the next step initialises again.
    pub fn reset(&mut self) {
        self.state = None;
        self.settling_left = None;
        self.fallbacks = 0;
        self.gate = Gate::default();
        self.gated = Gated::default();
        if let Some(path) = self.path.as_mut() {
            path.clear();
        }
    }

    /// Steps whose model prediction was unusable and replaced by a constant-rate one.
    pub fn fallbacks(&self) -> u64 {
        self.fallbacks
    }

    /// Measurements the gate rejected as implausible (spikes), ignored as stuck, and
    /// restarted the filter at, since the start.
    pub fn gated(&self) -> Gated {
        self.gated
    }

    /// The model the filter predicts with.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// The noise settings.
    pub fn config(&self) -> &ObserverConfig {
        &self.config
    }

    /// Thrust from the measurement, rate 0, no disturbance: the disturbance is learnt
    /// from the data at its drift's pace, never guessed.
    fn initial(&self, thrust_meas_n: f64) -> (Vec3, Mat3) {
        let c = &self.config;
        (
            Vec3::new(thrust_meas_n, 0.0, 0.0),
            Mat3::from_diagonal(&Vec3::new(c.initial_thrust_var_n2, c.initial_rate_var, 0.0)),
        )
    }

    /// Model prediction and its Jacobian, or `None` when either is unusable.
    fn predict(&self, x: &Vec3, throttle_pct: f64) -> Option<(Vec3, Mat3)> {
        let dt = STEP_S;
        let (t, rate, disturbance) = (x[0], x[1], x[2]);
        let a = self.params.accel(t, rate, throttle_pct) + disturbance;
        let free = Vec3::new(t + rate * dt + 0.5 * a * dt * dt, rate + a * dt, disturbance);
        let partials = self.params.accel_partials(t, rate, throttle_pct);
        let (a_t, a_d) = (partials.d_thrust_per_s2, partials.d_rate_per_s);
        #[rustfmt::skip]
        let f = Mat3::new(
            1.0 + 0.5 * a_t * dt * dt, dt + 0.5 * a_d * dt * dt, 0.5 * dt * dt,
            a_t * dt,                  1.0 + a_d * dt,           dt,
            0.0,                       0.0,                      1.0,
        );
        let (x_pred, f) = match self.config.rate_schedule {
            Some(schedule) if schedule.bound(free[0], free[1]) != free[1] => {
                // The rate runs on the schedule: it is the bound at the thrust reached,
                // which moves with the thrust alone (the throttle and the disturbance do
                // not move it), and the thrust integrates it.
                let held = schedule.bound(free[0], free[1]);
                let slope = schedule.bound_slope(free[0], free[1]);
                #[rustfmt::skip]
                let f = Mat3::new(
                    1.0 + 0.5 * slope * dt, 0.5 * dt,               0.0,
                    slope,                  0.5 * slope * dt,       0.0,
                    0.0,                    0.0,                    1.0,
                );
                (Vec3::new(t + 0.5 * (rate + held) * dt, held, disturbance), f)
            }
            _ => (free, f),
        };
        let usable = x_pred.iter().chain(f.iter()).all(|v| v.is_finite())
            && x_pred[0].abs() <= DIVERGENCE_THRUST_N
            && x_pred[1].abs() <= DIVERGENCE_RATE_N_PER_S;
        usable.then_some((x_pred, f))
    }

    /// The estimate at `x`, `p`; `[applied, engine]`: the throttle just applied and the
    /// one the engine followed.
    fn estimate(
        &self,
        x: &Vec3,
        p: &Mat3,
        [applied_pct, engine_pct]: [f64; 2],
        innovation_n: f64,
        verdict: Verdict,
    ) -> Estimate {
        let mut accel = self.params.accel(x[0], x[1], applied_pct) + x[2];
        if let Some(schedule) = self.config.rate_schedule {
            // On the schedule the rate follows its bound, which moves with the thrust.
            let free = x[1] + accel * STEP_S;
            if schedule.bound(x[0], free) != free {
                accel = schedule.bound_slope(x[0], free) * x[1];
            }
        }
        Estimate {
            thrust_n: x[0],
            thrust_rate_n_per_s: x[1],
            thrust_accel_n_per_s2: if accel.is_finite() { accel } else { 0.0 },
            disturbance_n_per_s2: x[2],
            innovation_n,
            engine_throttle_pct: engine_pct,
            thrust_var_n2: p[(0, 0)],
            thrust_rate_var: p[(1, 1)],
            verdict,
        }
    }
}

/// The rate variance a filter with `process_noise` and `measurement_var_n2` settles at on an
/// engine whose model adds nothing to the rate's memory: the steady state of the covariance
/// recursion of `[T, Ṫ, d]` with the thrust integrating the rate and the rate the disturbance
/// (a constant-acceleration filter). An engine model damps the rate and only lowers the
/// steady value, so the rate's variance comes down to it. Iterated from a filter that knows
/// nothing until it changes by less than one part in 10⁹ (at most 10 000 steps: a 3×3
/// recursion, once per observer).
fn steady_rate_var(process_noise: &Mat3, measurement_var_n2: f64) -> f64 {
    let dt = STEP_S;
    let f = Mat3::new(1.0, dt, 0.5 * dt * dt, 0.0, 1.0, dt, 0.0, 0.0, 1.0);
    let mut p = Mat3::from_diagonal(&Vec3::new(measurement_var_n2, 1.0e4, 0.0));
    for _ in 0..10_000 {
        let pred = f * p * f.transpose() + process_noise;
        let s = pred[(0, 0)] + measurement_var_n2;
        let k = Vec3::new(pred[(0, 0)] / s, pred[(1, 0)] / s, pred[(2, 0)] / s);
        let i_kh = Mat3::new(1.0 - k[0], 0.0, 0.0, -k[1], 1.0, 0.0, -k[2], 0.0, 1.0);
        let next = i_kh * pred * i_kh.transpose() + k * k.transpose() * measurement_var_n2;
        let done = (next[(1, 1)] - p[(1, 1)]).abs() <= 1e-9 * next[(1, 1)];
        p = (next + next.transpose()) * 0.5;
        if done {
            break;
        }
    }
    p[(1, 1)]
}

/// Counts of measurements the gate did not use ([`ThrustObserver::gated`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Gated {
    /// Measurements rejected as implausible (a spike: the innovation failed the
    /// chi-square test); the estimate was the prediction.
    pub rejected: u64,
    /// Measurements ignored because the sensor repeated the same reading bit for bit
    /// ([`GateConfig::stuck_after_samples`] times or more).
    pub stuck: u64,
    /// Times the filter restarted at the measurement after
    /// [`GateConfig::max_rejections`] rejections in a row (a real jump, or a bad first
    /// sample).
    pub restarts: u64,
}

/// Constant-rate prediction, used when the model's own prediction is unusable.
fn constant_rate(x: &Vec3) -> (Vec3, Mat3) {
    let dt = STEP_S;
    (Vec3::new(x[0] + x[1] * dt, x[1], x[2]), Mat3::new(1.0, dt, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_model::Preset;

    #[test]
    fn jacobian_matches_finite_differences_of_the_transition() {
        let observer = ThrustObserver::new(Preset::P100Ekf.params(), ObserverConfig::default());
        let x = Vec3::new(40.0, 15.0, 3.0);
        let u = 80.0;
        let (_, f) = observer.predict(&x, u).unwrap();
        let h = 1e-6;
        for col in 0..3 {
            let mut plus = x;
            let mut minus = x;
            plus[col] += h;
            minus[col] -= h;
            let (xp, _) = observer.predict(&plus, u).unwrap();
            let (xm, _) = observer.predict(&minus, u).unwrap();
            let numeric = (xp - xm) / (2.0 * h);
            for row in 0..3 {
                assert!(
                    (f[(row, col)] - numeric[row]).abs() < 1e-6,
                    "F[{row},{col}] = {} vs {}",
                    f[(row, col)],
                    numeric[row]
                );
            }
        }
    }
}
