//! Offline model tools: `simulate`, `excite`, `sim-record` and `export`.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use jetbench_ident::excite::{self, MIN_SAMPLES};
use jetbench_ident::synth::{self, Bench};
use jetbench_ident::validate;
use jetbench_model::{resolve_model, resolve_params, Effect, EffectKind};
use jetbench_record::series::Series;

/// Arguments of `jetbench simulate`.
#[derive(clap::Args)]
#[command(after_long_help = "\
The input's throttle_pct of row k is held until row k + 1. With measured thrust in the input, \
the run starts from the state fitted to its first 2 s and the error against it is printed; \
otherwise from rest at the first throttle.

Effects in the model file ([effects.<name>] tables, see `jetbench sim-record --help`) are \
simulated too, starting at rest at the first throttle: thrust_n is then the force the sensor \
reads (noise-free), as measured_n is.

Examples:
  jetbench simulate --model model.toml --input run.mcap --out sim.csv
  jetbench simulate --model p220-kerosene --input campaign.csv")]
pub struct SimulateArgs {
    /// Model: preset name (p100-diesel, ...) or model file.
    #[arg(long, value_name = "MODEL")]
    model: String,
    /// Throttle profile or recording (CSV `time_s,throttle_pct[,thrust_n]`, or MCAP).
    #[arg(long, value_name = "FILE")]
    input: PathBuf,
    /// Write `time_s,throttle_pct,thrust_n[,measured_n]` here instead of stdout.
    #[arg(long, value_name = "FILE.csv")]
    out: Option<PathBuf>,
}

pub fn simulate(args: SimulateArgs) -> anyhow::Result<ExitCode> {
    // Without effects the plant is the ten-parameter engine, bit for bit.
    let plant = resolve_model(&args.model)?.plant();
    let input = Series::load(&args.input, false)?;
    if input.runs().len() > 1 {
        eprintln!("warning: the input has gaps in time; it is simulated as one run with the throttle held over them");
    }
    let run = validate::simulate_input(&plant, &input);
    let out: Box<dyn Write> = match &args.out {
        Some(p) => Box::new(BufWriter::new(File::create(p).with_context(|| format!("cannot create {}", p.display()))?)),
        None => Box::new(std::io::stdout().lock()),
    };
    validate::write_simulation_csv(out, &input, &run.thrust_n)?;
    if let Some(at) = run.diverged_at_s {
        bail!(
            "the model diverged {at:.2} s into the run (t = {:.2} s); output stops there. The model is only locally \
             valid: check it with `jetbench identify` or keep the throttle where it was identified",
            input.t_s[0] + at
        );
    }
    if let Some(s) = validate::score(input.thrust_n.iter().copied().zip(run.thrust_n.iter().copied())) {
        eprintln!("against the measured thrust: MAE {:.3} N, RMSE {:.3} N, fit {:.1} %", s.mae_n, s.rmse_n, s.fit_pct);
    }
    Ok(ExitCode::SUCCESS)
}

/// Arguments of `jetbench excite`.
#[derive(clap::Args)]
#[command(after_long_help = "\
The campaign cycles through blocks of steps (large and small), ramps, sines and chirps, each \
at a random operating point and amplitude, so the data covers the whole throttle range, both \
directions of change and a band of frequencies. The file is `time_s,throttle_pct` at 100 Hz; \
play it open loop with `jetbench up --sim --open-loop FILE` (or `[control] controller = \
\"open-loop\"` and `throttle_profile` in the bench config).

The conditioning reported is that of the ten-parameter regression on this campaign, with the \
--model simulated noise-free: below about 10^4 every parameter is well determined.

Example:
  jetbench excite --duration 300 --seed 7 --out campaign.csv")]
pub struct ExciteArgs {
    /// Length, s (plant.md asks for at least 300 s, i.e. 30 000 samples).
    #[arg(long, default_value_t = 300.0, value_name = "SECONDS")]
    duration: f64,
    /// Seed of the random choices: the same seed gives the same campaign.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Model used to judge the campaign's conditioning.
    #[arg(long, default_value = "p100-diesel", value_name = "MODEL")]
    model: String,
    /// Where to write the profile (CSV).
    #[arg(long, value_name = "FILE.csv")]
    out: PathBuf,
}

pub fn excite(args: ExciteArgs) -> anyhow::Result<ExitCode> {
    if !(args.duration.is_finite() && args.duration >= 1.0 && args.duration <= 86_400.0) {
        bail!("--duration {} must be between 1 s and one day", args.duration);
    }
    let params = resolve_params(&args.model)?;
    let campaign = excite::campaign(args.duration, args.seed);
    write_csv(&campaign.profile, &args.out)?;
    let n = campaign.profile.len();
    println!("{}: {n} samples ({:.0} s), seed {}", args.out.display(), n as f64 * 0.01, args.seed);
    for block in &campaign.blocks {
        println!("  {block}");
    }
    match excite::regression_condition(&params, &campaign.profile.u_pct) {
        Some(c) => println!(
            "conditioning of the ten-parameter regression ({}): {c:.0}{}",
            args.model,
            if c < 1e4 { " (every parameter well determined)" } else { " (some parameters poorly determined)" }
        ),
        None => println!("conditioning: n/a ({} diverges on this campaign)", args.model),
    }
    if n < MIN_SAMPLES {
        eprintln!("warning: {n} samples is fewer than the {MIN_SAMPLES} an identification campaign should have");
    }
    Ok(ExitCode::SUCCESS)
}

/// Arguments of `jetbench sim-record`.
#[derive(clap::Args)]
#[command(after_long_help = sim_record_help())]
pub struct SimRecordArgs {
    /// Plant: preset name or model file (with its [effects.<name>] tables, if any).
    #[arg(long, value_name = "MODEL")]
    model: String,
    /// Add an effect to the plant, e.g. `input_delay:delay_s=0.08` (repeatable; replaces the
    /// model file's effect of the same name; catalogue in --help).
    #[arg(long = "effect", value_name = "NAME:KEY=VALUE,...", action = clap::ArgAction::Append)]
    effects: Vec<Effect>,
    /// Throttle profile to play (default: a campaign from --seed and --duration, as `jetbench excite`).
    #[arg(long, value_name = "FILE")]
    profile: Option<PathBuf>,
    /// Seed of the campaign and of the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Length of the generated campaign, s.
    #[arg(long, default_value_t = 300.0, value_name = "SECONDS")]
    duration: f64,
    /// Measurement noise variance, N² (P100 bench: about 7), coloured or not.
    #[arg(long, default_value_t = 7.0, value_name = "N2")]
    noise_var: f64,
    /// Coloured sensor noise: AR coefficients, e.g. `0.6` or `1.2,-0.45` (default: white).
    #[arg(long, value_delimiter = ',', value_name = "PHI,...", allow_hyphen_values = true)]
    noise_ar: Vec<f64>,
    /// Fraction of samples hit by a CAN spike of 20-40 N, e.g. 0.002.
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    spikes: f64,
    /// Fraction of rows lost from the file, e.g. 0.01.
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    drop: f64,
    /// Output CSV (`time_s,throttle_pct,thrust_n`).
    #[arg(long, value_name = "FILE.csv")]
    out: PathBuf,
}

/// The long help of `jetbench sim-record`: the text and the catalogue of effects.
fn sim_record_help() -> String {
    let mut help = String::from(
        "Runs the plant from rest at the first throttle (effects at rest there too), measured every 10 ms \
         with Gaussian noise (white, or AR with --noise-ar), as the simulated bench measures it, at the bench's \
         resolution (0.01 s, 0.01 %, 0.01 N), much faster than real time. --spikes and --drop add what a \
         real bench adds: CAN spikes and lost rows.\n\n\
         Effects (--effect NAME:KEY=VALUE,..., or [effects.NAME] with the same keys in a model file):\n",
    );
    help.push_str(&EffectKind::catalogue_help());
    help.push_str(
        "\nExamples:\n  \
         jetbench sim-record --model p220-kerosene --seed 3 --out p220.csv\n  \
         jetbench sim-record --model model.toml --profile campaign.csv --noise-var 9 --out run.csv\n  \
         jetbench sim-record --model p100-diesel --effect input_delay:delay_s=0.08 \\\n      \
         --effect rate_limit:up_pct_per_s=60,down_pct_per_s=120 --out delayed.csv",
    );
    help
}

pub fn sim_record(args: SimRecordArgs) -> anyhow::Result<ExitCode> {
    let mut plant = resolve_model(&args.model)?.plant();
    for effect in &args.effects {
        plant.effects = plant.effects.with(*effect);
    }
    let profile = match &args.profile {
        Some(p) => Series::load(p, false)?,
        None => {
            if !(args.duration.is_finite() && args.duration >= 1.0 && args.duration <= 86_400.0) {
                bail!("--duration {} must be between 1 s and one day", args.duration);
            }
            excite::campaign(args.duration, args.seed).profile
        }
    };
    let bench = Bench {
        noise_var_n2: args.noise_var,
        noise_ar: args.noise_ar.clone(),
        spike_fraction: args.spikes,
        drop_fraction: args.drop,
        resolution: true,
        ..Bench::default()
    };
    let recording = synth::record_bench(&plant, &profile, &bench, args.seed.wrapping_add(0x5eed))?;
    write_csv(&recording, &args.out)?;
    println!(
        "{}: {} samples of {} (effects: {}) with noise variance {} N²{}",
        args.out.display(),
        recording.len(),
        args.model,
        plant.effects,
        args.noise_var,
        if args.noise_ar.is_empty() { String::new() } else { format!(", AR {:?}", args.noise_ar) }
    );
    Ok(ExitCode::SUCCESS)
}

/// Arguments of `jetbench export`.
#[derive(clap::Args)]
#[command(after_long_help = "\
Writes the identification data of a recording as CSV `time_s,throttle_pct,thrust_n`: time from \
bench/thrust stamps, the measured thrust, and the throttle the board applied until the next \
sample. The numbers are written so that they read back exactly: `jetbench identify` gives the \
same result on the MCAP file and on its export.

Example:
  jetbench export run.mcap --out run.csv")]
pub struct ExportArgs {
    /// Recording (MCAP).
    #[arg(value_name = "FILE.mcap")]
    file: PathBuf,
    /// Output CSV (default: stdout).
    #[arg(long, value_name = "FILE.csv")]
    out: Option<PathBuf>,
}

pub fn export(args: ExportArgs) -> anyhow::Result<ExitCode> {
    let series = Series::load(&args.file, true)?;
    match &args.out {
        Some(p) => write_csv(&series, p)?,
        None => series.write_csv(std::io::stdout().lock())?,
    }
    Ok(ExitCode::SUCCESS)
}

fn write_csv(series: &Series, path: &Path) -> anyhow::Result<()> {
    let file = File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    series.write_csv(BufWriter::new(file)).with_context(|| format!("cannot write {}", path.display()))
}
