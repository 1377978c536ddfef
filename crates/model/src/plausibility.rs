//! Is a model fit to drive a real engine? The checks a controller's model must
//! pass before the stack uses it at the bench: one stable equilibrium at every
//! throttle, and full steps each way that stay bounded (the rules of a bounded
//! model, as `identify` applies them when it writes a model file).
//!
//! ```
//! use jetbench_model::{plausibility, Preset};
//!
//! assert!(plausibility::check(&Preset::P100Diesel.params()).is_ok());
//! let mut p = Preset::P100Diesel.params();
//! p.k_t = -p.k_t; // thrust that feeds itself
//! assert!(plausibility::check(&p).is_err());
//! ```

use crate::{Engine, Params, STEP_S, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};

/// Why a model is refused for a real engine.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Implausible {
    /// Not exactly one stable equilibrium at a throttle: the engine would
    /// settle at different thrusts for the same command, or at none.
    #[error("{count} stable equilibria at {throttle_pct:.0} % throttle (a plausible engine has exactly one)")]
    Equilibria {
        /// The throttle checked, %.
        throttle_pct: f64,
        /// How many stable equilibria the model has there.
        count: usize,
    },
    /// A full throttle step makes the simulated thrust run away.
    #[error("a full step {from_pct:.0} → {to_pct:.0} % diverges after {after_s:.2} s")]
    Diverges {
        /// Throttle before the step, %.
        from_pct: f64,
        /// Throttle after the step, %.
        to_pct: f64,
        /// Time after the step at which the state stopped being finite or bounded, s.
        after_s: f64,
    },
    /// A full throttle step drives the thrust outside what an engine can make.
    #[error("a full step {from_pct:.0} → {to_pct:.0} % leaves the bounds ({thrust_n:.1} N outside {low_n:.1}..{high_n:.1} N)")]
    Unbounded {
        /// Throttle before the step, %.
        from_pct: f64,
        /// Throttle after the step, %.
        to_pct: f64,
        /// The thrust that left the band, N.
        thrust_n: f64,
        /// The band's lower edge: 10 N below the idle thrust, N.
        low_n: f64,
        /// The band's upper edge: twice the full thrust, N.
        high_n: f64,
    },
}

/// Throttles at which the equilibria are checked, %.
const THROTTLES: [f64; 8] = [25.0, 35.0, 45.0, 55.0, 65.0, 75.0, 85.0, 100.0];
/// How long each full step is simulated, s.
const STEP_RUN_S: f64 = 10.0;

/// Checks `params`: one stable equilibrium at each of [`THROTTLES`], and full
/// steps idle ↔ full (and to and from 50 %) that neither diverge nor leave
/// the band from 10 N below idle (as `identify` rules a step down) to twice full thrust.
pub fn check(params: &Params) -> Result<(), Implausible> {
    for &u in &THROTTLES {
        let count = params.equilibria(u).into_iter().filter(|e| e.stable).count();
        if count != 1 {
            return Err(Implausible::Equilibria { throttle_pct: u, count });
        }
    }
    let idle_n = params.stable_equilibrium(THROTTLE_MIN_PCT).unwrap_or(0.0);
    let full_n = params.stable_equilibrium(THROTTLE_MAX_PCT).unwrap_or(0.0);
    let (low_n, high_n) = (idle_n - 10.0, 2.0 * full_n.max(idle_n) + 10.0);
    let levels = [THROTTLE_MIN_PCT, 50.0, THROTTLE_MAX_PCT];
    for &from_pct in &levels {
        for &to_pct in &levels {
            if from_pct == to_pct {
                continue;
            }
            let mut engine = Engine::at_equilibrium(*params, from_pct);
            for k in 0..(STEP_RUN_S / STEP_S) as usize {
                let thrust_n = match engine.step(to_pct) {
                    Ok(s) => s.thrust_n,
                    Err(_) => return Err(Implausible::Diverges { from_pct, to_pct, after_s: k as f64 * STEP_S }),
                };
                if !(low_n..=high_n).contains(&thrust_n) {
                    return Err(Implausible::Unbounded { from_pct, to_pct, thrust_n, low_n, high_n });
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Preset;

    #[test]
    fn every_preset_is_checked_and_the_study_models_pass() {
        for preset in Preset::ALL {
            let verdict = check(&preset.params());
            println!("{}: {verdict:?}", preset.name());
        }
        assert_eq!(check(&Preset::P100Diesel.params()), Ok(()));
        assert_eq!(check(&Preset::P220Kerosene.params()), Ok(()));
        // The study's EKF fits: one diverges on a full step, one has no idle.
        assert!(matches!(check(&Preset::P100Ekf.params()), Err(Implausible::Diverges { .. })));
        assert!(matches!(check(&Preset::P220Ekf.params()), Err(Implausible::Equilibria { count: 0, .. })));
    }
}
