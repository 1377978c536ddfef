//! `jetbench stop|hold|idle|clear|run|start`: one operator command to the
//! engine of the running set, given on this machine (origin local, authority
//! operator, identity `local:<user>`), and the control service's answer.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use jetbench_bus::Bus;
use jetbench_msgs::{channels, event_kinds, identity_text, operator_commands as op, OperatorCommand};
use jetbench_stack::runtime::lifecycle::{describe_event, local_command};

/// How long the control service has to answer.
const ANSWER_WAIT: Duration = Duration::from_secs(3);

/// Options of `jetbench stop`.
#[derive(clap::Args)]
pub struct StopArgs {
    /// Shut the engine down at once (the emergency stop), without idling first.
    #[arg(long)]
    now: bool,
}

/// Options of `jetbench hold`.
#[derive(clap::Args)]
pub struct HoldArgs {
    /// At most this throttle, % (default: the current one). Above the current
    /// one it raises the cap, which only an operator may.
    #[arg(value_name = "PERCENT")]
    throttle_pct: Option<f64>,
}

/// Options of `jetbench run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// The profile: a built-in one (steps, ramps, sines, chirp, campaign), scaled to
    /// the model's thrust range, or `config` for the bench config's [reference].
    #[arg(long, value_name = "NAME")]
    profile: String,
}

pub fn stop(args: StopArgs) -> anyhow::Result<ExitCode> {
    send(local_command(if args.now { op::STOP_NOW } else { op::STOP }, 0.0))
}

pub fn hold(args: HoldArgs) -> anyhow::Result<ExitCode> {
    let pct = args.throttle_pct.unwrap_or(0.0);
    if !(pct.is_finite() && (0.0..=100.0).contains(&pct)) {
        anyhow::bail!("hold {pct}: the throttle is a percentage within 0..100");
    }
    send(local_command(op::HOLD, pct))
}

pub fn idle() -> anyhow::Result<ExitCode> {
    send(local_command(op::IDLE, 0.0))
}

pub fn clear() -> anyhow::Result<ExitCode> {
    send(local_command(op::CLEAR_TRIPS, 0.0))
}

pub fn start() -> anyhow::Result<ExitCode> {
    send(local_command(op::START, 0.0))
}

pub fn run(args: RunArgs) -> anyhow::Result<ExitCode> {
    let index = if args.profile == "config" {
        -1.0
    } else {
        let i = jetbench_control::BUILTIN_PROFILES.iter().position(|p| *p == args.profile).with_context(|| {
            format!(
                "unknown profile {:?}; the profiles are {} and config",
                args.profile,
                jetbench_control::BUILTIN_PROFILES.join(", ")
            )
        })?;
        i as f64
    };
    send(local_command(op::RUN_PROFILE, index))
}

/// Sends one command on the bus of this namespace and waits for the control
/// service's verdict. Exit 0 accepted, 2 refused, 1 no answer.
pub fn send(command: OperatorCommand) -> anyhow::Result<ExitCode> {
    let name = op::name(command.command).unwrap_or("command");
    let bus = Bus::open(&format!("jetbench-command-{}", std::process::id()))?;
    // Listen before speaking, so the answer cannot be missed.
    let events = bus.polled_subscriber(channels::EVENTS, 256)?;
    let mut operator = bus.publisher(channels::OPERATOR)?;
    operator.publish(command)?;
    let who = identity_text(&command.identity);
    let until = Instant::now() + ANSWER_WAIT;
    while Instant::now() < until {
        while let Some(e) = events.try_recv()? {
            let verdict = e.kind == event_kinds::COMMAND_ACCEPTED || e.kind == event_kinds::COMMAND_REFUSED;
            if verdict && e.code == command.command && identity_text(&e.identity) == who {
                println!("{}", describe_event(&e));
                return Ok(if e.kind == event_kinds::COMMAND_ACCEPTED { ExitCode::SUCCESS } else { ExitCode::from(2) });
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    eprintln!(
        "{name} was sent, but no control service answered within {:.0} s: is `jetbench up` running in this bus \
         namespace ({}={})?",
        ANSWER_WAIT.as_secs_f64(),
        jetbench_bus::NAMESPACE_ENV,
        std::env::var(jetbench_bus::NAMESPACE_ENV).unwrap_or_else(|_| "unset".into())
    );
    Ok(ExitCode::from(1))
}
