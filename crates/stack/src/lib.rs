//! The runtime of the service set: the bench config, the step logic of every
//! service, the service lifecycle and the one runner every service process
//! runs under, the launcher and its supervisor, and real-time settings.
//!
//! ```
//! use jetbench_stack::config::BenchConfig;
//!
//! let config = BenchConfig::default_sim().expect("the built-in config is valid");
//! assert_eq!(config.actuation.idle_after_missed_cycles, 3);
//! ```

pub mod clock;
pub mod config;
pub mod health;
pub mod inject;
pub mod launch;
pub mod replay;
pub mod rt;
pub mod service;
pub mod step;
pub mod supervise;
pub mod synthetic;
pub mod tare;
