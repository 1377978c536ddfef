//! `jetbench`: launch the service set and look inside a running one.

use std::process::ExitCode;

use anyhow::bail;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

mod cmd;

use jetbench::VERSION;

/// Control stack for model-jet-engine thrust benches.
#[derive(Parser)]
#[command(version = VERSION, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Start the service set (sensing, estimation, control, actuation, recorder).
    ///
    /// Example: jetbench up --sim --duration 10 --record run.mcap
    Up(cmd::up::UpArgs),
    /// Start the engine through the ECU (it must be in standby).
    Start(cmd::command::RemoteArgs),
    /// Run a reference profile once the engine runs, e.g. `jetbench run --profile steps`.
    Run(cmd::command::RunArgs),
    /// Hold the throttle at or below its current value (or PERCENT).
    Hold(cmd::command::HoldArgs),
    /// Idle the engine and keep it there.
    Idle(cmd::command::RemoteArgs),
    /// Stop the test: idle, then shut down through the ECU with its cool-down (--now: at once).
    Stop(cmd::command::StopArgs),
    /// Clear the latched trips, so the throttle may rise again.
    Clear(cmd::command::RemoteArgs),
    /// List the channels and bus nodes that exist now.
    List,
    /// Print the samples of a channel as they arrive, e.g. `jetbench echo bench/thrust`.
    Echo {
        /// Channel name, e.g. bench/state (see `jetbench list`).
        channel: String,
        /// Stop after this many samples.
        #[arg(long, short = 'n')]
        count: Option<u64>,
        /// Print CSV: a header line once, then one line per sample.
        #[arg(long, conflicts_with = "json")]
        csv: bool,
        /// Print one JSON object per sample, one per line (JSON Lines).
        #[arg(long)]
        json: bool,
        /// Read the bench bridged at this Zenoh endpoint (`jetbench up --zenoh`), e.g. tcp/BENCH-PC:7447.
        #[arg(long, value_name = "ENDPOINT")]
        remote: Option<String>,
    },
    /// Measure a channel's rate and period jitter, e.g. `jetbench hz bench/thrust`.
    Hz {
        channel: String,
        /// Compute rate and jitter over the latest N messages (like `ros2 topic hz -w`); printed every second.
        #[arg(long, short = 'w', default_value_t = 10_000, value_name = "N")]
        window: usize,
        /// Stop after this many seconds (default: until Ctrl-C).
        #[arg(long)]
        duration: Option<f64>,
        /// Read the bench bridged at this Zenoh endpoint (`jetbench up --zenoh`), e.g. tcp/BENCH-PC:7447.
        #[arg(long, value_name = "ENDPOINT")]
        remote: Option<String>,
    },
    /// Record every channel of a running set to MCAP, here or from another machine.
    ///
    /// Example: jetbench record --remote tcp/BENCH-PC:7447 --duration 60 --out run.mcap
    Record(cmd::record::RecordArgs),
    /// A recording at a glance, like `ros2 bag info`: duration, size, channels and types, the run's config.
    Info(cmd::info::InfoArgs),
    /// Rewrite a truncated or damaged recording as a valid, indexed MCAP file.
    ///
    /// Exit status 0: nothing lost; 3: data lost (the rest recovered); 1: failure.
    /// Example: jetbench recover crashed.mcap --out fixed.mcap
    Recover(cmd::recover::RecoverArgs),
    /// Feed a recording's thrust through the estimator, as fast as possible, on recorded time.
    ///
    /// Example: jetbench replay run.mcap --out replayed.mcap
    Replay(cmd::replay::ReplayArgs),
    /// Identify the engine model from recordings (LS, EKF, SINDy), validated on held-out data.
    ///
    /// Example: jetbench identify run.mcap --out model.toml --plot plots/
    Identify(cmd::identify::IdentifyArgs),
    /// Find what a model leaves out of recordings, name the physics, model it, and show the fit improve.
    ///
    /// Example: jetbench diagnose --model model.toml run.mcap --plot plots/ --out improved.toml
    Diagnose(cmd::diagnose::DiagnoseArgs),
    /// Tracking figures of recorded runs, per controller: MAE, steady-state error, overshoot, settling, chattering.
    ///
    /// Example: jetbench metrics run.mcap --json
    Metrics(cmd::metrics::MetricsArgs),
    /// Free-run simulation of a model from a throttle profile or a recording's throttle.
    Simulate(cmd::simulate::SimulateArgs),
    /// Generate an identification campaign (throttle profile) to play open loop.
    Excite(cmd::excite::ExciteArgs),
    /// Record a simulated plant driven by a campaign, with sensor noise, faster than real time.
    SimRecord(cmd::sim_record::SimRecordArgs),
    /// Write a recording's identification data (time, applied throttle, thrust) as CSV.
    Export(cmd::export::ExportArgs),
    /// Decode a force-sensor candump log (`candump -l`) into CSV on stdout; rejections by kind on stderr.
    ///
    /// Example: jetbench can-decode recordings/can/sensor-example.log > forces.csv
    CanDecode(cmd::can_decode::CanDecodeArgs),
    /// Average the force sensor at rest and print (or --write) the [sensor] tare offsets.
    ///
    /// Example: jetbench tare --config bench.toml --seconds 2 --write
    Tare(cmd::tare::TareArgs),
    /// One process of a `jetbench latency` reference chain (started by it, not by hand).
    #[command(hide = true)]
    LatencyStage(cmd::latency_stage::LatencyStageArgs),
    /// Does the 100 Hz loop hold under load? The service set's latency, hop by hop, against the
    /// machine's floor (a bare eventfd ping) and a Unix-socket baseline, in one run.
    ///
    /// Example: jetbench latency --duration 60 --load cpu --rt --plot latency.png
    Latency(cmd::latency::LatencyArgs),
    /// The fault campaign: every process killed, recorder crashes, a full disk, bad sensor
    /// data, a second set, another user; bounds checked, report written.
    ///
    /// Example: jetbench faults --repeat 10 --report docs/faults/REPORT.md
    Faults(cmd::faults::FaultsArgs),
    /// The set for minutes under load: memory per process over time, lost samples, misses.
    ///
    /// Example: jetbench soak --minutes 30 --load all
    Soak(cmd::soak::SoakArgs),
    /// Play a recording onto the bus (or to Foxglove) at its recorded pace, like `ros2 bag play`.
    ///
    /// Example: jetbench play run.mcap --rate 2
    Play(cmd::play::PlayArgs),
    /// The built-in background load of `jetbench latency` (used where stress-ng is not installed).
    #[command(hide = true)]
    LatencyLoad(cmd::latency::LoadArgs),
}

fn main() -> ExitCode {
    // Piped into `head` or `less`, end quietly when the reader goes away,
    // as Unix tools do, instead of panicking on a broken pipe.
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
    jetbench::init_logging();
    jetbench_record::set_software_version(VERSION);
    match run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("jetbench: error: {}", error_text(&e));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes on one line, each said once: a cause whose text the
/// message before it already carries (a library error that prints its source and
/// also returns it as its cause) is not repeated, and the source-file locations
/// some dependencies put in their messages are left out.
fn error_text(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let message = without_source_locations(&cause.to_string());
        if message.is_empty() || text.contains(&message) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&message);
    }
    text
}

/// `message` without the ` at /path/to/file.rs:LINE` locations that some
/// dependencies (Zenoh) append to their errors: they say where in a library's
/// source the error was made, which tells a user nothing.
fn without_source_locations(message: &str) -> String {
    let mut out = String::new();
    for (i, line) in message.lines().enumerate() {
        let mut line = line.to_string();
        while let Some(at) = line.find(" at /") {
            let rest = &line[at + 4..];
            let end = rest.find(|c: char| c.is_whitespace() || c == ')' || c == ',').unwrap_or(rest.len());
            let location = &rest[..end];
            if !location.contains(".rs") {
                break;
            }
            line = format!("{}{}", &line[..at], &rest[end..]);
        }
        if i > 0 {
            out.push('\n');
        }
        out.push_str(line.trim_end());
    }
    out.trim().to_string()
}

/// The commands as `jetbench --help` lists them, by what they are for.
const GROUPS: &[(&str, &[&str])] = &[
    ("Run the bench", &["up", "tare", "record"]),
    ("Operate the engine", &["start", "run", "hold", "idle", "stop", "clear"]),
    ("Watch it", &["list", "echo", "hz", "play"]),
    ("Offline analysis", &["info", "recover", "replay", "identify", "diagnose", "metrics", "export", "can-decode"]),
    ("Experiments", &["excite", "simulate", "sim-record", "latency", "faults", "soak"]),
];

/// The CLI, its top-level help listing the commands in [`GROUPS`] (each with
/// the one-line summary of its own doc comment) instead of one flat list.
fn command() -> clap::Command {
    use std::fmt::Write;
    let cmd = Cli::command();
    let mut groups = String::new();
    for (heading, names) in GROUPS {
        let _ = writeln!(groups, "{heading}:");
        for name in *names {
            let about =
                cmd.find_subcommand(name).and_then(|c| c.get_about()).map(|a| a.to_string()).unwrap_or_default();
            let _ = writeln!(groups, "  {name:<12} {about}");
        }
        groups.push('\n');
    }
    let _ = write!(groups, "`jetbench help COMMAND` or `jetbench COMMAND --help` for a command's options.");
    cmd.help_template(
        "{about-with-newline}\n{usage-heading} {usage}\n\n{before-help}\n\nOptions:\n{options}{after-help}",
    )
    .before_help(groups)
}

fn run() -> anyhow::Result<ExitCode> {
    let cli = Cli::from_arg_matches(&command().get_matches())?;
    jetbench_bus::namespace()?;
    match cli.command {
        Cmd::Up(args) => cmd::up::run(args),
        Cmd::Start(remote) => cmd::command::start(remote),
        Cmd::Run(args) => cmd::command::run(args),
        Cmd::Hold(args) => cmd::command::hold(args),
        Cmd::Idle(remote) => cmd::command::idle(remote),
        Cmd::Stop(args) => cmd::command::stop(args),
        Cmd::Clear(remote) => cmd::command::clear(remote),
        Cmd::List => cmd::bus::list(),
        Cmd::Echo { channel, count, csv, json, remote } => {
            let format = match (csv, json) {
                (true, _) => cmd::bus::EchoFormat::Csv,
                (_, true) => cmd::bus::EchoFormat::Json,
                _ => cmd::bus::EchoFormat::Fields,
            };
            let local = remote.is_none();
            cmd::bus::with_channel(&channel, remote.as_deref(), cmd::bus::Echo { count, format, local })
        }
        Cmd::Hz { channel, window, duration, remote } => {
            if window < 2 {
                bail!("--window {window}: the rate needs at least 2 messages");
            }
            let local = remote.is_none();
            cmd::bus::with_channel(&channel, remote.as_deref(), cmd::bus::Hz { window, duration, local })
        }
        Cmd::Record(args) => cmd::record::run_record(args),
        Cmd::Info(args) => cmd::info::run(args),
        Cmd::Recover(args) => cmd::recover::run(args),
        Cmd::Replay(args) => cmd::replay::run(args),
        Cmd::Identify(args) => cmd::identify::run(args),
        Cmd::Diagnose(args) => cmd::diagnose::run(args),
        Cmd::Metrics(args) => cmd::metrics::run(args),
        Cmd::Simulate(args) => cmd::simulate::run(args),
        Cmd::Excite(args) => cmd::excite::run(args),
        Cmd::SimRecord(args) => cmd::sim_record::run(args),
        Cmd::Export(args) => cmd::export::run(args),
        Cmd::CanDecode(args) => cmd::can_decode::run(args),
        Cmd::Tare(args) => cmd::tare::run(args),
        Cmd::LatencyStage(args) => cmd::latency_stage::run(args),
        Cmd::Latency(args) => cmd::latency::run(args),
        Cmd::Play(args) => cmd::play::run(args),
        Cmd::Faults(args) => cmd::faults::run(args),
        Cmd::Soak(args) => cmd::soak::run(args),
        Cmd::LatencyLoad(args) => cmd::latency::run_load(args),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every command the CLI has is listed in exactly one group, and every listed name is a command.
    #[test]
    fn every_command_is_in_one_group() {
        let cmd = Cli::command();
        let listed: Vec<&str> = GROUPS.iter().flat_map(|(_, names)| names.iter().copied()).collect();
        for sub in cmd.get_subcommands().filter(|c| !c.is_hide_set()) {
            let n = listed.iter().filter(|&&l| l == sub.get_name()).count();
            assert_eq!(n, 1, "`{}` is listed {n} times in GROUPS", sub.get_name());
        }
        for name in &listed {
            assert!(cmd.find_subcommand(name).is_some_and(|c| !c.is_hide_set()), "`{name}` is not a command");
        }
    }

    #[test]
    fn an_error_says_each_cause_once_without_library_source_paths() {
        let io = std::io::Error::from(std::io::ErrorKind::NotFound);
        let e = anyhow::Error::new(io)
            .context(format!("cannot read x.mcap: {}", std::io::Error::from(std::io::ErrorKind::NotFound)));
        let text = error_text(&e);
        assert_eq!(text.matches("not found").count(), 1, "{text}");
        let zenoh = anyhow::anyhow!("Unable to connect to any of [tcp/127.0.0.1:1]! at /root/.cargo/registry/src/index/zenoh-1.0/src/net/runtime/orchestrator.rs:312.");
        let text = error_text(&zenoh.context("cannot reach the bench bridged at tcp/127.0.0.1:1"));
        assert!(!text.contains(".cargo") && !text.contains(".rs"), "{text}");
        assert!(text.contains("Unable to connect") && text.contains("cannot reach the bench"), "{text}");
    }

    #[test]
    fn help_groups_the_commands() {
        let help = command().render_help().to_string();
        for (heading, names) in GROUPS {
            assert!(help.contains(&format!("{heading}:")), "{help}");
            assert!(help.contains(&format!("  {:<12} ", names[0])), "{help}");
        }
        assert!(help.contains("Identify the engine model from recordings"), "{help}");
    }
}
