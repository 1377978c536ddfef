//! `jetbench simulate`: free-run simulation of a model from a throttle profile or a recording.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use jetbench_ident::validate;
use jetbench_model::resolve_model;
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

pub fn run(args: SimulateArgs) -> anyhow::Result<ExitCode> {
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
    if input.has_thrust() {
        // The figures are the report when the CSV goes to a file, a log line beside a CSV on stdout.
        let line = match validate::score(input.thrust_n.iter().copied().zip(run.thrust_n.iter().copied())) {
            Some(s) if s.fit_pct.is_finite() => {
                format!(
                    "against the measured thrust: MAE {:.3} N, RMSE {:.3} N, fit {:.1} %",
                    s.mae_n, s.rmse_n, s.fit_pct
                )
            }
            Some(s) => format!(
                "against the measured thrust: MAE {:.3} N, RMSE {:.3} N; fit not defined (the measured thrust is \
                 constant)",
                s.mae_n, s.rmse_n
            ),
            None => "against the measured thrust: no figures (no simulated sample to compare)".to_string(),
        };
        if args.out.is_some() {
            println!("{line}");
        } else {
            eprintln!("{line}");
        }
    }
    Ok(ExitCode::SUCCESS)
}
