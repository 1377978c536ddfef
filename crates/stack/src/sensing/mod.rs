//! Sensing: force/torque readings from the CAN sensor in, `bench/thrust` out.
//!
//! - [`SensingStep`] (`step.rs`), the algorithm: calibration, the frame
//!   counter, silences; plain code, run live, in replay and in tests.
//! - [`SensingService`] (`service.rs`), the adapter: the sensor's CAN source
//!   and the bus ports around the step, under [`crate::runtime::run`].

mod service;
mod step;

pub use service::SensingService;
pub use step::{SensingError, SensingStep};
