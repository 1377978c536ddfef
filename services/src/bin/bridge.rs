//! Bridge service: every bus channel published on Zenoh for other machines.
//!
//! `jetbench-bridge --endpoint tcp/0.0.0.0:7447`; keys `jetbench/<namespace>/<channel>`,
//! payloads the samples' CDR messages (as recorded).

use clap::Parser;
use jetbench::run_service;
use jetbench_bridge::{local_namespace, Bridge, Endpoint};
use std::process::ExitCode;

/// Bridge service: every bus channel on Zenoh under jetbench/<namespace>/<channel>.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// Where remote machines connect: tcp/HOST:PORT (tcp/0.0.0.0:7447 for other machines).
    #[arg(long, value_name = "tcp/HOST:PORT", default_value = "tcp/127.0.0.1:7447")]
    endpoint: Endpoint,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("bridge", || {
        let bus = jetbench_bus::Bus::open("bridge")?;
        let namespace = local_namespace()?;
        let bridge = Bridge::open(&bus, &args.endpoint, &namespace)?;
        tracing::info!("publishing every channel on zenoh {} under jetbench/{namespace}/", args.endpoint);
        jetbench_stack::service::announce_ready();
        eprint!("{}", bridge.run(&bus)?);
        Ok(())
    })
}
