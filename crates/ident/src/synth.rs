//! Synthetic recordings: a plant driven by a throttle profile, measured with noise,
//! exactly as the simulated bench measures it (one sample per 10 ms, the throttle
//! of each row held until the next).

use jetbench_model::{Effects, ModelError, Params, Plant};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::series::Series;

pub use crate::excite::test_profile;

/// Records `params` driven by `profile.u_pct`, starting at rest at the stable
/// equilibrium of the first throttle, with white Gaussian noise of variance
/// `noise_var_n2` (N²) from `seed`.
pub fn record(params: &Params, profile: &Series, noise_var_n2: f64, seed: u64) -> Result<Series, ModelError> {
    record_plant(&Plant::new(*params, Effects::none()), profile, noise_var_n2, seed)
}

/// [`record`] of a plant with effects: the recorded thrust is what the sensor reads.
pub fn record_plant(plant: &Plant, profile: &Series, noise_var_n2: f64, seed: u64) -> Result<Series, ModelError> {
    if !(noise_var_n2.is_finite() && noise_var_n2 >= 0.0) {
        return Err(ModelError::InvalidArgument { name: "noise_var_n2", value: noise_var_n2, expected: ">= 0" });
    }
    let noise = Normal::new(0.0, noise_var_n2.sqrt()).map_err(|_| ModelError::InvalidArgument {
        name: "noise_var_n2",
        value: noise_var_n2,
        expected: ">= 0",
    })?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut engine = plant.at_equilibrium(profile.u_pct.first().copied().unwrap_or(25.0));
    let mut thrust_n = Vec::with_capacity(profile.len());
    for (k, &u) in profile.u_pct.iter().enumerate() {
        thrust_n.push(engine.measured_n() + noise.sample(&mut rng));
        if k + 1 < profile.len() {
            engine.step(u)?;
        }
    }
    Ok(Series {
        name: format!("{} (simulated, noise {noise_var_n2} N², seed {seed})", profile.name),
        t_s: profile.t_s.clone(),
        u_pct: profile.u_pct.clone(),
        thrust_n,
    })
}
