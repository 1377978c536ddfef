//! `jetbench latency`: does the 100 Hz loop hold under load? The experiment is
//! [`jetbench_latency::campaign`]; this is its command line, progress bars and plot.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use jetbench_latency::campaign::{run_campaign, Campaign, CampaignOptions, Progress};
use jetbench_latency::load::{run_builtin, BuiltinLoad, LoadKind};

/// Options of `jetbench latency`.
#[derive(Debug, clap::Args)]
pub struct LatencyArgs {
    /// Seconds to measure each of the three (the service set over iceoryx2,
    /// over Unix sockets, the floor), spread over the rounds.
    #[arg(long, value_name = "SECONDS", default_value_t = 60.0)]
    duration: f64,
    /// Background load on every core while measuring: none, cpu (computation),
    /// all (computation, memory traffic, file I/O). stress-ng where installed,
    /// else the built-in generator.
    #[arg(long, default_value = "cpu", value_parser = load_kind)]
    load: LoadKind,
    /// Real-time settings (the config's `[rt]`): SCHED_FIFO priorities, CPU
    /// affinity, locked memory, for the services and the floor chain alike.
    #[arg(long)]
    rt: bool,
    /// Print the results as JSON on stdout (the progress goes to stderr).
    #[arg(long)]
    json: bool,
    /// Write a latency histogram plot (PNG and SVG beside it).
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// Keep the service sets' recordings in this folder
    /// (`iceoryx2-<round>.mcap`, `uds-<round>.mcap`).
    #[arg(long, value_name = "DIR")]
    keep: Option<PathBuf>,
    /// Bench config of the simulated bench (default: the built-in one).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Seconds at the start of each service-set run left out (start-up).
    #[arg(long, value_name = "SECONDS", default_value_t = 2.0)]
    warmup: f64,
    /// Rounds the duration is split into; each measures all three in turn.
    #[arg(long, value_name = "N", default_value_t = 2)]
    rounds: u32,
    /// Also measure the iceoryx2 set with the control room attached: the Foxglove
    /// viewer and the Zenoh bridge running, Foxglove clients that read everything,
    /// never read, and disconnect mid-stream, a Zenoh subscriber of every channel,
    /// and an operator who takes control over Zenoh with TLS and sends a heartbeat
    /// every 100 ms (an [operator] section and certificates made for the run, with
    /// openssl); and the same without the operator (only watching), in the same
    /// rounds. Reports the three end-to-end p99s, what the commands cost (commanding
    /// against watching), what the whole control room costs (against the bare set)
    /// and the deadline misses of each.
    #[arg(long)]
    control_room: bool,
}

fn load_kind(s: &str) -> Result<LoadKind, String> {
    s.parse()
}

/// Options of the built-in background load (`jetbench latency-load`).
#[derive(Debug, clap::Args)]
pub struct LoadArgs {
    /// Threads that compute without pause.
    #[arg(long, default_value_t = 2)]
    cpu: usize,
    /// Threads that stream through 128 MiB of memory each.
    #[arg(long, default_value_t = 0)]
    vm: usize,
    /// Threads that write and sync a 64 MiB file each.
    #[arg(long, default_value_t = 0)]
    io: usize,
}

/// Runs the built-in load until SIGINT/SIGTERM.
pub fn run_load(args: LoadArgs) -> anyhow::Result<ExitCode> {
    jetbench_bus::install_signal_flag()?;
    run_builtin(BuiltinLoad { cpu: args.cpu, vm: args.vm, io: args.io }, jetbench_bus::stop_requested)?;
    Ok(ExitCode::SUCCESS)
}

/// Progress on stderr: a bar per phase on a terminal, a line per phase in a log.
struct Bars {
    bar: ProgressBar,
    live: bool,
}

impl Progress for Bars {
    fn start(&mut self, what: &str, seconds: f64) {
        self.bar = if self.live {
            let bar = ProgressBar::new((seconds * 10.0).ceil() as u64);
            bar.set_style(
                ProgressStyle::with_template("{msg:<44} [{bar:30}] {elapsed}/{duration}")
                    .unwrap_or(ProgressStyle::default_bar()),
            );
            bar.set_message(what.to_string());
            bar
        } else {
            eprintln!("{what} ({seconds:.0} s)");
            ProgressBar::hidden()
        };
    }

    fn advance(&mut self, elapsed_s: f64) {
        self.bar.set_position((elapsed_s * 10.0) as u64);
    }

    fn finish(&mut self) {
        self.bar.finish_and_clear();
    }

    fn is_live(&self) -> bool {
        self.live
    }

    fn note(&mut self, line: &str) {
        self.bar.suspend(|| eprintln!("{line}"));
    }
}

pub fn run(args: LatencyArgs) -> anyhow::Result<ExitCode> {
    if let Some(dir) = &args.keep {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let options = CampaignOptions {
        duration_s: args.duration,
        rounds: args.rounds,
        warmup_s: args.warmup,
        load: args.load,
        rt: args.rt,
        config: args.config.clone(),
        keep: args.keep.clone(),
        exe: std::env::current_exe().context("cannot locate the jetbench binary")?,
        control_room: args.control_room,
    };
    let mut bars = Bars { bar: ProgressBar::hidden(), live: std::io::stderr().is_terminal() };
    let campaign = run_campaign(&options, &mut bars)?;
    if let Some(plot) = &args.plot {
        let files = write_plot(plot, &campaign)?;
        eprintln!("plot: {}", files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&campaign.report)?);
    } else {
        print!("{}", campaign.report);
    }
    Ok(ExitCode::SUCCESS)
}

fn write_plot(plot: &Path, campaign: &Campaign) -> anyhow::Result<Vec<PathBuf>> {
    let dir = plot.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let stem = plot.file_stem().and_then(|s| s.to_str()).context("--plot needs a file name, e.g. latency.png")?;
    let named = campaign.distributions();
    // Up to the largest p99.9, with room: the longest tail values land in the last bin.
    let upper = named.iter().map(|(_, h)| h.percentiles().p999).fold(0.0, f64::max) * 1.25;
    let series: Vec<(&str, Vec<f64>, Vec<f64>)> = named
        .iter()
        .map(|(name, h)| {
            let bins = h.bins(upper.max(1.0), 150);
            (*name, bins.iter().map(|b| b.0).collect(), bins.iter().map(|b| b.1 as f64).collect())
        })
        .collect();
    let refs: Vec<(&str, &[f64], &[f64])> = series.iter().map(|(n, x, y)| (*n, &x[..], &y[..])).collect();
    Ok(jetbench_plot::write_line_plot(
        dir,
        stem,
        &jetbench_plot::LinePlot {
            title: "Control path latency: sensor frame to board write (3 process hops)",
            x_label: "latency (µs); the last bin holds everything beyond",
            y_label: "cycles",
            series: &refs,
            hlines: &[],
            log_y: true,
            log_x: false,
        },
    )?)
}
