//! `jetbench soak`: the set for minutes under load, glue over [`jetbench_faults::soak`].

use std::process::ExitCode;
use std::time::Duration;

use jetbench_latency::load::LoadKind;

use super::faults::bench;

/// Arguments of `jetbench soak`.
#[derive(clap::Args)]
pub struct SoakArgs {
    /// How long, minutes.
    #[arg(long, default_value_t = 30.0)]
    minutes: f64,
    /// Background load: none, cpu, all (computation, memory traffic and file I/O).
    #[arg(long, default_value = "all")]
    load: LoadKind,
    /// Sample every process's memory every this many seconds.
    #[arg(long, default_value_t = 10.0)]
    every: f64,
    /// Run the set with its real-time settings (`jetbench up --rt`), as a bench under load should.
    #[arg(long)]
    rt: bool,
}

pub fn run(args: SoakArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.minutes > 0.0 && args.every > 0.0, "--minutes and --every must be positive");
    let bench = bench(None)?;
    let every = Duration::from_secs_f64(args.every);
    let soak = jetbench_faults::soak::soak(&bench, args.minutes, args.load, args.rt, every)?;
    print!("{soak}");
    let _ = std::fs::remove_dir_all(bench.scratch_dir());
    Ok(if soak.exit_ok { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
