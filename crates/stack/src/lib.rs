//! The service set: the bench config, the step logic of every service, the
//! runtime that wires each step to the bus, and the launcher.
//!
//! ```
//! use jetbench_stack::config::BenchConfig;
//!
//! let config = BenchConfig::default_sim().expect("the built-in config is valid");
//! assert_eq!(config.actuation.idle_after_missed_cycles, 3);
//! ```

pub mod chain;
pub mod clock;
pub mod config;
pub mod health;
pub mod latency;
pub mod launch;
pub mod replay;
pub mod rt;
pub mod service;
pub mod step;
