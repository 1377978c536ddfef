//! MPC solve time per 10 ms cycle, as percentiles over whole closed-loop runs.
//!
//! `cargo bench -p jetbench-control --bench mpc`
//!
//! Each case runs the MPC for the 55 s built-in `steps` profile (full-range steps that
//! saturate the throttle, and small ones) on the engine model, with the state estimate
//! disturbed like the bench observer's (σ 0.3 N on thrust, 3 N/s on its rate), and
//! times every cycle's optimisation. Percentiles, not a mean: the loop's deadline is
//! met or missed by the slow cycles.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::time::Instant;

use jetbench_control::{FblGains, Mpc, MpcSettings, Profile};
use jetbench_model::{Effects, Plant, Preset, State, STEP_S};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn main() {
    let params = Preset::P100Diesel.params();
    let nominal = Plant::new(params, Effects::none());
    let delayed = Plant::new(params, Effects::new(["input_delay:delay_s=0.12".parse().unwrap()]).unwrap());
    let profile =
        Profile::builtin("steps", params.stable_equilibrium(25.0).unwrap(), params.stable_equilibrium(100.0).unwrap())
            .unwrap();
    println!("MPC solve time per cycle, µs (horizon 0.8 s, 10 moves, 2 passes; {} cycles per case)", 5500);
    println!("{:<34} {:>7} {:>7} {:>7} {:>7} {:>7} {:>9}", "case", "p50", "p90", "p99", "p99.9", "max", "fallbacks");
    for (name, model) in [("p100-diesel", &nominal), ("p100-diesel + 120 ms input delay", &delayed)] {
        let mut mpc = Mpc::new(model.clone(), MpcSettings::default(), FblGains::default());
        let mut engine = model.at_equilibrium(25.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (thrust_noise, rate_noise) = (Normal::new(0.0, 0.3).unwrap(), Normal::new(0.0, 3.0).unwrap());
        let mut solve_us = Vec::with_capacity(5500);
        for k in 0..5500 {
            let s = engine.state();
            let started = Instant::now();
            let out = mpc
                .step(
                    State::new(
                        s.thrust_n + thrust_noise.sample(&mut rng),
                        s.thrust_rate_n_per_s + rate_noise.sample(&mut rng),
                    ),
                    k as f64 * STEP_S,
                    &profile,
                )
                .expect("valid inputs");
            solve_us.push(started.elapsed().as_secs_f64() * 1e6);
            engine.step(out.command.throttle_pct).expect("the model is stable");
        }
        solve_us.sort_by(f64::total_cmp);
        let at = |q: f64| solve_us[((solve_us.len() as f64 * q) as usize).min(solve_us.len() - 1)];
        println!(
            "{name:<34} {:>7.0} {:>7.0} {:>7.0} {:>7.0} {:>7.0} {:>9}",
            at(0.5),
            at(0.9),
            at(0.99),
            at(0.999),
            solve_us[solve_us.len() - 1],
            mpc.fallbacks()
        );
    }
}
