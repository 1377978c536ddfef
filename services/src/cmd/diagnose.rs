//! `jetbench diagnose`: where a model and recordings disagree, whether its parameters
//! are off or physics is missing, the model with it fixed, and the fit on held-out data.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use jetbench_ident::diagnose::{self, report, Options};
use jetbench_model::{resolve_model, EffectKind};
use jetbench_record::series::Series;

/// Arguments of `jetbench diagnose`.
#[derive(clap::Args)]
#[command(after_long_help = "\
Steps:
  1. prepare  put the recordings on the model's 10 ms grid (short gaps simulated through with the \
throttle held, the second after one in which the throttle stepped left out, long ones split runs; a CSV at \
another rate resampled), leave out spikes (beyond 5.5 robust \
standard deviations of their neighbours), model the sensor noise (AR, from the data alone)
  2. locate   simulate the model from the recorded throttle and analyse the residual against the noise \
model: whiteness, throttle correlation, rising/falling/steady phases, operating point, drift, spectrum, \
systematic windows
  3. name     fit every hypothesis on the first part of each file and score it on the held-out rest \
(likelihood of the prewhitened residual with a BIC penalty per parameter): each catalogue effect (a fit \
outside its physical range is evidence, not a claim), a refit of the ten parameters, and a sparse \
discrepancy of named terms for physics outside the catalogue
  4. model    keep the best that wins by a practical margin; when a refit explains the residual as well as \
the best effect, blame the parameters; look again with everything kept fitted jointly; drop what the \
held-out score does not need
  5. show     cause, validation MAE, fit % and whiteness before and after, and a verdict

Catalogue (name:parameters=[bounds in a model file]):
{catalogue}
Cause (JSON `cause`): none | parameters (re-identify; --out writes the refitted model) | missing_physics \
| ambiguous (`rivals` lists the explanations the recording cannot tell apart, with weights) | insufficient_data \
| unexplained.

Exit status: 0 when the diagnosis ran (whatever it found), 1 on bad input or a model that diverges.

Examples:
  jetbench diagnose --model model.toml run.mcap
  jetbench diagnose --model p100-diesel run.csv --json --plot plots/ --out improved.toml".replace("{catalogue}", &jetbench_model::EffectKind::catalogue_help()))]
pub struct DiagnoseArgs {
    /// The model the simulation uses: preset name or model file (effects in it are kept as given).
    #[arg(long, value_name = "MODEL")]
    model: String,
    /// Recordings (MCAP, or CSV `time_s,throttle_pct,thrust_n` at 100 Hz or another uniform rate).
    #[arg(value_name = "FILE", required = true)]
    files: Vec<PathBuf>,
    /// Print the diagnosis as JSON on stdout (the human report goes to stderr).
    #[arg(long)]
    json: bool,
    /// Write plots (PNG and SVG) into this folder.
    #[arg(long, value_name = "DIR")]
    plot: Option<PathBuf>,
    /// Write the improved model (refitted parameters, `[effects.*]` tables) here.
    #[arg(long, value_name = "improved.toml")]
    out: Option<PathBuf>,
    /// Fraction at the end of each file held out for validation.
    #[arg(long, default_value_t = 0.3, value_name = "FRACTION")]
    holdout: f64,
    /// Most effects to add.
    #[arg(long, default_value_t = 3)]
    max_effects: usize,
    /// Only try these effects (comma-separated names, `discrepancy` included; default: all).
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    only: Vec<String>,
    /// Never refit the ten parameters (blame only physics).
    #[arg(long)]
    no_refit: bool,
}

pub fn run(args: DiagnoseArgs) -> anyhow::Result<ExitCode> {
    let model = resolve_model(&args.model)?;
    let mut options =
        Options { holdout: args.holdout, max_effects: args.max_effects, refit: !args.no_refit, ..Options::default() };
    let mut data = Vec::with_capacity(args.files.len());
    for path in &args.files {
        let (series, note) = Series::load_any_rate(path, true)?;
        options.notes.extend(note);
        data.push(series);
    }
    if !args.only.is_empty() {
        options.candidates = args.only.iter().map(|n| n.trim().parse::<EffectKind>()).collect::<Result<_, _>>()?;
        if options.candidates.contains(&EffectKind::AccelSchedule) {
            bail!(
                "--only accel_schedule: an acceleration schedule is model structure that `jetbench identify` \
                 chooses, not a hypothesis the diagnosis weighs; give a model file that holds one instead"
            );
        }
    }
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {elapsed:>3} {msg}").unwrap_or(ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    // Each stage's wall time at debug level (`RUST_LOG=debug`): where a diagnosis spends it.
    let mut stage = (String::from("start"), Instant::now());
    let mut progress = |message: &str| {
        tracing::debug!(seconds = stage.1.elapsed().as_secs_f64(), "diagnose stage done: {}", stage.0);
        stage = (message.to_owned(), Instant::now());
        bar.set_message(message.to_owned());
    };
    let result = diagnose::diagnose(&model, &data, &options, &mut progress);
    progress("end");
    bar.finish_and_clear();
    let d = result?;

    // The report is the command's output, on stdout; with --json, stdout is the JSON a
    // script reads and the human report goes beside the logs, on stderr.
    if args.json {
        eprint!("{}", report::text(&d, &args.model));
        println!("{}", serde_json::to_string_pretty(&report::to_json(&d))?);
    } else {
        print!("{}", report::text(&d, &args.model));
    }
    if let Some(dir) = &args.plot {
        let written = report::plots(&d, &data, dir)?;
        if written == 0 {
            bail!("no plot written");
        }
        eprintln!("plots: {written} files in {}", dir.display());
    }
    if let Some(path) = &args.out {
        let files: Vec<String> = args.files.iter().map(|p| p.display().to_string()).collect();
        std::fs::write(path, report::model_file(&d, &args.model, &files))
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote the improved model to {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}
