//! Identification campaigns: open-loop throttle profiles that excite every term
//! of the model (docs/model/README.md: steps, ramps, sinusoids and chirps at several
//! amplitudes and operating points, at least 30 000 samples).

use jetbench_model::{Params, State, STEP_S, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use nalgebra::{DMatrix, SMatrix};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::series::Series;
use crate::validate::Dynamics;

/// Samples a campaign should have at least (docs/model/README.md).
pub const MIN_SAMPLES: usize = 30_000;

/// What a campaign is made of, for the report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Campaign {
    /// The throttle profile (no thrust column).
    pub profile: Series,
    /// One line per block: kind, time span and its settings.
    pub blocks: Vec<String>,
}

/// A campaign of `duration_s` seconds at 100 Hz, reproducible from `seed`.
///
/// Blocks cycle through steps (small and large), ramps, sines and chirps; each
/// draws its operating point and amplitude at random, so the data covers the
/// whole throttle range, both directions of change and a band of frequencies.
pub fn campaign(duration_s: f64, seed: u64) -> Campaign {
    campaign_over(duration_s, seed, (THROTTLE_MIN_PCT, THROTTLE_MAX_PCT))
}

/// Length of the iRonCub group's identification signal, s.
pub const IRONCUB_SIGNAL_S: f64 = 544.0;

/// An identification signal in the manner of the iRonCub group's: 544 s over the whole
/// 0–100 % throttle range of their jet model (`jetbench_model::ironcub`), made of the same
/// blocks as [`campaign`] (steps, ramps, sines, chirps), reproducible from `seed`. It is
/// not their recorded signal, which is not public: it has its length and range.
pub fn ironcub_signal(seed: u64) -> Campaign {
    let mut c = campaign_over(IRONCUB_SIGNAL_S, seed, (jetbench_model::ironcub::IRONCUB_THROTTLE_MIN_PCT, 100.0));
    c.profile.name = format!("iRonCub-style identification signal, 0-100 % (seed {seed})");
    c
}

/// [`campaign`] over the throttle range `(lo, hi)`, %.
pub fn campaign_over(duration_s: f64, seed: u64, (lo, hi): (f64, f64)) -> Campaign {
    let n = (duration_s.max(0.0) / STEP_S).round() as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut u: Vec<f64> = Vec::with_capacity(n + 1000);
    let mut blocks = Vec::new();
    let mut level: f64 = lo;
    let clamp = |x: f64| x.clamp(lo, hi);
    let mut kind = 0usize;
    while u.len() < n {
        let start_s = u.len() as f64 * STEP_S;
        let label = match kind % 4 {
            0 => {
                let mut levels = Vec::new();
                for i in 0..6 {
                    // Alternate large moves across the range with small ones around a point.
                    level = if i % 2 == 0 {
                        rng.random_range(lo..=hi)
                    } else {
                        clamp(level + rng.random_range(-15.0..15.0))
                    };
                    let hold = rng.random_range(2.0..5.0);
                    push_hold(&mut u, level, hold);
                    levels.push(format!("{level:.0}"));
                }
                format!("steps to {} %", levels.join(", "))
            }
            1 => {
                let mut levels = Vec::new();
                for _ in 0..4 {
                    let target = rng.random_range(lo..=hi);
                    let ramp = rng.random_range(1.5..8.0);
                    push_ramp(&mut u, level, target, ramp);
                    level = target;
                    push_hold(&mut u, level, rng.random_range(1.0..3.0));
                    levels.push(format!("{level:.0}"));
                }
                format!("ramps to {} %", levels.join(", "))
            }
            2 => {
                let amplitude: f64 = rng.random_range(4.0..25.0);
                let offset = rng.random_range(lo + amplitude..=hi - amplitude);
                let period = rng.random_range(1.0..8.0);
                let span = (rng.random_range(12.0f64..20.0) / period).ceil() * period;
                push_ramp(&mut u, level, offset, 1.0);
                let k0 = u.len();
                while ((u.len() - k0) as f64) * STEP_S < span {
                    let t = (u.len() - k0) as f64 * STEP_S;
                    u.push(clamp(offset + amplitude * (2.0 * std::f64::consts::PI * t / period).sin()));
                }
                level = offset;
                format!("sine {offset:.0} ± {amplitude:.0} %, period {period:.1} s")
            }
            _ => {
                let amplitude: f64 = rng.random_range(5.0..20.0);
                let offset = rng.random_range(lo + amplitude..=hi - amplitude);
                let (f0, f1, sweep) = (0.05, rng.random_range(0.8..2.0), rng.random_range(15.0..25.0));
                push_ramp(&mut u, level, offset, 1.0);
                let k0 = u.len();
                while ((u.len() - k0) as f64) * STEP_S < sweep {
                    let t = (u.len() - k0) as f64 * STEP_S;
                    let phase = 2.0 * std::f64::consts::PI * (f0 * t + (f1 - f0) * t * t / (2.0 * sweep));
                    u.push(clamp(offset + amplitude * phase.sin()));
                }
                level = offset;
                format!("chirp {offset:.0} ± {amplitude:.0} %, {f0}–{f1:.2} Hz over {sweep:.0} s")
            }
        };
        let end_s = u.len().min(n) as f64 * STEP_S;
        blocks.push(format!("{start_s:7.2}–{end_s:7.2} s  {label}"));
        kind += 1;
    }
    u.truncate(n);
    let t_s = (0..u.len()).map(|k| k as f64 * STEP_S).collect();
    Campaign {
        profile: Series { name: format!("campaign (seed {seed})"), t_s, u_pct: u, thrust_n: Vec::new() },
        blocks,
    }
}

fn push_hold(u: &mut Vec<f64>, level: f64, seconds: f64) {
    let steps = (seconds / STEP_S).round() as usize;
    u.extend(std::iter::repeat_n(level, steps));
}

fn push_ramp(u: &mut Vec<f64>, from: f64, to: f64, seconds: f64) {
    let steps = (seconds / STEP_S).round().max(1.0) as usize;
    u.extend((1..=steps).map(|i| from + (to - from) * i as f64 / steps as f64));
}

/// Condition number of the ten-parameter regression on a campaign: the model is
/// simulated noise-free from the profile, the sensitivities of `T̈` to each
/// parameter form the regressors, columns are scaled to unit norm, and the
/// ratio of the largest to the smallest singular value is returned. Large
/// values (say above 10⁴) mean some parameters cannot be told apart.
pub fn regression_condition(params: &Params, profile: &[f64]) -> Option<f64> {
    let initial = State { thrust_n: params.stable_equilibrium(*profile.first()?)?, thrust_rate_n_per_s: 0.0 };
    let mut thrust = Vec::new();
    if params.free_run(initial, profile, &mut thrust).is_some() {
        return None;
    }
    // Rate from the simulated thrust by central differences (noise-free).
    let mut gram = SMatrix::<f64, 10, 10>::zeros();
    for k in 1..thrust.len() - 1 {
        let (t, d, u) = (thrust[k], (thrust[k + 1] - thrust[k - 1]) / (2.0 * STEP_S), profile[k]);
        let row = SMatrix::<f64, 10, 1>::from(sensitivities(params, t, d, u));
        gram += row * row.transpose();
    }
    let scale = DMatrix::from_fn(10, 10, |i, j| gram[(i, j)] / (gram[(i, i)] * gram[(j, j)]).sqrt());
    let eig = scale.symmetric_eigenvalues();
    let (min, max) = eig.iter().fold((f64::MAX, 0f64), |(a, b), &e| (a.min(e), b.max(e)));
    (min > 0.0).then(|| (max / min).sqrt())
}

/// `∂T̈/∂θ` in [`Params::NAMES`] order.
pub fn sensitivities(p: &Params, t: f64, d: f64, u: f64) -> [f64; 10] {
    let v = p.v(u);
    [t, t * t, d, d * d, t * d, 1.0, v, t * v, d * v, p.g(t, d) * u * u]
}

/// A short random profile for tests and examples (steps, ramps, sines, chirps).
pub fn test_profile(samples: usize, seed: u64) -> Series {
    let mut c = campaign(samples as f64 * STEP_S, seed).profile;
    c.name = format!("test profile (seed {seed})");
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_model::Preset;

    #[test]
    fn campaign_has_the_length_and_range_asked_for() {
        let c = campaign(300.0, 4);
        assert_eq!(c.profile.len(), MIN_SAMPLES);
        assert!(c.profile.u_pct.iter().all(|u| (THROTTLE_MIN_PCT..=THROTTLE_MAX_PCT).contains(u)));
        let (lo, hi) = c.profile.u_pct.iter().fold((100f64, 0f64), |(a, b), &u| (a.min(u), b.max(u)));
        assert!(lo < 35.0 && hi > 90.0, "{lo} {hi}");
        for kind in ["steps", "ramps", "sine", "chirp"] {
            assert!(c.blocks.iter().any(|b| b.contains(kind)), "{kind} missing: {:?}", c.blocks);
        }
        assert_eq!(campaign(300.0, 4), c, "same seed, same campaign");
        assert_ne!(campaign(300.0, 5).profile, c.profile);
    }

    #[test]
    fn the_ironcub_signal_spans_its_range_for_544_s() {
        let c = ironcub_signal(2);
        assert_eq!(c.profile.len(), 54_400);
        let (lo, hi) = c.profile.u_pct.iter().fold((100f64, 0f64), |(a, b), &u| (a.min(u), b.max(u)));
        assert!((0.0..10.0).contains(&lo) && hi > 90.0 && hi <= 100.0, "{lo} {hi}");
        assert_eq!(campaign_over(300.0, 4, (THROTTLE_MIN_PCT, THROTTLE_MAX_PCT)), campaign(300.0, 4));
    }

    #[test]
    fn a_rich_campaign_is_better_conditioned_than_one_step() {
        let p = Preset::P100Diesel.params();
        let rich = regression_condition(&p, &campaign(300.0, 1).profile.u_pct).unwrap();
        let mut poor: Vec<f64> = vec![50.0; 15_000];
        poor.extend(vec![60.0; 15_000]);
        let poor = regression_condition(&p, &poor).map_or(f64::INFINITY, |c| c);
        assert!(rich < 1e4 && rich * 10.0 < poor, "rich {rich:.1}, one step {poor:.1}");
    }
}
