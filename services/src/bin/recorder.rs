//! Recorder service: every bus channel into one MCAP file.
//!
//! Started by `jetbench up --record FILE`; see `jetbench-recorder --help`.

use clap::Parser;
use jetbench::{run_service, ServiceArgs};
use std::path::PathBuf;
use std::process::ExitCode;

/// Recorder service: every bus channel into one MCAP file (cdr + ros2msg, zstd chunks).
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
    /// MCAP file to write.
    #[arg(long, value_name = "FILE.mcap")]
    out: PathBuf,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("recorder", || {
        let report =
            jetbench_stack::service::run_recorder(&args.service.start(jetbench_msgs::ServiceId::Recorder)?, &args.out)?;
        eprint!("{report}");
        if report.dropped_full > 0 {
            anyhow::bail!("{} samples were dropped because the disk writer fell behind", report.dropped_full);
        }
        Ok(())
    })
}
