//! `jetbench info`: a recording at a glance, like `ros2 bag info`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use jetbench_record::meta::RunMetadata;
use jetbench_record::Recording;

/// Arguments of `jetbench info`.
#[derive(clap::Args)]
#[command(after_long_help = "\
Prints the file's size, compression and the software that wrote it; when the run started and \
ended and how long it lasted; per channel the message type, count, rate and lost samples (seq \
gaps); and the run's bench config and engine model from the recording's metadata.

Examples:
  jetbench info run.mcap
  jetbench info run.mcap --schemas --config")]
pub struct InfoArgs {
    /// MCAP recording.
    file: PathBuf,
    /// Also print each channel's message definition (ros2msg).
    #[arg(long)]
    schemas: bool,
    /// Also print the whole bench config the run used (TOML).
    #[arg(long)]
    config: bool,
}

pub fn run(args: InfoArgs) -> anyhow::Result<ExitCode> {
    print_info(&args.file, args.schemas, args.config)?;
    Ok(ExitCode::SUCCESS)
}

/// The summary other commands print after writing a recording.
pub fn print_summary(path: &Path) -> anyhow::Result<()> {
    print_info(path, false, false)
}

/// Prints the recording's summary (see [`InfoArgs`]).
pub fn print_info(path: &Path, schemas: bool, full_config: bool) -> anyhow::Result<()> {
    let recording = Recording::open(path)?;
    let bytes = std::fs::read(path)?;
    let summary = mcap::Summary::read(&bytes).ok().flatten();
    let library = header_library(&bytes);

    let compression: BTreeSet<String> = summary
        .iter()
        .flat_map(|s| s.chunk_indexes.iter().map(|c| if c.compression.is_empty() { "none" } else { &c.compression }))
        .map(str::to_string)
        .collect();
    let compression = if compression.is_empty() {
        "compression unknown (no summary: the file was cut short)".to_string()
    } else {
        format!("{} compressed", compression.into_iter().collect::<Vec<_>>().join(", "))
    };
    let first = recording.messages.iter().map(|m| m.log_time_ns).min();
    let last = recording.messages.iter().map(|m| m.log_time_ns).max();
    let duration_s = first.zip(last).map_or(0.0, |(f, l)| l.saturating_sub(f) as f64 * 1e-9);
    println!(
        "{}: {} messages, {duration_s:.3} s, {}, {compression}{}",
        path.display(),
        recording.messages.len(),
        human_size(bytes.len() as u64),
        if recording.truncated {
            " (file truncated: read up to the last complete chunk; `jetbench recover` rewrites it whole)"
        } else {
            ""
        }
    );
    println!("  written by  {}", library.as_deref().unwrap_or("unknown"));
    let base = recording.time_base();
    // Why a time is unknown, from what the file shows: no message at all, the clock origin cut
    // off with the end of the file, or a recording older than the clock origin.
    let unknown = if first.is_none() {
        "unknown (no message in the file)"
    } else if recording.truncated {
        "unknown (the clock origin was not in the part of the file that survived)"
    } else {
        "unknown (an older recording without its clock origin)"
    };
    let when = |log_time_ns: Option<u64>| {
        log_time_ns
            .and_then(|t| base.unix_ns(t))
            .and_then(jetbench_record::clock::format_local)
            .unwrap_or_else(|| unknown.into())
    };
    println!("  start {}", when(first));
    println!("  end   {}", when(last));

    let types: BTreeMap<&str, &str> =
        recording.messages.iter().map(|m| (m.topic.as_str(), m.schema_name.as_str())).collect();
    println!("  channels:");
    for c in recording.summary() {
        let ty = types.get(c.topic.as_str()).copied().unwrap_or("?");
        println!(
            "    {:<18} {:<30} {:>7} messages  {:>6.1} Hz  {} seq gaps",
            c.topic, ty, c.messages, c.rate_hz, c.seq_gaps
        );
    }
    let known: BTreeSet<String> = recording.summary().into_iter().map(|c| c.topic).collect();
    for (topic, count) in recording.counts() {
        if !known.contains(&topic) {
            let ty = types.get(topic.as_str()).copied().unwrap_or("?");
            println!("    {topic:<18} {ty:<30} {count:>7} messages  (not a bench channel of this version)");
        }
    }
    if schemas {
        if let Some(summary) = &summary {
            println!("  schemas:");
            for schema in summary.schemas.values() {
                println!("    {} ({}):", schema.name, schema.encoding);
                for line in String::from_utf8_lossy(&schema.data).lines() {
                    println!("      {line}");
                }
            }
        }
    }

    match RunMetadata::of(&recording) {
        None if recording.truncated => {
            println!("  run: no run metadata in the part of the file that survived (it may have been cut off)")
        }
        None => println!("  run: no run metadata (not written by `jetbench up` or `jetbench record`)"),
        Some(run) => {
            let config = run.config_toml.parse::<toml::Table>().ok();
            let key = |table: &str, key: &str| -> Option<String> {
                let value = config.as_ref()?.get(table)?.get(key)?;
                Some(value.as_str().map_or_else(|| value.to_string(), str::to_string))
            };
            println!("  run:");
            println!("    devices     {}", key("bench", "devices").unwrap_or_else(|| "sim (default)".into()));
            if key("bench", "devices").as_deref() != Some("bench") {
                println!("    plant       {}", key("plant", "model").unwrap_or_else(|| "default".into()));
            }
            println!("    model       {}", key("model", "model").unwrap_or_else(|| "default".into()));
            println!("    controller  {}", key("control", "controller").unwrap_or_else(|| "fbl (default)".into()));
            match &run.model_toml {
                Some(model) => {
                    let params = model
                        .lines()
                        .map(str::trim)
                        .filter(|l| !l.starts_with('#') && !l.starts_with('[') && l.contains('='))
                        .collect::<Vec<_>>()
                        .join(", ");
                    println!("    parameters  {params}");
                }
                None => println!("    parameters  not recorded (an older recording)"),
            }
            if full_config {
                println!("    config:");
                for line in run.config_toml.lines() {
                    println!("      {line}");
                }
            } else {
                println!("    config      `jetbench info {} --config` prints it whole", path.display());
            }
        }
    }
    Ok(())
}

/// The `library` of the file's header record: the software that wrote it.
fn header_library(bytes: &[u8]) -> Option<String> {
    let reader = mcap::read::LinearReader::new_with_options(bytes, mcap::read::Options::IgnoreEndMagic.into()).ok()?;
    for record in reader.take(1) {
        if let Ok(mcap::records::Record::Header(h)) = record {
            return Some(if h.profile.is_empty() {
                h.library
            } else {
                format!("{} (profile {})", h.library, h.profile)
            });
        }
    }
    None
}

fn human_size(bytes: u64) -> String {
    let b = bytes as f64;
    if b >= 1024.0 * 1024.0 {
        format!("{:.1} MiB ({bytes} bytes)", b / (1024.0 * 1024.0))
    } else if b >= 1024.0 {
        format!("{:.1} KiB ({bytes} bytes)", b / 1024.0)
    } else {
        format!("{bytes} bytes")
    }
}
