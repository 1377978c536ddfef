//! `jetbench sim-record`: a simulated plant driven by a campaign, recorded faster than real time.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use jetbench_ident::excite::{self};
use jetbench_ident::synth::{self, Bench};
use jetbench_model::{resolve_plant, Effect, EffectKind};
use jetbench_record::series::Series;

/// Arguments of `jetbench sim-record`.
#[derive(clap::Args)]
#[command(after_long_help = sim_record_help())]
#[command(group = clap::ArgGroup::new("engine").required(true).args(["model", "plant"]))]
pub struct SimRecordArgs {
    /// Plant: preset name or model file (with its [effects.<name>] tables, if any).
    #[arg(long, value_name = "MODEL")]
    model: Option<String>,
    /// Plant that is not the ten-parameter model: `turbojet-p100`, `turbojet-p220`, or a
    /// plant file with a [turbojet] table (model presets and files work too).
    #[arg(long, value_name = "PLANT")]
    plant: Option<String>,
    /// Add an effect to the plant, e.g. `input_delay:delay_s=0.08` (repeatable; replaces the
    /// model file's effect of the same name; catalogue in --help).
    #[arg(long = "effect", value_name = "NAME:KEY=VALUE,...", action = clap::ArgAction::Append)]
    effects: Vec<Effect>,
    /// Throttle profile to play (default: a campaign from --seed and --duration, as `jetbench excite`).
    #[arg(long, value_name = "FILE", conflicts_with = "signal")]
    profile: Option<PathBuf>,
    /// Built-in signal instead of the campaign: `ironcub`, an identification signal in the
    /// manner of the iRonCub group's (0-100 % throttle, 544 s; --duration is not used).
    #[arg(long, value_name = "NAME", value_parser = ["ironcub"])]
    signal: Option<String>,
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
         --plant turbojet-p100 (or turbojet-p220, or a plant file with a [turbojet] table of the constants \
         named in the model crate's README, `base = \"p100\"` and overrides) runs a physically based turbojet \
         (spool, governor, fuel schedule, thrust growing with the square of the spool speed) instead of the \
         ten-parameter model: an engine outside the class `identify` fits. --plant ironcub runs the iRonCub \
         group's 13-coefficient jet (input gain in T², Ṫ² and T·Ṫ; 16-222 N over 0-100 % throttle), and \
         --signal ironcub drives it with an identification signal of their length and range (544 s, 0-100 %).\n\n\
         Effects (--effect NAME:KEY=VALUE,..., or [effects.NAME] with the same keys in a model file):\n",
    );
    help.push_str(&EffectKind::catalogue_help());
    help.push_str(
        "\nExamples:\n  \
         jetbench sim-record --model p220-kerosene --seed 3 --out p220.csv\n  \
         jetbench sim-record --plant turbojet-p100 --seed 3 --out turbojet.csv\n  \
         jetbench sim-record --plant ironcub --signal ironcub --seed 3 --out ironcub.csv\n  \
         jetbench sim-record --model model.toml --profile campaign.csv --noise-var 9 --out run.csv\n  \
         jetbench sim-record --model p100-diesel --effect input_delay:delay_s=0.08 \\\n      \
         --effect rate_limit:up_pct_per_s=60,down_pct_per_s=120 --out delayed.csv",
    );
    help
}

pub fn run(args: SimRecordArgs) -> anyhow::Result<ExitCode> {
    let spec = args.plant.as_deref().or(args.model.as_deref()).unwrap_or_default();
    let mut plant = resolve_plant(spec)?;
    for effect in &args.effects {
        plant.effects = plant.effects.with(*effect);
    }
    if let Some((kind, conflict)) = plant.turbojet_conflict() {
        bail!("--effect {kind}: {conflict}");
    }
    let profile = match (&args.profile, args.signal.as_deref()) {
        (Some(p), _) => Series::load(p, false)?,
        (None, Some(_)) => excite::ironcub_signal(args.seed).profile,
        (None, None) => {
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
    super::export::write_csv(&recording, &args.out)?;
    println!(
        "{}: {} samples of {} (effects: {}) with noise variance {} N²{}",
        args.out.display(),
        recording.len(),
        spec,
        plant.effects,
        args.noise_var,
        if args.noise_ar.is_empty() { String::new() } else { format!(", AR {:?}", args.noise_ar) }
    );
    Ok(ExitCode::SUCCESS)
}
