//! The second-order model of a model jet engine on a thrust bench, and its simulator.
//!
//! ```
//! use jetbench_model::{Engine, Preset};
//!
//! let params = Preset::P100Diesel.params();
//! // Start idling at 25 % and open the throttle fully for 3 s.
//! let mut engine = Engine::at_equilibrium(params, 25.0);
//! for _ in 0..300 {
//!     engine.step(100.0)?;
//! }
//! assert!(engine.state().thrust_n > 50.0);
//! // Rest points at full throttle: the stable one is the operating point.
//! let stable = params.equilibria(100.0).into_iter().find(|e| e.stable);
//! assert!((stable.map_or(0.0, |e| e.thrust_n) - 86.177).abs() < 0.01);
//! # Ok::<(), jetbench_model::ModelError>(())
//! ```
//!
//! The model (docs/model/README.md) is `T̈ = f(T, Ṫ) + g(T, Ṫ)·v(u)` with thrust `T` in N, its rate
//! `Ṫ` in N/s and throttle `u` in %. Identified parameter sets are only locally valid, so
//! the [`Engine`] reports divergence as [`ModelError::Diverged`] rather than returning NaN.
#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod discrepancy;
mod effects;
mod engine;
mod error;
mod file;
pub mod ironcub;
mod params;
mod plant;
pub mod plausibility;
mod preset;
mod throttle_path;
pub mod turbojet;

pub use effects::{Effect, EffectKind, Effects};
pub use engine::{
    rk4_step, settling_time_s, simulate, Engine, State, DIVERGENCE_RATE_N_PER_S, DIVERGENCE_THRUST_N,
    MAX_SETTLING_RUN_S,
};
pub use error::ModelError;
pub use file::{names_a_plant, resolve_model, resolve_params, resolve_plant, ModelFile, TURBOJET_PLANTS};
pub use params::{AccelPartials, Equilibrium, Params};
pub use plant::{
    DriveKey, DriveTrack, Plant, PlantEngine, PlantSample, RateSchedule, SlowStart, LOCKSTEP_LANES, SCHEDULE_FLOOR,
    SCHEDULE_REFERENCE_N,
};
pub use preset::Preset;
pub use throttle_path::{DelaySplit, ThrottlePath, Window, MAX_INPUT_DELAY_S, TICK_S};

/// The period of everything on the bench, ns: the model's discretisation step, the
/// control loop's cycle and every channel's sample interval (100 Hz, as on the original
/// bench). Every other period and deadline is derived from it.
pub const PERIOD_NS: u64 = 10_000_000;
/// [`PERIOD_NS`] in seconds (exactly the `f64` nearest 0.01).
pub const STEP_S: f64 = PERIOD_NS as f64 / 1e9;
/// RK4 substeps per [`STEP_S`] (integration at 1 kHz).
pub const SUBSTEPS: usize = 10;
/// Lowest throttle the ECU accepts, %.
pub const THROTTLE_MIN_PCT: f64 = 25.0;
/// Highest throttle the ECU accepts, %.
pub const THROTTLE_MAX_PCT: f64 = 100.0;
