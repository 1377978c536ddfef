//! `jetbench metrics`: tracking figures of recorded runs, one report per controller run.
//!
//! The figures themselves are [`jetbench_control::tracking_metrics`]; this module reads
//! recordings, joins each reference with its command and a thrust, splits a file where the
//! controller changes, and prints.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::ValueEnum;
use jetbench_control::{
    tracking_metrics, MetricsError, MetricsOptions, ThrottleLimit, TrackingMetrics, TrackingSample,
};
use jetbench_ident::plot::{write_line_plot, LinePlot};
use jetbench_msgs::{channels, command_flags, controller_kind, Command, Sample, SimTruth};
use jetbench_record::Recording;
use serde_json::{json, Value};

/// A true-thrust sample belongs to a reference if it was sampled at most this long before
/// the reference's sensor frame was received (1.5 periods of 10 ms).
const MAX_TRUTH_AGE_NS: u64 = 15_000_000;

/// Which thrust the reference is compared with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ThrustSource {
    /// `sim/truth`: the simulated engine's true thrust (simulated bench only).
    Truth,
    /// `bench/state`: the EKF estimate the controller acted on.
    Estimate,
    /// `bench/thrust`: the force sensor's thrust, with its noise.
    Measured,
}

impl ThrustSource {
    fn name(self) -> &'static str {
        match self {
            ThrustSource::Truth => "truth",
            ThrustSource::Estimate => "estimate",
            ThrustSource::Measured => "measured",
        }
    }

    fn describe(self) -> &'static str {
        match self {
            ThrustSource::Truth => "sim/truth (the simulated engine's true thrust)",
            ThrustSource::Estimate => "bench/state (the EKF estimate the controller used)",
            ThrustSource::Measured => "bench/thrust (measured, with the sensor's noise)",
        }
    }
}

/// Arguments of `jetbench metrics`.
#[derive(clap::Args)]
#[command(after_long_help = "\
Figures per controller run (a file where the controller changes gives one run per controller):
  MAE, RMSE        mean absolute and RMS of reference minus thrust, N
  within ±5 %      share of time with |r - T| <= max(5 % of |r|, 1 N)
  SS error         steady-state error mean(r - T) on each hold (a reference constant for >= 1 s), \
over the last 40 % of its level's time, % of the level; the table shows the worst and mean magnitude
  overshoot        per step (a move from one hold to the next): the excursion beyond the new level, \
% of the step
  settling         per step: time until T stays within ±5 % of the step size around the new level; \
the table shows the mean over the steps that did not saturate the throttle
  saturation       share of time at a throttle limit the law did not ask for
  TV               throttle total variation sum |du| (chattering), % per second of run
  mpc              FBL fallbacks (solver failures) and the solve time p50/p99/max, µs

Thrust: the true thrust (sim/truth) when the recording has it, else the measured thrust \
(bench/thrust); --thrust picks one. Overshoot and settling on measured thrust include the \
sensor's noise. Times are seconds from the file's first control cycle.

JSON: an array with one object per run: file, run (1, 2, ...), controller (fbl, smc, mpc, \
open-loop), controller_code, thrust_source, start_s and end_s (the run in the file), notes, and \
metrics: samples, start_s and end_s (after --skip), duration_s, mae_n, rmse_n, max_error_n, \
within_5pct, holds [{start_s, end_s, level_n, window_start_s, steady_state_error_n, \
steady_state_error_pct}], worst_ and mean_steady_state_error_pct, steps [{hold, start_s, end_s, \
from_n, to_n, overshoot_pct, settling_time_s, saturated, saturated_s}], saturated_steps, \
max_overshoot_pct, max_overshoot_unsaturated_pct, mean_settling_time_s, unsettled_steps, \
saturation_pct, saturated_low_pct, saturated_high_pct, mean_throttle_pct, throttle_change_rms_pct, \
throttle_tv_pct, throttle_tv_pct_per_s, fallbacks, solve_us {p50, p99, max}. A figure that does \
not exist (no holds, a step that never settles) is null.

Examples:
  jetbench up --sim --duration 30 --record run.mcap && jetbench metrics run.mcap
  jetbench metrics fbl.mcap smc.mcap mpc.mcap --skip 2
  jetbench metrics run.mcap --json | jq '.[] | {controller, mae: .metrics.mae_n}'")]
pub struct MetricsArgs {
    /// Recordings of closed-loop runs (MCAP, from `jetbench up --record`).
    #[arg(value_name = "FILE.mcap", required = true)]
    files: Vec<PathBuf>,
    /// Print one JSON document (an array of runs) instead of tables.
    #[arg(long)]
    json: bool,
    /// Thrust to compare with the reference [default: truth when recorded, else measured].
    #[arg(long, value_enum)]
    thrust: Option<ThrustSource>,
    /// Leave out the first SECONDS of each run (the start-up transient).
    #[arg(long, default_value_t = 0.0, value_name = "SECONDS", allow_negative_numbers = true)]
    skip: f64,
    /// Also draw each run (reference and thrust; throttle) into this folder, as PNG and SVG
    /// named after the file: `<file>-run<N>-tracking`, `<file>-run<N>-throttle`.
    #[arg(long, value_name = "DIR")]
    plot: Option<PathBuf>,
}

/// One controller run of one file.
struct Run {
    index: usize,
    controller: u32,
    start_s: f64,
    end_s: f64,
    metrics: TrackingMetrics,
    samples: Vec<TrackingSample>,
}

/// Everything found in one file.
struct FileReport {
    file: String,
    source: ThrustSource,
    notes: Vec<String>,
    runs: Vec<Run>,
}

pub fn run(args: MetricsArgs) -> anyhow::Result<ExitCode> {
    if !(args.skip.is_finite() && args.skip >= 0.0) {
        bail!("--skip {} must be a number of seconds >= 0", args.skip);
    }
    let options = MetricsOptions { skip_s: args.skip, ..MetricsOptions::default() };
    let mut reports = Vec::with_capacity(args.files.len());
    for path in &args.files {
        reports.push(analyse(path, args.thrust, &options)?);
    }
    if let Some(dir) = &args.plot {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create the plot folder {}", dir.display()))?;
        let mut written = 0;
        for report in &reports {
            written += plot_runs(dir, report)?;
        }
        eprintln!("wrote {written} plot files to {}", dir.display());
    }
    if args.json {
        let runs: Vec<Value> = reports.iter().flat_map(run_json).collect();
        println!("{}", serde_json::to_string_pretty(&runs)?);
        for report in &reports {
            for note in &report.notes {
                eprintln!("{}: {note}", report.file);
            }
        }
    } else {
        for (i, report) in reports.iter().enumerate() {
            if i > 0 {
                println!();
            }
            print_report(report);
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Reads `path` and computes the figures of each controller run in it.
fn analyse(path: &Path, thrust: Option<ThrustSource>, options: &MetricsOptions) -> anyhow::Result<FileReport> {
    let file = path.display().to_string();
    // Checked here so the message says it once (the reader's error repeats its cause).
    std::fs::metadata(path).with_context(|| format!("cannot read {file}"))?;
    let recording = Recording::open(path)?;
    let mut notes = Vec::new();
    if recording.truncated {
        notes.push(
            "the file is truncated (the recorder was stopped abruptly): read up to its last complete chunk".into(),
        );
    }

    let mut references = recording.samples(channels::REFERENCE);
    let (commands, legacy) = read_commands(&recording);
    let mut missing = Vec::new();
    if references.is_empty() {
        missing.push(missing_channel("/bench/reference", recording.malformed(channels::REFERENCE)));
    }
    if commands.is_empty() {
        missing.push(missing_channel("/bench/command", recording.malformed(channels::COMMAND)));
    }
    if !missing.is_empty() {
        let what = if recording.messages.is_empty() {
            "holds no messages at all".into()
        } else {
            format!("lacks {}", missing.join(" and "))
        };
        bail!(
            "{file} {what}: metrics compare the thrust with the reference the controller tracked and the throttle it \
             commanded, so they need a closed-loop recording of every channel, e.g. \
             `jetbench up --sim --duration 30 --record run.mcap`"
        );
    }
    if legacy > 0 {
        notes.push(format!(
            "{legacy} commands were recorded before commands named their controller; controller taken from the \
             recorded config"
        ));
    }

    let truth = {
        let mut truth = recording.samples(channels::SIM_TRUTH);
        truth.sort_by_key(|t| t.stamp_ns);
        truth
    };
    let source = match thrust {
        Some(ThrustSource::Truth) if truth.is_empty() => bail!(
            "{file}: no sim/truth samples (only the simulated bench records the true thrust); use --thrust measured \
             or --thrust estimate"
        ),
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
        bail!(
            "{file}: none of the {} references has both a command and a {} thrust sample of the same cycle; \
             is the recording complete? (`jetbench info {file}` lists its channels)",
            references.len(),
            source.name()
        );
    }

    // One run per stretch of cycles with the same controller.
    let mut runs = Vec::new();
    let mut start = 0;
    for end in 1..=cycles.len() {
        if end < cycles.len() && cycles[end].0 == cycles[start].0 {
            continue;
        }
        let controller = cycles[start].0;
        let samples: Vec<TrackingSample> = cycles[start..end].iter().map(|(_, s)| *s).collect();
        let index = runs.len() + 1;
        let (start_s, end_s) = (samples[0].time_s, samples[samples.len() - 1].time_s);
        match tracking_metrics(&samples, options) {
            Ok(metrics) => runs.push(Run { index, controller, start_s, end_s, metrics, samples }),
            Err(e @ (MetricsError::TooFewSamples { .. } | MetricsError::SkippedEverything { .. })) => notes.push(
                format!("left out a {} run at {start_s:.2}-{end_s:.2} s: {e}", controller_kind::name(controller)),
            ),
            Err(e) => {
                return Err(e).with_context(|| {
                    format!("{file}: the {} run at {start_s:.2}-{end_s:.2} s", controller_kind::name(controller))
                })
            }
        }
        start = end;
    }
    if runs.is_empty() {
        bail!("{file}: no controller run is long enough for metrics ({})", notes.join("; "));
    }
    Ok(FileReport { file, source, notes, runs })
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
    let controller = recorded_controller(recording);
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

/// The controller code named by the recorded config's `[control] controller` (FBL, the
/// default, when the recording has no config).
fn recorded_controller(recording: &Recording) -> u32 {
    use jetbench_record::meta::{KEY_CONFIG, RUN as METADATA_NAME};
    let name = recording
        .metadata
        .get(METADATA_NAME)
        .and_then(|m| m.get(KEY_CONFIG))
        .and_then(|text| text.parse::<toml::Table>().ok())
        .and_then(|config| config.get("control")?.get("controller")?.as_str().map(str::to_owned));
    let codes = [controller_kind::OPEN_LOOP, controller_kind::FBL, controller_kind::SMC, controller_kind::MPC];
    name.and_then(|name| codes.into_iter().find(|&c| controller_kind::name(c) == name)).unwrap_or(controller_kind::FBL)
}

fn run_json(report: &FileReport) -> Vec<Value> {
    report
        .runs
        .iter()
        .map(|run| {
            json!({
                "file": report.file,
                "run": run.index,
                "controller": controller_kind::name(run.controller),
                "controller_code": run.controller,
                "thrust_source": report.source.name(),
                "start_s": run.start_s,
                "end_s": run.end_s,
                "notes": report.notes,
                "metrics": run.metrics,
            })
        })
        .collect()
}

fn print_report(report: &FileReport) {
    println!("{}: thrust from {}", report.file, report.source.describe());
    for note in &report.notes {
        println!("  note: {note}");
    }
    let mpc = report.runs.iter().any(|r| r.controller == controller_kind::MPC);
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
    for run in &report.runs {
        let m = &run.metrics;
        let mut row = vec![
            run.index.to_string(),
            controller_kind::name(run.controller).to_string(),
            format!("{:.1}-{:.1}", m.start_s, m.end_s),
            format!("{:.2}", m.mae_n),
            format!("{:.1}", m.within_5pct),
            match (m.worst_steady_state_error_pct, m.mean_steady_state_error_pct) {
                (Some(worst), Some(mean)) => format!("{worst:.2} / {mean:.2}"),
                _ => "- (no holds)".into(),
            },
            opt(m.max_overshoot_pct, 1),
            settling(m),
            format!("{:.1}", m.saturation_pct),
            format!("{:.1}", m.throttle_tv_pct_per_s),
        ];
        if mpc {
            if run.controller == controller_kind::MPC {
                row.push(m.fallbacks.to_string());
                row.push(format!("{} / {} / {}", m.solve_us.p50, m.solve_us.p99, m.solve_us.max));
            } else {
                row.extend(["-".to_string(), "-".to_string()]);
            }
        }
        rows.push(row);
    }
    print_table(&rows, "  ");

    for run in &report.runs {
        let m = &run.metrics;
        if m.holds.is_empty() {
            continue;
        }
        println!();
        println!("  run {} ({}): holds and the steps into them", run.index, controller_kind::name(run.controller));
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
                step.map_or(
                    "-".into(),
                    |s| if s.saturated { format!("yes, {:.2} s", s.saturated_s) } else { "no".into() },
                ),
            ]);
        }
        print_table(&rows, "    ");
    }
}

/// Mean settling time of the unsaturated steps, with the count it is over.
fn settling(m: &TrackingMetrics) -> String {
    let unsaturated = m.steps.len() - m.saturated_steps;
    match m.mean_settling_time_s {
        _ if unsaturated == 0 && m.steps.is_empty() => "- (no steps)".into(),
        _ if unsaturated == 0 => "- (all saturated)".into(),
        Some(t) if m.unsettled_steps == 0 => format!("{t:.2} ({})", steps(unsaturated)),
        Some(t) => format!("{t:.2} ({}, {} never)", steps(unsaturated - m.unsettled_steps), m.unsettled_steps),
        None => format!("never ({})", steps(unsaturated)),
    }
}

fn steps(count: usize) -> String {
    format!("{count} step{}", if count == 1 { "" } else { "s" })
}

fn opt(value: Option<f64>, decimals: usize) -> String {
    value.map_or("-".into(), |v| format!("{v:.decimals$}"))
}

/// Prints rows with columns padded to their widest cell (first column left-aligned).
fn print_table(rows: &[Vec<String>], indent: &str) {
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
        println!("{indent}{}", cells.join("  ").trim_end());
    }
}

/// Draws every run of `report`: reference and thrust over time, and the throttle.
fn plot_runs(dir: &Path, report: &FileReport) -> anyhow::Result<usize> {
    let stem = Path::new(&report.file).file_stem().map_or_else(|| "run".into(), |s| s.to_string_lossy().into_owned());
    let mut written = 0;
    for run in &report.runs {
        let t: Vec<f64> = run.samples.iter().map(|s| s.time_s).collect();
        let column = |f: fn(&TrackingSample) -> f64| run.samples.iter().map(f).collect::<Vec<f64>>();
        let (reference, thrust, throttle) =
            (column(|s| s.reference_n), column(|s| s.thrust_n), column(|s| s.throttle_pct));
        let name = controller_kind::name(run.controller);
        let title = format!(
            "{stem}: {name}, MAE {:.2} N, {:.0} % of the time within ±5 %",
            run.metrics.mae_n, run.metrics.within_5pct
        );
        let thrust_label = format!("thrust ({})", report.source.name());
        let series = [("reference", &t[..], &reference[..]), (thrust_label.as_str(), &t[..], &thrust[..])];
        let plot = LinePlot {
            title: &title,
            x_label: "time (s)",
            y_label: "thrust (N)",
            series: &series,
            hlines: &[],
            log_y: false,
        };
        written += write_line_plot(dir, &format!("{stem}-run{}-tracking", run.index), &plot)?.len();
        let title = format!(
            "{stem}: {name} throttle, {:.0} % of the time at a limit, total variation {:.0} %/s",
            run.metrics.saturation_pct, run.metrics.throttle_tv_pct_per_s
        );
        let series = [("throttle", &t[..], &throttle[..])];
        let limits = [(25.0, "25 %"), (100.0, "100 %")];
        let plot = LinePlot {
            title: &title,
            x_label: "time (s)",
            y_label: "throttle (%)",
            series: &series,
            hlines: &limits,
            log_y: false,
        };
        written += write_line_plot(dir, &format!("{stem}-run{}-throttle", run.index), &plot)?.len();
    }
    Ok(written)
}
