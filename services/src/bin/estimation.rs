//! Estimation service: EKF of thrust and thrust rate, bench/thrust in, bench/state out.
//!
//! Started by `jetbench up`; see `jetbench-estimation --help`.

use clap::Parser;
use jetbench::{run_service, ServiceArgs};
use std::process::ExitCode;

/// Estimation service: EKF of thrust and thrust rate, bench/thrust in, bench/state out.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("estimation", || {
        Ok(jetbench_stack::service::run_estimation(&args.service.start(jetbench_msgs::ServiceId::Estimation)?)?)
    })
}
