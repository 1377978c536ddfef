//! The service set: the bench config, each process (its per-cycle algorithm
//! and the service that wires it to the bus, side by side), the runtime every
//! service runs under, and the offline runs of the same code.
//!
//! - Processes, one folder each, `step.rs` (the algorithm, plain code that
//!   never touches the bus, named `…Step`) beside `service.rs` (the adapter,
//!   named `…Service`): [`sensing`], [`estimation`], [`control`],
//!   [`actuation`], [`sim_bench`]; and the [`recorder`] (a service only).
//! - [`runtime`]: the service lifecycle and its runner, the launcher and its
//!   supervisor, real-time settings, health, the cycle clock.
//! - Offline: [`replay`] (a recording through the estimator and controller),
//!   [`synthetic`] (a closed-loop run faster than real time); and [`tare`]
//!   (the sensor's offset at zero load).
//! - [`config`]: the bench config; [`inject`]: faults injected into the
//!   simulated sensor path.
//!
//! ```
//! use jetbench_stack::config::BenchConfig;
//!
//! let config = BenchConfig::default_sim().expect("the built-in config is valid");
//! assert_eq!(config.actuation.idle_after_missed_cycles, 3);
//! ```
#![doc = include_str!("../README.md")]

pub mod actuation;
pub mod config;
pub mod control;
pub mod estimation;
pub mod inject;
pub mod limits;
pub mod recorder;
pub mod replay;
pub mod runtime;
pub mod sensing;
pub mod sim_bench;
pub mod synthetic;
pub mod tare;
