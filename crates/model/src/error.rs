//! Errors of the model crate.

use std::path::PathBuf;

/// Everything that can go wrong when loading, checking or simulating a model.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The simulated state left the range where the model means anything.
    #[error(
        "the model diverged at t = {time_s:.3} s (thrust {thrust_n:.4e} N, rate \
         {thrust_rate_n_per_s:.4e} N/s): the identified model is only locally valid; check \
         the parameters or keep the throttle in the range they were identified on"
    )]
    Diverged {
        /// Simulated time at which divergence was detected, s.
        time_s: f64,
        /// Thrust when divergence was detected (the last finite value), N.
        thrust_n: f64,
        /// Thrust rate when divergence was detected (the last finite value), N/s.
        thrust_rate_n_per_s: f64,
    },
    /// A model parameter is NaN or infinite.
    #[error("model parameter {name} is not finite ({value}); every parameter must be a finite number")]
    NonFinite {
        /// Parameter name as in model files (`K_T`, ...).
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A throttle input is NaN or infinite.
    #[error("throttle {throttle_pct} % is not a finite number")]
    InvalidThrottle {
        /// The offending throttle, %.
        throttle_pct: f64,
    },
    /// A numeric argument is out of its documented range.
    #[error("{name} = {value} is invalid: expected {expected}")]
    InvalidArgument {
        /// Argument name.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// What would be accepted.
        expected: &'static str,
    },
    /// A model file could not be read or written.
    #[error("cannot access model file {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A model file is not valid TOML or does not have the expected keys.
    #[error("cannot parse model file {path}: {message}")]
    Parse {
        /// File path, or `<string>` for text parsed from memory.
        path: String,
        /// Parser message; names the offending key and line.
        message: String,
    },
    /// A preset name is not known.
    #[error("unknown model preset `{name}`; valid presets: {valid}")]
    UnknownPreset {
        /// The name given.
        name: String,
        /// Comma-separated valid names.
        valid: String,
    },
    /// A model spec is neither a preset name nor a readable file.
    #[error("`{spec}` is neither a model preset ({valid}) nor a readable model file: {source}")]
    UnknownSpec {
        /// The spec given.
        spec: String,
        /// Comma-separated valid preset names.
        valid: String,
        /// Why the file could not be read.
        source: std::io::Error,
    },
    /// An effect name is not in the catalogue.
    #[error("unknown effect `{name}`; valid effects: {valid}")]
    UnknownEffect {
        /// The name given.
        name: String,
        /// Comma-separated valid names.
        valid: String,
    },
    /// An effect's parameters are missing, unknown or out of range.
    #[error("effect {effect}: {message}")]
    EffectParam {
        /// Effect name.
        effect: &'static str,
        /// What is wrong and what is expected.
        message: String,
    },
}
