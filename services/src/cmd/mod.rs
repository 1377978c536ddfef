//! Offline commands of the `jetbench` CLI, one module each.

pub mod can_decode;
pub mod diagnose;
pub mod identify;
pub mod latency;
pub mod latency_stage;
pub mod load;
pub mod metrics;
pub mod model;
pub mod play;
pub mod replay;
pub mod tare;
