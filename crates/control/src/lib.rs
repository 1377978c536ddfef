//! Thrust references and the feedback-linearising controller.
//!
//! ```
//! use jetbench_control::{Fbl, FblGains, Profile};
//! use jetbench_model::{Engine, Preset, STEP_S};
//!
//! let params = Preset::P100Diesel.params();
//! let profile = Profile::default(); // 20 N, then 50 N after 2.5 s, ...
//! profile.validate()?;
//! let mut engine = Engine::new(params, Default::default());
//! let mut fbl = Fbl::new(params, FblGains::default());
//! for k in 0..480 {
//!     let reference = profile.at(k as f64 * STEP_S);
//!     let state = engine.state();
//!     let command = fbl.step(state.thrust_n, state.thrust_rate_n_per_s, &reference)?;
//!     assert!((25.0..=100.0).contains(&command.throttle_pct));
//!     engine.step(command.throttle_pct)?;
//! }
//! assert!((engine.state().thrust_n - 50.0).abs() < 0.5);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! References are pure functions of time with analytic derivatives, so the controller
//! gets a consistent `[T_d, Ṫ_d, T̈_d]` and a replay reproduces them exactly. The
//! controller is a plain `step` function; wiring it to sensors and the ECU is the
//! service's job.

mod error;
mod fbl;
mod profile;

pub use error::ControlError;
pub use fbl::{clamp_throttle, Command, Fbl, FblGains, MIN_INPUT_GAIN};
pub use profile::{Profile, Reference};
