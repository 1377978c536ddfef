//! The commands of the `jetbench` CLI, one module each: each parses its
//! arguments, calls a library and prints.

pub mod bus;
pub mod can_decode;
pub mod diagnose;
pub mod faults;
pub mod identify;
pub mod info;
pub mod latency;
pub mod latency_stage;
pub mod metrics;
pub mod model;
pub mod play;
pub mod record;
pub mod recover;
pub mod replay;
pub mod tare;
pub mod up;
