//! Bench devices behind traits, with the codecs and drivers of the real ones.
//!
//! The services talk to a [`ForceSource`] (the force/torque sensor on CAN) and a
//! [`ThrottleOutput`] (the throttle board on a serial port); the simulated bench
//! plays the sensor through a [`ForceSink`] sending the same CAN frames, and the
//! throttle board and the ECU on pseudo-terminals ([`emulate`]), so the code that
//! runs at the bench runs here too.
//!
//! ```no_run
//! use jetbench_io::can::source::{CanForceSource, CanInterface};
//! use jetbench_io::can::{Codec, DEFAULT_BASE_ID};
//! use jetbench_io::ForceSource;
//! use std::time::Duration;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let mut sensor = CanForceSource::open(&"can0".parse::<CanInterface>()?, Codec::new(DEFAULT_BASE_ID)?)?;
//! if let Some(reading) = sensor.read(Duration::from_millis(30))? {
//!     println!("Fx = {} N", reading.force_n[0]);
//! }
//! # Ok(())
//! # }
//! ```
#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod board;
pub mod calib;
pub mod can;
pub mod candump;
pub mod ecu;
pub mod emulate;
pub mod serial;

use std::time::Duration;

/// One force/torque reading as the sensor reports it, before calibration.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ForceReading {
    /// Force on x, y, z, N.
    pub force_n: [f64; 3],
    /// Torque about x, y, z, N·m.
    pub torque_nm: [f64; 3],
    /// The sensor's wrapping frame counter.
    pub counter: u32,
    /// Status bits (see `jetbench_msgs::sensor_status`).
    pub status: u32,
}

/// Why a device operation failed.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// The device could not be opened, read or written (a missing port, a
    /// disconnected adapter, an interface that is down).
    #[error("device {device}: {reason}")]
    Io {
        /// The device, e.g. `throttle board on /dev/ttyUSB0`.
        device: String,
        /// What failed.
        reason: String,
    },
    /// A value the device cannot take (a throttle out of range, a poll rate of 0).
    #[error("device {device} rejected a value: {reason}")]
    InvalidValue {
        /// The device, e.g. `throttle board on /dev/ttyUSB0`.
        device: String,
        /// The value and why.
        reason: String,
    },
}

/// The force/torque sensor, read by the sensing service.
pub trait ForceSource {
    /// Waits up to `timeout` for the next reading; `Ok(None)` on timeout.
    fn read(&mut self, timeout: Duration) -> Result<Option<ForceReading>, DeviceError>;
    /// Rejected or lost frames so far.
    fn rejected(&self) -> u64 {
        0
    }
    /// Rejections by kind, where the source decodes frames itself.
    fn reject_counts(&self) -> Option<can::RejectCounts> {
        None
    }
    /// A short description for logs, e.g. `sim bus` or `can0`.
    fn describe(&self) -> String;
}

/// A device's acknowledgement of a throttle command.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Acknowledgement {
    /// The command's sequence number as sent.
    pub seq: u64,
    /// The throttle the device reports it outputs after the command, %.
    pub applied_pct: f64,
    /// From sending the command to receiving its acknowledgement, ns.
    pub round_trip_ns: u64,
    /// The device is armed (drives the engine).
    pub armed: bool,
    /// The device idles by its own watchdog.
    pub idle_fallback: bool,
}

/// The throttle board, driven by the actuation service.
pub trait ThrottleOutput {
    /// Sends a set-throttle command.
    fn write(&mut self, throttle_pct: f64) -> Result<(), DeviceError>;
    /// Round trip of the last acknowledged command, ns, where the device
    /// acknowledges; `None` otherwise.
    fn round_trip_ns(&self) -> Option<u64> {
        None
    }
    /// The newest acknowledgement, where the device acknowledges; it is the
    /// last write's when [`unacked_writes`](Self::unacked_writes) is 0.
    fn acknowledged(&self) -> Option<Acknowledgement> {
        None
    }
    /// When the last write's frame was handed to the device (the monotonic clock
    /// the driver was given, ns); `None` when the last write sent nothing.
    fn written_ns(&self) -> Option<u64> {
        None
    }
    /// Consecutive writes without an acknowledgement (0 for devices that do not acknowledge).
    fn unacked_writes(&self) -> u32 {
        0
    }
    /// Consecutive writes during which nothing valid came back from the
    /// device (no late acknowledgement, no status either): it is silent.
    fn silent_writes(&self) -> u32 {
        0
    }
    /// Puts the device in its safe state at shutdown (the board disarms).
    fn stop(&mut self) {}
    /// The device for messages, e.g. `throttle board on /dev/ttyUSB0 at 115200 baud`.
    fn describe(&self) -> String;
}

/// The simulated sensor's output side: emits readings to sensing.
pub trait ForceSink {
    /// Sends one reading, taken at `sampled_ns` on the bench clock, as the real
    /// sensor would (two CAN frames).
    fn emit(&mut self, reading: &ForceReading, sampled_ns: u64) -> Result<(), DeviceError>;
}
