//! `jetbench recover`: a truncated or damaged recording rewritten as a valid,
//! indexed MCAP file (glue over [`jetbench_record::recover`]).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};

/// Exit status when data was lost (the rest was recovered), as `mcap recover` has it.
const EXIT_DATA_LOST: u8 = 3;

/// Arguments of `jetbench recover`.
#[derive(clap::Args)]
#[command(after_help = "Exit status: 0 everything recovered, 3 data was lost (the rest recovered), 1 failure.

Example:
  jetbench recover crashed.mcap --out fixed.mcap")]
pub struct RecoverArgs {
    /// The recording to recover (e.g. one whose recorder was killed or whose disk filled).
    #[arg(value_name = "IN.mcap")]
    pub file: PathBuf,
    /// Where to write the recovered recording (not the input itself).
    #[arg(long, value_name = "OUT.mcap")]
    pub out: PathBuf,
}

pub fn run(args: RecoverArgs) -> anyhow::Result<ExitCode> {
    if super::replay::same_file(&args.file, &args.out) {
        bail!("--out {} is the input itself; write the recovered copy elsewhere", args.out.display());
    }
    // Written beside the target and renamed, so a failure leaves no half file.
    let partial = args.out.with_extension("mcap.partial");
    let report = match jetbench_record::recover::recover(&args.file, &partial) {
        Ok(report) => report,
        Err(e) => {
            let _ = std::fs::remove_file(&partial);
            return Err(e).with_context(|| format!("cannot recover {}", args.file.display()));
        }
    };
    std::fs::rename(&partial, &args.out).with_context(|| format!("cannot write {}", args.out.display()))?;
    print!("{}: {report}", args.file.display());
    super::info::print_summary(&args.out)?;
    Ok(if report.data_lost() { ExitCode::from(EXIT_DATA_LOST) } else { ExitCode::SUCCESS })
}
