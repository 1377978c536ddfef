//! `jetbench stop|hold|idle|clear|run|start`: one operator command to the
//! engine of the running set, given on this machine (origin local, authority
//! operator, identity `local:<user>`), and the control service's answer; or,
//! with `--remote ENDPOINT`, to a bench over Zenoh from the control room
//! (`tcp/` anyone's path, `tls/` with `--cert/--key/--ca` an operator's), with
//! the bench's answer.

use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use jetbench_bus::Bus;
use jetbench_msgs::{channels, event_kinds, identity_text, operator_commands as op, OperatorCommand};
use jetbench_stack::runtime::lifecycle::{describe_event, local_command};

/// How long the control service has to answer.
const ANSWER_WAIT: Duration = Duration::from_secs(3);

/// Where a command goes: this machine's bus, or a bench over Zenoh.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct RemoteArgs {
    /// Send it to the bench bridged at this Zenoh endpoint (`jetbench up --zenoh` with an
    /// [operator] section): tcp/BENCH:7447 is anyone's path (safe commands only);
    /// tls/BENCH:7448 with --cert/--key/--ca and --operator is the operator's.
    #[arg(long, value_name = "ENDPOINT")]
    remote: Option<String>,
    /// The operator's client certificate (PEM), for a tls/ endpoint.
    #[arg(long, value_name = "FILE", requires_all = ["remote", "key", "ca", "operator"])]
    cert: Option<std::path::PathBuf>,
    /// The key of --cert (PEM).
    #[arg(long, value_name = "FILE", requires = "cert")]
    key: Option<std::path::PathBuf>,
    /// The CA (PEM) that signed the bench's certificate.
    #[arg(long, value_name = "FILE", requires = "cert")]
    ca: Option<std::path::PathBuf>,
    /// The operator's name: the common name of --cert, one of the bench's [operator] operators.
    #[arg(long, value_name = "NAME", requires = "cert")]
    operator: Option<String>,
}

/// Options of `jetbench stop`.
#[derive(clap::Args)]
pub struct StopArgs {
    /// Shut the engine down at once (the emergency stop), without idling first.
    #[arg(long)]
    now: bool,
    #[command(flatten)]
    remote: RemoteArgs,
}

/// Options of `jetbench hold`.
#[derive(clap::Args)]
pub struct HoldArgs {
    /// At most this throttle, % (default: the current one). Above the current
    /// one it raises the cap, which only an operator may.
    #[arg(value_name = "PERCENT")]
    throttle_pct: Option<f64>,
    #[command(flatten)]
    remote: RemoteArgs,
}

/// Options of `jetbench run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// The profile: a built-in one (steps, ramps, sines, chirp, campaign), scaled to
    /// the model's thrust range, or `config` for the bench config's [reference].
    #[arg(long, value_name = "NAME")]
    profile: String,
    #[command(flatten)]
    remote: RemoteArgs,
}

pub fn stop(args: StopArgs) -> anyhow::Result<ExitCode> {
    dispatch(&args.remote, if args.now { op::STOP_NOW } else { op::STOP }, 0.0)
}

pub fn hold(args: HoldArgs) -> anyhow::Result<ExitCode> {
    let pct = args.throttle_pct.unwrap_or(0.0);
    if !(pct.is_finite() && (0.0..=100.0).contains(&pct)) {
        anyhow::bail!("hold {pct}: the throttle is a percentage within 0..100");
    }
    dispatch(&args.remote, op::HOLD, pct)
}

pub fn idle(remote: RemoteArgs) -> anyhow::Result<ExitCode> {
    dispatch(&remote, op::IDLE, 0.0)
}

pub fn clear(remote: RemoteArgs) -> anyhow::Result<ExitCode> {
    dispatch(&remote, op::CLEAR_TRIPS, 0.0)
}

pub fn start(remote: RemoteArgs) -> anyhow::Result<ExitCode> {
    dispatch(&remote, op::START, 0.0)
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
    dispatch(&args.remote, op::RUN_PROFILE, index)
}

/// To this machine's bus, or with `--remote` to a bench over Zenoh.
fn dispatch(remote: &RemoteArgs, command: i32, value: f64) -> anyhow::Result<ExitCode> {
    match &remote.remote {
        None => send(local_command(command, value)),
        Some(endpoint) => send_remote(remote, endpoint, command, value),
    }
}

/// Sends one command to the bench's Zenoh gateway and prints its answer. Exit 0
/// accepted, 2 refused, 1 no decision.
fn send_remote(remote: &RemoteArgs, endpoint: &str, command: i32, value: f64) -> anyhow::Result<ExitCode> {
    use jetbench_bridge::operator::{send_command, ClientTls, COMMANDS};
    let endpoint: jetbench_bridge::Endpoint = endpoint.parse()?;
    let name = COMMANDS.iter().find(|(_, c)| *c == command).map(|(n, _)| *n).context("a command without a key")?;
    let tls = match (&remote.cert, &remote.key, &remote.ca) {
        (Some(certificate), Some(private_key), Some(ca)) => {
            for (what, file) in [("--cert", certificate), ("--key", private_key), ("--ca", ca)] {
                anyhow::ensure!(file.is_file(), "{what} {}: no such file", file.display());
            }
            Some(ClientTls { ca: ca.clone(), certificate: certificate.clone(), private_key: private_key.clone() })
        }
        _ => None,
    };
    if endpoint.is_tls() != tls.is_some() {
        anyhow::bail!(if endpoint.is_tls() {
            "a tls/ endpoint is the operator's path: give --cert, --key, --ca and --operator"
        } else {
            "--cert is for the operator's tls/ endpoint (the bench's [operator] tls_listen); tcp/ is anyone's path"
        });
    }
    let namespace = jetbench_bus::namespace_name()?;
    let answer = send_command(&endpoint, tls.as_ref(), &namespace, remote.operator.as_deref(), name, Some(value))
        .with_context(|| format!("{name} to the bench at {endpoint}"))?;
    println!("{name} at {endpoint}: {answer}");
    Ok(if answer == "accepted" {
        ExitCode::SUCCESS
    } else if answer.starts_with("refused") {
        ExitCode::from(2)
    } else {
        ExitCode::from(1)
    })
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
