//! `jetbench excite`: an identification campaign (a throttle profile to play open loop), or
//! with `--discriminate` the campaign that separates the rivals a diagnosis left.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use jetbench_ident::diagnose::design::{self, DesignOptions};
use jetbench_ident::excite::{self, MIN_SAMPLES};
use jetbench_model::{resolve_model, resolve_params, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};

/// Arguments of `jetbench excite`.
#[derive(clap::Args)]
#[command(after_long_help = "\
The campaign cycles through blocks of steps (large and small), ramps, sines and chirps, each \
at a random operating point and amplitude, so the data covers the whole throttle range, both \
directions of change and a band of frequencies. The file is `time_s,throttle_pct` at 100 Hz; \
play it open loop with `jetbench up --sim --open-loop FILE` (or `[control] controller = \
\"open-loop\"` and `throttle_profile` in the bench config).

With --discriminate DIAGNOSIS.json (what `jetbench diagnose --json` wrote for an ambiguous \
case), the campaign is designed instead: each rival the diagnosis kept is rebuilt (the --model \
it was given, with the rival's effects at the values the diagnosis fitted, or its refit), and \
segments (holds, steps both ways, doublets, ramps, a chirp, long dwells) are chosen greedily, \
within --min/--max and --duration, where the rivals' predicted thrust differs most against the \
diagnosed noise. It prints, per pair of rivals, the expected difference of held-out scores and \
when the weakest pair becomes decisive (40 score units on the held-out 30 %), and refuses when \
fewer than two rivals are left or the limits and duration cannot make it decisive. Record the \
campaign and diagnose every recording so far together: those the diagnosis was made from and the \
new one. A verdict still ambiguous is designed for again from the new diagnosis.

The conditioning reported is that of the ten-parameter regression on this campaign, with the \
--model simulated noise-free: below about 10^4 every parameter is well determined.

Examples:
  jetbench excite --duration 300 --seed 7 --out campaign.csv
  jetbench diagnose --model p100-diesel run.csv --json > diagnosis.json
  jetbench excite --discriminate diagnosis.json --model p100-diesel --duration 120 --out design.csv
  jetbench up --sim --open-loop design.csv --duration 122 --record design.mcap
  jetbench diagnose --model p100-diesel run.csv design.mcap")]
pub struct ExciteArgs {
    /// Length, s (an identification campaign needs at least 300 s, i.e. 30 000 samples;
    /// default 300, or 120 with --discriminate).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
    /// Seed of the random choices: the same seed gives the same campaign.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Model used to judge the campaign's conditioning; with --discriminate, the model the
    /// diagnosis was given (required there).
    #[arg(long, value_name = "MODEL")]
    model: Option<String>,
    /// Design the campaign that separates the rivals of this diagnosis (`diagnose --json`).
    #[arg(long, value_name = "DIAGNOSIS.json")]
    discriminate: Option<PathBuf>,
    /// Lowest throttle the designed campaign may command, % (with --discriminate).
    #[arg(long = "min", default_value_t = THROTTLE_MIN_PCT, value_name = "PCT")]
    min_pct: f64,
    /// Highest throttle the designed campaign may command, % (with --discriminate).
    #[arg(long = "max", default_value_t = THROTTLE_MAX_PCT, value_name = "PCT")]
    max_pct: f64,
    /// Share at the end of each recording the diagnosis will hold out (its --holdout).
    #[arg(long, default_value_t = 0.3, value_name = "FRACTION")]
    holdout: f64,
    /// Where to write the profile (CSV).
    #[arg(long, value_name = "FILE.csv")]
    out: PathBuf,
}

pub fn run(args: ExciteArgs) -> anyhow::Result<ExitCode> {
    if let Some(diagnosis) = &args.discriminate {
        return discriminate(&args, diagnosis);
    }
    let duration = args.duration.unwrap_or(300.0);
    if !(duration.is_finite() && (1.0..=86_400.0).contains(&duration)) {
        bail!("--duration {duration} must be between 1 s and one day");
    }
    let model = args.model.as_deref().unwrap_or("p100-diesel");
    let params = resolve_params(model)?;
    let campaign = excite::campaign(duration, args.seed);
    super::export::write_csv(&campaign.profile, &args.out)?;
    let n = campaign.profile.len();
    println!("{}: {n} samples ({:.0} s), seed {}", args.out.display(), n as f64 * 0.01, args.seed);
    for block in &campaign.blocks {
        println!("  {block}");
    }
    match excite::regression_condition(&params, &campaign.profile.u_pct) {
        Some(c) => println!(
            "conditioning of the ten-parameter regression ({model}): {c:.0}{}",
            if c < 1e4 { " (every parameter well determined)" } else { " (some parameters poorly determined)" }
        ),
        None => println!("conditioning: n/a ({model} diverges on this campaign)"),
    }
    if n < MIN_SAMPLES {
        eprintln!("warning: {n} samples is fewer than the {MIN_SAMPLES} an identification campaign should have");
    }
    Ok(ExitCode::SUCCESS)
}

/// `--discriminate`: the campaign that separates the rivals of a diagnosis.
fn discriminate(args: &ExciteArgs, diagnosis: &Path) -> anyhow::Result<ExitCode> {
    let Some(model_name) = args.model.as_deref() else {
        bail!("--discriminate needs --model: the model the diagnosis was given (a preset or the model file)");
    };
    let model = resolve_model(model_name)?;
    let text = std::fs::read_to_string(diagnosis).with_context(|| format!("cannot read {}", diagnosis.display()))?;
    let json: serde_json::Value = serde_json::from_str(&text).with_context(|| {
        format!(
            "{} is not JSON: write it with `jetbench diagnose --json ... > {}`",
            diagnosis.display(),
            diagnosis.display()
        )
    })?;
    let rivals = design::rivals_from_json(&model, &json)?;
    let noise = design::Noise::from_json(&json)?;
    for note in &rivals.notes {
        eprintln!("note: {note}");
    }
    let options = DesignOptions {
        duration_s: args.duration.unwrap_or(120.0),
        min_pct: args.min_pct,
        max_pct: args.max_pct,
        holdout: args.holdout,
        ..DesignOptions::default()
    };
    let (d, left_out) = design::design_separable(&rivals.models, &noise, &options)?;
    for note in &left_out {
        eprintln!("note: {note}");
    }
    super::export::write_csv(&d.profile, &args.out)?;
    let names: Vec<String> = rivals
        .models
        .iter()
        .filter(|r| d.pairs.iter().any(|p| p.a == r.label || p.b == r.label))
        .map(|r| format!("{} (weight {:.2})", r.label, r.weight))
        .collect();
    println!(
        "{}: {} samples ({:.0} s) within {:.0}–{:.0} % separating {}",
        args.out.display(),
        d.profile.u_pct.len(),
        d.profile.u_pct.len() as f64 * 0.01,
        options.min_pct,
        options.max_pct,
        names.join(", ")
    );
    for segment in &d.segments {
        println!("  {segment}");
    }
    println!(
        "expected separation on the held-out {:.0} % (noise σ {:.2} N):",
        100.0 * options.holdout,
        noise.innovation_sigma_n
    );
    for pair in &d.pairs {
        println!("  {pair}");
    }
    if let Some(t) = d.decisive_after_s {
        println!(
            "decisive after {t:.0} s: the weakest pair reaches {:.0} score units on held-out data (a likelihood ratio of \
             e^{:.0}); rivals refitted on the new data give some of it back, so play it whole",
            options.decisive,
            options.decisive / 2.0
        );
    }
    println!(
        "next: play it open loop and record (`jetbench up --open-loop {} --record design.mcap`), then diagnose \
         every recording so far together, those this diagnosis was made from and the new one (`jetbench diagnose \
         --model {model_name} RECORDING... design.mcap`); still ambiguous, design again from that diagnosis",
        args.out.display()
    );
    Ok(ExitCode::SUCCESS)
}
