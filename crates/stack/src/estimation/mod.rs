//! Estimation: `bench/thrust` (and the newest `bench/actuation`) in, `bench/state` out.
//!
//! - [`EstimationStep`] (`step.rs`), the algorithm: the observer of
//!   `[T, Ṫ, d]` (`jetbench_estim::ThrustObserver`) on each thrust sample, its
//!   verdict turned into flags; plain code, run live, in replay and in tests.
//! - [`EstimationService`] (`service.rs`), the adapter: the bus ports around
//!   the step, and the log of each measurement the gate did not use.

mod service;
mod step;

pub use service::EstimationService;
pub use step::EstimationStep;
