//! Shared entry point of the jetbench binaries: logging, error reporting, and
//! the `main` of every service process.

use std::process::ExitCode;

use jetbench_stack::runtime::{run, RunOptions, Service};

/// `jetbench --version`, and the software named in every recording's header:
/// the release, the commit and the build date.
pub const VERSION: &str =
    concat!(env!("CARGO_PKG_VERSION"), " (", env!("JETBENCH_COMMIT"), ", built ", env!("JETBENCH_BUILD_DATE"), ")");

/// Sets up logging to stderr (`RUST_LOG` overrides the `info` default).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_log_filter()));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(|| jetbench_stack::runtime::status::ConsoleStderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        // A log line that cannot be written is dropped. Reporting it would print to
        // the same broken stderr, and a service whose launcher was killed (stderr a
        // closed pipe) would panic in its stop, before disarming the board and
        // recording the disarm.
        .log_internal_errors(false)
        .try_init();
}

/// `info` for jetbench; only errors from Zenoh's crates, whose warnings (an
/// unreachable endpoint, gossip settings) repeat what jetbench says itself, with
/// paths inside Zenoh's source. `RUST_LOG` replaces it.
fn default_log_filter() -> String {
    const ZENOH: &[&str] = &[
        "zenoh",
        "zenoh_buffers",
        "zenoh_codec",
        "zenoh_config",
        "zenoh_core",
        "zenoh_link",
        "zenoh_link_commons",
        "zenoh_link_tcp",
        "zenoh_protocol",
        "zenoh_runtime",
        "zenoh_sync",
        "zenoh_task",
        "zenoh_transport",
        "zenoh_util",
    ];
    std::iter::once("info".to_string()).chain(ZENOH.iter().map(|c| format!("{c}=error"))).collect::<Vec<_>>().join(",")
}

/// Arguments every service takes.
#[derive(Debug, clap::Parser)]
#[command(version)]
pub struct ServiceArgs {
    /// Bench config (TOML); the built-in simulated bench if omitted.
    #[arg(long, value_name = "FILE")]
    pub config: Option<std::path::PathBuf>,
    /// Run at the config's `[rt]` SCHED_FIFO priority and CPUs with memory locked,
    /// as if `[rt] enabled = true` (what the kernel refuses is logged, not fatal).
    #[arg(long)]
    pub rt: bool,
    /// The MCAP file to write (the recorder only).
    #[arg(long, value_name = "FILE.mcap")]
    pub out: Option<std::path::PathBuf>,
    /// Where to serve other machines (the viewer: HOST:PORT, default 127.0.0.1:8765;
    /// the bridge: a Zenoh endpoint, default tcp/127.0.0.1:7447; 0.0.0.0 for the control room).
    #[arg(long, value_name = "ADDRESS")]
    pub listen: Option<String>,
}

/// The `main` of service `S`: parses [`ServiceArgs`] (`about` is the binary's
/// `--help` line), runs the service inside a span named after it, and turns an
/// error into a message naming the service and a failing exit code.
pub fn service_main<S: Service>(about: &'static str) -> ExitCode {
    use clap::{CommandFactory, FromArgMatches};
    let name = S::ID.name();
    let matches = ServiceArgs::command().bin_name(format!("jetbench-{name}")).about(about).get_matches();
    let args = match ServiceArgs::from_arg_matches(&matches) {
        Ok(args) => args,
        Err(e) => e.exit(),
    };
    init_logging();
    jetbench_record::set_software_version(VERSION);
    let span = tracing::info_span!("service", name);
    let _entered = span.enter();
    match run::<S>(&RunOptions { config: args.config, rt: args.rt, output: args.out, listen: args.listen }) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            eprintln!("jetbench-{name}: error: {e:#}");
            jetbench_stack::runtime::announce_failure(&format_args!("{e:#}"));
            ExitCode::FAILURE
        }
    }
}
