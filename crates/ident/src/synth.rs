//! Synthetic recordings: a plant driven by a throttle profile, measured with noise,
//! exactly as the simulated bench measures it (one sample per 10 ms, the throttle
//! of each row held until the next), optionally with what a real bench adds:
//! coloured sensor noise, spikes from a noisy CAN bus, rows lost on the way, and
//! the bench's resolution.
//!
//! ```
//! use jetbench_ident::synth::{record_bench, Bench};
//! use jetbench_ident::excite;
//! use jetbench_model::{Effects, Plant, Preset};
//!
//! let plant = Plant::new(Preset::P100Diesel.params(), Effects::none());
//! let profile = excite::campaign(60.0, 1).profile;
//! let bench = Bench { noise_ar: vec![0.6], spike_fraction: 0.002, drop_fraction: 0.01, ..Bench::default() };
//! let recording = record_bench(&plant, &profile, &bench, 7)?;
//! assert!(recording.len() < profile.len());
//! # Ok::<(), jetbench_model::ModelError>(())
//! ```

use jetbench_model::{Effects, ModelError, Params, Plant, SlowStart};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::noise::ArModel;
use crate::series::Series;

pub use crate::excite::test_profile;

/// How a simulated bench measures.
#[derive(Clone, Debug, PartialEq)]
pub struct Bench {
    /// Variance of the sensor noise (all of it, coloured or not), N².
    pub noise_var_n2: f64,
    /// AR coefficients of the noise (empty: white).
    pub noise_ar: Vec<f64>,
    /// Fraction of samples hit by a spike.
    pub spike_fraction: f64,
    /// Size of a spike, N: uniform in this range, either sign.
    pub spike_n: (f64, f64),
    /// Fraction of rows lost (never the first or the last).
    pub drop_fraction: f64,
    /// Round time to 0.01 s, throttle to 0.01 % and thrust to 0.01 N, as the bench's
    /// board and sensor report them (docs/io/README.md).
    pub resolution: bool,
}

impl Default for Bench {
    fn default() -> Self {
        Self {
            noise_var_n2: 7.0,
            noise_ar: Vec::new(),
            spike_fraction: 0.0,
            spike_n: (20.0, 40.0),
            drop_fraction: 0.0,
            resolution: false,
        }
    }
}

/// Records `params` driven by `profile.u_pct`, starting at rest at the stable
/// equilibrium of the first throttle, with white Gaussian noise of variance
/// `noise_var_n2` (N²) from `seed`.
pub fn record(params: &Params, profile: &Series, noise_var_n2: f64, seed: u64) -> Result<Series, ModelError> {
    record_plant(&Plant::new(*params, Effects::none()), profile, noise_var_n2, seed)
}

/// [`record`] of a plant with effects: the recorded thrust is what the sensor reads.
pub fn record_plant(plant: &Plant, profile: &Series, noise_var_n2: f64, seed: u64) -> Result<Series, ModelError> {
    record_bench(plant, profile, &Bench { noise_var_n2, ..Bench::default() }, seed)
}

/// [`record_plant`] measured by `bench`. White noise, spikes and lost rows draw from
/// separate streams of `seed`, so the same seed gives the same noise with or without
/// artefacts.
pub fn record_bench(plant: &Plant, profile: &Series, bench: &Bench, seed: u64) -> Result<Series, ModelError> {
    record_bench_from(plant, SlowStart::SETTLED, profile, bench, seed)
}

/// [`record_bench`] of a recording that starts while the plant's slow states are on their
/// way (`slow`: a sensor tared a while ago, an engine not yet soaked), the engine itself at
/// rest at the first throttle.
pub fn record_bench_from(
    plant: &Plant,
    slow: SlowStart,
    profile: &Series,
    bench: &Bench,
    seed: u64,
) -> Result<Series, ModelError> {
    let var = bench.noise_var_n2;
    let invalid =
        |name: &'static str, value: f64, expected: &'static str| ModelError::InvalidArgument { name, value, expected };
    if !(var.is_finite() && var >= 0.0) {
        return Err(invalid("noise_var_n2", var, ">= 0"));
    }
    for (name, f) in [("spike_fraction", bench.spike_fraction), ("drop_fraction", bench.drop_fraction)] {
        if !(0.0..=0.5).contains(&f) {
            return Err(invalid(name, f, "a fraction in [0, 0.5]"));
        }
    }
    let (lo, hi) = bench.spike_n;
    if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi) {
        return Err(invalid("spike_n", lo, "0 <= low <= high"));
    }
    let ar = ArModel::new(bench.noise_ar.clone(), 1.0);
    if !ar.is_stationary() {
        return Err(invalid("noise_ar", bench.noise_ar.first().copied().unwrap_or(f64::NAN), "a stationary AR model"));
    }
    let mut profile = profile.clone();
    if bench.resolution {
        quantize(&mut profile.u_pct, 0.01);
        quantize(&mut profile.t_s, 0.01);
    }
    let n = profile.len();
    let noise: Vec<f64> = if bench.noise_ar.is_empty() {
        let normal = Normal::new(0.0, var.sqrt()).map_err(|_| invalid("noise_var_n2", var, ">= 0"))?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| normal.sample(&mut rng)).collect()
    } else {
        ar.with_marginal_var(var).generate(n, seed)
    };
    let u0_pct = profile.u_pct.first().copied().unwrap_or(25.0);
    let at_rest = plant.at_equilibrium(u0_pct);
    let mut engine = plant.engine_from(at_rest.state(), slow, u0_pct, 0.0);
    let mut thrust_n = Vec::with_capacity(n);
    for (k, &u) in profile.u_pct.iter().enumerate() {
        thrust_n.push(engine.measured_n() + noise[k]);
        if k + 1 < n {
            engine.step(u)?;
        }
    }
    let mut artefacts = ChaCha8Rng::seed_from_u64(seed ^ 0xa27e_fac7);
    for y in thrust_n.iter_mut() {
        if bench.spike_fraction > 0.0 && artefacts.random::<f64>() < bench.spike_fraction {
            let size = lo + (hi - lo) * artefacts.random::<f64>();
            *y += if artefacts.random::<bool>() { size } else { -size };
        }
    }
    if bench.resolution {
        quantize(&mut thrust_n, 0.01);
    }
    let mut recording = Series {
        name: format!("{} (simulated, noise {var} N², seed {seed})", profile.name),
        t_s: profile.t_s,
        u_pct: profile.u_pct,
        thrust_n,
    };
    if bench.drop_fraction > 0.0 {
        let keep: Vec<bool> =
            (0..n).map(|k| k == 0 || k + 1 == n || artefacts.random::<f64>() >= bench.drop_fraction).collect();
        let filter = |v: &mut Vec<f64>| {
            let mut i = 0;
            v.retain(|_| {
                i += 1;
                keep[i - 1]
            });
        };
        filter(&mut recording.t_s);
        filter(&mut recording.u_pct);
        filter(&mut recording.thrust_n);
    }
    Ok(recording)
}

/// Rounds every value to a multiple of `step`.
pub fn quantize(values: &mut [f64], step: f64) {
    for v in values {
        *v = (*v / step).round() * step;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_model::Preset;

    #[test]
    fn artefacts_are_what_was_asked_for() {
        let plant = Plant::new(Preset::P100Diesel.params(), Effects::none());
        let profile = test_profile(20_000, 4);
        let clean = record_bench(&plant, &profile, &Bench::default(), 3).unwrap();
        let bench = Bench { spike_fraction: 0.01, drop_fraction: 0.02, resolution: true, ..Bench::default() };
        let messy = record_bench(&plant, &profile, &bench, 3).unwrap();
        let lost = profile.len() - messy.len();
        assert!((300..500).contains(&lost), "{lost} rows lost");
        let spikes = messy
            .t_s
            .iter()
            .zip(&messy.thrust_n)
            .filter(|(t, y)| {
                let k = (*t / 0.01).round() as usize;
                (*y - clean.thrust_n[k]).abs() > 15.0
            })
            .count();
        assert!((140..260).contains(&spikes), "{spikes} spikes");
        assert!(messy.thrust_n.iter().all(|y| ((y * 100.0).round() - y * 100.0).abs() < 1e-6));
        let bad = Bench { noise_ar: vec![1.0], ..Bench::default() };
        assert!(record_bench(&plant, &profile, &bad, 3).is_err(), "a unit root is no stationary noise");
    }
}
