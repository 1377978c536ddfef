//! How much stepping plants in lockstep saves against running them one after the other:
//! eight plants like a fit's Jacobian columns over a 600 s campaign-like throttle (a rate
//! limit and a gain drift, parameters moved a little), on kept drives and each on its own
//! path. Checks the readings are the same bit for bit, then prints nanoseconds per plant
//! step.
//!
//! ```text
//! cargo build --release --workspace --all-targets && target/release/examples/lockstep
//! ```

use std::time::Instant;

use jetbench_model::{DriveTrack, Effects, Params, Plant, Preset, SlowStart, State};

const PLANTS: usize = 8;
const ROUNDS: usize = 5;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let steps = 60_000;
    let u: Vec<f64> = (0..steps)
        .map(|k| {
            let t = k as f64 * 0.01;
            let level = 45.0 + 25.0 * (t / 37.0).sin().signum();
            level + 10.0 * (t * 0.9).sin() * (t / 11.0).cos()
        })
        .collect();
    let given = Preset::P100Diesel.params();
    let effects = Effects::new([
        "rate_limit:up_pct_per_s=60,down_pct_per_s=90".parse()?,
        "gain_drift:per_minute=0.005".parse()?,
    ])?;
    let plants_of = |path_apart: bool| -> Result<Vec<Plant>, Box<dyn std::error::Error>> {
        (0..PLANTS)
            .map(|i| {
                let mut a = given.to_array();
                a[i % 9] *= 1.0 + 1e-4;
                let effects = if path_apart {
                    let rate = 60.0 + i as f64;
                    Effects::new([
                        format!("rate_limit:up_pct_per_s={rate},down_pct_per_s=90").parse()?,
                        "gain_drift:per_minute=0.005".parse()?,
                    ])?
                } else {
                    effects.clone()
                };
                Ok(Plant::new(Params::from_array(a), effects))
            })
            .collect()
    };
    let start = (
        State { thrust_n: Plant::new(given, Effects::none()).rest_thrust_n(u[0]), thrust_rate_n_per_s: 0.0 },
        SlowStart::SETTLED,
    );
    let starts = vec![start; PLANTS];
    for (label, path_apart) in [("kept drives", false), ("own paths", true)] {
        let plants = plants_of(path_apart)?;
        let refs: Vec<&Plant> = plants.iter().collect();
        let mut track = DriveTrack::default();
        plants[0].free_run_keeping(1, 0.0, start.0, start.1, &u, &mut Vec::new(), None, Some(&mut track));
        let track = (!path_apart).then_some(&track);
        let (mut alone, mut together) = (vec![Vec::new(); PLANTS], vec![Vec::new(); PLANTS]);
        let mut diverged_s = vec![None; PLANTS];
        // Read, not written: the drives are this plant's.
        let mut own = track.cloned();
        let (mut alone_s, mut together_s) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..ROUNDS {
            let clock = Instant::now();
            for (plant, out) in plants.iter().zip(alone.iter_mut()) {
                plant.free_run_keeping(1, 0.0, start.0, start.1, &u, out, None, own.as_mut());
            }
            alone_s = alone_s.min(clock.elapsed().as_secs_f64());
            let clock = Instant::now();
            Plant::free_runs_in_lockstep(&refs, 1, 0.0, &starts, &u, track, &mut together, &mut diverged_s);
            together_s = together_s.min(clock.elapsed().as_secs_f64());
        }
        let same = alone.iter().zip(&together).all(|(a, b)| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()));
        let per_step = |s: f64| s * 1e9 / (PLANTS * steps) as f64;
        println!(
            "{label}: alone {:.1} ns per plant step, in lockstep {:.1} ns ({:+.0} %), readings {}",
            per_step(alone_s),
            per_step(together_s),
            100.0 * (together_s / alone_s - 1.0),
            if same { "identical" } else { "DIFFERENT" }
        );
    }
    Ok(())
}
