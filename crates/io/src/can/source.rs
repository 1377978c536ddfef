//! The sensor behind [`ForceSource`] and its simulated end behind
//! [`ForceSink`], over any [`CanTransport`]: SocketCAN at the bench, the
//! [userspace bus](super::userspace) elsewhere. Both ends use the same
//! [`Codec`], so the simulated bench exercises exactly the bench's decoder.
//!
//! ```no_run
//! use jetbench_io::can::source::{CanForceSource, CanInterface};
//! use jetbench_io::can::{Codec, DEFAULT_BASE_ID};
//! use jetbench_io::ForceSource;
//! use std::time::Duration;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let interface: CanInterface = "user:simcan0".parse()?; // or "can0"
//! let mut sensor = CanForceSource::open(&interface, Codec::new(DEFAULT_BASE_ID)?)?;
//! if let Some(r) = sensor.read(Duration::from_millis(30))? {
//!     println!("Fx = {:.2} N, seq {}", r.force_n[0], r.counter);
//! }
//! println!("{}", sensor.counts());
//! # Ok(())
//! # }
//! ```

use std::fmt;
use std::str::FromStr;
use std::time::{Duration, Instant};

use super::socketcan::SocketCan;
use super::userspace::{self, UserspaceCan};
use super::{CanFrame, Codec, FrameDecoder, RejectCounts, RejectKind, SensorReading};
use crate::{DeviceError, ForceReading, ForceSink, ForceSource};

/// Carries classic CAN frames.
pub trait CanTransport: Send {
    /// Waits up to `timeout` for the next frame: `Ok(None)` on timeout,
    /// `Ok(Some(Err(kind)))` for something received that is not a frame.
    fn recv(&mut self, timeout: Duration) -> Result<Option<Result<CanFrame, RejectKind>>, DeviceError>;
    /// Sends one frame (the simulated sensor sends; sensing only receives).
    fn send(&mut self, frame: &CanFrame) -> Result<(), DeviceError>;
    /// Closes and opens the link again.
    fn reopen(&mut self) -> Result<(), DeviceError>;
    /// The link for messages, e.g. `SocketCAN can0`.
    fn describe(&self) -> String;
    /// The link's errors and reopenings so far (none for a link that cannot fail).
    fn link_stats(&self) -> LinkStats {
        LinkStats::default()
    }
}

/// How a link has fared: errors that closed it, and times it was opened again.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Errors that closed the link (the interface went down or away).
    pub errors: u64,
    /// Times the link was opened again after one.
    pub reopens: u64,
}

/// Where the sensor's frames travel, from `[sensor] can_interface`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CanInterface {
    /// A kernel interface, e.g. `can0`, `vcan0`.
    Kernel(String),
    /// A userspace bus, written `user:NAME`, in a bus namespace: service sets
    /// in different namespaces never hear each other.
    Userspace {
        /// The bus's name (after `user:`).
        name: String,
        /// The bus namespace it lives in.
        namespace: String,
    },
}

/// Why an interface name is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("CAN interface {name:?}: {reason}")]
pub struct InterfaceError {
    /// The name as written.
    pub name: String,
    /// What is wrong with it.
    pub reason: &'static str,
}

impl FromStr for CanInterface {
    type Err = InterfaceError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |reason| InterfaceError { name: s.into(), reason };
        if let Some(name) = s.strip_prefix("user:") {
            userspace::bus_dir(userspace::DEFAULT_NAMESPACE, name)
                .map_err(|_| bad("a userspace bus name has 1 to 32 letters, digits, _ or -"))?;
            return Ok(CanInterface::userspace(name, userspace::DEFAULT_NAMESPACE));
        }
        // Linux interface names: 1..=15 bytes, no '/', no whitespace.
        if s.is_empty()
            || s.len() > 15
            || s == "."
            || s == ".."
            || s.contains(['/', ':'])
            || s.contains(char::is_whitespace)
        {
            return Err(bad("a kernel interface name (e.g. can0) has 1 to 15 characters, no '/', ':' or spaces; a userspace bus is user:NAME"));
        }
        Ok(CanInterface::Kernel(s.into()))
    }
}

impl fmt::Display for CanInterface {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CanInterface::Kernel(name) => f.write_str(name),
            CanInterface::Userspace { name, .. } => write!(f, "user:{name}"),
        }
    }
}

impl CanInterface {
    /// Userspace bus `name` in bus namespace `namespace`.
    pub fn userspace(name: &str, namespace: &str) -> Self {
        CanInterface::Userspace { name: name.into(), namespace: namespace.into() }
    }

    /// The same interface, a userspace bus moved to bus namespace `namespace`
    /// (a kernel interface belongs to no namespace).
    pub fn in_namespace(self, namespace: &str) -> Self {
        match self {
            CanInterface::Userspace { name, .. } => CanInterface::userspace(&name, namespace),
            kernel => kernel,
        }
    }

    /// Opens the transport; `listen` to receive (a userspace sender need not).
    pub fn open(&self, listen: bool) -> Result<Box<dyn CanTransport>, DeviceError> {
        Ok(match self {
            CanInterface::Kernel(name) => Box::new(SocketCan::open(name)?),
            CanInterface::Userspace { name, namespace } if listen => Box::new(UserspaceCan::listen(namespace, name)?),
            CanInterface::Userspace { name, namespace } => Box::new(UserspaceCan::sender(namespace, name)?),
        })
    }
}

/// The force/torque sensor on CAN: frames in, paired readings out.
pub struct CanForceSource {
    transport: Box<dyn CanTransport>,
    decoder: FrameDecoder<()>,
    /// Receive errors after which the link was reopened.
    pub link_errors: u64,
}

impl CanForceSource {
    /// Reads `codec`'s frames from `transport`.
    pub fn new(transport: Box<dyn CanTransport>, codec: Codec) -> Self {
        CanForceSource { transport, decoder: FrameDecoder::new(codec), link_errors: 0 }
    }

    /// Opens `interface` for reading the sensor's frames.
    pub fn open(interface: &CanInterface, codec: Codec) -> Result<Self, DeviceError> {
        Ok(Self::new(interface.open(true)?, codec))
    }

    /// The next paired reading in counts, waiting up to `timeout`.
    pub fn read_counts(&mut self, timeout: Duration) -> Result<Option<SensorReading<()>>, DeviceError> {
        let deadline = Instant::now() + timeout;
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            match self.transport.recv(remaining) {
                Ok(Some(Ok(frame))) => {
                    if let Some(reading) = self.decoder.push(&frame, ()) {
                        return Ok(Some(reading));
                    }
                }
                Ok(Some(Err(kind))) => self.decoder.reject(kind),
                Ok(None) => return Ok(None),
                Err(e) => {
                    // Keep the stack running: report silence and reopen.
                    self.link_errors += 1;
                    if self.link_errors <= 5 || self.link_errors.is_multiple_of(100) {
                        tracing::warn!("{}: {e}; reopening", self.transport.describe());
                    }
                    if let Err(e) = self.transport.reopen() {
                        tracing::warn!("{}: reopen failed: {e}", self.transport.describe());
                    }
                    std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
                    return Ok(None);
                }
            }
        }
    }

    /// Frames rejected so far, by kind.
    pub fn counts(&self) -> &RejectCounts {
        self.decoder.counts()
    }

    /// The link's errors and reopenings, the transport's and this source's.
    pub fn link_stats(&self) -> LinkStats {
        let link = self.transport.link_stats();
        LinkStats { errors: link.errors + self.link_errors, reopens: link.reopens }
    }

    /// Frames (or datagrams) received and readings produced so far.
    pub fn frames_and_pairs(&self) -> (u64, u64) {
        (self.decoder.frames_in(), self.decoder.pairs_out())
    }
}

impl ForceSource for CanForceSource {
    fn read(&mut self, timeout: Duration) -> Result<Option<ForceReading>, DeviceError> {
        Ok(self.read_counts(timeout)?.map(|r| r.physical()))
    }

    fn rejected(&self) -> u64 {
        self.decoder.counts().frames_rejected()
    }

    fn reject_counts(&self) -> Option<RejectCounts> {
        Some(*self.decoder.counts())
    }

    fn describe(&self) -> String {
        format!("force/torque sensor (CAN base {:#x}) on {}", self.decoder.codec().base_id(), self.transport.describe())
    }
}

/// The simulated sensor's end: encodes readings into the two frames and sends them.
pub struct CanForceSink {
    transport: Box<dyn CanTransport>,
    codec: Codec,
}

impl CanForceSink {
    /// Writes `codec`'s frames to `transport`.
    pub fn new(transport: Box<dyn CanTransport>, codec: Codec) -> Self {
        CanForceSink { transport, codec }
    }

    /// Opens `interface` for sending the sensor's frames (the simulated sensor's end).
    pub fn open(interface: &CanInterface, codec: Codec) -> Result<Self, DeviceError> {
        Ok(Self::new(interface.open(false)?, codec))
    }

    /// Sends frames as they are (for tests that inject faults).
    pub fn send_raw(&mut self, frame: &CanFrame) -> Result<(), DeviceError> {
        self.transport.send(frame)
    }
}

impl ForceSink for CanForceSink {
    fn emit(&mut self, reading: &ForceReading, _sampled_ns: u64) -> Result<(), DeviceError> {
        let frames = self
            .codec
            .encode_reading(reading)
            .map_err(|e| DeviceError::InvalidValue { device: self.transport.describe(), reason: e.to_string() })?;
        for frame in &frames {
            self.transport.send(frame)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interface_names() {
        assert_eq!("can0".parse(), Ok(CanInterface::Kernel("can0".into())));
        assert_eq!("user:simcan0".parse(), Ok(CanInterface::userspace("simcan0", "default")));
        for bad in ["", "user:", "user:a/b", "a/b", "sixteen-chars-xx", "can 0"] {
            assert!(bad.parse::<CanInterface>().is_err(), "{bad:?}");
        }
        assert_eq!(CanInterface::userspace("x", "ns").to_string(), "user:x");
    }
}
