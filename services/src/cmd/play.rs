//! `jetbench play`: a recording played at its recorded pace, like `ros2 bag play`:
//! published on the bus (so `echo`, `hz`, `record` and the viewer see it as live),
//! or, with `--foxglove`, served to Foxglove (and with `--bus` as well, both).

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetbench_bus::lock::NamespaceLock;
use jetbench_bus::Bus;
use jetbench_record::clock::format_local;
use jetbench_viewer::{BusSink, FoxgloveServer, PlayOptions, PlayReport, Player, ServerOptions, DEFAULT_ADDR};

/// Options of `jetbench play`.
#[derive(clap::Args)]
#[command(after_long_help = "\
The recording is published on this machine's bus, in the namespace of JETBENCH_BUS, as a running \
service set would publish it: `jetbench echo bench/thrust`, `jetbench hz`, `jetbench record` and \
the viewer read it as live. Like a set, play takes the namespace for itself, so a recording is \
never mixed into a running bench (its commands would reach the engine); play in another namespace \
to watch a recording beside a live set. With --foxglove it is served to Foxglove instead, without \
the bus; add --bus for both.

Examples:
  jetbench play run.mcap --rate 2
  jetbench play run.mcap --foxglove --loop       (Foxglove at ws://127.0.0.1:8765)
  jetbench play run.mcap --foxglove --bus")]
pub struct PlayArgs {
    /// MCAP recording of `jetbench up --record` (or `jetbench record --remote`).
    file: PathBuf,
    /// Serve it on the Foxglove WebSocket protocol at HOST:PORT instead of publishing on the bus.
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = DEFAULT_ADDR)]
    foxglove: Option<String>,
    /// With --foxglove: publish on the bus as well.
    #[arg(long, requires = "foxglove")]
    bus: bool,
    /// Speed: 1 plays in real time, 2 twice as fast.
    #[arg(long, default_value_t = 1.0)]
    rate: f64,
    /// Start over at the end, until Ctrl-C.
    #[arg(long = "loop")]
    looped: bool,
}

pub fn run(args: PlayArgs) -> anyhow::Result<ExitCode> {
    jetbench_bus::install_signal_flag()?;
    let options = PlayOptions { rate: args.rate, looped: args.looped };
    if !options.rate.is_finite() || options.rate <= 0.0 {
        anyhow::bail!("--rate {} must be a positive number (1 = real time)", args.rate);
    }
    let player = Player::open(&args.file)?;
    let name = args.file.file_name().map_or_else(|| "recording".into(), |n| n.to_string_lossy().into_owned());
    let mut server = match &args.foxglove {
        Some(listen) => Some(
            FoxgloveServer::start(listen, &ServerOptions { name, time: true, ..ServerOptions::default() })
                .with_context(|| format!("cannot serve {}", args.file.display()))?,
        ),
        None => None,
    };
    let bus = if args.foxglove.is_some() && !args.bus {
        None
    } else {
        let lock = NamespaceLock::acquire("jetbench play")?;
        let bus = Bus::open(&format!("jetbench-play-{}", std::process::id()))?;
        Some((lock, BusSink::new(&bus)?, bus))
    };
    let span = player.span_unix_ns().and_then(|(first, last)| Some((format_local(first)?, format_local(last)?)));
    let mut out = std::io::stdout().lock();
    if let Some(server) = &server {
        writeln!(out, "serving {} on {}", args.file.display(), server.url())?;
    }
    if bus.is_some() {
        writeln!(out, "publishing {} on bus namespace {}", args.file.display(), jetbench_bus::namespace_name()?)?;
    }
    if let Some((first, last)) = span {
        writeln!(out, "recorded {first} to {last}")?;
    }
    out.flush()?;
    drop(out);
    let report: PlayReport = match (bus, &server) {
        (Some((_lock, sink, _bus)), Some(server)) => player.play((sink, server), Some(server), &options)?,
        (Some((_lock, sink, _bus)), None) => player.play(sink, None, &options)?,
        (None, Some(server)) => player.play(server, Some(server), &options)?,
        (None, None) => anyhow::bail!("nowhere to play to: neither the bus nor --foxglove"),
    };
    if let Some(server) = &mut server {
        server.stop();
    }
    eprintln!(
        "played {} messages in {} pass(es){}{}",
        report.served,
        report.passes,
        if report.skipped > 0 {
            format!(", {} skipped (not a bench channel or malformed)", report.skipped)
        } else {
            String::new()
        },
        if report.truncated { "; the file is truncated" } else { "" }
    );
    Ok(ExitCode::SUCCESS)
}
