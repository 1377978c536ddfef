//! Offline identification of the engine model from recordings.
//!
//! [`SavitzkyGolay`] smooths and differentiates whole recordings (thrust rate and
//! acceleration for LS and SINDy), with scipy's `savgol_filter` edge handling.
#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod diagnose;
pub mod ekf;
pub mod excite;
pub mod identify;
pub mod ls;
pub mod noise;
pub mod refine;
pub mod savgol;
/// Recordings as identification data; the loader lives with the recorder (`jetbench_record::series`).
pub use jetbench_record::series;
pub use savgol::{SavGolError, SavitzkyGolay};
pub mod sindy;
pub mod spd;
pub mod structure;
pub mod synth;
pub mod trust;
pub mod validate;

/// Why an identification could not be done.
#[derive(Debug, thiserror::Error)]
pub enum IdentError {
    /// The recording does not load or has unusable rows.
    #[error(transparent)]
    Data(#[from] series::DataError),
    /// An option out of range (which, and why).
    #[error("bad option: {0}")]
    Options(String),
    /// Fewer samples than the method needs (how many, and how many it needs).
    #[error("too little data: {0}")]
    TooLittleData(String),
    /// The regression's matrix is singular: the throttle did not move enough to tell
    /// the terms apart (which method).
    #[error(
        "{0}: the regression is singular; the data does not excite every term (use a campaign from `jetbench excite`)"
    )]
    Singular(String),
    /// The method ran and failed (why).
    #[error("{0}")]
    Failed(String),
}
