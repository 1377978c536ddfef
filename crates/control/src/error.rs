//! Errors of the control crate.

/// Why a profile or a controller step was rejected. `Copy`, so a controller built with
/// bad settings can report the reason on every step.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum ControlError {
    /// Open loop was asked of [`crate::Law`], which runs the feedback laws only.
    #[error("open loop is no feedback law: it plays a throttle profile (`[control] throttle_profile`)")]
    NotAFeedbackLaw,
    /// A step or ramp profile has no levels.
    #[error("{kind} profile has no levels; give at least one value in levels_n")]
    EmptyLevels {
        /// Profile kind.
        kind: &'static str,
    },
    /// A profile setting is NaN or infinite.
    #[error("profile setting {field} is not finite ({value})")]
    NonFinite {
        /// Field name as in the config file.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A profile duration is out of range.
    #[error("profile setting {field} = {value_s} s is invalid: it must be {requirement}")]
    InvalidDuration {
        /// Field name as in the config file.
        field: &'static str,
        /// The offending value, s.
        value_s: f64,
        /// What is accepted.
        requirement: &'static str,
    },
    /// A chirp frequency is negative.
    #[error("profile setting {field} = {value_hz} Hz is invalid: it must be >= 0")]
    InvalidFrequency {
        /// Field name as in the config file.
        field: &'static str,
        /// The offending value, Hz.
        value_hz: f64,
    },
    /// A controller input (state or reference) is NaN or infinite.
    #[error("{what} is not finite ({value}); no command computed")]
    NonFiniteInput {
        /// Which input.
        what: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A controller setting or model parameter is NaN or infinite.
    #[error("controller setting {name} is not finite ({value}); fix the gains or the model")]
    InvalidSetting {
        /// Gain (`kp`, `kd`) or model parameter name (`K_T`, ...).
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A controller setting is outside the range it works in.
    #[error("controller setting {name} = {value} is invalid: it must be {requirement}")]
    SettingOutOfRange {
        /// Setting name as in the config file.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// What is accepted.
        requirement: &'static str,
    },
}

/// `Ok` when `value` is finite and positive (or, with `zero_ok`, zero); otherwise the
/// error naming the setting and what it must be.
pub(crate) fn check_gain(name: &'static str, value: f64, zero_ok: bool) -> Result<(), ControlError> {
    let ok = value.is_finite() && if zero_ok { value >= 0.0 } else { value > 0.0 };
    if ok {
        Ok(())
    } else {
        let requirement = if zero_ok { "a number >= 0" } else { "a positive number" };
        Err(ControlError::SettingOutOfRange { name, value, requirement })
    }
}
