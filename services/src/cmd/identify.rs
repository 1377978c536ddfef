//! `jetbench identify`: the engine model from recordings, by LS, EKF and SINDy.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::ValueEnum;
use indicatif::{ProgressBar, ProgressStyle};
use jetbench_ident::excite::MIN_SAMPLES;
use jetbench_ident::identify::{self, Method, Report};
use jetbench_model::STEP_S;
use jetbench_plot::{write_fit_plot, FitPlot};
use jetbench_record::series::Series;

/// Which methods to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    Ls,
    Ekf,
    Sindy,
    /// LS and EKF, then both refined by simulation error with plausibility as a
    /// constraint (and a bounded linear start): a bounded model whenever a stable engine
    /// can describe the data.
    Oe,
    All,
}

/// Arguments of `jetbench identify`.
#[derive(clap::Args)]
#[command(after_long_help = "\
Every method is validated by free-run simulation from the recorded throttle on held-out data \
(the last 30 % of each file, or the --validate files), starting from the state fitted to the \
first 2 s of each run. MAE is in N; fit % is 100·(1 − ‖y − ŷ‖/‖y − ȳ‖). The noise floor is the \
mean absolute value of the measurement noise, estimated from the data: no model can do better.

Methods:
  ls     the ten parameters by linear least squares on Savitzky–Golay derivatives; the regressors \
and the target of each equation come from the two interleaved halves of the samples, so the \
noise does not bias the estimate
  ekf    the ten parameters in a 12-state EKF, passes over the calibration data from the LS \
estimate until validation stops improving
  sindy  sparse regression of T'' on all 56 monomials of degree <= 5 in (T, T', u)

Examples:
  jetbench identify run.mcap
  jetbench identify day1.csv day2.mcap --validate day3.csv --out model.toml --plot plots/
  jetbench identify run.mcap --method ls --json")]
pub struct IdentifyArgs {
    /// Recordings to identify from (MCAP or CSV `time_s,throttle_pct,thrust_n`).
    #[arg(value_name = "FILE", required = true)]
    files: Vec<PathBuf>,
    /// Method(s) to run.
    #[arg(long, value_enum, default_value = "all")]
    method: MethodArg,
    /// Validate on these recordings instead of holding out the end of each file.
    #[arg(long, value_name = "FILE", num_args = 1..)]
    validate: Vec<PathBuf>,
    /// Fraction of each file held out for validation when --validate is not given.
    #[arg(long, default_value_t = 0.3, value_name = "FRACTION")]
    holdout: f64,
    /// Write the best ten-parameter model here (model-file TOML).
    #[arg(long, value_name = "model.toml")]
    out: Option<PathBuf>,
    /// Print the result as JSON on stdout (the human report then goes to stderr).
    #[arg(long)]
    json: bool,
    /// Write plots (PNG and SVG) of every method into this folder.
    #[arg(long, value_name = "DIR")]
    plot: Option<PathBuf>,
    /// LS: Savitzky–Golay window, samples (odd).
    #[arg(long, default_value_t = 101, value_name = "SAMPLES")]
    ls_window: usize,
    /// EKF: measurement noise variance R, N² [default: estimated from the data].
    #[arg(long, value_name = "N2")]
    ekf_measurement_var: Option<f64>,
    /// EKF: unmodelled acceleration standard deviation, N/s² [default: 8·σ].
    #[arg(long, value_name = "N_PER_S2")]
    ekf_accel_noise: Option<f64>,
    /// EKF: initial parameter standard deviation, relative to each parameter's scale.
    #[arg(long, default_value_t = 0.1, value_name = "RELATIVE")]
    ekf_p0: f64,
    /// EKF: parameter random walk per sample, relative to each parameter's scale.
    #[arg(long, default_value_t = 1e-5, value_name = "RELATIVE")]
    ekf_walk: f64,
    /// EKF: most passes over the calibration data.
    #[arg(long, default_value_t = 20)]
    ekf_passes: usize,
    /// SINDy: STLSQ threshold on the scaled library (share of T'' a term must explain).
    #[arg(long, default_value_t = 0.1)]
    sindy_threshold: f64,
    /// Let the structure search also pace the model with an acceleration schedule (an engine
    /// whose fuel schedule holds its steps to a thrust rate). For simulation and diagnosis
    /// only: the bench refuses a paced model, whose ten parameters alone run far too fast
    /// for FBL and SMC, which cancel them (docs/identify/OUT-OF-CLASS.md).
    #[arg(long)]
    schedule: bool,
}

pub fn run(args: IdentifyArgs) -> anyhow::Result<ExitCode> {
    if !(args.holdout > 0.0 && args.holdout < 1.0) {
        bail!("--holdout {} must be between 0 and 1", args.holdout);
    }
    for (name, v) in
        [("--ekf-p0", args.ekf_p0), ("--ekf-walk", args.ekf_walk), ("--sindy-threshold", args.sindy_threshold)]
    {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{name} {v} must be a non-negative number");
        }
    }
    let load = |paths: &[PathBuf]| -> anyhow::Result<Vec<Series>> {
        paths.iter().map(|p| Ok(Series::load(p, true)?)).collect()
    };
    let data = load(&args.files)?;
    let (calibration, validation) =
        if args.validate.is_empty() { identify::hold_out(&data, args.holdout) } else { (data, load(&args.validate)?) };
    let mut options = identify::Options {
        methods: match args.method {
            MethodArg::Ls => vec![Method::Ls],
            MethodArg::Ekf => vec![Method::Ekf],
            MethodArg::Sindy => vec![Method::Sindy],
            MethodArg::Oe => vec![Method::Ls, Method::Ekf, Method::Oe],
            MethodArg::All => Method::ALL.to_vec(),
        },
        schedule: args.schedule,
        ..identify::Options::default()
    };
    options.ls.window = args.ls_window;
    options.ekf.measurement_var_n2 = args.ekf_measurement_var;
    options.ekf.accel_noise_n_per_s2 = args.ekf_accel_noise;
    options.ekf.p0_relative = args.ekf_p0;
    options.ekf.walk_relative = args.ekf_walk;
    options.ekf.max_passes = args.ekf_passes;
    options.sindy.stlsq.threshold = args.sindy_threshold;

    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {elapsed:>3} {msg}").unwrap_or(ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let report = identify::identify(&calibration, &validation, &options, |method, message| {
        bar.set_message(format!("{}: {message}", method.name()));
    })?;
    bar.finish_and_clear();

    // The report is the command's output (`jetbench identify run.mcap > report.txt`);
    // with --json the JSON is, and the text goes with the logs.
    let text = format!("{}{}", amount_note(&calibration), report.text(&calibration, &validation));
    if args.json {
        eprint!("{text}");
        println!("{}", serde_json::to_string_pretty(&report.to_json())?);
    } else {
        print!("{text}");
    }
    if let Some(dir) = &args.plot {
        let written = plot(&report, &calibration, &validation, dir, args.validate.is_empty())?;
        eprintln!("plots: {} files in {}", written, dir.display());
    }
    if let Some(path) = &args.out {
        // Only a bounded model is ever written: one stable equilibrium per throttle, full
        // steps both ways bounded, bounded on the validation data.
        let (Some((result, _)), Some(text)) = (report.best_params(), report.model_file_text()) else {
            bail!("nothing written to {}: {}", path.display(), report.written_text().trim_start_matches("model file: "))
        };
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?;
        let extended = report.chosen_structure().map_or(String::new(), |s| {
            format!(" extended by {}", s.chosen.iter().map(|t| t.key).collect::<Vec<_>>().join(", "))
        });
        eprintln!("wrote the {} model{extended} to {}", result.method.name(), path.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// A file's name without its folders, for a title.
fn short_name(path: &str) -> String {
    Path::new(path).file_name().map_or_else(|| path.to_string(), |n| n.to_string_lossy().into_owned())
}

/// How strong an answer the amount of calibration data allows: a campaign of
/// `jetbench excite` is 300 s; with less the parameters are weakly determined,
/// and the report says so before its figures.
fn amount_note(calibration: &[Series]) -> String {
    let samples: usize = calibration.iter().map(Series::len).sum();
    if samples >= MIN_SAMPLES {
        return String::new();
    }
    format!(
        "note: {:.0} s of calibration data ({samples} samples); an identification campaign needs {:.0} s \
         ({MIN_SAMPLES} samples, `jetbench excite`). With {:.0} % of that the parameters are weakly determined: \
         trust the validation figures below, not the parameter values.\n\n",
        samples as f64 * STEP_S,
        MIN_SAMPLES as f64 * STEP_S,
        100.0 * samples as f64 / MIN_SAMPLES as f64
    )
}

/// Per method: measured vs simulated with the residual, over calibration and
/// validation (one figure per file when the validation data is the end of it),
/// and one figure comparing every method on the validation data.
fn plot(
    report: &Report,
    calibration: &[Series],
    validation: &[Series],
    dir: &Path,
    held_out: bool,
) -> anyhow::Result<usize> {
    let mut written = 0;
    let mut figure = |stem: String, title: String, s: &Series, models: &[(&str, &[f64])], split_s: Option<f64>| {
        let fig = FitPlot {
            title: &title,
            t_s: &s.t_s,
            measured_n: &s.thrust_n,
            models,
            split_s,
            windows: &[],
            throttle_pct: Some(&s.u_pct),
        };
        write_fit_plot(dir, &stem, &fig).map(|files| written += files.len())
    };
    for r in &report.results {
        let name = r.method.name();
        if held_out {
            // One figure per file: calibration and validation joined, split marked.
            for (i, (cal, val)) in calibration.iter().zip(validation).enumerate() {
                let joined = Series {
                    name: cal.name.clone(),
                    t_s: cal.t_s.iter().chain(&val.t_s).copied().collect(),
                    u_pct: cal.u_pct.iter().chain(&val.u_pct).copied().collect(),
                    thrust_n: cal.thrust_n.iter().chain(&val.thrust_n).copied().collect(),
                };
                let sim: Vec<f64> =
                    r.calibration.thrust_n[i].iter().chain(&r.validation.thrust_n[i]).copied().collect();
                let title = format!("{name}: {}, validation MAE {}", short_name(&cal.name), r.score_text());
                figure(format!("{name}-{i}"), title, &joined, &[(name, &sim)], val.t_s.first().copied())?;
            }
        } else {
            for (part, data, sim) in
                [("calibration", calibration, &r.calibration), ("validation", validation, &r.validation)]
            {
                for (i, s) in data.iter().enumerate() {
                    let title = format!("{name}, {part}: {}", short_name(&s.name));
                    figure(format!("{name}-{part}-{i}"), title, s, &[(name, &sim.thrust_n[i])], None)?;
                }
            }
        }
    }
    for (i, s) in validation.iter().enumerate() {
        let models: Vec<(&str, &[f64])> =
            report.results.iter().map(|r| (r.method.name(), r.validation.thrust_n[i].as_slice())).collect();
        let title = format!("every method on the validation data: {}", short_name(&s.name));
        figure(format!("validation-all-{i}"), title, s, &models, None)?;
    }
    Ok(written)
}
