//! Shared entry point of the jetbench binaries: logging and error reporting.

use std::process::ExitCode;

/// Sets up logging to stderr (`RUST_LOG` overrides the `info` default).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}

/// Runs a service body inside a span named after the service, and turns an
/// error into a message naming the service and a failing exit code.
pub fn run_service(name: &'static str, body: impl FnOnce() -> anyhow::Result<()>) -> ExitCode {
    init_logging();
    let span = tracing::info_span!("service", name);
    let _entered = span.enter();
    match body() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            eprintln!("jetbench-{name}: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Arguments every service takes.
#[derive(Debug, clap::Args)]
pub struct ServiceArgs {
    /// Bench config (TOML); the built-in simulated bench if omitted.
    #[arg(long, value_name = "FILE")]
    pub config: Option<std::path::PathBuf>,
    /// Run at the config's `[rt]` SCHED_FIFO priority and CPUs with memory locked,
    /// as if `[rt] enabled = true` (what the kernel refuses is logged, not fatal).
    #[arg(long)]
    pub rt: bool,
}

impl ServiceArgs {
    pub fn load(&self) -> anyhow::Result<jetbench_stack::config::BenchConfig> {
        Ok(jetbench_stack::config::BenchConfig::load_or_default(self.config.as_deref())?)
    }

    /// Loads the config and applies the real-time settings of service `id`
    /// (before any thread starts, so every thread inherits them).
    pub fn start(&self, id: jetbench_msgs::ServiceId) -> anyhow::Result<jetbench_stack::config::BenchConfig> {
        let mut config = self.load()?;
        // `--rt` is `[rt] enabled = true` for this run: the service's own threads follow it.
        config.rt.enabled |= self.rt;
        if let Some(request) = config.rt.request(id, false) {
            jetbench_stack::rt::apply(&request).log(id.name());
        }
        Ok(config)
    }
}
