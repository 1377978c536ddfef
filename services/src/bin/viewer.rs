//! Viewer service: the Foxglove live view of every bus channel.
//!
//! `jetbench-viewer --listen 0.0.0.0:8765`, then in the Foxglove app: Open
//! connection, Foxglove WebSocket, `ws://BENCH-PC:8765`.

use clap::Parser;
use jetbench::run_service;
use jetbench_viewer::{FoxgloveServer, LiveView, ServerOptions, DEFAULT_ADDR};
use std::process::ExitCode;

/// Viewer service: every bus channel served live to Foxglove (cdr + ros2msg, as recorded).
#[derive(Parser)]
#[command(version)]
struct Args {
    /// Where Foxglove clients connect: HOST:PORT (0.0.0.0:8765 for other machines).
    #[arg(long, value_name = "HOST:PORT", default_value = DEFAULT_ADDR)]
    listen: String,
    /// Messages queued per client before its oldest are dropped.
    #[arg(long, value_name = "MESSAGES", default_value_t = ServerOptions::default().backlog)]
    backlog: usize,
}

fn main() -> ExitCode {
    let args = Args::parse();
    run_service("viewer", || {
        let bus = jetbench_bus::Bus::open("viewer")?;
        let options = ServerOptions { backlog: args.backlog, ..ServerOptions::default() };
        let view = LiveView::open(&bus, FoxgloveServer::start(&args.listen, &options)?)?;
        tracing::info!("Foxglove live view on {}", view.server().url());
        jetbench_stack::service::announce_ready();
        eprint!("{}", view.run(&bus)?);
        Ok(())
    })
}
