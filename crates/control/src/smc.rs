//! Sliding-mode thrust controller (docs/model/README.md).

use jetbench_model::{Params, State};
use serde::{Deserialize, Serialize};

use crate::throttle::{at_limit, throttle_for_virtual};
use crate::{ControlError, Reference, ThrottleCommand, MIN_INPUT_GAIN};

/// Gains of the sliding-mode law.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SmcGains {
    /// Slope of the sliding surface `s = a1·(T − T_d) + (Ṫ − Ṫ_d)`, 1/s.
    pub a1: f64,
    /// Switching amplitude, in units of the virtual input `v`.
    pub beta: f64,
    /// Steepness of the `tanh` boundary layer, s/N: `1/K` is the layer's half width in
    /// N/s of `s`. Smaller `K` means a wider layer, less chattering, a softer law.
    pub k: f64,
}

impl SmcGains {
    /// Checks the gains; the error names the first bad one. `beta` may be zero (the
    /// equivalent control alone).
    pub fn validate(&self) -> Result<(), ControlError> {
        crate::error::check_gain("a1", self.a1, false)?;
        crate::error::check_gain("k", self.k, false)?;
        crate::error::check_gain("beta", self.beta, true)
    }
}

impl Default for SmcGains {
    /// The study's gains: `a1 = 20`, `β = 900`, `K = 0.15`.
    fn default() -> Self {
        Self { a1: 20.0, beta: 900.0, k: 0.15 }
    }
}

/// Sliding mode:
///
/// ```text
/// s = a1·(T − T_d) + (Ṫ − Ṫ_d)
/// v = −(a1·(Ṫ − Ṫ_d) + f(T, Ṫ) − T̈_d) / g(T, Ṫ) − β·tanh(K·s)
/// u = smallest non-negative root of u + B_UU·u² = v, clamped to [25, 100] %
/// ```
///
/// The equivalent control drives `ṡ` to zero on the model; the switching term pulls `s`
/// to zero against what the model gets wrong. With the study's `β` the switching term
/// spans the whole throttle range, so noise on `Ṫ` shows as throttle chattering: the
/// tracking metrics report it as the throttle's total variation, and `k` trades it
/// against robustness. Never NaN; when `g ≈ 0` the throttle goes to the limit that
/// reduces `s`.
#[derive(Clone, Debug, PartialEq)]
pub struct Smc {
    params: Params,
    gains: SmcGains,
    invalid: Option<ControlError>,
}

impl Smc {
    /// A controller for the model `params`. Non-finite gains or parameters do not panic:
    /// every [`Smc::step`] then returns the reason.
    pub fn new(params: Params, gains: SmcGains) -> Self {
        let invalid = crate::non_finite_setting(&[("a1", gains.a1), ("beta", gains.beta), ("k", gains.k)], &params);
        Self { params, gains, invalid }
    }

    /// The gains.
    pub fn gains(&self) -> &SmcGains {
        &self.gains
    }

    /// Throttle for the current state estimate and reference.
    pub fn step(&mut self, state: State, reference: &Reference) -> Result<ThrottleCommand, ControlError> {
        crate::check_step(self.invalid, state, reference)?;
        let State { thrust_n, thrust_rate_n_per_s } = state;
        let rate_error = thrust_rate_n_per_s - reference.thrust_rate_n_per_s;
        let s = self.gains.a1 * (thrust_n - reference.thrust_n) + rate_error;
        let f = self.params.f(thrust_n, thrust_rate_n_per_s);
        let g = self.params.g(thrust_n, thrust_rate_n_per_s);
        let equivalent = -(self.gains.a1 * rate_error + f - reference.thrust_accel_n_per_s2) / g;
        let v = equivalent - self.gains.beta * (self.gains.k * s).tanh();
        if !(g.abs() >= MIN_INPUT_GAIN && v.is_finite()) {
            // s > 0: thrust above the surface, so less throttle.
            return Ok(at_limit(&self.params, s < 0.0));
        }
        Ok(throttle_for_virtual(&self.params, v))
    }
}
