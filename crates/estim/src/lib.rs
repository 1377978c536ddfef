//! EKF observer of thrust and thrust rate from thrust measurements alone.
//!
//! ```
//! use jetbench_estim::{ObserverConfig, ThrustObserver};
//! use jetbench_model::Preset;
//!
//! let mut observer = ThrustObserver::new(Preset::P100Diesel.params(), ObserverConfig::default());
//! // The first measurement initialises the thrust estimate.
//! let first = observer.step(24.9, 50.0)?;
//! assert_eq!(first.thrust_n, 24.9);
//! // Each later call predicts over the last 10 ms with the throttle that was applied,
//! // then corrects with the new measurement.
//! let next = observer.step(25.3, 50.0)?;
//! assert!(next.thrust_rate_n_per_s.is_finite());
//! // Bad input is rejected and leaves the filter untouched.
//! assert!(observer.step(f64::NAN, 50.0).is_err());
//! # Ok::<(), jetbench_estim::EstimError>(())
//! ```
//!
//! The bench measures only thrust; the controllers need `[T, Ṫ]`, and FBL the
//! disturbance `d`: the acceleration the model does not explain. The filter uses the
//! discretisation of the model (docs/model/README.md) at `Δt = STEP_S`:
//!
//! ```text
//! T[k+1] = T + Ṫ·Δt + T̈·Δt²/2,   Ṫ[k+1] = Ṫ + T̈·Δt,   T̈ = f(T, Ṫ) + g(T, Ṫ)·v(u) + d,   d[k+1] = d,   y = T
//! ```
//!
//! with an analytic Jacobian, white unmodelled acceleration as process noise, and `d` a
//! random walk (`disturbance_drift_n_per_s2`; 0 keeps it at 0: the 2-state filter). With
//! a model input delay (`input_delay_s`) `u` is the throttle applied that long ago (the
//! model's [`jetbench_model::ThrottlePath`]). Each
//! measurement passes a [`gate`] first: a spike (chi-square test on the innovation) or a
//! stuck sensor (the same reading over and over) is not used, and the estimate says so.
#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod gate;
mod observer;

pub use gate::{GateConfig, Verdict};
pub use jetbench_model::MAX_INPUT_DELAY_S;
pub use observer::{
    EstimError, Estimate, Gated, ObserverConfig, ThrustObserver, MAX_SETTLING_STEPS, SETTLED_RATE_VAR_FACTOR,
};
