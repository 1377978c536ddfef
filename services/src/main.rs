//! `jetbench`: launch the service set and look inside a running one.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

mod cmd;

/// Control stack for model-jet-engine thrust benches.
#[derive(Parser)]
#[command(version, about, long_about = None)]
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
    Start,
    /// Run a reference profile once the engine runs, e.g. `jetbench run --profile steps`.
    Run(cmd::command::RunArgs),
    /// Hold the throttle at or below its current value (or PERCENT).
    Hold(cmd::command::HoldArgs),
    /// Idle the engine and keep it there.
    Idle,
    /// Stop the test: idle, then shut down through the ECU with its cool-down (--now: at once).
    Stop(cmd::command::StopArgs),
    /// Clear the latched trips, so the throttle may rise again.
    Clear,
    /// List the channels and bus nodes that exist now.
    List,
    /// Print the samples of a channel as they arrive, e.g. `jetbench echo bench/thrust`.
    Echo {
        /// Channel name, e.g. bench/state (see `jetbench list`).
        channel: String,
        /// Stop after this many samples.
        #[arg(long, short = 'n')]
        count: Option<u64>,
        /// Read the bench bridged at this Zenoh endpoint (`jetbench up --zenoh`), e.g. tcp/BENCH-PC:7447.
        #[arg(long, value_name = "ENDPOINT")]
        remote: Option<String>,
    },
    /// Measure a channel's rate and period jitter, e.g. `jetbench hz bench/thrust`.
    Hz {
        channel: String,
        /// Report every this many seconds.
        #[arg(long, default_value_t = 1.0)]
        window: f64,
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
    /// Summarise an MCAP recording: messages, rates and sequence gaps per channel.
    Info { file: PathBuf },
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
    /// Serve a recording to Foxglove at its recorded pace, like `ros2 bag play`.
    ///
    /// Example: jetbench play run.mcap --foxglove 127.0.0.1:8765 --rate 2 --loop
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
    match run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("jetbench: error: {e:#}");
            ExitCode::FAILURE
        }
    }
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
        Cmd::Start => cmd::command::start(),
        Cmd::Run(args) => cmd::command::run(args),
        Cmd::Hold(args) => cmd::command::hold(args),
        Cmd::Idle => cmd::command::idle(),
        Cmd::Stop(args) => cmd::command::stop(args),
        Cmd::Clear => cmd::command::clear(),
        Cmd::List => cmd::bus::list(),
        Cmd::Echo { channel, count, remote } => {
            cmd::bus::with_channel(&channel, remote.as_deref(), cmd::bus::Echo { count })
        }
        Cmd::Hz { channel, window, duration, remote } => {
            if !window.is_finite() || window <= 0.0 {
                bail!("--window must be a positive number of seconds");
            }
            cmd::bus::with_channel(&channel, remote.as_deref(), cmd::bus::Hz { window, duration })
        }
        Cmd::Record(args) => cmd::record::run_record(args),
        Cmd::Info { file } => cmd::info::run(&file),
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
    fn help_groups_the_commands() {
        let help = command().render_help().to_string();
        for (heading, names) in GROUPS {
            assert!(help.contains(&format!("{heading}:")), "{help}");
            assert!(help.contains(&format!("  {:<12} ", names[0])), "{help}");
        }
        assert!(help.contains("Identify the engine model from recordings"), "{help}");
    }
}
