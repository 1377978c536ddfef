//! Actuation: `bench/command` in, the throttle board (and the ECU's telemetry)
//! out, `bench/actuation` and `bench/ecu` published.
//!
//! - [`ActuationStep`] (`step.rs`), the algorithm: commands applied, held while
//!   late, idle when they stop, what the board acknowledged; plain code, run
//!   live and in tests.
//! - [`ActuationService`] (`service.rs`), the adapter: the board's serial link,
//!   the ECU poller and the bus ports around the step.

mod service;
mod step;

pub use service::ActuationService;
pub use step::ActuationStep;
