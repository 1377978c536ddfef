//! `jetbench faults`: the fault campaign, glue over [`jetbench_faults`].

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetbench_faults::campaign::{Options, Part};
use jetbench_faults::Bench;

/// Arguments of `jetbench faults`.
#[derive(clap::Args)]
#[command(after_help = "Exit status: 0 every bound held, 1 a bound broke or an experiment could not run.

Examples:
  jetbench faults --repeat 10 --report docs/faults/REPORT.md   # the whole campaign (scripts/faults.sh)
  jetbench faults --only kill:actuation --repeat 3
  jetbench faults --only disk --only recorder
  jetbench faults --only limits --limits-runs 10 --limits-seconds 60 --report docs/faults/REPORT.md")]
pub struct FaultsArgs {
    /// Kill each process, and crash the recorder, this many times at random moments.
    #[arg(long, default_value_t = 10)]
    repeat: usize,
    /// Seed of the random moments.
    #[arg(long, default_value_t = 17)]
    seed: u64,
    /// Only these parts (repeatable): kill, kill:PROCESS (sensing, estimation, control,
    /// actuation, sim-bench, recorder, launcher), recorder, disk, inject, second-up, access, limits.
    #[arg(long, value_name = "PART")]
    only: Vec<Part>,
    /// Length of the run with spikes (and of the one without), s.
    #[arg(long, default_value_t = 30)]
    spike_seconds: u32,
    /// Healthy-engine runs per profile (campaign, steps) with every limit on (part `limits`).
    #[arg(long, default_value_t = 10)]
    limits_runs: usize,
    /// Length of each healthy-engine run, s.
    #[arg(long, default_value_t = 60)]
    limits_seconds: u32,
    /// The healthy-engine runs with real-time settings (`jetbench up --rt`: SCHED_FIFO,
    /// CPU affinity, locked memory), as a bench PC runs the engine.
    #[arg(long)]
    limits_rt: bool,
    /// Write the report (Markdown) here. With --only, an existing report keeps
    /// its other sections: only those of the parts run are replaced.
    #[arg(long, value_name = "FILE.md")]
    report: Option<PathBuf>,
    /// Python with `mcap` installed, to read recovered files independently (scripts/pyenv.sh prints it).
    #[arg(long, value_name = "PYTHON")]
    python: Option<PathBuf>,
}

/// The runner of faults and soak: this `jetbench` binary, a scratch folder.
pub(super) fn bench(python: Option<PathBuf>) -> anyhow::Result<Bench> {
    let exe = std::env::current_exe().context("cannot locate the jetbench binary")?;
    let scratch = std::env::temp_dir().join(format!("jetbench-faults-{}", std::process::id()));
    let mut bench = Bench::new(exe, "faults", scratch)?;
    bench.python = python;
    Ok(bench)
}

fn machine() -> String {
    let cpus = jetbench_stack::runtime::rt::online_cpus();
    let kernel = std::fs::read_to_string("/proc/sys/kernel/osrelease").unwrap_or_default();
    format!("{cpus} CPUs, Linux {}", kernel.trim())
}

pub fn run(args: FaultsArgs) -> anyhow::Result<ExitCode> {
    let bench = bench(args.python)?;
    let options = Options {
        repeat: args.repeat.max(1),
        seed: args.seed,
        spike_seconds: args.spike_seconds,
        only: args.only,
        limits_runs: args.limits_runs.max(1),
        limits_seconds: args.limits_seconds.max(5),
        limits_rt: args.limits_rt,
    };
    let campaign = jetbench_faults::campaign::run(&bench, &options, &mut |what| eprintln!("faults: {what}"));
    let existing = args.report.as_ref().and_then(|p| std::fs::read_to_string(p).ok());
    let report = campaign.report(existing.as_deref(), &machine());
    match &args.report {
        Some(path) => {
            std::fs::write(path, &report).with_context(|| format!("cannot write {}", path.display()))?;
            println!("report written to {}", path.display());
        }
        None => print!("{report}"),
    }
    let problems = campaign.problems();
    for p in &problems {
        eprintln!("faults: bound broken: {p}");
    }
    let _ = std::fs::remove_dir_all(bench.scratch_dir());
    Ok(if problems.is_empty() { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
