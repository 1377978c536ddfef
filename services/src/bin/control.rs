//! Control service: reference profile and feedback linearisation, bench/state in, bench/reference and bench/command out.
//!
//! Started by `jetbench up`; see `jetbench-control --help`.

use clap::Parser;
use jetbench::{run_service, ServiceArgs};
use std::process::ExitCode;

/// Control service: reference profile and feedback linearisation, bench/state in, bench/reference and bench/command out.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("control", || {
        Ok(jetbench_stack::service::run_control(&args.service.start(jetbench_msgs::ServiceId::Control)?)?)
    })
}
