//! From the virtual input `v` a control law asks for to the throttle the ECU can take.

use jetbench_model::{Params, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};

use crate::ThrottleLimit;

/// One controller output.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ThrottleCommand {
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

impl ThrottleCommand {
    /// The limit a saturated command sits at: low at idle, high anywhere above it (full
    /// throttle, or the peak of a map that bends over). Read from the throttle, not from
    /// `unclamped_pct`: a virtual input below the map, or a fall-back to the low limit,
    /// leaves `unclamped_pct` at idle itself, not below it. A NaN throttle counts as low.
    pub fn limit(&self) -> Option<ThrottleLimit> {
        self.saturated.then_some(if self.throttle_pct > THROTTLE_MIN_PCT {
            ThrottleLimit::High
        } else {
            ThrottleLimit::Low
        })
    }
}

/// Clamps a throttle to the ECU range `[THROTTLE_MIN_PCT, THROTTLE_MAX_PCT]`; NaN gives
/// the minimum, the safe side for an engine.
pub fn clamp_throttle(u_pct: f64) -> f64 {
    if u_pct.is_nan() {
        return THROTTLE_MIN_PCT;
    }
    u_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT)
}

/// The command at a throttle limit: the maximum when the thrust must rise.
pub fn at_limit(params: &Params, more_thrust: bool) -> ThrottleCommand {
    let throttle_pct = if more_thrust { THROTTLE_MAX_PCT } else { THROTTLE_MIN_PCT };
    ThrottleCommand {
        throttle_pct,
        unclamped_pct: throttle_pct,
        virtual_input: params.v(throttle_pct),
        saturated: true,
    }
}

/// Throttle for the virtual input `v`: the positive root of `u + B_UU·u² = v`, clamped
/// to the ECU range. When `v` has no root (below the map's range, or beyond the peak of
/// `v(u)` when `B_UU < 0`), the throttle in range whose `v(u)` comes closest; ties go to
/// the lower throttle. `v` must be finite.
pub fn throttle_for_virtual(params: &Params, v: f64) -> ThrottleCommand {
    match params.invert_v(v) {
        Some(u_pct) => {
            let throttle_pct = clamp_throttle(u_pct);
            ThrottleCommand { throttle_pct, unclamped_pct: u_pct, virtual_input: v, saturated: throttle_pct != u_pct }
        }
        None => {
            let b = params.b_uu;
            let peak_pct = if b < 0.0 { clamp_throttle(-1.0 / (2.0 * b)) } else { THROTTLE_MIN_PCT };
            let throttle_pct = [THROTTLE_MIN_PCT, peak_pct, THROTTLE_MAX_PCT]
                .into_iter()
                .map(|u| (u, (params.v(u) - v).abs()))
                .fold((THROTTLE_MIN_PCT, f64::INFINITY), |best, (u, gap)| if gap < best.1 { (u, gap) } else { best })
                .0;
            ThrottleCommand { throttle_pct, unclamped_pct: throttle_pct, virtual_input: v, saturated: true }
        }
    }
}

/// Throttle that makes `g·v(u)` supply `needed` N/s² on top of the drift `f`. When `g ≈ 0`
/// or the numbers overflow, the limit in the direction `fallback_up` says.
pub fn throttle_for_accel(params: &Params, needed: f64, g: f64, fallback_up: bool) -> ThrottleCommand {
    if !needed.is_finite() || !g.is_finite() {
        return at_limit(params, fallback_up);
    }
    if g.abs() < crate::MIN_INPUT_GAIN {
        return at_limit(params, needed > 0.0);
    }
    let v = needed / g;
    if !v.is_finite() {
        return at_limit(params, fallback_up);
    }
    throttle_for_virtual(params, v)
}

/// The throttle that holds `thrust_n` at rest on the model (`f + g·v = 0` at `Ṫ = 0`), in
/// range; the minimum when no throttle does. How a controller assumes the engine was
/// driven before its first command.
pub(crate) fn resting_throttle(params: &Params, thrust_n: f64) -> f64 {
    let v = -params.f(thrust_n, 0.0) / params.g(thrust_n, 0.0);
    params.invert_v(v).map_or(THROTTLE_MIN_PCT, clamp_throttle)
}
