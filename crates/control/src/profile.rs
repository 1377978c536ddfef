//! Thrust reference profiles: pure functions of time with analytic derivatives.

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use crate::ControlError;

/// Desired thrust and its first two derivatives, as the controllers need them.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Reference {
    /// Desired thrust, N.
    pub thrust_n: f64,
    /// Desired thrust rate, N/s.
    pub thrust_rate_n_per_s: f64,
    /// Desired thrust acceleration, N/s².
    pub thrust_accel_n_per_s2: f64,
}

/// Past jumps older than this many smoothing time constants are left out of a step
/// profile; their remainder, `(1 + 40)·e⁻⁴⁰ ≈ 2e-16` of the jump, is below rounding.
const SMOOTHING_HORIZON: f64 = 40.0;
/// Upper bound on `smoothing_s / hold_s`, which bounds the work of one evaluation.
const MAX_SMOOTHING_PER_HOLD: f64 = 100.0;
/// Most past jumps inside the horizon that a valid step profile can have.
const MAX_JUMPS_IN_HORIZON: usize = (SMOOTHING_HORIZON * MAX_SMOOTHING_PER_HOLD) as usize + 2;

/// A reference profile, read from a TOML table such as
///
/// ```toml
/// [reference]
/// kind = "steps"            # steps | ramps | sines | chirp | campaign
/// levels_n = [20.0, 50.0, 35.0, 70.0]
/// hold_s = 2.5
/// smoothing_s = 0.2
/// ```
///
/// or made from a [`ProfileSpec`] (`Profile::from(ProfileSpec::Steps { .. })`). Every
/// profile repeats, so any run length works, and is a pure function of time, so a replay
/// gives the same reference. Unknown keys are rejected.
///
/// The spec is checked once, when the profile is made, and cannot change afterwards:
/// [`Profile::at`] runs every control cycle (the MPC evaluates the horizon ahead, about
/// 80 times a cycle) and only looks up the verdict.
///
/// ```
/// use jetbench_control::{Profile, ProfileSpec};
///
/// let profile = Profile::from(ProfileSpec::Steps { levels_n: vec![20.0, 60.0], hold_s: 2.0, smoothing_s: 0.0 });
/// assert!(profile.validate().is_ok());
/// assert_eq!(profile.at(2.5).thrust_n, 60.0);
/// let bad = Profile::from(ProfileSpec::Steps { levels_n: vec![], hold_s: 2.0, smoothing_s: 0.0 });
/// assert!(bad.validate().is_err());
/// assert_eq!(bad.at(2.5).thrust_n, 0.0);
/// ```
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(from = "ProfileSpec", into = "ProfileSpec")]
pub struct Profile {
    spec: ProfileSpec,
    /// Why the spec cannot be followed, found once by [`ProfileSpec::validate`].
    invalid: Option<ControlError>,
}

/// The shape of a [`Profile`]: its kind and settings, as a config file gives them.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum ProfileSpec {
    /// Levels held for `hold_s` each, cycling. Each jump passes through a critically
    /// damped second-order prefilter `1/(τs + 1)²` with `τ = smoothing_s`, evaluated in
    /// closed form so `r`, `r'` and `r''` are exact; `smoothing_s = 0` gives raw steps
    /// (with zero derivatives).
    Steps {
        /// Thrust levels, N.
        levels_n: Vec<f64>,
        /// Time at each level, s.
        hold_s: f64,
        /// Prefilter time constant, s.
        smoothing_s: f64,
    },
    /// Each level held for `hold_s`, then a linear ramp of `ramp_s` to the next, cycling.
    /// `r''` is zero (corners are not smoothed).
    Ramps {
        /// Thrust levels, N.
        levels_n: Vec<f64>,
        /// Duration of each ramp, s.
        ramp_s: f64,
        /// Time at each level before its ramp, s.
        hold_s: f64,
    },
    /// `offset_n + amplitude_n·sin(2πt/period_s)`.
    Sines {
        /// Mean thrust, N.
        offset_n: f64,
        /// Amplitude, N.
        amplitude_n: f64,
        /// Period, s.
        period_s: f64,
    },
    /// Linear chirp from `f0_hz` to `f1_hz` over `sweep_s`, then again from `f0_hz`.
    /// The wrap is a jump unless the sweep holds a whole number of cycles.
    Chirp {
        /// Mean thrust, N.
        offset_n: f64,
        /// Amplitude, N.
        amplitude_n: f64,
        /// Start frequency, Hz.
        f0_hz: f64,
        /// End frequency, Hz.
        f1_hz: f64,
        /// Sweep duration, s.
        sweep_s: f64,
    },
    /// Other profiles one after the other, each for its `duration_s`, cycling. Each part
    /// starts at its own time zero; the reference may jump where parts meet.
    Campaign {
        /// The parts, in order.
        segments: Vec<Segment>,
    },
}

/// One part of a [`ProfileSpec::Campaign`].
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Segment {
    /// How long this part runs, s.
    pub duration_s: f64,
    /// The part.
    pub profile: Profile,
}

/// Names of the built-in profiles, for `--profile`.
pub const BUILTIN_PROFILES: [&str; 5] = ["steps", "ramps", "sines", "chirp", "campaign"];

impl Default for Profile {
    /// Steps across the default plant's range (about 0-86 N): 20, 50, 35, 70, 45, 30 N,
    /// 2.5 s each, smoothed with 0.2 s.
    fn default() -> Self {
        Profile::from(ProfileSpec::Steps {
            levels_n: vec![20.0, 50.0, 35.0, 70.0, 45.0, 30.0],
            hold_s: 2.5,
            smoothing_s: 0.2,
        })
    }
}

impl From<ProfileSpec> for Profile {
    /// Checks the spec once; a spec that fails [`ProfileSpec::validate`] still makes a
    /// profile, whose [`Profile::validate`] returns the reason and whose reference is zero.
    fn from(spec: ProfileSpec) -> Self {
        let invalid = spec.validate().err();
        Self { spec, invalid }
    }
}

impl From<Profile> for ProfileSpec {
    fn from(profile: Profile) -> Self {
        profile.spec
    }
}

impl Profile {
    /// The spec the profile was made from.
    pub fn spec(&self) -> &ProfileSpec {
        &self.spec
    }

    /// The `kind` name used in config files.
    pub fn kind(&self) -> &'static str {
        self.spec.kind()
    }

    /// A built-in profile (see [`BUILTIN_PROFILES`]) for an engine whose steady thrust
    /// runs from `idle_n` (at 25 % throttle) to `max_n` (at 100 %), so the same name suits
    /// a P100 and a P220. Levels are fractions of that span:
    ///
    /// - `steps`: 20, 50, 30, 95, 25, 65, 60, 40, 45, 80, 20 %, 5 s each, smoothed with
    ///   0.2 s. 30 → 95 % and 95 → 25 % are full-range steps that saturate the throttle;
    ///   65 → 60 % and 40 → 45 % are small ones that should not.
    /// - `ramps`: 10, 60, 30, 90 %, held 1.5 s, ramps of 2 s.
    /// - `sines`: 50 % ± 30 %, period 4 s.
    /// - `chirp`: 50 % ± 20 %, 0.05 → 1 Hz over 20 s.
    /// - `campaign`: the four in turn (55 s, 14 s, 12 s, 20 s).
    ///
    /// `None` for an unknown name or a span that is not finite and positive.
    pub fn builtin(name: &str, idle_n: f64, max_n: f64) -> Option<Profile> {
        let span_n = max_n - idle_n;
        if !(idle_n.is_finite() && span_n.is_finite() && span_n > 0.0) {
            return None;
        }
        let at = |fraction: f64| idle_n + fraction * span_n;
        let levels = |fractions: &[f64]| fractions.iter().map(|&f| at(f)).collect::<Vec<_>>();
        let spec = match name {
            "steps" => ProfileSpec::Steps {
                levels_n: levels(&[0.2, 0.5, 0.3, 0.95, 0.25, 0.65, 0.6, 0.4, 0.45, 0.8, 0.2]),
                hold_s: 5.0,
                smoothing_s: 0.2,
            },
            "ramps" => ProfileSpec::Ramps { levels_n: levels(&[0.1, 0.6, 0.3, 0.9]), ramp_s: 2.0, hold_s: 1.5 },
            "sines" => ProfileSpec::Sines { offset_n: at(0.5), amplitude_n: 0.3 * span_n, period_s: 4.0 },
            "chirp" => ProfileSpec::Chirp {
                offset_n: at(0.5),
                amplitude_n: 0.2 * span_n,
                f0_hz: 0.05,
                f1_hz: 1.0,
                sweep_s: 20.0,
            },
            "campaign" => ProfileSpec::Campaign {
                segments: [("steps", 55.0), ("ramps", 14.0), ("sines", 12.0), ("chirp", 20.0)]
                    .into_iter()
                    .map(|(part, duration_s)| {
                        Profile::builtin(part, idle_n, max_n).map(|profile| Segment { duration_s, profile })
                    })
                    .collect::<Option<Vec<_>>>()?,
            },
            _ => return None,
        };
        Some(Profile::from(spec))
    }

    /// Whether the spec can be followed (checked when the profile was made), so a bad
    /// config fails at load rather than producing NaN.
    pub fn validate(&self) -> Result<(), ControlError> {
        self.invalid.map_or(Ok(()), Err)
    }

    /// Reference at `t_s` seconds since the profile start. Negative or non-finite times
    /// count as 0. A profile that fails [`Profile::validate`] gives a zero reference
    /// rather than NaN.
    pub fn at(&self, t_s: f64) -> Reference {
        if self.invalid.is_some() {
            return Reference::default();
        }
        let t = if t_s.is_finite() && t_s > 0.0 { t_s } else { 0.0 };
        match &self.spec {
            ProfileSpec::Steps { levels_n, hold_s, smoothing_s } => steps_at(levels_n, *hold_s, *smoothing_s, t),
            ProfileSpec::Ramps { levels_n, ramp_s, hold_s } => ramps_at(levels_n, *ramp_s, *hold_s, t),
            ProfileSpec::Sines { offset_n, amplitude_n, period_s } => {
                let w = 2.0 * PI / period_s;
                let (sin, cos) = (w * t).sin_cos();
                Reference {
                    thrust_n: offset_n + amplitude_n * sin,
                    thrust_rate_n_per_s: amplitude_n * w * cos,
                    thrust_accel_n_per_s2: -amplitude_n * w * w * sin,
                }
            }
            ProfileSpec::Chirp { offset_n, amplitude_n, f0_hz, f1_hz, sweep_s } => {
                let ts = t - (t / sweep_s).floor() * sweep_s;
                let k = (f1_hz - f0_hz) / sweep_s;
                let phase = 2.0 * PI * (f0_hz * ts + 0.5 * k * ts * ts);
                let phase_rate = 2.0 * PI * (f0_hz + k * ts);
                let phase_accel = 2.0 * PI * k;
                let (sin, cos) = phase.sin_cos();
                Reference {
                    thrust_n: offset_n + amplitude_n * sin,
                    thrust_rate_n_per_s: amplitude_n * cos * phase_rate,
                    thrust_accel_n_per_s2: amplitude_n * (cos * phase_accel - sin * phase_rate * phase_rate),
                }
            }
            ProfileSpec::Campaign { segments } => {
                let total_s: f64 = segments.iter().map(|s| s.duration_s).sum();
                let mut local_s = t - (t / total_s).floor() * total_s;
                for segment in segments {
                    if local_s < segment.duration_s {
                        return segment.profile.at(local_s);
                    }
                    local_s -= segment.duration_s;
                }
                // Rounding left the time just past the end: the last part's end.
                segments.last().map_or_else(Reference::default, |s| s.profile.at(s.duration_s))
            }
        }
    }

    /// Lowest and highest thrust the profile visits, N (the step prefilter does not
    /// overshoot). `(0, 0)` for an empty level list.
    pub fn span_n(&self) -> (f64, f64) {
        match &self.spec {
            ProfileSpec::Steps { levels_n, .. } | ProfileSpec::Ramps { levels_n, .. } => {
                if levels_n.is_empty() {
                    return (0.0, 0.0);
                }
                levels_n.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &l| (lo.min(l), hi.max(l)))
            }
            ProfileSpec::Sines { offset_n, amplitude_n, .. } | ProfileSpec::Chirp { offset_n, amplitude_n, .. } => {
                (offset_n - amplitude_n.abs(), offset_n + amplitude_n.abs())
            }
            ProfileSpec::Campaign { segments } => segments
                .iter()
                .map(|s| s.profile.span_n())
                .reduce(|(lo, hi), (l, h)| (lo.min(l), hi.max(h)))
                .unwrap_or((0.0, 0.0)),
        }
    }
}

impl ProfileSpec {
    /// The `kind` name used in config files.
    pub fn kind(&self) -> &'static str {
        match self {
            ProfileSpec::Steps { .. } => "steps",
            ProfileSpec::Ramps { .. } => "ramps",
            ProfileSpec::Sines { .. } => "sines",
            ProfileSpec::Chirp { .. } => "chirp",
            ProfileSpec::Campaign { .. } => "campaign",
        }
    }

    /// Checks the settings: what [`Profile`] does once, when it is made.
    pub fn validate(&self) -> Result<(), ControlError> {
        match self {
            ProfileSpec::Steps { levels_n, hold_s, smoothing_s } => {
                check_levels(self.kind(), levels_n)?;
                check_duration("hold_s", *hold_s, false)?;
                check_duration("smoothing_s", *smoothing_s, true)?;
                if *smoothing_s > MAX_SMOOTHING_PER_HOLD * hold_s {
                    return Err(ControlError::InvalidDuration {
                        field: "smoothing_s",
                        value_s: *smoothing_s,
                        requirement: "at most 100 times hold_s",
                    });
                }
                Ok(())
            }
            ProfileSpec::Ramps { levels_n, ramp_s, hold_s } => {
                check_levels(self.kind(), levels_n)?;
                check_duration("ramp_s", *ramp_s, false)?;
                check_duration("hold_s", *hold_s, true)
            }
            ProfileSpec::Sines { offset_n, amplitude_n, period_s } => {
                check_finite("offset_n", *offset_n)?;
                check_finite("amplitude_n", *amplitude_n)?;
                check_duration("period_s", *period_s, false)
            }
            ProfileSpec::Chirp { offset_n, amplitude_n, f0_hz, f1_hz, sweep_s } => {
                check_finite("offset_n", *offset_n)?;
                check_finite("amplitude_n", *amplitude_n)?;
                check_frequency("f0_hz", *f0_hz)?;
                check_frequency("f1_hz", *f1_hz)?;
                check_duration("sweep_s", *sweep_s, false)
            }
            ProfileSpec::Campaign { segments } => {
                if segments.is_empty() {
                    return Err(ControlError::EmptyLevels { kind: "campaign" });
                }
                segments.iter().try_for_each(|s| {
                    check_duration("duration_s", s.duration_s, false)?;
                    s.profile.validate()
                })
            }
        }
    }
}

fn level(levels_n: &[f64], index: u64) -> f64 {
    let n = levels_n.len() as u64;
    if n == 0 {
        return 0.0;
    }
    levels_n[(index % n) as usize]
}

/// Sum of the prefilter responses to every jump so far. Jump `j ≥ 1` happens at
/// `j·hold_s` from level `j-1` to level `j`; the prefilter starts at rest on level 0.
/// For a jump `Δ` at age `s`: `r = L_new − Δ·(1 + s/τ)·e^(−s/τ)`,
/// `r' = Δ·(s/τ²)·e^(−s/τ)`, `r'' = Δ·(1 − s/τ)/τ²·e^(−s/τ)`.
fn steps_at(levels_n: &[f64], hold_s: f64, smoothing_s: f64, t: f64) -> Reference {
    let current = (t / hold_s).floor() as u64;
    let mut r = Reference { thrust_n: level(levels_n, current), ..Reference::default() };
    if smoothing_s <= 0.0 {
        return r;
    }
    let tau = smoothing_s;
    for j in (1..=current).rev().take(MAX_JUMPS_IN_HORIZON) {
        let age_s = t - j as f64 * hold_s;
        if age_s > SMOOTHING_HORIZON * tau {
            break;
        }
        let jump_n = level(levels_n, j) - level(levels_n, j - 1);
        let x = age_s / tau;
        let decay = (-x).exp();
        r.thrust_n -= jump_n * (1.0 + x) * decay;
        r.thrust_rate_n_per_s += jump_n * x / tau * decay;
        r.thrust_accel_n_per_s2 += jump_n * (1.0 - x) / (tau * tau) * decay;
    }
    r
}

fn ramps_at(levels_n: &[f64], ramp_s: f64, hold_s: f64, t: f64) -> Reference {
    let segment_s = hold_s + ramp_s;
    let k = (t / segment_s).floor();
    let since_s = t - k * segment_s;
    let index = k as u64;
    let from_n = level(levels_n, index);
    let to_n = level(levels_n, index.wrapping_add(1));
    if since_s < hold_s {
        return Reference { thrust_n: from_n, ..Reference::default() };
    }
    let rate = (to_n - from_n) / ramp_s;
    Reference { thrust_n: from_n + rate * (since_s - hold_s), thrust_rate_n_per_s: rate, thrust_accel_n_per_s2: 0.0 }
}

fn check_levels(kind: &'static str, levels_n: &[f64]) -> Result<(), ControlError> {
    if levels_n.is_empty() {
        return Err(ControlError::EmptyLevels { kind });
    }
    levels_n.iter().try_for_each(|&l| check_finite("levels_n", l))
}

fn check_finite(field: &'static str, value: f64) -> Result<(), ControlError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(ControlError::NonFinite { field, value })
    }
}

fn check_duration(field: &'static str, value_s: f64, zero_ok: bool) -> Result<(), ControlError> {
    check_finite(field, value_s)?;
    let ok = if zero_ok { value_s >= 0.0 } else { value_s > 0.0 };
    if ok {
        Ok(())
    } else {
        Err(ControlError::InvalidDuration { field, value_s, requirement: if zero_ok { ">= 0" } else { "> 0" } })
    }
}

fn check_frequency(field: &'static str, value_hz: f64) -> Result<(), ControlError> {
    check_finite(field, value_hz)?;
    if value_hz >= 0.0 {
        Ok(())
    } else {
        Err(ControlError::InvalidFrequency { field, value_hz })
    }
}
