//! Tracking figures of a run: how closely thrust followed the reference, and at what cost
//! in throttle activity.
//!
//! ```
//! use jetbench_control::{tracking_metrics, MetricsOptions, TrackingSample};
//!
//! // 3 s at 100 Hz: the reference holds 50 N, the thrust sits 0.5 N below it.
//! let samples: Vec<TrackingSample> = (0..300)
//!     .map(|k| TrackingSample {
//!         time_s: k as f64 * 0.01,
//!         reference_n: 50.0,
//!         thrust_n: 49.5,
//!         throttle_pct: 60.0,
//!         ..TrackingSample::default()
//!     })
//!     .collect();
//! let m = tracking_metrics(&samples, &MetricsOptions::default())?;
//! assert!((m.mae_n - 0.5).abs() < 1e-12);
//! assert_eq!(m.within_5pct, 100.0);
//! assert_eq!(m.holds.len(), 1);
//! // r − T = +0.5 N on a 50 N hold: 1 % (positive: thrust below the reference).
//! assert!((m.holds[0].steady_state_error_pct - 1.0).abs() < 1e-9);
//! assert!(m.steps.is_empty());
//! # Ok::<(), jetbench_control::MetricsError>(())
//! ```
//!
//! `jetbench metrics FILE.mcap` computes these from a recording, per controller run.
//!
//! # Definitions
//! With `e = r − T` (reference minus thrust, N) per sample, `u` the applied throttle (%):
//!
//! - `mae_n = mean |e|`, `rmse_n = √mean(e²)`.
//! - `within_5pct`: share of samples (%) with `|e| ≤ max(5 % of |r|, within_floor_n)`. The
//!   floor (default 1 N) keeps the band meaningful for references near 0 N, where 5 %
//!   would be narrower than the sensor noise. Samples come at a fixed rate (100 Hz), so a
//!   share of samples is a share of time; lost samples are left out, not interpolated.
//! - **Holds** are found from the reference alone. A sample is *quiet* when the recorded
//!   `|ṙ|` and the sample-to-sample `|Δr/Δt|` are both at most `hold_rate_n_per_s`
//!   (default 2 N/s; the difference catches raw jumps whose recorded rate is 0). Each run of
//!   quiet samples is cut, from its end backwards, into stretches where `r` stays within
//!   `max(hold_band_pct·|level|, hold_band_floor_n)` (default 1 %, 0.2 N) of the stretch's
//!   last value, its *level*. A stretch lasting at least `min_hold_s` (default 1 s) is a
//!   hold. A smoothed step of the default `steps` profile (τ = 0.2 s, 2.5 s per level)
//!   becomes a hold about 1.25 s after the jump, once its tail is inside the band.
//! - **Steps**: two consecutive holds whose levels differ by at least `min_step_n` (1 N),
//!   with the reference between them staying within the band of the range
//!   `[from, to]` (a monotonic move: a step or a ramp, not a sine burst). A step starts at
//!   the first sample after the previous hold and ends with its hold.
//! - **Steady-state error** per hold: `mean(e)` over its *steady window*, the last
//!   `steady_fraction` (40 %) of the time from the step start (the hold start for a hold
//!   that does not follow a step) to the hold end, never earlier than the hold start, less
//!   its last `preview_guard_s` (0.8 s, at most half the window): a law that previews the
//!   reference starts on the next step that early. For a 5 s level, 3.0-4.2 s into it. As a percentage of `max(|level|, within_floor_n)`. Signed:
//!   positive when the thrust stays below the reference. The run's worst and mean are of
//!   magnitudes.
//! - **Overshoot** per step: the largest excursion of `T` beyond the new level, in the
//!   direction of the step, from the step start to the hold end, as % of `|to − from|`
//!   (0 when `T` never passes the level).
//! - **Settling time** per step: from the step start until `T` enters, for the rest of
//!   the hold, the band `±settle_band_pct` (5 %) of the step size around the new level,
//!   never narrower than `±settle_floor_n` (0.5 N: a band inside the wiggle that sensor
//!   noise leaves in any closed loop would time the noise, not the law);
//!   `None` when `T` is outside the band at the last sample judged. Overshoot and settling
//!   both stop `preview_guard_s` before the hold ends (at most half the hold), like the
//!   steady window. On measured thrust the
//!   sensor noise (σ ≈ 2.6 N on the P100) exceeds the band of small steps, so use the true
//!   or the estimated thrust for settling times.
//! - A step is **saturated** when any sample from its start until
//!   `max(start + saturation_window_s, hold start)` (1.5 s; clipped to the hold end) has
//!   the throttle at a limit the law did not ask for; `saturated_s` says for how long. Compare controllers on the steps that
//!   are not: `mean_settling_time_s` and `max_overshoot_unsaturated_pct` use only those.
//! - `saturation_pct`: share of samples at a throttle limit the law did not ask for.
//! - Effort: `mean_throttle_pct = mean(u)`, `throttle_change_rms_pct = √mean(Δu²)`.
//! - Chattering: the total variation `throttle_tv_pct = Σ|Δu|`, and per second of run.
//! - Solver: `fallbacks` counts cycles whose law failed and fell back to FBL; `solve_us`
//!   gives the nearest-rank p50, p99 and the maximum of the per-cycle solve time, µs.

use std::ops::Range;

use serde::Serialize;

/// Tracking band of [`TrackingMetrics::within_5pct`], % of the reference.
pub const TRACKING_BAND_PCT: f64 = 5.0;

/// A throttle limit the command was held at although the law asked for more (or less).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ThrottleLimit {
    /// Held at the idle limit (25 %): the law asked for less.
    Low,
    /// Held at full throttle (100 %): the law asked for more.
    High,
}

/// One control cycle: the reference, the thrust it is compared with, and the command.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrackingSample {
    /// Time of the cycle, s; strictly increasing.
    pub time_s: f64,
    /// Reference thrust `r`, N.
    pub reference_n: f64,
    /// Reference thrust rate `ṙ`, N/s (used to find holds).
    pub reference_rate_n_per_s: f64,
    /// Thrust `T` compared with the reference (true, estimated or measured), N.
    pub thrust_n: f64,
    /// Throttle commanded (after clamping), %.
    pub throttle_pct: f64,
    /// The limit the throttle was held at, if the law asked beyond it.
    pub saturated: Option<ThrottleLimit>,
    /// The configured law failed this cycle and a fallback computed the command.
    pub fallback: bool,
    /// Time the law took, µs (0 for closed-form laws).
    pub solve_us: u32,
}

/// Thresholds of the definitions in the [module docs](self); the defaults suit 100 Hz
/// runs of the built-in profiles.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MetricsOptions {
    /// Leave out the samples of the first `skip_s` seconds (start-up transient), s.
    pub skip_s: f64,
    /// Smallest half-width of the tracking band and denominator of percentages, N.
    pub within_floor_n: f64,
    /// Largest `|ṙ|` of a hold, N/s.
    pub hold_rate_n_per_s: f64,
    /// Half-width of a hold's level band, % of the level.
    pub hold_band_pct: f64,
    /// Smallest half-width of a hold's level band, N.
    pub hold_band_floor_n: f64,
    /// Shortest hold, s.
    pub min_hold_s: f64,
    /// Smallest level change that counts as a step, N.
    pub min_step_n: f64,
    /// Share of a level's time, at its end, over which the steady-state error is taken (0-1].
    pub steady_fraction: f64,
    /// Time left out at the end of a steady window, s (at most half the window): a law
    /// that previews the reference (the MPC) starts on the next step that early, which is
    /// anticipation, not steady-state error.
    pub preview_guard_s: f64,
    /// Half-width of the settling band, % of the step size.
    pub settle_band_pct: f64,
    /// Smallest half-width of the settling band, N.
    pub settle_floor_n: f64,
    /// How long after a step starts a saturated throttle marks the step as saturated, s.
    pub saturation_window_s: f64,
}

impl Default for MetricsOptions {
    fn default() -> Self {
        MetricsOptions {
            skip_s: 0.0,
            within_floor_n: 1.0,
            hold_rate_n_per_s: 2.0,
            hold_band_pct: 1.0,
            hold_band_floor_n: 0.2,
            min_hold_s: 1.0,
            min_step_n: 1.0,
            steady_fraction: 0.4,
            preview_guard_s: 0.8,
            settle_band_pct: 5.0,
            settle_floor_n: 1.0,
            saturation_window_s: 1.5,
        }
    }
}

/// Why tracking figures could not be computed.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum MetricsError {
    /// Fewer than two samples: no duration, no throttle change.
    #[error("{samples} samples: at least 2 are needed for tracking figures")]
    TooFewSamples {
        /// Samples given.
        samples: usize,
    },
    /// `skip_s` leaves fewer than two samples.
    #[error(
        "skipping the first {skip_s} s leaves {left} of {samples} samples (the run lasts {duration_s:.2} s); skip less"
    )]
    SkippedEverything {
        /// The skip asked for, s.
        skip_s: f64,
        /// Samples left.
        left: usize,
        /// Samples given.
        samples: usize,
        /// Duration of the samples given, s.
        duration_s: f64,
    },
    /// A sample value is NaN or infinite.
    #[error("sample {index}: {field} is not finite ({value}); drop such samples first")]
    NonFinite {
        /// Index of the sample.
        index: usize,
        /// Field name.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// Time does not increase.
    #[error("sample {index}: time {time_s} s does not come after {previous_s} s; sort the samples by time")]
    TimeNotIncreasing {
        /// Index of the sample.
        index: usize,
        /// Its time, s.
        time_s: f64,
        /// The previous sample's time, s.
        previous_s: f64,
    },
    /// An option is out of range.
    #[error("metrics option {name} = {value} is invalid: it must be {requirement}")]
    InvalidOption {
        /// Field of [`MetricsOptions`].
        name: &'static str,
        /// The offending value.
        value: f64,
        /// What is accepted.
        requirement: &'static str,
    },
}

/// A stretch where the reference holds a level.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HoldMetrics {
    /// First sample of the hold, s.
    pub start_s: f64,
    /// Last sample of the hold, s.
    pub end_s: f64,
    /// Reference at the hold's last sample, N.
    pub level_n: f64,
    /// Start of the window the steady-state error is taken over, s.
    pub window_start_s: f64,
    /// `mean(r − T)` over the window, N; positive when the thrust stays below.
    pub steady_state_error_n: f64,
    /// The same as % of `max(|level|, within_floor_n)`.
    pub steady_state_error_pct: f64,
}

/// A change of level between two holds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StepMetrics {
    /// Index in [`TrackingMetrics::holds`] of the hold the step arrives at.
    pub hold: usize,
    /// First sample after the previous hold, s.
    pub start_s: f64,
    /// Last sample of the hold it arrives at, s.
    pub end_s: f64,
    /// Level of the previous hold, N.
    pub from_n: f64,
    /// Level of the new hold, N.
    pub to_n: f64,
    /// Largest excursion beyond `to_n`, % of `|to_n − from_n|`.
    pub overshoot_pct: f64,
    /// Time from the start until the thrust stays within the settling band; `None` if it
    /// never does before the hold ends.
    pub settling_time_s: Option<f64>,
    /// The throttle hit a limit the law did not ask for early in the step.
    pub saturated: bool,
    /// Time the throttle spent at such a limit early in the step, s.
    pub saturated_s: f64,
}

/// Nearest-rank percentiles of the law's solve time, µs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct SolveTimeUs {
    /// Median.
    pub p50: u32,
    /// 99th percentile.
    pub p99: u32,
    /// Longest.
    pub max: u32,
}

/// Tracking figures of one run (see the [module docs](self) for the definitions).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrackingMetrics {
    /// Samples used (after `skip_s`).
    pub samples: usize,
    /// Time of the first sample used, s.
    pub start_s: f64,
    /// Time of the last sample used, s.
    pub end_s: f64,
    /// Time from the first to the last sample used, s.
    pub duration_s: f64,
    /// Mean absolute tracking error, N.
    pub mae_n: f64,
    /// Root-mean-square tracking error, N.
    pub rmse_n: f64,
    /// Largest absolute tracking error, N.
    pub max_error_n: f64,
    /// Share of samples within ±5 % of the reference (or the floor), %.
    pub within_5pct: f64,
    /// Holds, in time order.
    pub holds: Vec<HoldMetrics>,
    /// Largest steady-state error magnitude over the holds, %; `None` without holds.
    pub worst_steady_state_error_pct: Option<f64>,
    /// Mean steady-state error magnitude over the holds, %; `None` without holds.
    pub mean_steady_state_error_pct: Option<f64>,
    /// Steps, in time order.
    pub steps: Vec<StepMetrics>,
    /// Steps that saturated the throttle.
    pub saturated_steps: usize,
    /// Largest overshoot over all steps, %; `None` without steps.
    pub max_overshoot_pct: Option<f64>,
    /// Largest overshoot over the steps that did not saturate, %.
    pub max_overshoot_unsaturated_pct: Option<f64>,
    /// Mean settling time of the steps that did not saturate and settled, s.
    pub mean_settling_time_s: Option<f64>,
    /// Steps that did not saturate and never settled.
    pub unsettled_steps: usize,
    /// Share of samples at a throttle limit the law did not ask for, %.
    pub saturation_pct: f64,
    /// The same at the idle limit, %.
    pub saturated_low_pct: f64,
    /// The same at full throttle, %.
    pub saturated_high_pct: f64,
    /// Mean throttle, %.
    pub mean_throttle_pct: f64,
    /// RMS of the sample-to-sample throttle change, %.
    pub throttle_change_rms_pct: f64,
    /// Total variation of the throttle `Σ|Δu|`, %.
    pub throttle_tv_pct: f64,
    /// Total variation per second of run, %/s.
    pub throttle_tv_pct_per_s: f64,
    /// Cycles computed by the fallback law.
    pub fallbacks: usize,
    /// Solve time of the law, µs.
    pub solve_us: SolveTimeUs,
}

/// Computes the tracking figures of `samples` (one per control cycle, in time order).
///
/// Fails on fewer than two samples (after `options.skip_s`), non-finite values, time that
/// does not increase, or options out of range; never panics.
pub fn tracking_metrics(samples: &[TrackingSample], options: &MetricsOptions) -> Result<TrackingMetrics, MetricsError> {
    check_options(options)?;
    check_samples(samples)?;
    let first_s = samples[0].time_s;
    let from = samples.partition_point(|s| s.time_s < first_s + options.skip_s);
    let s = &samples[from..];
    if s.len() < 2 {
        return Err(MetricsError::SkippedEverything {
            skip_s: options.skip_s,
            left: s.len(),
            samples: samples.len(),
            duration_s: samples[samples.len() - 1].time_s - first_s,
        });
    }
    let n = s.len() as f64;
    let duration_s = s[s.len() - 1].time_s - s[0].time_s;

    let errors: Vec<f64> = s.iter().map(|x| x.reference_n - x.thrust_n).collect();
    let mae_n = errors.iter().map(|e| e.abs()).sum::<f64>() / n;
    let rmse_n = (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    let max_error_n = errors.iter().fold(0.0_f64, |m, e| m.max(e.abs()));
    let within = s
        .iter()
        .zip(&errors)
        .filter(|(x, e)| e.abs() <= (TRACKING_BAND_PCT / 100.0 * x.reference_n.abs()).max(options.within_floor_n))
        .count();

    let hold_ranges = find_holds(s, options);
    let (holds, steps) = holds_and_steps(s, &hold_ranges, options);
    let magnitudes: Vec<f64> = holds.iter().map(|h| h.steady_state_error_pct.abs()).collect();
    let unsaturated: Vec<&StepMetrics> = steps.iter().filter(|st| !st.saturated).collect();
    let settled: Vec<f64> = unsaturated.iter().filter_map(|st| st.settling_time_s).collect();

    let count = |f: &dyn Fn(&TrackingSample) -> bool| s.iter().filter(|x| f(x)).count();
    let low = count(&|x| x.saturated == Some(ThrottleLimit::Low));
    let high = count(&|x| x.saturated == Some(ThrottleLimit::High));
    let changes: Vec<f64> = s.windows(2).map(|w| w[1].throttle_pct - w[0].throttle_pct).collect();
    let throttle_tv_pct: f64 = changes.iter().map(|d| d.abs()).sum();

    Ok(TrackingMetrics {
        samples: s.len(),
        start_s: s[0].time_s,
        end_s: s[s.len() - 1].time_s,
        duration_s,
        mae_n,
        rmse_n,
        max_error_n,
        within_5pct: 100.0 * within as f64 / n,
        worst_steady_state_error_pct: max_of(&magnitudes),
        mean_steady_state_error_pct: mean_of(&magnitudes),
        holds,
        saturated_steps: steps.len() - unsaturated.len(),
        max_overshoot_pct: max_of(&steps.iter().map(|st| st.overshoot_pct).collect::<Vec<_>>()),
        max_overshoot_unsaturated_pct: max_of(&unsaturated.iter().map(|st| st.overshoot_pct).collect::<Vec<_>>()),
        mean_settling_time_s: mean_of(&settled),
        unsettled_steps: unsaturated.len() - settled.len(),
        steps,
        saturation_pct: 100.0 * (low + high) as f64 / n,
        saturated_low_pct: 100.0 * low as f64 / n,
        saturated_high_pct: 100.0 * high as f64 / n,
        mean_throttle_pct: s.iter().map(|x| x.throttle_pct).sum::<f64>() / n,
        throttle_change_rms_pct: (changes.iter().map(|d| d * d).sum::<f64>() / changes.len() as f64).sqrt(),
        throttle_tv_pct,
        // Samples strictly increase in time, so the duration is positive.
        throttle_tv_pct_per_s: throttle_tv_pct / duration_s,
        fallbacks: count(&|x| x.fallback),
        solve_us: solve_time(s),
    })
}

fn check_options(o: &MetricsOptions) -> Result<(), MetricsError> {
    let non_negative = [
        ("skip_s", o.skip_s),
        ("within_floor_n", o.within_floor_n),
        ("hold_rate_n_per_s", o.hold_rate_n_per_s),
        ("hold_band_pct", o.hold_band_pct),
        ("hold_band_floor_n", o.hold_band_floor_n),
        ("settle_band_pct", o.settle_band_pct),
        ("settle_floor_n", o.settle_floor_n),
        ("saturation_window_s", o.saturation_window_s),
        ("preview_guard_s", o.preview_guard_s),
    ];
    for (name, value) in non_negative {
        if !(value.is_finite() && value >= 0.0) {
            return Err(MetricsError::InvalidOption { name, value, requirement: "a finite number >= 0" });
        }
    }
    for (name, value) in [("min_hold_s", o.min_hold_s), ("min_step_n", o.min_step_n)] {
        if !(value.is_finite() && value > 0.0) {
            return Err(MetricsError::InvalidOption { name, value, requirement: "a finite number > 0" });
        }
    }
    if !(o.steady_fraction > 0.0 && o.steady_fraction <= 1.0) {
        return Err(MetricsError::InvalidOption {
            name: "steady_fraction",
            value: o.steady_fraction,
            requirement: "in (0, 1]",
        });
    }
    Ok(())
}

fn check_samples(samples: &[TrackingSample]) -> Result<(), MetricsError> {
    if samples.len() < 2 {
        return Err(MetricsError::TooFewSamples { samples: samples.len() });
    }
    for (index, x) in samples.iter().enumerate() {
        let fields = [
            ("time_s", x.time_s),
            ("reference_n", x.reference_n),
            ("reference_rate_n_per_s", x.reference_rate_n_per_s),
            ("thrust_n", x.thrust_n),
            ("throttle_pct", x.throttle_pct),
        ];
        if let Some((field, value)) = fields.into_iter().find(|(_, v)| !v.is_finite()) {
            return Err(MetricsError::NonFinite { index, field, value });
        }
        if index > 0 && x.time_s <= samples[index - 1].time_s {
            return Err(MetricsError::TimeNotIncreasing {
                index,
                time_s: x.time_s,
                previous_s: samples[index - 1].time_s,
            });
        }
    }
    Ok(())
}

/// Half-width of the level band around `level_n`, N.
fn hold_band_n(level_n: f64, o: &MetricsOptions) -> f64 {
    (o.hold_band_pct / 100.0 * level_n.abs()).max(o.hold_band_floor_n)
}

/// Index ranges of the holds, in time order (see the module docs).
fn find_holds(s: &[TrackingSample], o: &MetricsOptions) -> Vec<Range<usize>> {
    let quiet = |k: usize| {
        let rate_ok = s[k].reference_rate_n_per_s.abs() <= o.hold_rate_n_per_s;
        let jump_ok = k == 0 || {
            let (a, b) = (&s[k - 1], &s[k]);
            (b.reference_n - a.reference_n).abs() <= o.hold_rate_n_per_s * (b.time_s - a.time_s)
        };
        rate_ok && jump_ok
    };
    let mut holds = Vec::new();
    let mut k = 0;
    while k < s.len() {
        if !quiet(k) {
            k += 1;
            continue;
        }
        let start = k;
        while k < s.len() && quiet(k) {
            k += 1;
        }
        // Quiet samples start..k: cut into level stretches from the end backwards.
        let mut found = Vec::new();
        let mut end = k;
        while end > start {
            let level_n = s[end - 1].reference_n;
            let band_n = hold_band_n(level_n, o);
            let mut first = end - 1;
            while first > start && (s[first - 1].reference_n - level_n).abs() <= band_n {
                first -= 1;
            }
            if s[end - 1].time_s - s[first].time_s >= o.min_hold_s {
                found.push(first..end);
            }
            end = first;
        }
        holds.extend(found.into_iter().rev());
    }
    holds
}

fn holds_and_steps(
    s: &[TrackingSample],
    ranges: &[Range<usize>],
    o: &MetricsOptions,
) -> (Vec<HoldMetrics>, Vec<StepMetrics>) {
    let mut holds = Vec::with_capacity(ranges.len());
    let mut steps = Vec::new();
    for (i, range) in ranges.iter().enumerate() {
        let last = range.end - 1;
        let level_n = s[last].reference_n;
        let step_start = (i > 0 && is_step(s, &ranges[i - 1], range, o)).then(|| ranges[i - 1].end);
        if let Some(start) = step_start {
            steps.push(step_metrics(s, i, ranges[i - 1].end - 1, start, range, o));
        }

        // Steady window: the last `steady_fraction` of the level's time, within the hold.
        let segment_start_s = s[step_start.unwrap_or(range.start)].time_s;
        let window_from_s = s[last].time_s - o.steady_fraction * (s[last].time_s - segment_start_s);
        let window_start = (range.start..range.end).find(|&k| s[k].time_s >= window_from_s).unwrap_or(last);
        let guard_s = o.preview_guard_s.min(0.5 * (s[last].time_s - s[window_start].time_s));
        let window_end = (window_start..range.end).rfind(|&k| s[k].time_s <= s[last].time_s - guard_s).unwrap_or(last);
        let window = &s[window_start..=window_end];
        let steady_state_error_n = window.iter().map(|x| x.reference_n - x.thrust_n).sum::<f64>() / window.len() as f64;
        holds.push(HoldMetrics {
            start_s: s[range.start].time_s,
            end_s: s[last].time_s,
            level_n,
            window_start_s: s[window_start].time_s,
            steady_state_error_n,
            steady_state_error_pct: 100.0 * steady_state_error_n / level_n.abs().max(o.within_floor_n),
        });
    }
    (holds, steps)
}

/// True when the move from hold `prev` to hold `next` is a step: a large enough level
/// change with the reference in between staying within the range of the two levels.
fn is_step(s: &[TrackingSample], prev: &Range<usize>, next: &Range<usize>, o: &MetricsOptions) -> bool {
    let from_n = s[prev.end - 1].reference_n;
    let to_n = s[next.end - 1].reference_n;
    if (to_n - from_n).abs() < o.min_step_n {
        return false;
    }
    let band_n = hold_band_n(from_n, o).max(hold_band_n(to_n, o));
    let (lo, hi) = (from_n.min(to_n) - band_n, from_n.max(to_n) + band_n);
    s[prev.end..next.start].iter().all(|x| (lo..=hi).contains(&x.reference_n))
}

fn step_metrics(
    s: &[TrackingSample],
    hold: usize,
    prev_last: usize,
    start: usize,
    range: &Range<usize>,
    o: &MetricsOptions,
) -> StepMetrics {
    let last = range.end - 1;
    let from_n = s[prev_last].reference_n;
    let to_n = s[last].reference_n;
    let size_n = (to_n - from_n).abs();
    let direction = (to_n - from_n).signum();
    let start_s = s[start].time_s;
    // Judged up to the hold's end less the preview guard, as the steady window is.
    let hold_s = s[last].time_s - s[range.start].time_s;
    let until_s = s[last].time_s - o.preview_guard_s.min(0.5 * hold_s);
    let end = (start..range.end).rfind(|&k| s[k].time_s <= until_s).map_or(range.end, |k| k + 1);
    let span = &s[start..end];

    let beyond_n = span.iter().map(|x| direction * (x.thrust_n - to_n)).fold(0.0_f64, f64::max);

    let band_n = (o.settle_band_pct / 100.0 * size_n).max(o.settle_floor_n);
    let outside = |x: &TrackingSample| (x.thrust_n - to_n).abs() > band_n;
    let settling_time_s = match span.iter().rposition(outside) {
        None => Some(0.0),
        Some(k) if k + 1 == span.len() => None,
        Some(k) => Some(span[k + 1].time_s - start_s),
    };

    // Each saturated sample counts until the next one (the last, as long as the one before).
    let window_end_s = (start_s + o.saturation_window_s).max(s[range.start].time_s);
    let window = span.iter().take_while(|x| x.time_s <= window_end_s).count();
    let saturated = span[..window].iter().any(|x| x.saturated.is_some());
    let saturated_s = (start..start + window)
        .filter(|&k| s[k].saturated.is_some())
        .map(|k| if k + 1 < s.len() { s[k + 1].time_s - s[k].time_s } else { s[k].time_s - s[k - 1].time_s })
        .sum();

    StepMetrics {
        hold,
        start_s,
        end_s: s[last].time_s,
        from_n,
        to_n,
        overshoot_pct: 100.0 * beyond_n / size_n,
        settling_time_s,
        saturated,
        saturated_s,
    }
}

fn solve_time(s: &[TrackingSample]) -> SolveTimeUs {
    let mut us: Vec<u32> = s.iter().map(|x| x.solve_us).collect();
    us.sort_unstable();
    // Nearest rank: the smallest value with at least p % of the samples at or below it.
    let rank = |p: f64| us[((p / 100.0 * us.len() as f64).ceil() as usize).clamp(1, us.len()) - 1];
    SolveTimeUs { p50: rank(50.0), p99: rank(99.0), max: us[us.len() - 1] }
}

fn max_of(values: &[f64]) -> Option<f64> {
    values.iter().copied().reduce(f64::max)
}

fn mean_of(values: &[f64]) -> Option<f64> {
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}
