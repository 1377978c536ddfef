//! Control: `bench/state` in, `bench/command` and `bench/reference` out.
//!
//! - [`ControlStep`] (`step.rs`), the algorithm: the reference profile and the
//!   law (`jetbench_control::Law`: FBL, SMC or MPC), or a throttle profile played
//!   open loop ([`ControlLaw`]); plain code, run live, in replay and in tests.
//! - [`EngineSupervisor`] (`engine.rs`): the ECU's state, the limits and the
//!   operator's commands decide how much of the law's throttle reaches the engine.
//! - [`ControlService`] (`service.rs`), the adapter: the bus ports around the step.

pub mod engine;
mod service;
mod step;

pub use engine::EngineSupervisor;
pub use service::ControlService;
pub use step::{disturbance, ControlLaw, ControlStep};
