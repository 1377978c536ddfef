//! Sensing service: force sensor frames in, calibrated thrust out on bench/thrust.
//!
//! Started by `jetbench up`; see `jetbench-sensing --help`.

use clap::Parser;
use jetbench::{run_service, ServiceArgs};
use std::process::ExitCode;

/// Sensing service: force sensor frames in, calibrated thrust out on bench/thrust.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("sensing", || {
        Ok(jetbench_stack::service::run_sensing(&args.service.start(jetbench_msgs::ServiceId::Sensing)?)?)
    })
}
