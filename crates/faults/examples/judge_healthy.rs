//! Judges kept healthy-engine recordings as the fault campaign's `limits`
//! part does (trips, the margin each P100 limit kept, the pauses in the
//! telemetry) and prints that section of the report: to look again at runs
//! whose recordings were kept, or at any recording of `jetbench up --sim`
//! with the P100 limits on.
//!
//! ```sh
//! cargo run --release --example judge_healthy -- --seconds 60 campaign:a.mcap campaign:b.mcap steps:c.mcap
//! ```
//!
//! Each argument is `PROFILE:FILE` (the profile the run followed, for the
//! report's columns) or a bare `FILE` (counted as `campaign`); `--seconds N`
//! is the `--duration` the runs had (else the span of each recording).

use std::path::Path;
use std::process::ExitCode;

use jetbench_faults::campaign::{Campaign, Part};
use jetbench_faults::limits::judge;
use jetbench_record::Recording;
use jetbench_stack::limits::Limits;

fn main() -> ExitCode {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut seconds: Option<u32> = None;
    if args.first().map(String::as_str) == Some("--seconds") {
        seconds = args.get(1).and_then(|s| s.parse().ok());
        if seconds.is_none() {
            eprintln!("--seconds takes a whole number of seconds");
            return ExitCode::from(2);
        }
        args.drain(..2);
    }
    if args.is_empty() {
        eprintln!("usage: judge_healthy [--seconds N] [PROFILE:]FILE.mcap ...");
        return ExitCode::from(2);
    }
    let Some(limits) = Limits::preset("p100") else {
        eprintln!("the p100 preset is missing");
        return ExitCode::FAILURE;
    };
    let mut campaign = Campaign { only: vec![Part::Limits], ..Campaign::default() };
    for arg in &args {
        let (profile, file) = arg.split_once(':').unwrap_or(("campaign", arg.as_str()));
        let recording = match Recording::open(Path::new(file)) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("{file}: {e}");
                return ExitCode::FAILURE;
            }
        };
        let mut run = judge(&recording, &limits);
        run.profile = profile.into();
        let times = recording.messages.iter().map(|m| m.log_time_ns);
        let (first, last) = (times.clone().min().unwrap_or(0), times.max().unwrap_or(0));
        run.duration_s = seconds.unwrap_or(((last - first) as f64 * 1e-9).round() as u32);
        for p in &run.problems {
            eprintln!("{file}: {p}");
        }
        campaign.healthy.push(run);
    }
    print!("{}", campaign.markdown("this machine"));
    ExitCode::SUCCESS
}
