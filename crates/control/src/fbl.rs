//! Feedback-linearising thrust controller (plant.md).

use jetbench_model::{Params, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use serde::{Deserialize, Serialize};

use crate::{ControlError, Reference};

/// Below this `|g|` (N/s² per unit of `v`) the throttle barely moves the acceleration, so
/// dividing by `g` would only amplify noise; the controller saturates instead.
pub const MIN_INPUT_GAIN: f64 = 1e-6;

/// Gains of the error dynamics `ë + kd·ė + kp·e = 0`.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FblGains {
    /// Position gain, 1/s².
    pub kp: f64,
    /// Rate gain, 1/s.
    pub kd: f64,
}

impl Default for FblGains {
    /// The study's gains: `kp = 10`, `kd = 2·√kp` (critically damped).
    fn default() -> Self {
        Self { kp: 10.0, kd: 2.0 * 10.0_f64.sqrt() }
    }
}

/// One controller output.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Command {
    /// Throttle to apply, %, always within `[THROTTLE_MIN_PCT, THROTTLE_MAX_PCT]`.
    pub throttle_pct: f64,
    /// Throttle the law asked for before clamping, %; when it had no answer (no root,
    /// `g ≈ 0`, overflow) the limit chosen instead.
    pub unclamped_pct: f64,
    /// Virtual input `v` the law asked for; if that is not finite, `v` of the applied
    /// throttle.
    pub virtual_input: f64,
    /// True when the command is at a limit the law did not ask for: clamped, or chosen
    /// because the law had no answer. Tracking is not guaranteed while it is set.
    pub saturated: bool,
}

/// Clamps a throttle to the ECU range `[THROTTLE_MIN_PCT, THROTTLE_MAX_PCT]`; NaN gives
/// the minimum, the safe side for an engine.
pub fn clamp_throttle(u_pct: f64) -> f64 {
    if u_pct.is_nan() {
        return THROTTLE_MIN_PCT;
    }
    u_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT)
}

/// Feedback linearisation:
///
/// ```text
/// v = (T̈_d + kp·(T_d − T) + kd·(Ṫ_d − Ṫ) − f(T, Ṫ)) / g(T, Ṫ)
/// u = smallest non-negative root of u + B_UU·u² = v, clamped to [25, 100] %
/// ```
///
/// When `g ≈ 0` the throttle goes to the limit in the direction the thrust must move;
/// when `v` has no root, to the throttle in range whose `g·v(u)` comes closest to the
/// acceleration asked for. The command is never NaN.
#[derive(Clone, Debug, PartialEq)]
pub struct Fbl {
    params: Params,
    gains: FblGains,
    /// Why the controller cannot run, found once at construction.
    invalid: Option<ControlError>,
}

impl Fbl {
    /// A controller for the model `params`. Non-finite gains or parameters do not panic:
    /// every [`Fbl::step`] then returns the reason.
    pub fn new(params: Params, gains: FblGains) -> Self {
        let settings = [("kp", gains.kp), ("kd", gains.kd)];
        let invalid = settings
            .into_iter()
            .chain(Params::NAMES.into_iter().zip(params.to_array()))
            .find(|(_, value)| !value.is_finite())
            .map(|(name, value)| ControlError::InvalidSetting { name, value });
        Self { params, gains, invalid }
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
    pub fn step(
        &mut self,
        thrust_n: f64,
        thrust_rate_n_per_s: f64,
        reference: &Reference,
    ) -> Result<Command, ControlError> {
        if let Some(e) = self.invalid {
            return Err(e);
        }
        let inputs = [
            ("thrust", thrust_n),
            ("thrust rate", thrust_rate_n_per_s),
            ("reference thrust", reference.thrust_n),
            ("reference thrust rate", reference.thrust_rate_n_per_s),
            ("reference thrust acceleration", reference.thrust_accel_n_per_s2),
        ];
        if let Some((what, value)) = inputs.into_iter().find(|(_, v)| !v.is_finite()) {
            return Err(ControlError::NonFiniteInput { what, value });
        }

        let error_n = reference.thrust_n - thrust_n;
        let accel_wanted = reference.thrust_accel_n_per_s2
            + self.gains.kp * error_n
            + self.gains.kd * (reference.thrust_rate_n_per_s - thrust_rate_n_per_s);
        // What g·v must supply on top of the drift, N/s².
        let needed = accel_wanted - self.params.f(thrust_n, thrust_rate_n_per_s);
        let g = self.params.g(thrust_n, thrust_rate_n_per_s);

        if !needed.is_finite() || !g.is_finite() {
            // Overflow at absurd states: follow the tracking error, which is always finite
            // or infinite with a sign.
            return Ok(self.at_limit(error_n > 0.0));
        }
        if g.abs() < MIN_INPUT_GAIN {
            return Ok(self.at_limit(needed > 0.0));
        }
        let v = needed / g;
        match self.params.invert_v(v) {
            Some(u_pct) => {
                let throttle_pct = clamp_throttle(u_pct);
                Ok(Command { throttle_pct, unclamped_pct: u_pct, virtual_input: v, saturated: throttle_pct != u_pct })
            }
            None => {
                let throttle_pct = self.closest_reachable(needed, g);
                Ok(Command {
                    throttle_pct,
                    unclamped_pct: throttle_pct,
                    virtual_input: if v.is_finite() { v } else { self.params.v(throttle_pct) },
                    saturated: true,
                })
            }
        }
    }

    fn at_limit(&self, more_thrust: bool) -> Command {
        let throttle_pct = if more_thrust { THROTTLE_MAX_PCT } else { THROTTLE_MIN_PCT };
        Command {
            throttle_pct,
            unclamped_pct: throttle_pct,
            virtual_input: self.params.v(throttle_pct),
            saturated: true,
        }
    }

    /// Throttle in range whose `g·v(u)` is closest to `needed`: the limits, plus the peak
    /// of `v(u)` when `B_UU < 0` puts it inside the range. Ties go to the lower throttle.
    fn closest_reachable(&self, needed: f64, g: f64) -> f64 {
        let b = self.params.b_uu;
        let peak_pct = if b < 0.0 { clamp_throttle(-1.0 / (2.0 * b)) } else { THROTTLE_MIN_PCT };
        [THROTTLE_MIN_PCT, peak_pct, THROTTLE_MAX_PCT]
            .into_iter()
            .map(|u| (u, (g * self.params.v(u) - needed).abs()))
            .fold((THROTTLE_MIN_PCT, f64::INFINITY), |best, (u, cost)| if cost < best.1 { (u, cost) } else { best })
            .0
    }
}
