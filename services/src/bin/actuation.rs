//! Actuation service: applies bench/command to the throttle board, idles when commands stop.
//!
//! Started by `jetbench up`; see `jetbench-actuation --help`.

use clap::Parser;
use jetbench::{run_service, ServiceArgs};
use std::process::ExitCode;

/// Actuation service: applies bench/command to the throttle board, idles when commands stop.
#[derive(Parser)]
#[command(version)]
struct Args {
    #[command(flatten)]
    service: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("actuation", || {
        Ok(jetbench_stack::service::run_actuation(&args.service.start(jetbench_msgs::ServiceId::Actuation)?)?)
    })
}
