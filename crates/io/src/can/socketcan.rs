//! Kernel CAN (SocketCAN) through the `socketcan` crate: `can0` at the bench,
//! `vcan0` for tests where the kernel has vcan.
//!
//! A read or write error (the adapter unplugged, the interface taken down)
//! closes the socket; the next calls try to open it again, at most every
//! [`REOPEN_EVERY`], and report silence meanwhile, so the stack keeps running
//! and the sensor comes back by itself.
//!
//! ```no_run
//! use jetbench_io::can::socketcan::SocketCan;
//! use jetbench_io::can::source::CanTransport;
//! use std::time::Duration;
//!
//! # fn main() -> Result<(), jetbench_io::DeviceError> {
//! let mut can = SocketCan::open("can0")?;
//! if let Some(Ok(frame)) = can.recv(Duration::from_millis(30))? {
//!     println!("{:03x} {:02x?}", frame.id, frame.data());
//! }
//! # Ok(())
//! # }
//! ```

use std::io::ErrorKind;
use std::time::{Duration, Instant};

use ::socketcan::{CanSocket, EmbeddedFrame, Socket, StandardId};

use super::source::{CanTransport, LinkStats};
use super::{CanFrame, RejectKind, CAN_EFF_FLAG, CAN_ERR_FLAG, CAN_RTR_FLAG};
use crate::DeviceError;

/// How often a closed socket is tried again.
pub const REOPEN_EVERY: Duration = Duration::from_millis(100);

/// A raw CAN socket on one interface.
pub struct SocketCan {
    ifname: String,
    socket: Option<CanSocket>,
    last_attempt: Instant,
    /// Read/write errors that closed the socket.
    pub link_errors: u64,
    /// Times the socket was opened again after an error.
    pub reopens: u64,
}

/// Whether this kernel can open a raw CAN socket at all (`AF_CAN`), whatever
/// interfaces exist: `Err` with the socket error where it cannot.
pub fn probe_af_can() -> std::io::Result<()> {
    // SAFETY: socket(2) with constant arguments; the descriptor is closed at once.
    let fd = unsafe { libc::socket(libc::AF_CAN, libc::SOCK_RAW, libc::CAN_RAW) };
    if fd < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: `fd` is the descriptor just opened and owned here.
    unsafe { libc::close(fd) };
    Ok(())
}

/// The reason a CAN socket cannot be opened, with what to do about it at a
/// bench: the kernel's CAN modules, the adapter and its interface, the
/// bitrate, permissions. (The simulated bench needs none of this: it runs on
/// a userspace bus, `user:NAME`.)
fn open_error(ifname: &str, e: &std::io::Error) -> DeviceError {
    let up = up_command(ifname);
    let hint = match (e.raw_os_error(), probe_af_can()) {
        (_, Err(af)) => format!(
            ". This kernel has no SocketCAN (socket(AF_CAN) fails: {af}). At the bench: load the CAN modules and \
             your adapter's driver (`sudo modprobe can can_raw can_dev` and e.g. `gs_usb`, `peak_usb`, or `slcan` \
             for a serial adapter), plug the adapter in, then `{up}`. (Without kernel CAN only the simulated bench \
             runs, on a userspace bus: `user:NAME`.)"
        ),
        (Some(libc::ENODEV), Ok(())) if link_kind(ifname) == LinkKind::Virtual => format!(
            ". No interface `{ifname}`: a virtual CAN bus is made with `sudo modprobe vcan && sudo ip link add dev \
             {ifname} type vcan`; then `{up}`."
        ),
        (Some(libc::ENODEV), Ok(())) => format!(
            ". No interface `{ifname}`: is the adapter plugged in and its driver loaded? `ip -br link` lists the \
             interfaces (a USB adapter appears as can0; a serial slcan adapter after \
             `sudo slcand -o -s8 /dev/ttyACM0 {ifname}`); then `{up}`."
        ),
        (Some(libc::EPERM | libc::EACCES), Ok(())) => format!(
            ". Not permitted: this user may not open a raw CAN socket on `{ifname}` (a security policy, or a \
             container without the CAN family); run the bench as a user that may, or allow AF_CAN."
        ),
        (Some(libc::ENETDOWN), Ok(())) => format!(". `{ifname}` is down: `{up}`."),
        _ => String::new(),
    };
    DeviceError::Io { device: ifname.into(), reason: format!("cannot open the CAN socket: {e}{hint}") }
}

/// A warning for an interface that exists but is down (its socket opens, and
/// no frame will come until it is up), with the command that brings it up.
pub fn down_warning(ifname: &str) -> Option<String> {
    let state = std::fs::read_to_string(format!("/sys/class/net/{ifname}/operstate")).ok()?;
    (state.trim() == "down").then(|| format!("{ifname} is down: no frame will arrive until `{}`", up_command(ifname)))
}

/// What kind of CAN interface a name stands for, which decides how it is
/// brought up: only a controller on the wire has a bitrate to set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkKind {
    /// A CAN controller (a USB or PCI adapter): `type can bitrate ...`.
    Controller,
    /// A virtual bus (`vcan`): no wire, no bitrate.
    Virtual,
    /// A serial adapter through `slcand` (`slcan`): the bitrate is slcand's
    /// `-s` option (`-s8` for 1 Mbit/s), set when it is attached.
    Serial,
    /// An interface with no controller behind it (no kernel device: a `vcan`
    /// or an `slcand` interface under another name): no bitrate to set here.
    Unwired,
}

/// The kind of interface `ifname`: a `vcan*` or `slcan*` name, or, for an
/// interface that exists, whether a controller is behind it
/// (`/sys/class/net/IF/device` links an adapter's; a virtual bus and an
/// `slcand` interface have none); otherwise a controller.
pub fn link_kind(ifname: &str) -> LinkKind {
    if ifname.starts_with("vcan") {
        return LinkKind::Virtual;
    }
    if ifname.starts_with("slcan") {
        return LinkKind::Serial;
    }
    let sys = std::path::Path::new("/sys/class/net").join(ifname);
    if sys.exists() && !sys.join("device").exists() {
        return LinkKind::Unwired;
    }
    LinkKind::Controller
}

/// The command that brings `ifname` up, for its kind ([`link_kind`]).
pub fn up_command(ifname: &str) -> String {
    match link_kind(ifname) {
        LinkKind::Controller => {
            format!("sudo ip link set {ifname} up type can bitrate 1000000   # the sensor's bitrate")
        }
        LinkKind::Virtual => format!("sudo ip link set {ifname} up   # a virtual bus: no bitrate"),
        LinkKind::Serial => {
            format!("sudo ip link set {ifname} up   # the bitrate is slcand's -s option (-s8: 1 Mbit/s)")
        }
        LinkKind::Unwired => {
            format!("sudo ip link set {ifname} up   # no controller behind it: vcan, or slcand's -s sets the bitrate")
        }
    }
}

impl SocketCan {
    /// Opens `ifname`; fails if the interface or kernel CAN is missing.
    pub fn open(ifname: &str) -> Result<Self, DeviceError> {
        let socket = CanSocket::open(ifname).map_err(|e| open_error(ifname, &e))?;
        if let Some(warning) = down_warning(ifname) {
            tracing::warn!("{warning}");
        }
        Ok(SocketCan {
            ifname: ifname.into(),
            socket: Some(socket),
            last_attempt: Instant::now(),
            link_errors: 0,
            reopens: 0,
        })
    }

    /// True while the socket is open.
    pub fn is_open(&self) -> bool {
        self.socket.is_some()
    }

    fn fail(&mut self, what: &str, e: &std::io::Error) {
        self.link_errors += 1;
        if self.link_errors <= 5 || self.link_errors.is_multiple_of(100) {
            tracing::warn!("{}: {what} failed ({e}); reopening", self.ifname);
        }
        self.socket = None;
        self.last_attempt = Instant::now();
    }

    fn ensure_open(&mut self) -> bool {
        if self.socket.is_none() && self.last_attempt.elapsed() >= REOPEN_EVERY {
            self.last_attempt = Instant::now();
            if let Ok(s) = CanSocket::open(&self.ifname) {
                self.socket = Some(s);
                self.reopens += 1;
                if self.reopens <= 5 || self.reopens.is_multiple_of(100) {
                    tracing::info!("{}: socket open again (reopen {})", self.ifname, self.reopens);
                }
            }
        }
        self.socket.is_some()
    }
}

impl CanTransport for SocketCan {
    fn recv(&mut self, timeout: Duration) -> Result<Option<Result<CanFrame, RejectKind>>, DeviceError> {
        if !self.ensure_open() {
            // Down: report silence after the wait a frame would have had.
            std::thread::sleep(timeout.min(REOPEN_EVERY));
            return Ok(None);
        }
        let Some(socket) = &self.socket else { return Ok(None) };
        let result =
            socket.set_read_timeout(timeout.max(Duration::from_micros(100))).and_then(|()| socket.read_raw_frame());
        match result {
            Ok(raw) => {
                if raw.can_dlc > 8 {
                    return Ok(Some(Err(RejectKind::BadDlc)));
                }
                Ok(Some(Ok(CanFrame { id: raw.can_id, len: raw.can_dlc, data: raw.data })))
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted) => {
                Ok(None)
            }
            Err(e) => {
                self.fail("read", &e);
                Ok(None)
            }
        }
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), DeviceError> {
        if frame.id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG) != 0 {
            return Err(DeviceError::InvalidValue {
                device: self.ifname.clone(),
                reason: "only classic data frames are sent".into(),
            });
        }
        let id = u16::try_from(frame.id).ok().and_then(StandardId::new);
        let Some(out) = id.and_then(|id| ::socketcan::CanFrame::new(id, frame.data())) else {
            return Err(DeviceError::InvalidValue {
                device: self.ifname.clone(),
                reason: format!("bad frame {frame:?}"),
            });
        };
        if !self.ensure_open() {
            return Ok(()); // down: the frame is lost, as on a disconnected bus
        }
        if let Some(socket) = &self.socket {
            if let Err(e) = socket.write_frame(&out) {
                if e.kind() != ErrorKind::WouldBlock {
                    self.fail("write", &e);
                }
            }
        }
        Ok(())
    }

    fn reopen(&mut self) -> Result<(), DeviceError> {
        self.socket = None;
        let socket = CanSocket::open(&self.ifname).map_err(|e| open_error(&self.ifname, &e))?;
        self.socket = Some(socket);
        self.reopens += 1;
        Ok(())
    }

    fn describe(&self) -> String {
        format!("SocketCAN {}", self.ifname)
    }

    fn link_stats(&self) -> LinkStats {
        LinkStats { errors: self.link_errors, reopens: self.reopens }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_controller_is_told_to_set_a_bitrate() {
        assert_eq!(link_kind("vcan0"), LinkKind::Virtual);
        assert!(!up_command("vcan0").contains("bitrate 1000000"), "{}", up_command("vcan0"));
        assert_eq!(link_kind("slcan0"), LinkKind::Serial);
        assert!(up_command("slcan0").contains("-s8"), "{}", up_command("slcan0"));
        // An interface that exists with no device behind it (the loopback
        // here stands for a vcan or slcand interface named otherwise).
        assert_eq!(link_kind("lo"), LinkKind::Unwired);
        assert!(!up_command("lo").contains("type can"));
        // A name that is no interface here: an adapter to plug in.
        assert_eq!(link_kind("jbcan7"), LinkKind::Controller);
        assert!(up_command("jbcan7").contains("sudo ip link set jbcan7 up type can bitrate 1000000"));
    }
}
