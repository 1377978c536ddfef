//! Simulated bench: engine, force sensor and throttle board in real time at 100 Hz.
//!
//! Started by `jetbench up`; see `jetbench-sim-bench --help`.

use clap::Parser;
use jetbench::{run_service, ServiceArgs};
use std::process::ExitCode;

/// Simulated bench: engine, force sensor and throttle board in real time at 100 Hz.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("sim-bench", || {
        Ok(jetbench_stack::service::run_sim_bench(&args.service.start(jetbench_msgs::ServiceId::SimBench)?)?)
    })
}
