//! `jetbench record`: every channel of a running service set into an MCAP file,
//! from this machine's bus (the recorder service, run here) or, with
//! `--remote ENDPOINT`, from a bench bridged over Zenoh.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use jetbench_bridge::{record_remote, Endpoint, RemoteBench};
use jetbench_stack::recorder::RecorderService;
use jetbench_stack::runtime::{run, Reader, RunOptions};

/// Options of `jetbench record`.
#[derive(clap::Args)]
pub struct RecordArgs {
    /// The MCAP file to write (cdr + ros2msg, as `jetbench up --record` writes it).
    #[arg(long, value_name = "FILE.mcap")]
    out: PathBuf,
    /// Record the bench bridged at this Zenoh endpoint (`jetbench up --zenoh`), e.g.
    /// tcp/BENCH-PC:7447, instead of this machine's bus.
    #[arg(long, value_name = "ENDPOINT")]
    remote: Option<String>,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
    /// Bench config of the running set (its recording then replays without --config; local only).
    #[arg(long, value_name = "FILE", conflicts_with = "remote")]
    config: Option<PathBuf>,
}

pub fn run_record(args: RecordArgs) -> anyhow::Result<ExitCode> {
    let duration = match args.duration {
        Some(d) if d.is_finite() && d > 0.0 => Some(Duration::from_secs_f64(d)),
        Some(d) => bail!("--duration {d} must be a positive number of seconds"),
        None => None,
    };
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty() && !d.is_dir()) {
        bail!("cannot record to {}: folder {} does not exist", args.out.display(), dir.display());
    }
    jetbench_bus::install_signal_flag()?;
    match &args.remote {
        Some(endpoint) => {
            let endpoint: Endpoint = endpoint.parse()?;
            let bench = RemoteBench::connect(&endpoint, &jetbench_bus::namespace_name()?)
                .with_context(|| format!("cannot reach the bench bridged at {endpoint}"))?;
            eprintln!("recording {} to {}", bench.describe(), args.out.display());
            let mut tap = bench.subscribe_all(8192)?;
            let report = record_remote(&mut tap, &args.out, duration, &bench.describe())?;
            eprint!("{report}");
        }
        None => {
            if let Some(d) = duration {
                // The recorder runs until a stop request: ask for one when the time is up.
                std::thread::spawn(move || {
                    std::thread::sleep(d);
                    jetbench_bus::request_stop();
                });
            }
            let options = RunOptions { config: args.config, output: Some(args.out.clone()), ..RunOptions::default() };
            run::<Reader<RecorderService>>(&options).context("recording this machine's bus")?;
        }
    }
    super::info::print_summary(&args.out)?;
    Ok(ExitCode::SUCCESS)
}
