//! The commands of the `jetbench` CLI, one module each: each parses its
//! arguments, calls a library and prints.

pub mod bus;
pub mod can_decode;
pub mod command;
pub mod diagnose;
pub mod excite;
pub mod export;
pub mod faults;
pub mod identify;
pub mod info;
pub mod latency;
pub mod latency_stage;
pub mod metrics;
pub mod play;
pub mod record;
pub mod recover;
pub mod replay;
pub mod sim_record;
pub mod simulate;
pub mod soak;
pub mod tare;
pub mod up;
