//! `jetbench diagnose`: where a model and recordings disagree, which physics it
//! leaves out, the model with it added, and the fit on held-out data.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};
use jetbench_ident::diagnose::{self, Diagnosis, Options};
use jetbench_ident::plot::{write_fit_plot, write_line_plot, FitPlot, LinePlot};
use jetbench_model::{resolve_model, EffectKind};
use jetbench_record::series::Series;
use serde_json::json;

/// Arguments of `jetbench diagnose`.
#[derive(clap::Args)]
#[command(after_long_help = "\
Steps:
  1. locate   simulate the model from the recorded throttle (from the state fitted to the first \
2 s of each run) and analyse the residual: whiteness, correlation with throttle changes, \
rising/falling/steady phases, operating point, drift over time, spectrum, systematic windows
  2. name     fit each effect of the catalogue on the first part of each file and score it on the \
held-out rest (log-likelihood with a BIC penalty per parameter); a sparse regression of the \
residual on a library of terms reports what the catalogue may not name
  3. model    keep the best effect if it wins on held-out data by a practical margin, refit, and \
look again until nothing significant remains (a model that explains the data gets nothing)
  4. show     validation MAE, fit % and residual whiteness before and after, and a verdict

Catalogue (name: parameters):
  input_delay: delay_s                         the engine follows u(t - delay_s)
  actuator_lag: time_constant_s                first-order lag on u
  rate_limit: up_pct_per_s, down_pct_per_s     the throttle moves no faster than these
  sensor_drift: gain, time_constant_s          measured = T + b, b' = (gain*T - b)/time_constant_s
  gain_drift: per_minute                       v(u) scaled by (1 - per_minute*t/60)
  bearing_friction: force_n                    measured force follows T only beyond a band of force_n

Exit status: 0 when the diagnosis ran (whatever it found), 1 on bad input or a model that diverges.

Examples:
  jetbench diagnose --model model.toml run.mcap
  jetbench diagnose --model p100-diesel run.csv --json --plot plots/ --out improved.toml")]
pub struct DiagnoseArgs {
    /// The model the simulation uses: preset name or model file (effects in it are kept as given).
    #[arg(long, value_name = "MODEL")]
    model: String,
    /// Recordings (MCAP, or CSV `time_s,throttle_pct,thrust_n`).
    #[arg(value_name = "FILE", required = true)]
    files: Vec<PathBuf>,
    /// Print the diagnosis as JSON on stdout (the human report goes to stderr).
    #[arg(long)]
    json: bool,
    /// Write plots (PNG and SVG) into this folder.
    #[arg(long, value_name = "DIR")]
    plot: Option<PathBuf>,
    /// Write the improved model (with `[effects.*]` tables) here.
    #[arg(long, value_name = "improved.toml")]
    out: Option<PathBuf>,
    /// Fraction at the end of each file held out for validation.
    #[arg(long, default_value_t = 0.3, value_name = "FRACTION")]
    holdout: f64,
    /// Most effects to add.
    #[arg(long, default_value_t = 3)]
    max_effects: usize,
    /// Only try these effects (comma-separated names; default: the whole catalogue).
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    only: Vec<String>,
}

pub fn run(args: DiagnoseArgs) -> anyhow::Result<ExitCode> {
    let model = resolve_model(&args.model)?;
    let data: Vec<Series> = args.files.iter().map(|p| Ok(Series::load(p, true)?)).collect::<anyhow::Result<_>>()?;
    let mut options = Options { holdout: args.holdout, max_effects: args.max_effects, ..Options::default() };
    if !args.only.is_empty() {
        options.candidates = args.only.iter().map(|n| n.trim().parse::<EffectKind>()).collect::<Result<_, _>>()?;
    }
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {elapsed:>3} {msg}").unwrap_or(ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    let result = diagnose::diagnose(&model, &data, &options, &mut |message| bar.set_message(message.to_owned()));
    bar.finish_and_clear();
    let d = result?;

    print_report(&d, &args.model);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&to_json(&d))?);
    }
    if let Some(dir) = &args.plot {
        let written = plot(&d, &data, dir)?;
        eprintln!("plots: {written} files in {}", dir.display());
    }
    if let Some(path) = &args.out {
        let mut text = format!(
            "# {} with the effects `jetbench diagnose` found in {}\n# validation MAE {:.3} N -> {:.3} N (noise \
             floor {:.3} N)\n",
            args.model,
            args.files.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "),
            d.mae_before_n,
            d.mae_after_n,
            d.noise_floor_n
        );
        text.push_str(&d.improved.to_toml_string());
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote the improved model to {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// The JSON contract: `effects[{name, params, evidence}]`, `mae_before_n`, `mae_after_n`,
/// `noise_floor_n`, `verdict`, plus the details.
fn to_json(d: &Diagnosis) -> serde_json::Value {
    let mut value = serde_json::to_value(d).unwrap_or_else(|e| json!({ "error": e.to_string() }));
    if let Some(obj) = value.as_object_mut() {
        // Spectra and correlation curves are for plots; keep the JSON readable.
        for part in ["before", "after"] {
            if let Some(a) = obj.get_mut(part).and_then(|a| a.as_object_mut()) {
                if let Some(s) = a.get_mut("spectrum").and_then(|s| s.as_object_mut()) {
                    s.remove("freq_hz");
                    s.remove("ratio");
                }
                if let Some(x) = a.get_mut("input_correlation").and_then(|s| s.as_object_mut()) {
                    x.remove("lags_s");
                    x.remove("values");
                }
            }
        }
    }
    value
}

fn print_report(d: &Diagnosis, model: &str) {
    eprintln!(
        "model {model}: {} calibration + {} validation samples; noise σ {:.2} N, floor (MAE) {:.2} N",
        d.calibration_samples, d.validation_samples, d.noise.sigma_n, d.noise_floor_n
    );
    eprintln!("\nlocate (residual of the model as given):");
    for f in &d.before.findings {
        eprintln!("  - {f}");
    }
    eprintln!("  discrepancy model: {}", d.discrepancy_before.equation());
    for (i, round) in d.rounds.iter().enumerate() {
        eprintln!("\nround {} (validation MAE {:.3} N): hypotheses, best first", i + 1, round.mae_val_n);
        for c in &round.candidates {
            let params: Vec<String> = c
                .params
                .iter()
                .map(|(k, v)| format!("{k}={v:.4}±{:.4}", c.uncertainty.get(k).copied().unwrap_or(f64::NAN)))
                .collect();
            eprintln!(
                "  {:<17} score {:>9}  MAE {:.3} N  {}{}",
                c.name,
                c.score_gain.map_or("diverged".to_owned(), |g| format!("{g:+.1}")),
                c.mae_val_n,
                params.join(" "),
                if round.accepted == Some(c.name) { "  <- kept" } else { "" }
            );
        }
    }
    eprintln!("\nafter:");
    for f in &d.after.findings {
        eprintln!("  - {f}");
    }
    eprintln!("  discrepancy model: {}", d.discrepancy_after.equation());
    eprintln!(
        "\nvalidation MAE {:.3} N -> {:.3} N, fit {:.1} % -> {:.1} % (noise floor {:.3} N)",
        d.mae_before_n, d.mae_after_n, d.fit_before_pct, d.fit_after_pct, d.noise_floor_n
    );
    eprintln!("\n{}", d.verdict);
}

/// Per file: recording vs the model as given and as improved, split and systematic
/// windows marked; residual autocorrelation, throttle correlation and spectrum,
/// before and after.
fn plot(d: &Diagnosis, data: &[Series], dir: &Path) -> anyhow::Result<usize> {
    let mut written = 0;
    for (i, s) in data.iter().enumerate() {
        let labels: Vec<String> =
            d.before.windows.iter().filter(|w| w.file == i).map(|w| format!("{:+.1} N", w.mean_n)).collect();
        let windows: Vec<(f64, f64, &str)> = d
            .before
            .windows
            .iter()
            .filter(|w| w.file == i)
            .zip(&labels)
            .map(|(w, l)| (w.start_s, w.end_s, l.as_str()))
            .collect();
        let title = format!(
            "{}: model as given (MAE {:.2} N) and with {} (MAE {:.2} N), floor {:.2} N",
            s.name,
            d.mae_before_n,
            if d.effects.is_empty() { "nothing added".to_owned() } else { names(d) },
            d.mae_after_n,
            d.noise_floor_n
        );
        let fig = FitPlot {
            title: &title,
            t_s: &s.t_s,
            measured_n: &s.thrust_n,
            models: &[("as given", &d.sim_before[i]), ("improved", &d.sim_after[i])],
            split_s: s.t_s.get(d.cut[i]).copied(),
            windows: &windows,
        };
        written += write_fit_plot(dir, &format!("diagnose-fit-{i}"), &fig)?.len();
    }
    let lags: Vec<f64> = (1..=d.before.whiteness.acf.len()).map(|k| k as f64 * 0.01).collect();
    let (b, a) = (&d.before, &d.after);
    let bounds = |x: f64| vec![(x, "+95 %"), (-x, "-95 %")];
    let figures = [
        BeforeAfter {
            stem: "diagnose-acf",
            title: "residual autocorrelation (white noise stays within the bounds)",
            x_label: "lag (s)",
            y_label: "autocorrelation",
            before: (&lags, &b.whiteness.acf),
            after: (&lags, &a.whiteness.acf),
            hlines: bounds(b.whiteness.bound),
            log_y: false,
        },
        BeforeAfter {
            stem: "diagnose-input-correlation",
            title: "residual vs earlier throttle changes",
            x_label: "lag (s)",
            y_label: "correlation",
            before: (&b.input_correlation.lags_s, &b.input_correlation.values),
            after: (&a.input_correlation.lags_s, &a.input_correlation.values),
            hlines: bounds(b.input_correlation.bound),
            log_y: false,
        },
        BeforeAfter {
            stem: "diagnose-spectrum",
            title: "residual power over its white level",
            x_label: "frequency (Hz)",
            y_label: "power / white level",
            before: (&b.spectrum.freq_hz, &b.spectrum.ratio),
            after: (&a.spectrum.freq_hz, &a.spectrum.ratio),
            hlines: vec![(1.0, "white")],
            log_y: true,
        },
    ];
    for f in figures {
        let series = [("as given", f.before.0, f.before.1), ("improved", f.after.0, f.after.1)];
        let plot = LinePlot {
            title: f.title,
            x_label: f.x_label,
            y_label: f.y_label,
            series: &series,
            hlines: &f.hlines,
            log_y: f.log_y,
        };
        written += write_line_plot(dir, f.stem, &plot)?.len();
    }
    if written == 0 {
        bail!("no plot written");
    }
    Ok(written)
}

fn names(d: &Diagnosis) -> String {
    d.effects.iter().map(|e| e.name).collect::<Vec<_>>().join(" + ")
}

/// One residual statistic drawn before and after the diagnosis, as `(x, y)` slices.
struct BeforeAfter<'a> {
    stem: &'a str,
    title: &'a str,
    x_label: &'a str,
    y_label: &'a str,
    before: (&'a [f64], &'a [f64]),
    after: (&'a [f64], &'a [f64]),
    hlines: Vec<(f64, &'a str)>,
    log_y: bool,
}
