//! Reference shaping: what the engine can follow, from the model and the throttle limits.

use jetbench_model::{Params, STEP_S, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use serde::{Deserialize, Serialize};

use crate::{ControlError, Reference};

/// Settings of the [`ReferenceShaper`].
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ShaperSettings {
    /// Shape the reference at all; off, the law gets the profile as it is (the study).
    pub enabled: bool,
    /// Share of the model's acceleration range, at the shaped reference, that the shaped
    /// reference may use; the rest is left to feedback.
    pub authority: f64,
    /// Bandwidth with which the shaped reference closes on the profile, rad/s. Much
    /// faster than the engine, so a feasible profile passes unchanged.
    pub bandwidth_rad_per_s: f64,
}

impl ShaperSettings {
    /// Checks the settings; the error names the first bad one.
    pub fn validate(&self) -> Result<(), ControlError> {
        if !(self.authority > 0.0 && self.authority <= 1.0) {
            return Err(ControlError::SettingOutOfRange {
                name: "authority",
                value: self.authority,
                requirement: "in (0, 1]",
            });
        }
        crate::error::check_gain("bandwidth_rad_per_s", self.bandwidth_rad_per_s, false)
    }
}

impl Default for ShaperSettings {
    fn default() -> Self {
        Self { enabled: true, authority: 0.8, bandwidth_rad_per_s: 30.0 }
    }
}

/// Turns a profile into a reference the engine can follow: thrust within the model's
/// steady range `[T_eq(25 %), T_eq(100 %)]`, and an acceleration within `authority` of
/// what the model can produce between the throttle limits at the shaped reference's own
/// state:
///
/// ```text
/// a* = T̈_p + ω²·(T_p − T_s) + 2ω·(Ṫ_p − Ṫ_s)
/// a  = clamp(a*, authority · [f(T_s, Ṫ_s) + g(T_s, Ṫ_s)·v(u)  for u in [25, 100] %])
/// ```
///
/// A feasible profile passes unchanged (the shaped state then equals the profile and
/// `a = T̈_p`); a step larger than the engine can take becomes the fastest transition the
/// model allows with a margin. A law tracking the shaped reference therefore is not asked
/// for thrust it cannot reach, which is where the study's controllers lost accuracy.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceShaper {
    params: Params,
    settings: ShaperSettings,
    range_n: Option<(f64, f64)>,
    state: Option<(f64, f64)>,
}

impl ReferenceShaper {
    /// A shaper for the model `params`.
    pub fn new(params: Params, settings: ShaperSettings) -> Self {
        let range_n = match (params.stable_equilibrium(THROTTLE_MIN_PCT), params.stable_equilibrium(THROTTLE_MAX_PCT)) {
            (Some(lo), Some(hi)) if lo < hi => Some((lo, hi)),
            _ => None,
        };
        Self { params, settings, range_n, state: None }
    }

    /// The model it shapes for.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// The settings.
    pub fn settings(&self) -> &ShaperSettings {
        &self.settings
    }

    /// Starts the shaped reference at the engine's state, so the first command does not
    /// jump; without it the shaper starts on the profile.
    pub fn start_at(&mut self, thrust_n: f64, thrust_rate_n_per_s: f64) {
        if thrust_n.is_finite() && thrust_rate_n_per_s.is_finite() {
            self.state = Some((thrust_n, thrust_rate_n_per_s));
        }
    }

    /// The shaped reference now, given the profile's, and one [`STEP_S`] of progress.
    pub fn step(&mut self, profile: &Reference) -> Reference {
        if !self.settings.enabled {
            return *profile;
        }
        let (target_n, target_rate, target_accel) = match self.range_n {
            Some((lo, hi)) if profile.thrust_n < lo || profile.thrust_n > hi => {
                (profile.thrust_n.clamp(lo, hi), 0.0, 0.0)
            }
            _ => (profile.thrust_n, profile.thrust_rate_n_per_s, profile.thrust_accel_n_per_s2),
        };
        let (r, rd) = *self.state.get_or_insert((target_n, target_rate));
        let w = self.settings.bandwidth_rad_per_s;
        let wanted = target_accel + w * w * (target_n - r) + 2.0 * w * (target_rate - rd);
        let accel = match self.accel_range(r, rd) {
            Some((lo, hi)) => wanted.clamp(lo, hi),
            None => wanted,
        };
        let rd_next = rd + accel * STEP_S;
        let r_next = r + rd_next * STEP_S;
        if !(r_next.is_finite() && rd_next.is_finite()) {
            self.state = None;
            return *profile;
        }
        self.state = Some((r_next, rd_next));
        Reference { thrust_n: r, thrust_rate_n_per_s: rd, thrust_accel_n_per_s2: accel }
    }

    /// Accelerations the model reaches between the throttle limits at `(T, Ṫ)`. When the
    /// state can be held (zero acceleration is in range) both bounds shrink towards zero
    /// by `authority`, so a small margin near full thrust stays usable; otherwise the
    /// range is what it is.
    fn accel_range(&self, thrust_n: f64, thrust_rate_n_per_s: f64) -> Option<(f64, f64)> {
        let p = &self.params;
        let a = p.accel(thrust_n, thrust_rate_n_per_s, THROTTLE_MIN_PCT);
        let b = p.accel(thrust_n, thrust_rate_n_per_s, THROTTLE_MAX_PCT);
        let (lo, hi) = (a.min(b), a.max(b));
        if !(lo.is_finite() && hi.is_finite()) {
            return None;
        }
        let authority = self.settings.authority.clamp(0.0, 1.0);
        if lo <= 0.0 && hi >= 0.0 {
            Some((authority * lo, authority * hi))
        } else {
            Some((lo, hi))
        }
    }
}
