//! `jetbench replay`: recorded thrust through the live estimator code.
//!
//! Glue over [`jetbench_stack::replay`]: read the file, replay, print the
//! summary, optionally write the replayed recording, and turn the comparison
//! into the exit status (0 identical, 1 differs, 2 error) so that scripts can
//! check the determinism contract.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context};
use jetbench_record::Recording;
use jetbench_stack::config::BenchConfig;
use jetbench_stack::replay::{replay, write_replayed, EstimatorSetup, EstimatorSource, InputRule, ReplayReport};

/// Exit status when the replay differs from the recording.
const EXIT_DIFFERS: u8 = 1;
/// Exit status on an error (unreadable file, nothing to replay, unknown estimator).
const EXIT_ERROR: u8 = 2;

/// Arguments of `jetbench replay`.
#[derive(clap::Args)]
#[command(after_help = "Exit status: 0 identical to the recording (or nothing to compare), 1 differs, 2 error. \
More with --help.")]
#[command(after_long_help = "\
Each prediction uses the throttle the live estimator used, read from the recorded bench/state \
(input_throttle_pct of the state whose source_seq is the thrust sample's seq); thrust samples \
the live estimator never processed are skipped and counted. Without bench/state (or with \
--inputs actuation) the throttle is the last bench/actuation whose publish_ns <= the thrust \
sample's stamp_ns.

The estimator's model comes from the recording's `jetbench` metadata (the resolved model: \
its parameters, and the input delay the filter predicts through, so a model file deleted \
since does not matter). --config replaces it, and the replay is then not expected to match \
the recording bit for bit.

Exit status:
  0  every replayed estimate equals its recorded bench/state bit for bit
     (all f64 fields by their bits, stamp_ns, source_seq, flags), or there was nothing to compare
  1  the replay differs from the recording
  2  error (not an MCAP file, no thrust samples, no estimator config, ...)

Examples:
  jetbench replay run.mcap
  jetbench replay run.mcap --out replayed.mcap
  jetbench replay old-run.mcap --config my-bench.toml --inputs actuation")]
pub struct ReplayArgs {
    /// The recording to replay (MCAP, e.g. from `jetbench up --record`).
    #[arg(value_name = "FILE.mcap")]
    pub file: PathBuf,
    /// Write a copy of the recording whose bench/state holds the replayed
    /// estimates, plus a `replay` metadata record.
    #[arg(long, value_name = "FILE.mcap")]
    pub out: Option<PathBuf>,
    /// Take the estimator's model and noise settings from this bench config
    /// instead of the recording (then the replay need not be bit-exact).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Where each prediction's throttle comes from.
    #[arg(long, value_enum, default_value_t = Inputs::Auto)]
    pub inputs: Inputs,
}

/// `--inputs`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Inputs {
    /// The recorded bench/state when there is any, else bench/actuation.
    Auto,
    /// input_throttle_pct of the recorded bench/state (bit-exact).
    State,
    /// The last bench/actuation published at or before the thrust sample's stamp_ns.
    Actuation,
}

impl From<Inputs> for InputRule {
    fn from(inputs: Inputs) -> Self {
        match inputs {
            Inputs::Auto => InputRule::Auto,
            Inputs::State => InputRule::RecordedState,
            Inputs::Actuation => InputRule::Actuation,
        }
    }
}

/// Runs `jetbench replay`; errors are printed here so that they get their
/// own exit status (2), apart from "differs" (1).
pub fn run(args: ReplayArgs) -> anyhow::Result<ExitCode> {
    match replay_file(&args) {
        Ok(true) => Ok(ExitCode::SUCCESS),
        Ok(false) => Ok(ExitCode::from(EXIT_DIFFERS)),
        Err(e) => {
            eprintln!("jetbench: error: {}", crate::error_text(&e));
            Ok(ExitCode::from(EXIT_ERROR))
        }
    }
}

/// Replays, prints the summary and writes `--out`; true when identical.
fn replay_file(args: &ReplayArgs) -> anyhow::Result<bool> {
    if let Some(out) = &args.out {
        if same_file(out, &args.file) {
            bail!("--out {} is the recording being replayed; choose another file", out.display());
        }
    }
    let source = match &args.config {
        Some(path) => {
            let config = BenchConfig::load(path)?;
            let setup = EstimatorSetup::from_config(&config)
                .with_context(|| format!("the estimator model of {}", path.display()))?;
            EstimatorSource::Given(setup)
        }
        None => EstimatorSource::Recorded,
    };
    let recording = Recording::open(&args.file)?;

    let start = Instant::now();
    let outcome = replay(&recording, source, args.inputs.into())
        .with_context(|| format!("cannot replay {}", args.file.display()))?;
    let elapsed_s = start.elapsed().as_secs_f64();
    let report = &outcome.report;
    print_summary(&args.file, report, elapsed_s);

    if let Some(out) = &args.out {
        // Written beside the target and renamed, so a failure leaves no half file.
        let partial = out.with_extension("mcap.partial");
        let written = write_replayed(&recording, &outcome, &partial, report.metadata(&args.file))
            .with_context(|| format!("cannot write {}", out.display()));
        let written = match written {
            Ok(w) => w,
            Err(e) => {
                let _ = std::fs::remove_file(&partial);
                return Err(e);
            }
        };
        std::fs::rename(&partial, out).with_context(|| format!("cannot write {}", out.display()))?;
        println!(
            "  written:    {} ({} messages; bench/state replaced by the {} replayed estimates)",
            out.display(),
            written.written,
            outcome.estimates.len()
        );
        if written.not_copied > 0 {
            eprintln!(
                "jetbench: warning: {} messages were not copied to {} (not a jetbench channel, or not a CDR sample)",
                written.not_copied,
                out.display()
            );
        }
    }
    Ok(report.is_identical())
}

fn print_summary(file: &Path, r: &ReplayReport, elapsed_s: f64) {
    println!("replay of {}", file.display());
    println!("  estimator:  {}", r.estimator);
    println!("  inputs:     {}", r.inputs);
    println!("  replayed:   {} of {} thrust samples", r.replayed, r.thrust_samples);
    println!("  skipped:    {} (never processed by the live estimator)", r.skipped);
    if r.rejected > 0 {
        println!("  rejected:   {} (not finite; the live estimator rejects them too)", r.rejected);
    }
    println!("  compared:   {} with the recorded bench/state", r.compared);
    println!("  identical:  {} (bit for bit)", r.identical);
    if !r.is_identical() {
        println!(
            "  max |diff|: thrust_n {:.3e} N, thrust_rate_n_per_s {:.3e} N/s",
            r.max_diff_thrust_n, r.max_diff_thrust_rate_n_per_s
        );
        if let Some(d) = r.first_difference {
            println!("  first diff: thrust seq {} ({})", d.source_seq, d.field);
        }
    }
    let rate = if elapsed_s > 0.0 { r.replayed as f64 / elapsed_s } else { f64::INFINITY };
    println!("  rate:       {rate:.3e} samples/s ({} samples in {:.3} ms)", r.replayed, elapsed_s * 1e3);
    let verdict = match (r.compared, r.is_identical()) {
        (0, _) => "nothing to compare (the recording has no bench/state)",
        (_, true) => "identical to the recording",
        (_, false) => "DIFFERS from the recording",
    };
    println!("  result:     {verdict}");

    if r.truncated {
        eprintln!("jetbench: warning: {} is truncated; replayed what it holds", file.display());
    }
    if r.skipped > 0 {
        eprintln!(
            "jetbench: note: {} thrust samples were skipped: the live estimator never processed them \
             (it started late or its queue overflowed)",
            r.skipped
        );
    }
    if r.states_without_thrust > 0 {
        eprintln!(
            "jetbench: warning: {} recorded states have no thrust sample in the recording (the recorder lost \
             them); estimates after such a gap cannot match",
            r.states_without_thrust
        );
    }
    let m = r.malformed;
    if m.total() > 0 {
        eprintln!(
            "jetbench: warning: {} malformed samples ignored ({} thrust, {} state, {} actuation)",
            m.total(),
            m.thrust,
            m.state,
            m.actuation
        );
    }
    if !r.estimator.exact_expected() {
        eprintln!("jetbench: note: --config replaces the recorded estimator, so a bit-exact match is not expected");
    }
}

/// True when both paths name one existing file.
pub fn same_file(a: &Path, b: &Path) -> bool {
    matches!((std::fs::canonicalize(a), std::fs::canonicalize(b)), (Ok(a), Ok(b)) if a == b)
}
