//! `jetbench tare`: the sensor's calibrated reading at rest, averaged, as
//! `[sensor] tare` offsets ([`jetbench_stack::tare`]).
//!
//! Example: `jetbench tare --config bench.toml --seconds 2 --write`

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use jetbench_stack::config::BenchConfig;
use jetbench_stack::tare::{measure, source_of, write_tare, AXES};

#[derive(clap::Args)]
pub struct TareArgs {
    /// Bench config (default: the built-in simulated bench).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// How long to average, s.
    #[arg(long, default_value_t = 2.0)]
    seconds: f64,
    /// Write the offsets into the config's [sensor] table (needs --config).
    #[arg(long)]
    write: bool,
}

pub fn run(args: TareArgs) -> anyhow::Result<ExitCode> {
    if !(args.seconds.is_finite() && (0.1..=600.0).contains(&args.seconds)) {
        bail!("--seconds {} must be within 0.1..600", args.seconds);
    }
    if args.write && args.config.is_none() {
        bail!("--write needs --config FILE (the built-in config cannot be changed)");
    }
    let config = BenchConfig::load_or_default(args.config.as_deref())?;
    match source_of(&config)? {
        (bus, true) => eprintln!(
            "tare: simulated bench: the sensor at rest (engine off, zero load) is simulated here and sends \
             [plant] sensor_zero = {:?} plus noise as CAN frames on {bus}",
            config.plant.sensor_zero
        ),
        (interface, false) => {
            eprintln!("tare: reading the sensor on {interface}; the engine must be off and the stand untouched")
        }
    }
    let tare = measure(&config, args.seconds)?;
    let (sd, n) = (tare.std_dev, tare.readings);
    eprintln!("tare: {n} readings in {:.1} s; rejected: {}", args.seconds, tare.rejected);
    eprintln!("  axis   offset      std-dev   ± (std error of the mean)");
    for (i, name) in AXES.iter().enumerate() {
        eprintln!("  {name:<6} {:>+10.4} {:>10.4}   ± {:.4}", tare.offsets[i], sd[i], sd[i] / (n as f64).sqrt());
    }
    let o = tare.offsets;
    println!("tare = [{:.4}, {:.4}, {:.4}, {:.5}, {:.5}, {:.5}]", o[0], o[1], o[2], o[3], o[4], o[5]);
    if let (true, Some(path)) = (args.write, &args.config) {
        write_tare(path, tare.rounded())?;
        eprintln!("tare: written to [sensor] in {}", path.display());
    }
    Ok(ExitCode::SUCCESS)
}
