//! Taring the force sensor: its calibrated reading at rest, averaged, as the
//! `[sensor] tare` offsets of a bench config.
//!
//! At the bench the live sensor is read on its CAN interface; the engine must
//! be off and nothing may touch the stand. With the simulated bench "at rest"
//! means the engine off and zero load: a simulated sensor ([`RestingSensor`],
//! the bench's [`SimForceSensor`](crate::sim_bench::SimForceSensor) reading zero thrust) sends `[plant]
//! sensor_zero` plus sensor noise as real CAN frames over a private userspace
//! bus, and the offsets are read back through the same codec and calibration as
//! sensing uses.
//!
//! ```
//! use jetbench_stack::tare::with_tare;
//!
//! let text = "[sensor]\n# from the calibration sheet\nthrust_axis = \"x\"\ntare_n = [0.0, 0.0, 0.0]\n";
//! let new = with_tare(text, [1.25, 0.0, 0.0, 0.0, 0.0, 0.0]).unwrap();
//! assert!(new.contains("# from the calibration sheet"));
//! assert!(new.contains("tare = [1.25, 0.0, 0.0, 0.0, 0.0, 0.0]") && !new.contains("tare_n"));
//! ```

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use jetbench_io::calib::Tare;
use jetbench_io::can::source::{CanForceSink, CanForceSource, CanInterface};
use jetbench_io::can::RejectCounts;
use jetbench_io::{DeviceError, ForceSink, ForceSource};

use crate::config::{bus_namespace, BenchConfig, ConfigError, Devices};
use crate::runtime::clock::PERIOD;
use crate::sim_bench::SimError;

/// Why a tare failed.
#[derive(Debug, thiserror::Error)]
pub enum TareError {
    /// The `[sensor]` settings are unusable.
    #[error("{0}")]
    Setup(String),
    /// The CAN interface or the simulated sensor's bus.
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// The simulated sensor's noise.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The sensor said nothing.
    #[error("no readings from the sensor on {interface} for 1 s ({counts}): is it powered and is the interface up?")]
    Silent {
        /// The CAN interface listened on.
        interface: CanInterface,
        /// What the decoder rejected meanwhile.
        counts: RejectCounts,
    },
    /// Readings arrived, but none could be averaged.
    #[error("no readings to average: {0}")]
    NoReadings(String),
    /// The config file to write the tare into.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The config file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The config file is not TOML that can be edited in place.
    #[error("{path} is not TOML that can be edited: {message}")]
    Edit {
        /// The config file.
        path: String,
        /// The parser's words.
        message: String,
    },
    /// The edited config would not load; the file is left as it was.
    #[error("the config with the new tare does not load, so {path} was left unchanged: {source}")]
    Invalid {
        /// The config file.
        path: PathBuf,
        /// Why the edited config does not load.
        source: ConfigError,
    },
    /// The edited config could not be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The config file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

/// The axes of a tare, in the order of `[sensor] tare`.
pub const AXES: [&str; 6] = ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"];

/// What a tare found.
#[derive(Clone, Debug)]
pub struct TareResult {
    /// Mean calibrated reading at rest `[Fx, Fy, Fz, Tx, Ty, Tz]`, N and N·m.
    pub offsets: [f64; 6],
    /// Standard deviation of the readings per axis.
    pub std_dev: [f64; 6],
    /// Readings averaged.
    pub readings: u64,
    /// Frames the decoder rejected meanwhile.
    pub rejected: RejectCounts,
}

impl TareResult {
    /// The offsets as written: forces to 0.1 mN, torques to 0.01 mN·m.
    pub fn rounded(&self) -> [f64; 6] {
        std::array::from_fn(|i| {
            let scale = if i < 3 { 1e4 } else { 1e5 };
            (self.offsets[i] * scale).round() / scale
        })
    }
}

/// Where a tare listens: the sensor's interface, or a private userspace bus
/// with a simulated sensor at rest (`simulated`).
pub fn source_of(config: &BenchConfig) -> Result<(CanInterface, bool), TareError> {
    match config.bench.devices {
        Devices::Sim => Ok((CanInterface::userspace(&format!("tare{}", std::process::id()), &bus_namespace()), true)),
        Devices::Bench => {
            Ok((config.sensor.interface(config.bench.devices).map_err(|e| TareError::Setup(e.to_string()))?, false))
        }
    }
}

/// Averages the sensor at rest for `seconds`.
pub fn measure(config: &BenchConfig, seconds: f64) -> Result<TareResult, TareError> {
    let calibration = config.sensor.calibration().map_err(|e| TareError::Setup(format!("[sensor] {e}")))?;
    let codec = config.sensor.codec().map_err(|e| TareError::Setup(format!("[sensor] {e}")))?;
    let (interface, simulated) = source_of(config)?;
    // Listen before the simulated sensor starts, so no frame is missed.
    let mut source = CanForceSource::open(&interface, codec)?;
    let sender = if simulated { Some(RestingSensor::start(config, &interface)?) } else { None };
    let mut tare = Tare::new();
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    let mut last_reading = Instant::now();
    let result = loop {
        let now = Instant::now();
        if now >= end {
            break Ok(());
        }
        if last_reading.elapsed() > Duration::from_secs(1) {
            break Err(TareError::Silent { interface: interface.clone(), counts: *source.counts() });
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
    let rejected = *source.counts();
    drop(source);
    drop(sender);
    if simulated {
        if let CanInterface::Userspace { name, namespace } = &interface {
            let _ = jetbench_io::can::userspace::bus_dir(namespace, name).map(std::fs::remove_dir);
        }
    }
    result?;
    let offsets = tare.offsets().map_err(|e| TareError::NoReadings(e.to_string()))?;
    Ok(TareResult { offsets, std_dev: tare.std_dev(), readings: tare.samples(), rejected })
}

/// The simulated sensor at rest: zero thrust on the bench's sensor
/// (`[plant]` noise, seed and `sensor_zero`), sent as CAN frames every
/// period on a thread of its own until dropped.
pub struct RestingSensor {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl RestingSensor {
    /// Opens `interface` with the config's codec and starts collecting readings.
    pub fn start(config: &BenchConfig, interface: &CanInterface) -> Result<Self, TareError> {
        let codec = config.sensor.codec().map_err(|e| TareError::Setup(format!("[sensor] {e}")))?;
        let mut sink = CanForceSink::open(interface, codec)?;
        let mut sensor = config.plant.sensor()?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            let mut next = Instant::now();
            while !flag.load(Ordering::Relaxed) {
                if let Err(e) = sink.emit(&sensor.read(0.0), 0) {
                    tracing::error!("the simulated sensor at rest failed: {e}");
                    return;
                }
                next += PERIOD;
                std::thread::sleep(next.saturating_duration_since(Instant::now()));
            }
        });
        Ok(RestingSensor { stop, thread: Some(thread) })
    }
}

impl Drop for RestingSensor {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// `text` (a bench config) with `[sensor] tare` set to `offsets`, every other
/// line, comment and layout kept; an old `tare_n` goes (the two cannot be
/// given together), and a missing `[sensor]` table is added.
pub fn with_tare(text: &str, offsets: [f64; 6]) -> Result<String, TareError> {
    let edit_error = |message: String| TareError::Edit { path: "the config".into(), message };
    let mut doc: toml_edit::DocumentMut = text.parse().map_err(|e: toml_edit::TomlError| edit_error(e.to_string()))?;
    let sensor = doc
        .entry("sensor")
        .or_insert_with(|| toml_edit::Item::Table(toml_edit::Table::new()))
        .as_table_like_mut()
        .ok_or_else(|| edit_error("`sensor` is not a table".into()))?;
    sensor.remove("tare_n");
    let mut array: toml_edit::Array = offsets.iter().copied().collect();
    array.set_trailing_comma(false);
    match sensor.get_mut("tare").and_then(|item| item.as_value_mut()) {
        // Keeps the key's position and its comments.
        Some(value) => {
            let decor = value.decor().clone();
            *value = toml_edit::Value::Array(array);
            *value.decor_mut() = decor;
        }
        None => {
            sensor.insert("tare", toml_edit::value(array));
        }
    }
    Ok(doc.to_string())
}

/// Sets `[sensor] tare` in the config file at `path`, checked as the services
/// will read it before the file is replaced (atomically).
pub fn write_tare(path: &Path, offsets: [f64; 6]) -> Result<(), TareError> {
    let text = std::fs::read_to_string(path).map_err(|source| TareError::Read { path: path.into(), source })?;
    let new = with_tare(&text, offsets).map_err(|e| match e {
        TareError::Edit { message, .. } => TareError::Edit { path: path.display().to_string(), message },
        e => e,
    })?;
    BenchConfig::from_toml_str(&new, &path.display().to_string(), path.parent())
        .map_err(|source| TareError::Invalid { path: path.into(), source })?;
    let tmp = path.with_extension("toml.tare-tmp");
    std::fs::write(&tmp, &new).map_err(|source| TareError::Write { path: tmp.clone(), source })?;
    std::fs::rename(&tmp, path).map_err(|source| TareError::Write { path: path.into(), source })
}

#[cfg(test)]
mod tests {
    use super::*;

    const TARE: [f64; 6] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];

    fn tare_of(text: &str) -> toml::Value {
        let table: toml::Table = text.parse().expect("valid TOML");
        table["sensor"]["tare"].clone()
    }

    #[test]
    fn tare_replaces_or_adds_and_keeps_the_rest() {
        let old = "[bench]\ndevices = \"sim\"\n\n[sensor]\nthrust_axis = \"x\"\ntare_n = [0.0, 0.0, 0.0]\n\n[control]\nkp = 1.0\n";
        let new = with_tare(old, TARE).unwrap();
        assert!(new.starts_with("[bench]\ndevices = \"sim\"\n\n[sensor]\nthrust_axis = \"x\"\n"), "{new}");
        assert!(!new.contains("tare_n") && new.ends_with("[control]\nkp = 1.0\n"), "{new}");
        assert_eq!(tare_of(&new), toml::Value::Array(TARE.iter().map(|&v| v.into()).collect()));

        let multi = "[sensor]\ntare = [\n  0.0, 0.0, 0.0,\n  0.0, 0.0, 0.0,\n] # at rest\n[plant]\nx = 1\n";
        let new = with_tare(multi, TARE).unwrap();
        assert_eq!(new, "[sensor]\ntare = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0] # at rest\n[plant]\nx = 1\n");

        let added = with_tare("[plant]\nx = 1\n", TARE).unwrap();
        assert!(added.starts_with("[plant]\nx = 1\n") && added.contains("[sensor]\ntare = [1.0,"), "{added}");
        // Rows of a multi-line array are not table headers, and comments stay.
        let matrix = "[sensor]\ncalibration = [\n    [1.0, 0.0],\n    [0.0, 1.0], # row 2\n]\ntare = [0.0]\n[plant]\n";
        let new = with_tare(matrix, TARE).unwrap();
        assert!(new.contains("    [0.0, 1.0], # row 2\n]\ntare = [1.0, 0.0,"), "{new}");
    }

    #[test]
    fn a_config_that_is_not_toml_is_an_error_not_a_rewrite() {
        assert!(matches!(with_tare("[sensor\nx = ", TARE), Err(TareError::Edit { .. })));
        assert!(matches!(with_tare("sensor = 3\n", TARE), Err(TareError::Edit { .. })));
    }

    #[test]
    fn offsets_are_rounded_as_written() {
        let r = TareResult {
            offsets: [1.234_56, -0.000_04, 0.0, 0.012_345_6, 0.0, 0.0],
            std_dev: [0.0; 6],
            readings: 1,
            rejected: RejectCounts::default(),
        };
        assert_eq!(r.rounded(), [1.2346, -0.0, 0.0, 0.01235, 0.0, 0.0]);
    }
}
