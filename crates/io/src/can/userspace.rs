//! A CAN bus in userspace, for machines without kernel CAN: every frame is
//! the 16-byte `struct can_frame`, sent as one Unix datagram to every
//! listener of the bus, like a broadcast bus.
//!
//! A bus named `NAME` (`can_interface = "user:NAME"` in the bench config) is
//! a folder `$TMPDIR/jetbench-can/<bus namespace>/NAME/`; each listener binds
//! a socket there and every sender writes each frame to all sockets it finds
//! (re-listed every 20 ms, so listeners may come and go). A sender never
//! blocks: a listener whose queue is full loses the frame, as a CAN
//! controller whose receive buffer overflows does, and the sequence counter
//! shows it.
//!
//! ```no_run
//! use jetbench_io::can::userspace::UserspaceCan;
//! use jetbench_io::can::{source::CanTransport, CanFrame};
//! use std::time::Duration;
//!
//! # fn main() -> Result<(), jetbench_io::DeviceError> {
//! // Bus `example0` of bus namespace `default` (the caller's `JETBENCH_BUS`).
//! let mut rx = UserspaceCan::listen("default", "example0")?;
//! let mut tx = UserspaceCan::sender("default", "example0")?;
//! tx.send(&CanFrame::standard(0x101, &[0; 8]).unwrap())?;
//! let frame = rx.recv(Duration::from_millis(100))?;
//! # Ok(())
//! # }
//! ```

use std::io::ErrorKind;
use std::os::fd::AsRawFd;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use super::source::CanTransport;
use super::{CanFrame, RejectKind, CAN_FRAME_BYTES};
use crate::DeviceError;

/// How often a sender re-lists the bus's listeners.
const RESCAN: Duration = Duration::from_millis(20);

/// The bus namespace of a userspace bus given as `user:NAME` alone.
pub const DEFAULT_NAMESPACE: &str = "default";

/// The folder of userspace bus `name` in bus namespace `namespace`.
pub fn bus_dir(namespace: &str, name: &str) -> Result<PathBuf, DeviceError> {
    if name.is_empty() || name.len() > 32 || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
        return Err(DeviceError::InvalidValue {
            device: format!("user:{name}"),
            reason: "a userspace CAN bus name has 1 to 32 letters, digits, _ or -".into(),
        });
    }
    Ok(std::env::temp_dir().join("jetbench-can").join(namespace).join(name))
}

struct Listener {
    socket: UnixDatagram,
    path: PathBuf,
    /// The receive timeout the socket has now.
    timeout: Option<Duration>,
}

impl Drop for Listener {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// One end of a userspace CAN bus: a listener, a sender, or both.
pub struct UserspaceCan {
    name: String,
    dir: PathBuf,
    listener: Option<Listener>,
    sender: UnixDatagram,
    peers: Vec<PathBuf>,
    scanned: Option<Instant>,
    /// Frames a listener could not take (its queue was full).
    pub dropped: u64,
    /// Times the listening socket was bound again after it vanished.
    pub rebinds: u64,
}

fn io_error(name: &str, what: &str, e: std::io::Error) -> DeviceError {
    DeviceError::Io { device: format!("user:{name}"), reason: format!("{what}: {e}") }
}

impl UserspaceCan {
    /// Joins bus `name` of bus namespace `namespace` as a listener (and may also send).
    pub fn listen(namespace: &str, name: &str) -> Result<Self, DeviceError> {
        let mut bus = Self::sender(namespace, name)?;
        bus.bind()?;
        Ok(bus)
    }

    /// Joins bus `name` of bus namespace `namespace` to send only.
    pub fn sender(namespace: &str, name: &str) -> Result<Self, DeviceError> {
        let dir = bus_dir(namespace, name)?;
        std::fs::create_dir_all(&dir).map_err(|e| io_error(name, &format!("cannot create {}", dir.display()), e))?;
        let sender = UnixDatagram::unbound().map_err(|e| io_error(name, "cannot create a socket", e))?;
        sender.set_nonblocking(true).map_err(|e| io_error(name, "cannot make the socket non-blocking", e))?;
        Ok(UserspaceCan {
            name: name.into(),
            dir,
            listener: None,
            sender,
            peers: Vec::new(),
            scanned: None,
            dropped: 0,
            rebinds: 0,
        })
    }

    fn bind(&mut self) -> Result<(), DeviceError> {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        std::fs::create_dir_all(&self.dir)
            .map_err(|e| io_error(&self.name, &format!("cannot create {}", self.dir.display()), e))?;
        let path = self.dir.join(format!("{}-{}.sock", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)));
        let _ = std::fs::remove_file(&path);
        let socket = UnixDatagram::bind(&path)
            .map_err(|e| io_error(&self.name, &format!("cannot listen on {}", path.display()), e))?;
        self.listener = Some(Listener { socket, path, timeout: None });
        Ok(())
    }

    /// The folder of this bus.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn rescan(&mut self) {
        self.peers.clear();
        let own = self.listener.as_ref().map(|l| l.path.clone());
        if let Ok(entries) = std::fs::read_dir(&self.dir) {
            for entry in entries.flatten() {
                let path = entry.path();
                if path.extension().is_some_and(|e| e == "sock") && Some(&path) != own.as_ref() {
                    self.peers.push(path);
                }
            }
        }
        self.scanned = Some(Instant::now());
    }
}

impl CanTransport for UserspaceCan {
    fn recv(&mut self, timeout: Duration) -> Result<Option<Result<CanFrame, RejectKind>>, DeviceError> {
        let Some(listener) = self.listener.as_mut() else {
            return Err(DeviceError::Io { device: self.describe(), reason: "opened to send only".into() });
        };
        // Larger than a frame, so an oversized datagram is seen as such.
        let mut buf = [0u8; 4 * CAN_FRAME_BYTES];
        // A frame already queued (the second of a pair, a burst) is taken
        // with one system call; only an empty queue is waited on.
        // SAFETY: receives at most `buf.len()` bytes into a live buffer.
        let n =
            unsafe { libc::recv(listener.socket.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len(), libc::MSG_DONTWAIT) };
        if let Ok(n) = usize::try_from(n) {
            return Ok(Some(CanFrame::from_bytes(&buf[..n])));
        }
        // A zero timeout means "block forever" to the socket.
        let timeout = timeout.max(Duration::from_micros(100));
        // A wait asks for its caller's whole deadline, nearly the same every
        // time: the socket's timeout is changed only when it is off by more
        // than TIMEOUT_SLACK.
        if listener.timeout.is_none_or(|set| set.abs_diff(timeout) > TIMEOUT_SLACK) {
            listener.socket.set_read_timeout(Some(timeout)).map_err(|e| io_error(&self.name, "set timeout", e))?;
            listener.timeout = Some(timeout);
        }
        match listener.socket.recv(&mut buf) {
            Ok(n) => Ok(Some(CanFrame::from_bytes(&buf[..n]))),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted) => {
                // Quiet: check our socket is still there (a cleaned /tmp, a
                // restarted bus); if not, listen again.
                if !listener.path.exists() {
                    self.reopen()?;
                }
                Ok(None)
            }
            Err(e) => Err(io_error(&self.name, "receive", e)),
        }
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), DeviceError> {
        if self.scanned.is_none_or(|t| t.elapsed() >= RESCAN) {
            self.rescan();
        }
        let bytes = frame.to_bytes();
        let mut gone = Vec::new();
        for (i, peer) in self.peers.iter().enumerate() {
            match send_with_patience(&self.sender, &bytes, peer) {
                Ok(_) => {}
                Err(e) if e.kind() == ErrorKind::WouldBlock => self.dropped += 1,
                Err(e) if e.kind() == ErrorKind::ConnectionRefused => {
                    // Nobody is bound there: the file of a listener that died.
                    let _ = std::fs::remove_file(peer);
                    gone.push(i);
                }
                Err(_) => gone.push(i),
            }
        }
        for i in gone.into_iter().rev() {
            self.peers.swap_remove(i);
        }
        Ok(())
    }

    fn reopen(&mut self) -> Result<(), DeviceError> {
        if self.listener.take().is_some() {
            self.rebinds += 1;
            self.bind()?;
        }
        self.scanned = None;
        Ok(())
    }

    fn describe(&self) -> String {
        format!("userspace CAN bus user:{} ({})", self.name, self.dir.display())
    }
}

/// Sends one datagram, giving a full receive queue up to [`SEND_PATIENCE`] to drain.
/// A Unix datagram queue holds only `net.unix.max_dgram_qlen` (10 by default) frames,
/// so the catch-up burst after a scheduling hiccup of the sender would otherwise
/// overflow it and lose frames a kernel CAN socket's buffer would have kept.
fn send_with_patience(socket: &UnixDatagram, bytes: &[u8], peer: &Path) -> std::io::Result<usize> {
    let started = Instant::now();
    loop {
        match socket.send_to(bytes, peer) {
            Err(e) if e.kind() == ErrorKind::WouldBlock && started.elapsed() < SEND_PATIENCE => {
                std::thread::sleep(Duration::from_micros(100));
            }
            other => return other,
        }
    }
}

/// How far the socket's receive timeout may be from what a wait asks for
/// before it is set again: a wait for a frame ends at most this late or early.
const TIMEOUT_SLACK: Duration = Duration::from_millis(1);

/// How long a frame waits for a full receive queue before it is counted as dropped.
const SEND_PATIENCE: Duration = Duration::from_millis(2);
