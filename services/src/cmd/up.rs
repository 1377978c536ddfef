//! `jetbench up`: start the service set, run it, stop it cleanly.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use jetbench_control::{Controller, BUILTIN_PROFILES};
use jetbench_stack::config::{BenchConfig, Devices, Overrides};
use jetbench_stack::runtime::launch::{up, UpOptions};

fn bin_dir() -> anyhow::Result<PathBuf> {
    if let Some(dir) = std::env::var_os("JETBENCH_BIN_DIR") {
        return Ok(dir.into());
    }
    let exe = std::env::current_exe().context("cannot locate the jetbench binary")?;
    Ok(exe.parent().context("the jetbench binary has no folder")?.to_path_buf())
}

/// Options of `jetbench up`.
#[derive(clap::Args)]
pub struct UpArgs {
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
    #[arg(long, value_name = "LAW", value_parser = feedback_law)]
    controller: Option<Controller>,
    /// Model for the estimator and the controller, overriding `[model] model`: a preset
    /// or a model file, e.g. one from `jetbench identify` or `jetbench diagnose --out`.
    #[arg(long, value_name = "PRESET|FILE")]
    model: Option<String>,
    /// Simulated engine, overriding `[plant] model` (with --sim): a preset or a model
    /// file, which may carry effects (`[effects.input_delay]`, ...), or a turbojet that is
    /// not the model (`turbojet-p100`, `turbojet-p220`, a plant file with `[turbojet]`).
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
    /// Inject a fault into the simulated sensor's path (repeatable; the kinds compose):
    /// spikes:rate_per_s=R,size_n=N[,seed=S], stuck:at_s=T,for_s=D, nan:at_s=T[,for_s=D],
    /// silence:at_s=T,for_s=D (times from the sensor's first frame).
    #[arg(long, value_name = "KIND:KEY=VALUE,...", requires = "sim")]
    inject: Vec<String>,
    /// How samples travel between the services: iceoryx2 shared memory, or
    /// copied through Unix domain sockets (uds, the baseline `jetbench latency`
    /// measures against). Default: $JETBENCH_TRANSPORT, else iceoryx2.
    #[arg(long, value_enum)]
    transport: Option<TransportArg>,
    /// Serve the Foxglove live view of every channel (the viewer service) at HOST:PORT:
    /// 127.0.0.1:8765 without a value, 0.0.0.0:8765 for the control room.
    #[arg(long, value_name = "HOST:PORT", num_args = 0..=1, default_missing_value = jetbench_viewer::DEFAULT_ADDR)]
    foxglove: Option<String>,
    /// Publish every channel on Zenoh (the bridge service), listening at ENDPOINT, e.g.
    /// tcp/0.0.0.0:7447; keys jetbench/<namespace>/<channel>, payloads the CDR samples.
    #[arg(long, value_name = "ENDPOINT")]
    zenoh: Option<String>,
}

/// `--controller`: a feedback law (open loop comes with its profile, `--open-loop FILE`).
fn feedback_law(s: &str) -> Result<Controller, String> {
    match s.parse()? {
        Controller::OpenLoop => Err("open loop plays a throttle profile: use --open-loop FILE.csv".into()),
        law => Ok(law),
    }
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
    /// The config keys these options override.
    fn overrides(&self) -> Overrides {
        Overrides {
            controller: self.controller,
            model: self.model.as_deref().map(model_spec),
            plant: self.plant.as_deref().map(model_spec),
            profile: self.profile.clone(),
            open_loop: self.open_loop.as_ref().map(|p| std::path::absolute(p).unwrap_or_else(|_| p.clone())),
            inject: self.inject.clone(),
        }
    }
}

/// A preset name as it is, a model file as an absolute path (the services run elsewhere).
fn model_spec(spec: &str) -> String {
    let turbojet = jetbench_model::TURBOJET_PLANTS.iter().any(|name| spec.trim().eq_ignore_ascii_case(name));
    if turbojet || spec.parse::<jetbench_model::Preset>().is_ok() {
        return spec.to_string();
    }
    std::path::absolute(spec).map_or_else(|_| spec.to_string(), |p| p.display().to_string())
}

pub fn run(args: UpArgs) -> anyhow::Result<ExitCode> {
    // Check the config here so a typo is reported once, not by six services.
    let mut checked = BenchConfig::load_or_default(args.config.as_deref())?;
    // Command-line overrides go into a derived config file that every service reads.
    let mut derived = None;
    let overrides = args.overrides();
    let config = if !overrides.is_empty() {
        checked = checked.with_overrides(&overrides)?;
        let text = toml::to_string(&checked).context("cannot write the derived bench config")?;
        let path = jetbench_stack::runtime::launch::derived_config_path();
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

fn run_up(args: &UpArgs, config: Option<PathBuf>, checked: &BenchConfig) -> anyhow::Result<ExitCode> {
    let UpArgs { sim, duration, quiet, rt, .. } = *args;
    let record = args.record.clone();
    let transport = match args.transport {
        Some(t) => t.into(),
        None => jetbench_bus::transport()?,
    };
    if !sim && config.is_none() {
        bail!("no bench config given: use --sim for the simulated bench, or --config FILE");
    }
    if !sim && checked.bench.devices == Devices::Sim {
        bail!("the config selects the simulated devices ([bench] devices = \"sim\"); add --sim to confirm");
    }
    if sim && checked.bench.devices == Devices::Bench {
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
    if checked.bench.devices == Devices::Bench {
        // A real engine gets no model that cannot keep a simulation bounded.
        let params = checked.model_params().context("[model] model")?;
        if let Err(why) = jetbench_model::plausibility::check(&params) {
            bail!(
                "[model] model {} is refused for a real engine: {why} (identify again, or use a bounded model)",
                checked.model.model
            );
        }
    }
    if let Some(group) = &checked.bench.group {
        // Every service inherits it: their files are shared with the group.
        std::env::set_var(jetbench_bus::access::GROUP_ENV, group);
    }
    let options = UpOptions {
        config: config.map(|c| std::path::absolute(&c).unwrap_or(c)),
        duration,
        record: record.clone().map(|r| std::path::absolute(&r).unwrap_or(r)),
        bin_dir: bin_dir()?,
        status: !quiet,
        simulated: checked.bench.devices == Devices::Sim,
        rt,
        transport,
        foxglove: args.foxglove.clone(),
        zenoh: args.zenoh.clone(),
        engine: checked.engine.clone(),
    };
    if let Some(listen) = &options.foxglove {
        jetbench_viewer::parse_listen(listen).context("--foxglove")?;
    }
    if let Some(endpoint) = &options.zenoh {
        endpoint.parse::<jetbench_bridge::Endpoint>().context("--zenoh")?;
    }
    up(&options)?;
    println!("all services stopped cleanly");
    if let Some(path) = record {
        super::info::print_summary(&path)?;
    }
    Ok(ExitCode::SUCCESS)
}
