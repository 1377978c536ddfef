//! `jetbench export`: a recording's identification data as CSV.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use jetbench_record::series::Series;

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

pub fn run(args: ExportArgs) -> anyhow::Result<ExitCode> {
    let series = Series::load(&args.file, true)?;
    match &args.out {
        Some(p) => write_csv(&series, p)?,
        None => series.write_csv(std::io::stdout().lock())?,
    }
    Ok(ExitCode::SUCCESS)
}

pub(super) fn write_csv(series: &Series, path: &Path) -> anyhow::Result<()> {
    let file = File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    series.write_csv(BufWriter::new(file)).with_context(|| format!("cannot write {}", path.display()))
}
