//! Feedback-linearising thrust controller (docs/model/README.md).

use jetbench_model::{Params, State, STEP_S, THROTTLE_MAX_PCT};
use serde::{Deserialize, Serialize};

use crate::throttle::throttle_for_accel;
use crate::{ControlError, Reference, ThrottleCommand};

/// Below this `|g|` (N/s² per unit of `v`) the throttle barely moves the acceleration, so
/// dividing by `g` would only amplify noise; the controller saturates instead.
pub const MIN_INPUT_GAIN: f64 = 1e-6;

/// Gains of the error dynamics `ë + kd·ė + kp·e + ki·∫e = 0`.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct FblGains {
    /// Position gain, 1/s².
    pub kp: f64,
    /// Rate gain, 1/s.
    pub kd: f64,
    /// Integral gain, 1/s³ (0 in the study). Stable while `ki < kp·kd`.
    pub ki: f64,
}

impl FblGains {
    /// Checks the gains; the error names the first bad one. Positive `kp` and `kd` make
    /// the error dynamics stable; `ki` may be zero (no integral action).
    pub fn validate(&self) -> Result<(), ControlError> {
        crate::error::check_gain("kp", self.kp, false)?;
        crate::error::check_gain("kd", self.kd, false)?;
        crate::error::check_gain("ki", self.ki, true)
    }
}

impl Default for FblGains {
    /// The study's gains: `kp = 10`, `kd = 2·√kp` (critically damped), no integral.
    fn default() -> Self {
        Self { kp: 10.0, kd: 2.0 * 10.0_f64.sqrt(), ki: 0.0 }
    }
}

/// Feedback linearisation:
///
/// ```text
/// v = (T̈_d + kp·(T_d − T) + kd·(Ṫ_d − Ṫ) + ki·∫(T_d − T) − f(T, Ṫ) − d) / g(T, Ṫ)
/// u = smallest non-negative root of u + B_UU·u² = v, clamped to [25, 100] %
/// ```
///
/// When `g ≈ 0` the throttle goes to the limit in the direction the thrust must move;
/// when `v` has no root, to the throttle in range whose `g·v(u)` comes closest to the
/// acceleration asked for. `d` is the disturbance the observer estimates (the acceleration
/// the model does not explain, [`Fbl::step_with_disturbance`]); 0 in the study's law.
/// The command is never NaN. The integral (off with the study's
/// gains) stops while the throttle is held at a limit the error pushes against, so it
/// does not wind up in saturation. Each call is one [`STEP_S`] of control.
#[derive(Clone, Debug, PartialEq)]
pub struct Fbl {
    params: Params,
    gains: FblGains,
    /// `∫(T_d − T) dt`, N·s.
    integral_ns: f64,
    /// Why the controller cannot run, found once at construction.
    invalid: Option<ControlError>,
}

impl Fbl {
    /// A controller for the model `params`. Non-finite gains or parameters do not panic:
    /// every [`Fbl::step`] then returns the reason.
    pub fn new(params: Params, gains: FblGains) -> Self {
        let invalid = crate::non_finite_setting(&[("kp", gains.kp), ("kd", gains.kd), ("ki", gains.ki)], &params);
        Self { params, gains, integral_ns: 0.0, invalid }
    }

    /// The model the law cancels.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// The gains.
    pub fn gains(&self) -> &FblGains {
        &self.gains
    }

    /// Throttle for the current state estimate and reference. Non-finite inputs return
    /// [`ControlError::NonFiniteInput`].
    pub fn step(&mut self, state: State, reference: &Reference) -> Result<ThrottleCommand, ControlError> {
        self.step_with_disturbance(state, 0.0, reference)
    }

    /// [`Fbl::step`] cancelling `disturbance_n_per_s2` too: the acceleration the state
    /// estimate carries beyond the model's. A non-finite disturbance counts as 0.
    pub fn step_with_disturbance(
        &mut self,
        state: State,
        disturbance_n_per_s2: f64,
        reference: &Reference,
    ) -> Result<ThrottleCommand, ControlError> {
        crate::check_step(self.invalid, state, reference)?;
        let disturbance = if disturbance_n_per_s2.is_finite() { disturbance_n_per_s2 } else { 0.0 };
        let State { thrust_n, thrust_rate_n_per_s } = state;
        let error_n = reference.thrust_n - thrust_n;
        let integral_ns = self.integral_ns + error_n * STEP_S;
        let accel_wanted = reference.thrust_accel_n_per_s2
            + self.gains.kp * error_n
            + self.gains.kd * (reference.thrust_rate_n_per_s - thrust_rate_n_per_s)
            + self.gains.ki * integral_ns;
        // What g·v must supply on top of the drift, N/s².
        let needed = accel_wanted - self.params.f(thrust_n, thrust_rate_n_per_s) - disturbance;
        let g = self.params.g(thrust_n, thrust_rate_n_per_s);
        let command = throttle_for_accel(&self.params, needed, g, error_n > 0.0);
        if !winds_up(&command, error_n) {
            self.integral_ns = integral_ns;
        }
        Ok(command)
    }
}

/// True when integrating `error_n` would push further against the limit the command is
/// held at (conditional-integration anti-windup).
pub(crate) fn winds_up(command: &ThrottleCommand, error_n: f64) -> bool {
    command.saturated && ((command.throttle_pct >= THROTTLE_MAX_PCT) == (error_n > 0.0))
}
