//! Thrust references and the controllers that track them: the study's feedback
//! linearisation (FBL) and sliding mode (SMC), and a model predictive controller (MPC)
//! that knows the throttle limits and the identified model's effects.
//!
//! ```
//! use jetbench_control::{Fbl, FblGains, Profile};
//! use jetbench_model::{Engine, Preset, STEP_S};
//!
//! let params = Preset::P100Diesel.params();
//! let profile = Profile::default(); // 20 N, then 50 N after 2.5 s, ...
//! profile.validate()?;
//! let mut engine = Engine::new(params, Default::default());
//! let mut fbl = Fbl::new(params, FblGains::default());
//! for k in 0..480 {
//!     let reference = profile.at(k as f64 * STEP_S);
//!     let command = fbl.step(engine.state(), &reference)?;
//!     assert!((25.0..=100.0).contains(&command.throttle_pct));
//!     engine.step(command.throttle_pct)?;
//! }
//! assert!((engine.state().thrust_n - 50.0).abs() < 0.5);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! References are pure functions of time with analytic derivatives, so the controller
//! gets a consistent `[T_d, Ṫ_d, T̈_d]`, a replay reproduces them exactly, and the MPC can
//! look ahead. Every controller is a plain `step` function; [`Law`] picks one from the
//! bench config; wiring it to sensors and the ECU is the service's job.
#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

use jetbench_model::State;

mod error;
mod fbl;
mod law;
mod metrics;
mod mpc;
pub mod operator;
mod profile;
pub mod recorded;
mod shaper;
mod smc;
mod throttle;

pub use error::ControlError;
pub use fbl::{Fbl, FblGains, MIN_INPUT_GAIN};
pub use law::{Controller, Law, LawOutput, LawSettings, LawSettingsError};
pub use metrics::{
    tracking_metrics, HoldMetrics, MetricsError, MetricsOptions, SolveTimeUs, StepMetrics, ThrottleLimit,
    TrackingMetrics, TrackingSample, TRACKING_BAND_PCT,
};
pub use mpc::{Mpc, MpcOutput, MpcSettings};
pub use profile::{Profile, ProfileSpec, Reference, Segment, BUILTIN_PROFILES};
pub use shaper::{ReferenceShaper, ShaperSettings};
pub use smc::{Smc, SmcGains};
pub use throttle::{clamp_throttle, throttle_for_virtual, ThrottleCommand};

/// The first gain or model parameter that is NaN or infinite, as the error every step of
/// a controller built with it returns.
pub(crate) fn non_finite_setting(
    gains: &[(&'static str, f64)],
    params: &jetbench_model::Params,
) -> Option<ControlError> {
    gains
        .iter()
        .copied()
        .chain(jetbench_model::Params::NAMES.into_iter().zip(params.to_array()))
        .find(|(_, value)| !value.is_finite())
        .map(|(name, value)| ControlError::InvalidSetting { name, value })
}

/// Rejects a step of a law built with bad settings (`invalid`), or with a NaN or
/// infinite state estimate or reference, before the law uses them.
pub(crate) fn check_step(
    invalid: Option<ControlError>,
    state: State,
    reference: &Reference,
) -> Result<(), ControlError> {
    if let Some(e) = invalid {
        return Err(e);
    }
    let inputs = [
        ("thrust", state.thrust_n),
        ("thrust rate", state.thrust_rate_n_per_s),
        ("reference thrust", reference.thrust_n),
        ("reference thrust rate", reference.thrust_rate_n_per_s),
        ("reference thrust acceleration", reference.thrust_accel_n_per_s2),
    ];
    match inputs.into_iter().find(|(_, v)| !v.is_finite()) {
        Some((what, value)) => Err(ControlError::NonFiniteInput { what, value }),
        None => Ok(()),
    }
}
