//! `jetbench`: launch the service set and look inside a running one.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use jetbench_bus::{Bus, Flow};
use jetbench_control::{ControllerKind, BUILTIN_PROFILES};
use jetbench_msgs::{format_fields, visit_channels, Channel, ChannelVisitor, Sample};
use jetbench_record::Recording;
use jetbench_stack::launch::{up, UpOptions};

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
    Up(UpArgs),
    /// List the channels and bus nodes that exist now.
    List,
    /// Print the samples of a channel as they arrive, e.g. `jetbench echo bench/thrust`.
    Echo {
        /// Channel name, e.g. bench/state (see `jetbench list`).
        channel: String,
        /// Stop after this many samples.
        #[arg(long, short = 'n')]
        count: Option<u64>,
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
    },
    /// Summarise an MCAP recording: messages, rates and sequence gaps per channel.
    Info { file: PathBuf },
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
    Simulate(cmd::model::SimulateArgs),
    /// Generate an identification campaign (throttle profile) to play open loop.
    Excite(cmd::model::ExciteArgs),
    /// Record a simulated plant driven by a campaign, with sensor noise, faster than real time.
    SimRecord(cmd::model::SimRecordArgs),
    /// Write a recording's identification data (time, applied throttle, thrust) as CSV.
    Export(cmd::model::ExportArgs),
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
    /// Serve a recording to Foxglove at its recorded pace, like `ros2 bag play`.
    ///
    /// Example: jetbench play run.mcap --foxglove 127.0.0.1:8765 --rate 2 --loop
    Play(cmd::play::PlayArgs),
    /// The built-in background load of `jetbench latency` (used where stress-ng is not installed).
    #[command(hide = true)]
    LatencyLoad(cmd::load::LoadArgs),
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

fn run() -> anyhow::Result<ExitCode> {
    let cli = Cli::parse();
    jetbench_bus::namespace()?;
    match cli.command {
        Cmd::Up(args) => cmd_up(args),
        Cmd::List => cmd_list(),
        Cmd::Echo { channel, count } => with_channel(&channel, Echo { count, result: Ok(()) }),
        Cmd::Hz { channel, window, duration } => {
            if !window.is_finite() || window <= 0.0 {
                bail!("--window must be a positive number of seconds");
            }
            with_channel(&channel, Hz { window, duration, result: Ok(()) })
        }
        Cmd::Info { file } => cmd_info(&file),
        Cmd::Replay(args) => cmd::replay::run(args),
        Cmd::Identify(args) => cmd::identify::run(args),
        Cmd::Diagnose(args) => cmd::diagnose::run(args),
        Cmd::Metrics(args) => cmd::metrics::run(args),
        Cmd::Simulate(args) => cmd::model::simulate(args),
        Cmd::Excite(args) => cmd::model::excite(args),
        Cmd::SimRecord(args) => cmd::model::sim_record(args),
        Cmd::Export(args) => cmd::model::export(args),
        Cmd::CanDecode(args) => cmd::can_decode::run(args),
        Cmd::Tare(args) => cmd::tare::run(args),
        Cmd::LatencyStage(args) => cmd::latency_stage::run(args),
        Cmd::Latency(args) => cmd::latency::run(args),
        Cmd::Play(args) => cmd::play::run(args),
        Cmd::LatencyLoad(args) => cmd::load::run(args).map(|()| ExitCode::SUCCESS),
    }
}

fn bin_dir() -> anyhow::Result<PathBuf> {
    if let Some(dir) = std::env::var_os("JETBENCH_BIN_DIR") {
        return Ok(dir.into());
    }
    let exe = std::env::current_exe().context("cannot locate the jetbench binary")?;
    Ok(exe.parent().context("the jetbench binary has no folder")?.to_path_buf())
}

/// Options of `jetbench up`.
#[derive(clap::Args)]
struct UpArgs {
    /// Run against the simulated bench (engine, sensor and throttle board simulated).
    #[arg(long)]
    sim: bool,
    /// Bench config (TOML); `--sim` without it uses the built-in config/sim.toml.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Stop after this many seconds of running (default: until Ctrl-C).
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
    duration: Option<f64>,
    /// Record every channel to this MCAP file.
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// No live status line.
    #[arg(long)]
    quiet: bool,
    /// Real-time settings for every service: the config's `[rt]` SCHED_FIFO priorities
    /// and CPUs, memory locked (what the kernel refuses is reported, and the run goes on).
    #[arg(long)]
    rt: bool,
    /// Controller, overriding `[control] controller`: fbl and smc (the study), or mpc
    /// (knows the throttle limits and the model's effects).
    #[arg(long, value_name = "LAW")]
    controller: Option<ControllerKind>,
    /// Model for the estimator and the controller, overriding `[model] model`: a preset
    /// or a model file, e.g. one from `jetbench identify` or `jetbench diagnose --out`.
    #[arg(long, value_name = "PRESET|FILE")]
    model: Option<String>,
    /// Simulated engine, overriding `[plant] model` (with --sim): a preset or a model
    /// file, which may carry effects (`[effects.input_delay]`, ...).
    #[arg(long, value_name = "PRESET|FILE", requires = "sim")]
    plant: Option<String>,
    /// Built-in reference profile, scaled to the model's thrust range, overriding
    /// `[reference]`: steps (includes full-range steps that saturate the throttle),
    /// ramps, sines, chirp, or campaign (all four in turn).
    #[arg(long, value_name = "NAME", value_parser = clap::builder::PossibleValuesParser::new(BUILTIN_PROFILES))]
    profile: Option<String>,
    /// Play this throttle profile open loop instead of closing the loop
    /// (CSV `time_s,throttle_pct`, e.g. from `jetbench excite`).
    #[arg(long, value_name = "FILE.csv", conflicts_with_all = ["controller", "profile"])]
    open_loop: Option<PathBuf>,
    /// How samples travel between the services: iceoryx2 shared memory, or
    /// copied through Unix domain sockets (uds, the baseline `jetbench latency`
    /// measures against). Default: $JETBENCH_TRANSPORT, else iceoryx2.
    #[arg(long, value_enum)]
    transport: Option<TransportArg>,
}

/// `--transport` values.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum TransportArg {
    Iceoryx2,
    Uds,
}

impl From<TransportArg> for jetbench_bus::Transport {
    fn from(t: TransportArg) -> Self {
        match t {
            TransportArg::Iceoryx2 => jetbench_bus::Transport::Iceoryx2,
            TransportArg::Uds => jetbench_bus::Transport::UnixSockets,
        }
    }
}

impl UpArgs {
    fn overrides_config(&self) -> bool {
        self.controller.is_some()
            || self.model.is_some()
            || self.plant.is_some()
            || self.profile.is_some()
            || self.open_loop.is_some()
    }
}

/// A preset name as it is, a model file as an absolute path (the services run elsewhere).
fn model_spec(spec: &str) -> String {
    if spec.parse::<jetbench_model::Preset>().is_ok() {
        return spec.to_string();
    }
    std::path::absolute(spec).map_or_else(|_| spec.to_string(), |p| p.display().to_string())
}

fn cmd_up(args: UpArgs) -> anyhow::Result<ExitCode> {
    use jetbench_stack::config::{BenchConfig, Controller};
    // Check the config here so a typo is reported once, not by six services.
    let mut checked = BenchConfig::load_or_default(args.config.as_deref())?;
    // Command-line overrides go into a derived config file that every service reads.
    let mut derived = None;
    let config = if args.overrides_config() {
        if let Some(kind) = args.controller {
            checked.control.controller = Controller::from(kind);
        }
        if let Some(model) = &args.model {
            checked.model.model = model_spec(model);
        }
        if let Some(plant) = &args.plant {
            checked.plant.model = model_spec(plant);
        }
        if let Some(name) = &args.profile {
            let params = checked.model_params().context("--profile scales to the model's thrust range")?;
            let range = params
                .stable_equilibrium(jetbench_model::THROTTLE_MIN_PCT)
                .zip(params.stable_equilibrium(jetbench_model::THROTTLE_MAX_PCT));
            let (idle_n, max_n) = range.with_context(|| {
                format!(
                    "model {} has no stable thrust at 25 % or 100 % throttle to scale --profile to",
                    checked.model.model
                )
            })?;
            checked.reference = jetbench_control::Profile::builtin(name, idle_n, max_n)
                .with_context(|| format!("the model's thrust range {idle_n:.1}..{max_n:.1} N is empty"))?;
        }
        if let Some(profile) = &args.open_loop {
            let profile = std::path::absolute(profile).unwrap_or_else(|_| profile.clone());
            checked.control.controller = Controller::OpenLoop;
            checked.control.throttle_profile = Some(profile.display().to_string());
        }
        let text = toml::to_string(&checked).context("cannot write the derived bench config")?;
        // Check it as the services will read it (this also loads models and profiles).
        BenchConfig::from_toml_str(&text, "the command-line options", None)?;
        let path = std::env::temp_dir().join(format!("jetbench-up-{}.toml", std::process::id()));
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
        derived = Some(path.clone());
        Some(path)
    } else {
        args.config.clone()
    };
    let result = run_up(&args, config, &checked);
    if let Some(path) = derived {
        let _ = std::fs::remove_file(path);
    }
    result
}

fn run_up(
    args: &UpArgs,
    config: Option<PathBuf>,
    checked: &jetbench_stack::config::BenchConfig,
) -> anyhow::Result<ExitCode> {
    let UpArgs { sim, duration, quiet, rt, .. } = *args;
    let record = args.record.clone();
    let transport = match args.transport {
        Some(t) => t.into(),
        None => jetbench_bus::transport()?,
    };
    if !sim && config.is_none() {
        bail!("no bench config given: use --sim for the simulated bench, or --config FILE");
    }
    if !sim && checked.bench.devices == jetbench_stack::config::Devices::Sim {
        bail!("the config selects the simulated devices ([bench] devices = \"sim\"); add --sim to confirm");
    }
    if sim && checked.bench.devices == jetbench_stack::config::Devices::Bench {
        bail!("the config selects the real bench ([bench] devices = \"bench\"); drop --sim to run against it");
    }
    let duration = match duration {
        Some(d) if d.is_finite() && d > 0.0 => Some(Duration::from_secs_f64(d)),
        Some(d) => bail!("--duration {d} must be a positive number of seconds"),
        None => None,
    };
    if let Some(path) = &record {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            if !dir.is_dir() {
                bail!("cannot record to {}: folder {} does not exist", path.display(), dir.display());
            }
        }
    }
    let options = UpOptions {
        config: config.map(|c| std::path::absolute(&c).unwrap_or(c)),
        duration,
        record: record.clone().map(|r| std::path::absolute(&r).unwrap_or(r)),
        bin_dir: bin_dir()?,
        status: !quiet,
        simulated: checked.bench.devices == jetbench_stack::config::Devices::Sim,
        rt,
        transport,
    };
    up(&options)?;
    println!("all services stopped cleanly");
    if let Some(path) = record {
        print_summary(&path)?;
    }
    Ok(ExitCode::SUCCESS)
}

fn cmd_list() -> anyhow::Result<ExitCode> {
    let known = jetbench_msgs::channel_names();
    let live = jetbench_bus::list_channels();
    println!("channels:");
    if live.is_empty() {
        println!("  (none: is `jetbench up` running?)");
    }
    for name in &live {
        let note = if known.contains(&name.as_str()) { "" } else { "  (not a jetbench channel)" };
        println!("  {name}{note}");
    }
    println!("nodes:");
    for node in jetbench_bus::list_nodes() {
        println!("  {node}");
    }
    Ok(ExitCode::SUCCESS)
}

/// Finds the channel called `name` and runs `action` with its type.
trait ChannelAction {
    fn act<T: Sample>(&mut self, bus: &Bus, channel: Channel<T>) -> anyhow::Result<()>;
}

fn with_channel<A: ChannelAction>(name: &str, action: A) -> anyhow::Result<ExitCode> {
    struct Find<A> {
        name: String,
        action: A,
        found: bool,
        result: anyhow::Result<()>,
    }
    impl<A: ChannelAction> ChannelVisitor for Find<A> {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            if !self.found && self.name.trim_start_matches('/') == channel.name {
                self.found = true;
                self.result = Bus::open(&format!("jetbench-cli-{}", std::process::id()))
                    .map_err(anyhow::Error::from)
                    .and_then(|bus| self.action.act(&bus, channel));
            }
        }
    }
    let mut find = Find { name: name.to_string(), action, found: false, result: Ok(()) };
    visit_channels(&mut find);
    if !find.found {
        bail!("unknown channel {name:?}; channels are: {}", jetbench_msgs::channel_names().join(", "));
    }
    find.result.map(|()| ExitCode::SUCCESS)
}

struct Echo {
    count: Option<u64>,
    result: anyhow::Result<()>,
}

impl ChannelAction for Echo {
    fn act<T: Sample>(&mut self, bus: &Bus, channel: Channel<T>) -> anyhow::Result<()> {
        let sub = bus.subscriber(channel, 256)?;
        let mut printed = 0;
        bus.run(&[(&sub, None)], None, |_| {
            while let Ok(Some(sample)) = sub.try_recv() {
                println!("{}", format_fields(&sample));
                printed += 1;
                if self.count.is_some_and(|n| printed >= n) {
                    return Flow::Stop;
                }
            }
            Flow::Continue
        })?;
        std::mem::replace(&mut self.result, Ok(()))
    }
}

struct Hz {
    window: f64,
    duration: Option<f64>,
    result: anyhow::Result<()>,
}

impl ChannelAction for Hz {
    fn act<T: Sample>(&mut self, bus: &Bus, channel: Channel<T>) -> anyhow::Result<()> {
        let sub = bus.subscriber(channel, 512)?;
        let start = Instant::now();
        let mut window_start = start;
        let mut last_arrival: Option<Instant> = None;
        let mut periods_ms: Vec<f64> = Vec::new();
        let window = Duration::from_secs_f64(self.window);
        bus.run(&[(&sub, None)], Some(Duration::from_millis(100)), |_| {
            while let Ok(Some(_)) = sub.try_recv() {
                let now = Instant::now();
                if let Some(last) = last_arrival {
                    periods_ms.push((now - last).as_secs_f64() * 1e3);
                }
                last_arrival = Some(now);
            }
            let now = Instant::now();
            if now - window_start >= window {
                let n = periods_ms.len();
                if n == 0 {
                    println!("{}: no samples", channel.name);
                } else {
                    let mean = periods_ms.iter().sum::<f64>() / n as f64;
                    let std = (periods_ms.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
                    let (min, max) = periods_ms.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(*p), b.max(*p)));
                    println!(
                        "{}: {:.2} Hz  period mean {mean:.3} ms  min {min:.3}  max {max:.3}  std {std:.3}  lost {}",
                        channel.name,
                        1e3 / mean,
                        sub.gaps()
                    );
                }
                periods_ms.clear();
                window_start = now;
            }
            match self.duration {
                Some(d) if (now - start).as_secs_f64() >= d => Flow::Stop,
                _ => Flow::Continue,
            }
        })?;
        std::mem::replace(&mut self.result, Ok(()))
    }
}

fn cmd_info(path: &std::path::Path) -> anyhow::Result<ExitCode> {
    print_summary(path)?;
    Ok(ExitCode::SUCCESS)
}

/// Prints messages, rate and seq gaps per channel of a recording.
fn print_summary(path: &std::path::Path) -> anyhow::Result<()> {
    let recording = Recording::open(path)?;
    struct Summary<'a> {
        recording: &'a Recording,
    }
    impl ChannelVisitor for Summary<'_> {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            let samples = self.recording.samples(channel);
            if samples.is_empty() {
                return;
            }
            // Rate on the recorder's receive time: every sample has one.
            let topic = channel.topic();
            let times: Vec<u64> =
                self.recording.messages.iter().filter(|m| m.topic == topic).map(|m| m.log_time_ns).collect();
            let span_s = times.last().zip(times.first()).map_or(0, |(l, f)| l.saturating_sub(*f)) as f64 * 1e-9;
            let rate = if span_s > 0.0 { (times.len() - 1) as f64 / span_s } else { 0.0 };
            // bench/health has one publisher per service: gaps are per publisher.
            let gaps = if channel.name == jetbench_msgs::channels::HEALTH.name {
                let health = self.recording.samples(jetbench_msgs::channels::HEALTH);
                jetbench_msgs::ServiceId::ALL
                    .iter()
                    .map(|id| {
                        let mine: Vec<_> = health.iter().copied().filter(|h| h.service_id == *id as u32).collect();
                        jetbench_record::seq_gaps(&mine)
                    })
                    .sum()
            } else {
                jetbench_record::seq_gaps(&samples)
            };
            println!("  {:<18} {:>7} messages  {:>6.1} Hz  {} seq gaps", channel.topic(), samples.len(), rate, gaps);
        }
    }
    println!(
        "{}: {} messages{}",
        path.display(),
        recording.messages.len(),
        if recording.truncated { " (file truncated: read up to the last complete chunk)" } else { "" }
    );
    visit_channels(&mut Summary { recording: &recording });
    Ok(())
}
