//! Sim-bench: the simulated engine, throttle board, force sensor and ECU,
//! `bench/sim_truth` out.
//!
//! - [`SimBenchStep`] (`step.rs`), the algorithm: the plant with its effects, the
//!   board's firmware and the simulated force sensor ([`SimForceSensor`]), 10 ms
//!   at a time; plain code, run live and in synthetic runs ([`crate::synthetic`]).
//! - [`SimBenchService`] (`service.rs`), the adapter: the step on its own clock,
//!   the board and ECU behind ptys, the sensor's frames on CAN.

mod service;
mod step;

pub use service::{SimBenchService, SENSOR_UNPLUGGED_FILE};
pub use step::{SimBenchStep, SimBoard, SimError, SimForceSensor};
