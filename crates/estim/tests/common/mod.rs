//! Simulated bench data shared by the observer tests.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_model::{Effects, Params, Plant, State, STEP_S};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// P100 bench measurement noise variance, N².
pub const NOISE_VAR_N2: f64 = 7.0;

/// Truth and noisy measurements of a run.
pub struct Run {
    /// Throttle applied over the interval ending at each sample (index 0: before the run).
    pub throttle_pct: Vec<f64>,
    pub truth: Vec<State>,
    pub thrust_meas_n: Vec<f64>,
}

/// Throttle profile: steps across the range, then a sine, then full steps.
pub fn throttle_profile_pct(t_s: f64) -> f64 {
    match t_s {
        t if t < 5.0 => 40.0,
        t if t < 10.0 => 80.0,
        t if t < 15.0 => 30.0,
        t if t < 20.0 => 60.0,
        t if t < 40.0 => 60.0 + 30.0 * (2.0 * std::f64::consts::PI * 0.3 * (t - 20.0)).sin(),
        t if t < 45.0 => 100.0,
        _ => 25.0,
    }
}

/// Simulates `params` for `duration_s` from rest at 40 % and adds seeded Gaussian noise.
pub fn simulate_run(params: Params, duration_s: f64, seed: u64) -> Run {
    simulate_plant_run(&Plant::new(params, Effects::none()), duration_s, seed)
}

/// [`simulate_run`] of a plant with effects (without any, the same run bit for bit).
pub fn simulate_plant_run(plant: &Plant, duration_s: f64, seed: u64) -> Run {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, NOISE_VAR_N2.sqrt()).unwrap();
    let mut engine = plant.at_equilibrium(throttle_profile_pct(0.0));
    let steps = (duration_s / STEP_S).round() as usize;
    let mut run = Run {
        throttle_pct: vec![throttle_profile_pct(0.0)],
        truth: vec![engine.state()],
        thrust_meas_n: vec![engine.state().thrust_n + noise.sample(&mut rng)],
    };
    for k in 0..steps {
        let u = throttle_profile_pct(k as f64 * STEP_S);
        let s = engine.step(u).unwrap().state;
        run.throttle_pct.push(u);
        run.truth.push(s);
        run.thrust_meas_n.push(s.thrust_n + noise.sample(&mut rng));
    }
    run
}

pub fn rms(errors: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = errors.fold((0.0, 0usize), |(s, n), e| (s + e * e, n + 1));
    (sum / n.max(1) as f64).sqrt()
}
