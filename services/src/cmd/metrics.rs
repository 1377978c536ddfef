//! `jetbench metrics`: tracking figures of recorded runs, one report per controller run
//! ([`jetbench_control::recorded`]).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use jetbench_control::recorded::{recording_metrics, RecordingMetrics, ThrustSource};
use jetbench_control::{MetricsOptions, TrackingSample};
use jetbench_plot::{write_line_plot, LinePlot};
use jetbench_record::Recording;
use serde_json::{json, Value};

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
    #[arg(long, value_name = "truth|estimate|measured", value_parser = thrust_source)]
    thrust: Option<ThrustSource>,
    /// Leave out the first SECONDS of each run (the start-up transient).
    #[arg(long, default_value_t = 0.0, value_name = "SECONDS", allow_negative_numbers = true)]
    skip: f64,
    /// Also draw each run (reference and thrust; throttle) into this folder, as PNG and SVG
    /// named after the file: `<file>-run<N>-tracking`, `<file>-run<N>-throttle`.
    #[arg(long, value_name = "DIR")]
    plot: Option<PathBuf>,
}

fn thrust_source(s: &str) -> Result<ThrustSource, String> {
    s.parse()
}

/// The figures of one file.
struct FileReport {
    file: String,
    metrics: RecordingMetrics,
}

pub fn run(args: MetricsArgs) -> anyhow::Result<ExitCode> {
    if !(args.skip.is_finite() && args.skip >= 0.0) {
        bail!("--skip {} must be a number of seconds >= 0", args.skip);
    }
    let options = MetricsOptions { skip_s: args.skip, ..MetricsOptions::default() };
    let mut reports = Vec::with_capacity(args.files.len());
    for path in &args.files {
        let file = path.display().to_string();
        // Checked here so the message says it once (the reader's error repeats its cause).
        std::fs::metadata(path).with_context(|| format!("cannot read {file}"))?;
        let recording = Recording::open(path)?;
        let metrics = recording_metrics(&recording, args.thrust, &options).with_context(|| file.clone())?;
        reports.push(FileReport { file, metrics });
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
            for note in &report.metrics.notes {
                eprintln!("{}: {note}", report.file);
            }
        }
    } else {
        for (i, report) in reports.iter().enumerate() {
            if i > 0 {
                println!();
            }
            print!("{}: {}", report.file, report.metrics);
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn run_json(report: &FileReport) -> Vec<Value> {
    let m = &report.metrics;
    m.runs
        .iter()
        .map(|run| {
            json!({
                "file": report.file,
                "run": run.index,
                "controller": run.controller,
                "controller_code": run.code,
                "thrust_source": m.source.name(),
                "start_s": run.start_s,
                "end_s": run.end_s,
                "notes": m.notes,
                "metrics": run.metrics,
            })
        })
        .collect()
}

/// Draws every run of `report`: reference and thrust over time, and the throttle.
fn plot_runs(dir: &Path, report: &FileReport) -> anyhow::Result<usize> {
    let stem = Path::new(&report.file).file_stem().map_or_else(|| "run".into(), |s| s.to_string_lossy().into_owned());
    let mut written = 0;
    for run in &report.metrics.runs {
        let t: Vec<f64> = run.samples.iter().map(|s| s.time_s).collect();
        let column = |f: fn(&TrackingSample) -> f64| run.samples.iter().map(f).collect::<Vec<f64>>();
        let (reference, thrust, throttle) =
            (column(|s| s.reference_n), column(|s| s.thrust_n), column(|s| s.throttle_pct));
        let name = run.controller;
        let title = format!(
            "{stem}: {name}, MAE {:.2} N, {:.0} % of the time within ±5 %",
            run.metrics.mae_n, run.metrics.within_5pct
        );
        let thrust_label = format!("thrust ({})", report.metrics.source.name());
        let series = [("reference", &t[..], &reference[..]), (thrust_label.as_str(), &t[..], &thrust[..])];
        let plot = LinePlot {
            title: &title,
            x_label: "time (s)",
            y_label: "thrust (N)",
            series: &series,
            hlines: &[],
            log_y: false,
            log_x: false,
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
            log_x: false,
        };
        written += write_line_plot(dir, &format!("{stem}-run{}-throttle", run.index), &plot)?.len();
    }
    Ok(written)
}
