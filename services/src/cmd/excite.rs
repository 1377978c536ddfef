//! `jetbench excite`: an identification campaign (a throttle profile to play open loop).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use jetbench_ident::excite::{self, MIN_SAMPLES};
use jetbench_model::resolve_params;

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
    /// Length, s (an identification campaign needs at least 300 s, i.e. 30 000 samples).
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

pub fn run(args: ExciteArgs) -> anyhow::Result<ExitCode> {
    if !(args.duration.is_finite() && args.duration >= 1.0 && args.duration <= 86_400.0) {
        bail!("--duration {} must be between 1 s and one day", args.duration);
    }
    let params = resolve_params(&args.model)?;
    let campaign = excite::campaign(args.duration, args.seed);
    super::export::write_csv(&campaign.profile, &args.out)?;
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
