//! Offline identification of the engine model from recordings.

pub mod diagnose;
pub mod ekf;
pub mod excite;
pub mod identify;
pub mod ls;
pub mod noise;
pub mod plot;
pub mod refine;
/// Recordings as identification data; the loader lives with the recorder (`jetbench_record::series`).
pub use jetbench_record::series;
pub mod sindy;
pub mod synth;
pub mod validate;

/// Why an identification could not be done.
#[derive(Debug, thiserror::Error)]
pub enum IdentError {
    #[error(transparent)]
    Data(#[from] series::DataError),
    #[error("bad option: {0}")]
    Options(String),
    #[error("too little data: {0}")]
    TooLittleData(String),
    #[error(
        "{0}: the regression is singular; the data does not excite every term (use a campaign from `jetbench excite`)"
    )]
    Singular(String),
    #[error("{0}")]
    Failed(String),
}
