//! `jetbench info`: a recording at a glance.

use std::path::Path;
use std::process::ExitCode;

use jetbench_record::Recording;

pub fn run(path: &Path) -> anyhow::Result<ExitCode> {
    print_summary(path)?;
    Ok(ExitCode::SUCCESS)
}

/// Prints messages, rate and seq gaps per channel of a recording.
pub fn print_summary(path: &Path) -> anyhow::Result<()> {
    let recording = Recording::open(path)?;
    println!(
        "{}: {} messages{}",
        path.display(),
        recording.messages.len(),
        if recording.truncated { " (file truncated: read up to the last complete chunk)" } else { "" }
    );
    let base = recording.time_base();
    let when = |log_time_ns: Option<u64>| {
        log_time_ns
            .and_then(|t| base.unix_ns(t))
            .and_then(jetbench_record::clock::format_local)
            .unwrap_or_else(|| "unknown (an older recording without its clock origin)".into())
    };
    let (first, last) = (recording.messages.first(), recording.messages.iter().map(|m| m.log_time_ns).max());
    println!("  start {}", when(first.map(|m| m.log_time_ns)));
    println!("  end   {}", when(last));
    for c in recording.summary() {
        println!("  {:<18} {:>7} messages  {:>6.1} Hz  {} seq gaps", c.topic, c.messages, c.rate_hz, c.seq_gaps);
    }
    Ok(())
}
