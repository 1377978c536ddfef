//! Tracking figures of recorded runs: a recording's references joined with the
//! commands and a thrust of the same control cycle, split where the controller
//! changes, each run scored by [`tracking_metrics`] (`jetbench metrics`).
//!
//! ```no_run
//! use jetbench_control::recorded::recording_metrics;
//! use jetbench_control::MetricsOptions;
//! use jetbench_record::Recording;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let report = recording_metrics(&Recording::open("run.mcap".as_ref())?, None, &MetricsOptions::default())?;
//! for run in &report.runs {
//!     println!("{}: MAE {:.2} N", run.controller, run.metrics.mae_n);
//! }
//! print!("{report}"); // the tables `jetbench metrics` prints
//! # Ok(())
//! # }
//! ```

use std::collections::HashMap;
use std::fmt;

use jetbench_msgs::{channels, command_flags, Command, Sample, SimTruth};
use jetbench_record::meta::RunMetadata;
use jetbench_record::Recording;

use crate::{
    tracking_metrics, Controller, MetricsError, MetricsOptions, ThrottleLimit, TrackingMetrics, TrackingSample,
};

/// A true-thrust sample belongs to a reference if it was sampled at most this long before
/// the reference's sensor frame was received (one and a half periods).
const MAX_TRUTH_AGE_NS: u64 = jetbench_model::PERIOD_NS * 3 / 2;

/// Which thrust the reference is compared with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ThrustSource {
    /// `sim/truth`: the simulated engine's true thrust (simulated bench only).
    Truth,
    /// `bench/state`: the EKF estimate the controller acted on.
    Estimate,
    /// `bench/thrust`: the force sensor's thrust, with its noise.
    Measured,
}

impl ThrustSource {
    /// Every source with its name, for the command line.
    pub const ALL: [ThrustSource; 3] = [ThrustSource::Truth, ThrustSource::Estimate, ThrustSource::Measured];

    /// The name on the command line (`--thrust truth|estimate|measured`).
    pub fn name(self) -> &'static str {
        match self {
            ThrustSource::Truth => "truth",
            ThrustSource::Estimate => "estimate",
            ThrustSource::Measured => "measured",
        }
    }

    /// The channel it is read from and what it is, for a report's header.
    pub fn describe(self) -> &'static str {
        match self {
            ThrustSource::Truth => "sim/truth (the simulated engine's true thrust)",
            ThrustSource::Estimate => "bench/state (the EKF estimate the controller used)",
            ThrustSource::Measured => "bench/thrust (measured, with the sensor's noise)",
        }
    }
}

impl std::str::FromStr for ThrustSource {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|t| t.name() == s)
            .ok_or_else(|| format!("unknown thrust {s:?}: truth, estimate or measured"))
    }
}

/// Why a recording gives no figures.
#[derive(Debug, thiserror::Error)]
pub enum RecordedError {
    /// The recording lacks a channel metrics need (`what` names it): it is not a
    /// closed-loop recording of every channel.
    #[error(
        "{what}: metrics compare the thrust with the reference the controller tracked and the throttle it \
         commanded, so they need a closed-loop recording of every channel, e.g. \
         `jetbench up --sim --duration 30 --record run.mcap`"
    )]
    NotClosedLoop {
        /// What is missing, e.g. "no bench/command samples".
        what: String,
    },
    /// `--thrust truth` on a recording without `sim/truth` (a real bench has none).
    #[error("no sim/truth samples (only the simulated bench records the true thrust); use --thrust measured or --thrust estimate")]
    NoTruth,
    /// No reference could be joined with a command and a thrust of the same cycle.
    #[error(
        "none of the {references} references has both a command and a {thrust} thrust sample of the same cycle; \
         is the recording complete? (`jetbench info` lists its channels)"
    )]
    NothingJoined {
        /// References in the recording.
        references: usize,
        /// The thrust source asked for ([`ThrustSource::name`]).
        thrust: &'static str,
    },
    /// A controller run's metrics failed.
    #[error("the {controller} run at {start_s:.2}-{end_s:.2} s: {error}")]
    Metrics {
        /// The run's law ([`crate::Controller::name`]).
        controller: &'static str,
        /// The run's start, s from the recording's first control cycle.
        start_s: f64,
        /// The run's end, s from the recording's first control cycle.
        end_s: f64,
        /// Why its metrics failed.
        error: MetricsError,
    },
    /// Every controller run was too short for metrics.
    #[error("no controller run is long enough for metrics ({})", notes.join("; "))]
    NoRun {
        /// Why each run was skipped.
        notes: Vec<String>,
    },
}

/// One controller run of a recording.
#[derive(Clone, Debug)]
pub struct ControllerRun {
    /// 1, 2, ... in the recording.
    pub index: usize,
    /// The law; `code` keeps what the recording said when this build does not know it.
    pub controller: &'static str,
    /// The law's wire code ([`crate::Controller::code`]) as recorded.
    pub code: u32,
    /// The run in the recording, s from its first control cycle.
    pub start_s: f64,
    /// Its end, s from the recording's first control cycle.
    pub end_s: f64,
    /// Tracking figures over the run ([`TrackingMetrics`]).
    pub metrics: TrackingMetrics,
    /// Every joined cycle of the run: reference, thrust and throttle.
    pub samples: Vec<TrackingSample>,
}

/// Everything found in one recording.
#[derive(Clone, Debug)]
pub struct RecordingMetrics {
    /// Which thrust the metrics are of.
    pub source: ThrustSource,
    /// What was left out and why.
    pub notes: Vec<String>,
    /// The controller runs, in recording order.
    pub runs: Vec<ControllerRun>,
}

/// Joins the references of `recording` with their commands and a thrust
/// (`thrust`, or the true thrust when recorded, else the measured one), splits
/// the cycles where the controller changes and computes each run's figures.
pub fn recording_metrics(
    recording: &Recording,
    thrust: Option<ThrustSource>,
    options: &MetricsOptions,
) -> Result<RecordingMetrics, RecordedError> {
    let mut notes = Vec::new();
    if recording.truncated {
        notes.push(
            "the file is truncated (the recorder was stopped abruptly): read up to its last complete chunk".into(),
        );
    }
    let mut references = recording.samples(channels::REFERENCE);
    let (commands, legacy) = read_commands(recording);
    let missing: Vec<String> = [
        (references.is_empty(), "/bench/reference", recording.malformed(channels::REFERENCE)),
        (commands.is_empty(), "/bench/command", recording.malformed(channels::COMMAND)),
    ]
    .into_iter()
    .filter(|(missing, ..)| *missing)
    .map(|(_, topic, malformed)| missing_channel(topic, malformed))
    .collect();
    if !missing.is_empty() {
        let what = if recording.messages.is_empty() {
            "it holds no messages at all".into()
        } else {
            format!("it lacks {}", missing.join(" and "))
        };
        return Err(RecordedError::NotClosedLoop { what });
    }
    if legacy > 0 {
        notes.push(format!(
            "{legacy} commands were recorded before commands named their controller; controller taken from the \
             recorded config"
        ));
    }

    let mut truth = recording.samples(channels::SIM_TRUTH);
    truth.sort_by_key(|t| t.stamp_ns);
    let source = match thrust {
        Some(ThrustSource::Truth) if truth.is_empty() => return Err(RecordedError::NoTruth),
        Some(source) => source,
        None if truth.is_empty() => ThrustSource::Measured,
        None => ThrustSource::Truth,
    };
    let states: HashMap<u64, f64> = recording.samples(channels::STATE).iter().map(|s| (s.seq, s.thrust_n)).collect();
    let measured: HashMap<u64, f64> =
        recording.samples(channels::THRUST).iter().map(|t| (t.stamp_ns, t.thrust_n)).collect();
    let thrust_at = |stamp_ns: u64, state_seq: u64| -> Option<f64> {
        match source {
            ThrustSource::Truth => truth_at(&truth, stamp_ns),
            ThrustSource::Estimate => states.get(&state_seq).copied(),
            ThrustSource::Measured => measured.get(&stamp_ns).copied(),
        }
    };
    let by_cycle: HashMap<(u64, u64), &Command> = commands.iter().map(|c| ((c.stamp_ns, c.source_seq), c)).collect();

    // Join: one sample per control cycle, in time order.
    references.sort_by_key(|r| r.stamp_ns);
    let origin_ns = references[0].stamp_ns;
    let (mut no_command, mut no_thrust, mut non_finite, mut repeated) = (0, 0, 0, 0);
    let mut cycles: Vec<(u32, TrackingSample)> = Vec::with_capacity(references.len());
    let mut last_stamp = None;
    for r in &references {
        if last_stamp == Some(r.stamp_ns) {
            repeated += 1;
            continue;
        }
        let Some(command) = by_cycle.get(&(r.stamp_ns, r.source_seq)) else {
            no_command += 1;
            continue;
        };
        let Some(thrust_n) = thrust_at(r.stamp_ns, r.source_seq) else {
            no_thrust += 1;
            continue;
        };
        let sample = TrackingSample {
            time_s: (r.stamp_ns - origin_ns) as f64 * 1e-9,
            reference_n: r.thrust_n,
            reference_rate_n_per_s: r.thrust_rate_n_per_s,
            thrust_n,
            throttle_pct: command.throttle_pct,
            saturated: if command.flags & command_flags::SATURATED_HIGH != 0 {
                Some(ThrottleLimit::High)
            } else if command.flags & command_flags::SATURATED_LOW != 0 {
                Some(ThrottleLimit::Low)
            } else {
                None
            },
            fallback: command.flags & command_flags::FALLBACK != 0,
            solve_us: command.solve_us,
        };
        let values = [sample.reference_n, sample.reference_rate_n_per_s, sample.thrust_n, sample.throttle_pct];
        if values.iter().any(|v| !v.is_finite()) {
            non_finite += 1;
            continue;
        }
        last_stamp = Some(r.stamp_ns);
        cycles.push((command.controller, sample));
    }
    let left_out = [
        (no_command, "had no command".to_string()),
        (no_thrust, format!("had no {} thrust", source.name())),
        (non_finite, "had a value that is not a number".to_string()),
        (repeated, "repeated an earlier cycle".to_string()),
    ];
    for (count, why) in left_out {
        if count > 0 {
            notes.push(format!("left out {count} of {} references that {why}", references.len()));
        }
    }
    if cycles.is_empty() {
        return Err(RecordedError::NothingJoined { references: references.len(), thrust: source.name() });
    }

    // One run per stretch of cycles with the same controller.
    let mut runs = Vec::new();
    for stretch in cycles.chunk_by(|a, b| a.0 == b.0) {
        let code = stretch[0].0;
        let controller = Controller::name_of_code(code);
        let samples: Vec<TrackingSample> = stretch.iter().map(|(_, s)| *s).collect();
        let (start_s, end_s) = (samples[0].time_s, samples[samples.len() - 1].time_s);
        match tracking_metrics(&samples, options) {
            Ok(metrics) => {
                runs.push(ControllerRun { index: runs.len() + 1, controller, code, start_s, end_s, metrics, samples })
            }
            Err(e @ (MetricsError::TooFewSamples { .. } | MetricsError::SkippedEverything { .. })) => {
                notes.push(format!("left out a {controller} run at {start_s:.2}-{end_s:.2} s: {e}"))
            }
            Err(error) => return Err(RecordedError::Metrics { controller, start_s, end_s, error }),
        }
    }
    if runs.is_empty() {
        return Err(RecordedError::NoRun { notes });
    }
    Ok(RecordingMetrics { source, notes, runs })
}

/// A channel that gave no samples, and why if its messages are there but do not decode.
fn missing_channel(topic: &str, malformed: usize) -> String {
    if malformed > 0 {
        format!("{topic} (its {malformed} messages do not decode: recorded by an incompatible jetbench version?)")
    } else {
        topic.to_string()
    }
}

/// The true thrust sampled last before `stamp_ns` (the reference's sensor frame was received
/// then), if recent enough to be that frame's.
fn truth_at(truth: &[SimTruth], stamp_ns: u64) -> Option<f64> {
    let k = truth.partition_point(|t| t.stamp_ns <= stamp_ns).checked_sub(1)?;
    (stamp_ns - truth[k].stamp_ns <= MAX_TRUTH_AGE_NS).then_some(truth[k].thrust_n)
}

/// Decoded commands, and how many had the layout from before `controller` and `solve_us`
/// (those get the controller of the recorded config, and a solve time of 0).
fn read_commands(recording: &Recording) -> (Vec<Command>, usize) {
    let mut commands = recording.samples(channels::COMMAND);
    let Some(legacy_len) = Command::FIELDS.iter().find(|f| f.name == "controller").map(|f| f.offset) else {
        return (commands, 0);
    };
    let topic = channels::COMMAND.topic();
    let mut legacy = 0;
    let controller = recorded_controller(recording).code();
    for message in recording.messages.iter().filter(|m| m.topic == topic) {
        let Some(body) = message.data.strip_prefix(&jetbench_msgs::CDR_HEADER[..]) else { continue };
        if body.len() != legacy_len {
            continue;
        }
        let mut bytes = vec![0u8; std::mem::size_of::<Command>()];
        bytes[..legacy_len].copy_from_slice(body);
        if let Some(mut command) = Command::from_bytes(&bytes) {
            command.controller = controller;
            commands.push(command);
            legacy += 1;
        }
    }
    (commands, legacy)
}

/// The controller named by the recorded config's `[control] controller` (FBL, the
/// default, when the recording has no config).
fn recorded_controller(recording: &Recording) -> Controller {
    RunMetadata::of(recording)
        .and_then(|run| run.config_toml.parse::<toml::Table>().ok())
        .and_then(|config| config.get("control")?.get("controller")?.as_str()?.parse().ok())
        .unwrap_or_default()
}

/// The tables `jetbench metrics` prints: one row per run, then each run's holds
/// and the steps into them.
impl fmt::Display for RecordingMetrics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "thrust from {}", self.source.describe())?;
        for note in &self.notes {
            writeln!(f, "  note: {note}")?;
        }
        let mpc = self.runs.iter().any(|r| r.code == Controller::Mpc.code());
        let mut header = vec![
            "run",
            "controller",
            "time s",
            "MAE N",
            "within ±5 %",
            "SS error worst/mean %",
            "overshoot %",
            "settling s",
            "saturated %",
            "TV %/s",
        ];
        if mpc {
            header.extend(["fallbacks", "solve µs p50/p99/max"]);
        }
        let mut rows = vec![header.iter().map(|h| h.to_string()).collect::<Vec<_>>()];
        for run in &self.runs {
            let m = &run.metrics;
            let mut row = vec![
                run.index.to_string(),
                run.controller.to_string(),
                format!("{:.1}-{:.1}", m.start_s, m.end_s),
                format!("{:.2}", m.mae_n),
                format!("{:.1}", m.within_5pct),
                match (m.worst_steady_state_error_pct, m.mean_steady_state_error_pct) {
                    (Some(worst), Some(mean)) => format!("{worst:.2} / {mean:.2}"),
                    _ => "- (no holds)".into(),
                },
                m.max_overshoot_pct.map_or("-".into(), |v| format!("{v:.1}")),
                settling(m),
                format!("{:.1}", m.saturation_pct),
                format!("{:.1}", m.throttle_tv_pct_per_s),
            ];
            if mpc {
                if run.code == Controller::Mpc.code() {
                    row.push(m.fallbacks.to_string());
                    row.push(format!("{} / {} / {}", m.solve_us.p50, m.solve_us.p99, m.solve_us.max));
                } else {
                    row.extend(["-".to_string(), "-".to_string()]);
                }
            }
            rows.push(row);
        }
        table(f, &rows, "  ")?;

        for run in self.runs.iter().filter(|r| !r.metrics.holds.is_empty()) {
            let m = &run.metrics;
            writeln!(f)?;
            writeln!(f, "  run {} ({}): holds and the steps into them", run.index, run.controller)?;
            let mut rows = vec![["at s", "level N", "from N", "SS error %", "overshoot %", "settling s", "saturated"]
                .iter()
                .map(|h| h.to_string())
                .collect::<Vec<_>>()];
            for (i, hold) in m.holds.iter().enumerate() {
                let step = m.steps.iter().find(|s| s.hold == i);
                rows.push(vec![
                    format!("{:.2}", step.map_or(hold.start_s, |s| s.start_s)),
                    format!("{:.1}", hold.level_n),
                    step.map_or("-".into(), |s| format!("{:.1}", s.from_n)),
                    format!("{:+.2}", hold.steady_state_error_pct),
                    step.map_or("-".into(), |s| format!("{:.1}", s.overshoot_pct)),
                    step.map_or("-".into(), |s| s.settling_time_s.map_or("never".into(), |t| format!("{t:.2}"))),
                    step.map_or("-".into(), |s| {
                        if s.saturated {
                            format!("yes, {:.2} s", s.saturated_s)
                        } else {
                            "no".into()
                        }
                    }),
                ]);
            }
            table(f, &rows, "    ")?;
        }
        Ok(())
    }
}

/// Mean settling time of the unsaturated steps, with the count it is over.
fn settling(m: &TrackingMetrics) -> String {
    let steps = |count: usize| format!("{count} step{}", if count == 1 { "" } else { "s" });
    let unsaturated = m.steps.len() - m.saturated_steps;
    match m.mean_settling_time_s {
        _ if unsaturated == 0 && m.steps.is_empty() => "- (no steps)".into(),
        _ if unsaturated == 0 => "- (all saturated)".into(),
        Some(t) if m.unsettled_steps == 0 => format!("{t:.2} ({})", steps(unsaturated)),
        Some(t) => format!("{t:.2} ({}, {} never)", steps(unsaturated - m.unsettled_steps), m.unsettled_steps),
        None => format!("never ({})", steps(unsaturated)),
    }
}

/// Rows with columns padded to their widest cell (the first two left-aligned).
fn table(f: &mut fmt::Formatter<'_>, rows: &[Vec<String>], indent: &str) -> fmt::Result {
    let columns = rows.iter().map(Vec::len).max().unwrap_or(0);
    let widths: Vec<usize> = (0..columns)
        .map(|c| rows.iter().filter_map(|r| r.get(c)).map(|s| s.chars().count()).max().unwrap_or(0))
        .collect();
    for row in rows {
        let cells: Vec<String> = row
            .iter()
            .enumerate()
            .map(|(c, cell)| {
                let pad = " ".repeat(widths[c] - cell.chars().count());
                if c <= 1 {
                    format!("{cell}{pad}")
                } else {
                    format!("{pad}{cell}")
                }
            })
            .collect();
        writeln!(f, "{indent}{}", cells.join("  ").trim_end())?;
    }
    Ok(())
}
