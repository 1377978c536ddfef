//! `jetbench play`: a recording served to Foxglove at its recorded pace.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetbench_record::clock::format_local;
use jetbench_viewer::{FoxgloveServer, PlayOptions, Player, ServerOptions, DEFAULT_ADDR};

/// Options of `jetbench play`.
#[derive(clap::Args)]
pub struct PlayArgs {
    /// MCAP recording of `jetbench up --record` (or `jetbench record --remote`).
    file: PathBuf,
    /// Serve it on the Foxglove WebSocket protocol at HOST:PORT.
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = DEFAULT_ADDR, required = true)]
    foxglove: Option<String>,
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
    let listen = args.foxglove.as_deref().unwrap_or(DEFAULT_ADDR);
    let mut server = FoxgloveServer::start(listen, &ServerOptions { name, time: true, ..ServerOptions::default() })
        .with_context(|| format!("cannot serve {}", args.file.display()))?;
    let span = player.span_unix_ns().and_then(|(first, last)| Some((format_local(first)?, format_local(last)?)));
    let mut out = std::io::stdout().lock();
    writeln!(out, "serving {} on {}", args.file.display(), server.url())?;
    if let Some((first, last)) = span {
        writeln!(out, "recorded {first} to {last}")?;
    }
    out.flush()?;
    drop(out);
    let report = player.play(&server, &options)?;
    server.stop();
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
