//! `jetbench tare`: the sensor's calibrated reading at rest, averaged, as
//! `[sensor] tare` offsets.
//!
//! At the bench (`[sensor] can_interface = "can0"`) it listens to the live
//! sensor next to a running stack or alone; the engine must be off and
//! nothing may touch the stand. With the simulated bench (`[bench] devices =
//! "sim"`) "at rest" means the engine off and zero load: a simulated sensor,
//! run in this process for the purpose, sends `[plant] sensor_zero` plus
//! sensor noise as real CAN frames over a private userspace bus, and the
//! offsets are read back through the same codec and calibration as sensing
//! uses. (A running `jetbench up --sim` is not at rest: its engine idles.)
//!
//! Example: `jetbench tare --config bench.toml --seconds 2 --write`

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use jetbench_io::calib::Tare;
use jetbench_io::can::source::{CanForceSink, CanForceSource, CanInterface};
use jetbench_io::{ForceReading, ForceSink, ForceSource};
use jetbench_stack::config::{BenchConfig, Devices};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

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

/// Noise on the axes that do not carry thrust, as the simulated bench has it, N.
const SIM_CROSS_NOISE_N: f64 = 0.3;

/// The simulated sensor at rest: zero load, `zero` offset, noise; sends
/// frames at 100 Hz until `stop`.
fn spawn_sim_sensor(
    config: &BenchConfig,
    interface: CanInterface,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<std::thread::JoinHandle<()>> {
    let codec = config.sensor.codec()?;
    let mut sink = CanForceSink::open(&interface, codec)?;
    let zero = config.plant.sensor_zero;
    let thrust_noise = Normal::new(0.0, config.plant.noise_var_n2.sqrt())?;
    let cross_noise = Normal::new(0.0, SIM_CROSS_NOISE_N)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(config.plant.seed);
    Ok(std::thread::spawn(move || {
        let mut counter = 0u32;
        let mut next = Instant::now();
        while !stop.load(Ordering::Relaxed) {
            let mut r = ForceReading { counter, ..ForceReading::default() };
            r.force_n = [thrust_noise.sample(&mut rng), cross_noise.sample(&mut rng), cross_noise.sample(&mut rng)];
            r.torque_nm = std::array::from_fn(|_| 0.01 * cross_noise.sample(&mut rng));
            for i in 0..3 {
                r.force_n[i] += zero[i];
                r.torque_nm[i] += zero[3 + i];
            }
            if let Err(e) = sink.emit(&r, 0) {
                eprintln!("tare: the simulated sensor failed: {e}");
                return;
            }
            counter = (counter + 1) & 0xff;
            next += Duration::from_millis(10);
            std::thread::sleep(next.saturating_duration_since(Instant::now()));
        }
    }))
}

/// Bracket depth change of a TOML line, ignoring a trailing comment.
fn depth_change(line: &str) -> i64 {
    let code = line.split('#').next().unwrap_or("");
    code.matches('[').count() as i64 - code.matches(']').count() as i64
}

/// Replaces or adds `tare = [...]` in the `[sensor]` table of a config text
/// (a `tare_n` line is replaced, since the two cannot be given together).
pub fn with_tare(text: &str, line: &str) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut in_sensor = false;
    let mut done = false;
    let mut had_sensor = false;
    // Inside a multi-line array a line may start with '[' without being a table header.
    let mut depth = 0i64;
    let mut lines = text.lines();
    while let Some(l) = lines.next() {
        let t = l.trim_start();
        if depth == 0 && t.starts_with('[') {
            if in_sensor && !done {
                out.push(line.to_string());
                done = true;
            }
            in_sensor = t.starts_with("[sensor]");
            had_sensor |= in_sensor;
        } else if depth == 0
            && in_sensor
            && !done
            && (t.starts_with("tare ") || t.starts_with("tare=") || t.starts_with("tare_n"))
        {
            // Drop the old value, all of its lines.
            let mut d = depth_change(l);
            while d > 0 {
                let Some(next) = lines.next() else { break };
                d += depth_change(next);
            }
            out.push(line.to_string());
            done = true;
            continue;
        } else {
            depth = (depth + depth_change(l)).max(0);
        }
        out.push(l.to_string());
    }
    if in_sensor && !done {
        out.push(line.to_string());
        done = true;
    }
    if !had_sensor && !done {
        out.push(String::new());
        out.push("[sensor]".into());
        out.push(line.to_string());
    }
    let mut s = out.join("\n");
    s.push('\n');
    s
}

pub fn run(args: TareArgs) -> anyhow::Result<ExitCode> {
    if !(args.seconds.is_finite() && (0.1..=600.0).contains(&args.seconds)) {
        bail!("--seconds {} must be within 0.1..600", args.seconds);
    }
    if args.write && args.config.is_none() {
        bail!("--write needs --config FILE (the built-in config cannot be changed)");
    }
    let config = BenchConfig::load_or_default(args.config.as_deref())?;
    let calibration = config.sensor.calibration()?;
    let codec = config.sensor.codec()?;
    let stop = Arc::new(AtomicBool::new(false));
    let (interface, sim) = match config.bench.devices {
        Devices::Sim => {
            let bus = CanInterface::Userspace(format!("tare{}", std::process::id()));
            eprintln!(
                "tare: simulated bench: the sensor at rest (engine off, zero load) is simulated here and sends \
                 [plant] sensor_zero = {:?} plus noise as CAN frames on {bus}",
                config.plant.sensor_zero
            );
            (bus, true)
        }
        #[allow(unreachable_patterns)]
        _ => {
            let interface = config.sensor.interface(config.bench.devices)?;
            eprintln!("tare: reading the sensor on {interface}; the engine must be off and the stand untouched");
            (interface, false)
        }
    };
    // Listen before the simulated sensor starts, so no frame is missed.
    let mut source = CanForceSource::open(&interface, codec)?;
    let sender = if sim { Some(spawn_sim_sensor(&config, interface.clone(), Arc::clone(&stop))?) } else { None };

    let mut tare = Tare::new();
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(args.seconds);
    let mut last_reading = Instant::now();
    let result = loop {
        let now = Instant::now();
        if now >= end {
            break Ok(());
        }
        if last_reading.elapsed() > Duration::from_secs(1) {
            break Err(anyhow::anyhow!(
                "no readings from the sensor on {interface} for 1 s ({}): is it powered and is the interface up?",
                source.counts()
            ));
        }
        match source.read(Duration::from_millis(100).min(end - now)) {
            Ok(Some(r)) => {
                tare.add(&calibration.calibrated_untared(&r));
                last_reading = Instant::now();
            }
            Ok(None) => {}
            Err(e) => break Err(e.into()),
        }
    };
    stop.store(true, Ordering::Relaxed);
    let counts = *source.counts();
    drop(source);
    if let Some(handle) = sender {
        let _ = handle.join();
    }
    if sim {
        if let CanInterface::Userspace(name) = &interface {
            let _ = jetbench_io::can::userspace::bus_dir(name).map(std::fs::remove_dir);
        }
    }
    result?;
    let offsets = tare.offsets()?;
    let sd = tare.std_dev();
    let n = tare.samples();
    eprintln!("tare: {n} readings in {:.1} s; rejected: {counts}", args.seconds);
    eprintln!("  axis   offset      std-dev   ± (std error of the mean)");
    for (i, name) in ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"].iter().enumerate() {
        eprintln!("  {name:<6} {:>+10.4} {:>10.4}   ± {:.4}", offsets[i], sd[i], sd[i] / (n as f64).sqrt());
    }
    let line = format!(
        "tare = [{:.4}, {:.4}, {:.4}, {:.5}, {:.5}, {:.5}]",
        offsets[0], offsets[1], offsets[2], offsets[3], offsets[4], offsets[5]
    );
    println!("{line}");
    if args.write {
        if let Some(path) = &args.config {
            write_tare(path, &line)?;
            eprintln!("tare: written to [sensor] in {}", path.display());
        }
    }
    Ok(ExitCode::SUCCESS)
}

fn write_tare(path: &Path, line: &str) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let new = with_tare(&text, line);
    // Check the result as the services will read it before replacing the file.
    BenchConfig::from_toml_str(&new, &path.display().to_string(), path.parent())
        .context("the config with the new tare does not load; file left unchanged")?;
    let tmp = path.with_extension("toml.tare-tmp");
    std::fs::write(&tmp, &new).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot replace {}", path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::with_tare;

    #[test]
    fn tare_line_replaces_or_adds() {
        let line = "tare = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]";
        let old = "[bench]\ndevices = \"sim\"\n\n[sensor]\nthrust_axis = \"x\"\ntare_n = [0.0, 0.0, 0.0]\n\n[control]\nkp = 1.0\n";
        let new = with_tare(old, line);
        assert!(new.contains("[sensor]\nthrust_axis = \"x\"\ntare = [1.0,"), "{new}");
        assert!(!new.contains("tare_n"));
        let multi = "[sensor]\ntare = [\n  0.0, 0.0, 0.0,\n  0.0, 0.0, 0.0,\n]\n[plant]\nx = 1\n";
        assert_eq!(with_tare(multi, line), format!("[sensor]\n{line}\n[plant]\nx = 1\n"));
        assert_eq!(with_tare("[plant]\nx = 1\n", line), format!("[plant]\nx = 1\n\n[sensor]\n{line}\n"));
        assert_eq!(with_tare("[sensor]\n", line), format!("[sensor]\n{line}\n"));
        // Rows of a multi-line array are not table headers.
        let matrix = "[sensor]\ncalibration = [\n    [1.0, 0.0],\n    [0.0, 1.0], # row 2\n]\ntare = [0.0]\n[plant]\n";
        assert_eq!(
            with_tare(matrix, line),
            format!("[sensor]\ncalibration = [\n    [1.0, 0.0],\n    [0.0, 1.0], # row 2\n]\n{line}\n[plant]\n")
        );
    }
}
