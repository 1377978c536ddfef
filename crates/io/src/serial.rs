//! Serial drivers: the throttle board and the ECU poller.
//!
//! Both open their port by path (`/dev/ttyUSB0` at the bench, the link to a
//! pseudo-terminal that sim-bench creates here) and survive the device going
//! away: a silent device is reported within [`SILENT_AFTER`] cycles, its port
//! is closed, and it is reopened by path until it answers again, without
//! restarting anything.
//!
//! ```no_run
//! use jetbench_io::serial::{EcuPoller, ThrottleBoard};
//! use jetbench_io::ThrottleOutput;
//!
//! fn clock() -> u64 {
//!     std::time::UNIX_EPOCH.elapsed().map_or(0, |d| d.as_nanos() as u64)
//! }
//! let mut board = ThrottleBoard::new("/dev/ttyUSB0", 115_200, clock);
//! board.write(42.5).unwrap(); // opens, arms, sends, waits up to ACK_WAIT for the ack
//! if let Some(ack) = board.acknowledged() {
//!     println!("board applies {} % ({} ns round trip)", ack.applied_pct, ack.round_trip_ns);
//! }
//! let ecu = EcuPoller::spawn("/dev/ttyUSB1", 9600, 20.0, clock).unwrap();
//! for telemetry in ecu.try_iter() {
//!     println!("{} rpm, EGT {} °C", telemetry.rpm, telemetry.egt_c);
//! }
//! ```

use std::io::{ErrorKind, Read, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TrySendError};
use jetbench_msgs::{ecu_flags, EcuTelemetry};
use serialport::{SerialPort, TTYPort};

use crate::board::{self, board_flags, BoardStatus, Deframer, Frame, Throttle};
use crate::ecu::{self, EcuCounters, EcuReply, LineDecoder, PcCommand};
use crate::{Acknowledgement, DeviceError, ThrottleOutput};

/// How long a write waits for the board's acknowledgement before the cycle
/// goes on without it (a late ack is still read, and counted, next cycle).
pub const ACK_WAIT: Duration = Duration::from_millis(4);
/// How long [`ThrottleOutput::stop`] keeps sending the disarm until it is
/// acknowledged: as long as the board's own watchdog takes to idle the engine.
pub const DISARM_WAIT: Duration = Duration::from_nanos(board::WATCHDOG_NS);
/// Cycles (board writes, ECU polls) without an answer after which the
/// device is reported silent and its port is reopened.
pub const SILENT_AFTER: u32 = 3;
/// While a board is unreachable, its port is reopened every this many writes.
pub const REOPEN_EVERY: u32 = 5;
use crate::emulate::PARTIAL_FRAME_NS;

/// Opens a serial port by path, 8N1, no flow control, exclusive.
pub fn open_port(path: &Path, baud: u32) -> Result<TTYPort, serialport::Error> {
    serialport::new(path.to_string_lossy(), baud)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .timeout(ACK_WAIT)
        .open_native()
}

/// Sets `O_NONBLOCK` on `fd`.
fn set_nonblocking(fd: std::os::fd::RawFd) -> std::io::Result<()> {
    // SAFETY: fcntl on a descriptor the caller holds open.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    // SAFETY: as above.
    if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Writes a whole frame to a non-blocking port. One `write(2)` takes it
/// when the kernel has room, as it has but for a stalled line; only then does
/// the port's own write (which polls for room, up to its timeout) finish it.
/// (That write polls before every frame: a second system call per command on
/// the control path.)
fn write_frame(port: &mut TTYPort, bytes: &[u8]) -> std::io::Result<()> {
    // SAFETY: writes at most `bytes.len()` bytes from a live buffer.
    let n = unsafe { libc::write(port.as_raw_fd(), bytes.as_ptr().cast(), bytes.len()) };
    let done = match usize::try_from(n) {
        Ok(n) if n == bytes.len() => return Ok(()),
        Ok(n) => n,
        Err(_) => {
            let e = std::io::Error::last_os_error();
            if !matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::Interrupted) {
                return Err(e);
            }
            0
        }
    };
    port.write_all(&bytes[done..])
}

/// Waits up to `timeout_ns` for `fd` to have bytes to read (or to report an
/// error or hang-up, which the following read then returns).
fn wait_readable(fd: std::os::fd::RawFd, timeout_ns: u64) -> std::io::Result<bool> {
    let mut pollfd = libc::pollfd { fd, events: libc::POLLIN, revents: 0 };
    let timeout = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: one valid pollfd, a valid timespec, no signal mask.
    let n = unsafe { libc::ppoll(&mut pollfd, 1, &timeout, std::ptr::null()) };
    match n {
        n if n > 0 => Ok(true),
        0 => Ok(false),
        _ => {
            let e = std::io::Error::last_os_error();
            if e.kind() == ErrorKind::Interrupted {
                Ok(false)
            } else {
                Err(e)
            }
        }
    }
}

/// The throttle board driver. Implements [`ThrottleOutput`]: every
/// [`write`](ThrottleOutput::write) sends one set-throttle frame and waits at
/// most [`ACK_WAIT`] for its acknowledgement.
pub struct ThrottleBoard {
    path: PathBuf,
    baud: u32,
    clock: fn() -> u64,
    ack_wait: Duration,
    port: Option<TTYPort>,
    deframer: Deframer,
    next_seq: u16,
    need_arm: bool,
    last_ack: Option<Acknowledgement>,
    status: Option<BoardStatus>,
    /// Send times of the latest commands, to time acknowledgements that come late.
    sent: [(u16, u64); 8],
    heard: bool,
    unacked: u32,
    silent: u32,
    writes_down: u32,
    link_error: Option<String>,
    opens: u64,
    late_acks: u64,
    last_rx_ns: u64,
    /// When the last set-throttle frame left, if the last write sent one.
    written_ns: Option<u64>,
    /// Reused buffers of the per-cycle path (it allocates nothing once they have grown).
    tx: Vec<u8>,
    rx_frames: Vec<Frame>,
}

impl ThrottleBoard {
    /// A driver for the board at `path`; the port is opened on the first write.
    pub fn new(path: impl Into<PathBuf>, baud: u32, clock: fn() -> u64) -> Self {
        ThrottleBoard {
            path: path.into(),
            baud,
            clock,
            ack_wait: ACK_WAIT,
            port: None,
            deframer: Deframer::new(),
            next_seq: 0,
            need_arm: true,
            last_ack: None,
            status: None,
            sent: [(u16::MAX, 0); 8],
            heard: false,
            unacked: 0,
            silent: 0,
            writes_down: 0,
            link_error: None,
            opens: 0,
            late_acks: 0,
            last_rx_ns: 0,
            written_ns: None,
            tx: Vec::with_capacity(board::MAX_FRAME),
            rx_frames: Vec::with_capacity(16),
        }
    }

    /// Changes the bounded wait for acknowledgements.
    pub fn with_ack_wait(mut self, wait: Duration) -> Self {
        self.ack_wait = wait;
        self
    }

    /// Opens the port now and arms the board.
    pub fn connect(&mut self) -> Result<(), DeviceError> {
        self.port = None;
        let port = open_port(&self.path, self.baud).map_err(|e| self.io_error(e.to_string()))?;
        // Bytes from before this open (a previous session's acks) are not ours.
        let _ = port.clear(serialport::ClearBuffer::All);
        // Frames are written straight to the descriptor (see `write_frame`),
        // which must then never block the control loop.
        set_nonblocking(port.as_raw_fd())
            .map_err(|e| self.io_error(format!("cannot make the port non-blocking: {e}")))?;
        self.port = Some(port);
        self.opens += 1;
        self.need_arm = true;
        self.link_error = None;
        self.arm()
    }

    fn arm(&mut self) -> Result<(), DeviceError> {
        let seq = self.take_seq();
        self.need_arm = false;
        if self.send(&Frame::Arm { seq }) {
            self.wait_for_ack(seq, (self.clock)());
        }
        Ok(())
    }

    fn io_error(&self, reason: String) -> DeviceError {
        DeviceError::Io { device: self.describe(), reason }
    }

    fn take_seq(&mut self) -> u16 {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        seq
    }

    fn sent_at(&self, seq: u16) -> Option<u64> {
        self.sent.iter().find(|(s, _)| *s == seq).map(|(_, t)| *t)
    }

    /// Sends a frame; on failure the link is dropped (and reopened later).
    fn send(&mut self, frame: &Frame) -> bool {
        let Some(port) = self.port.as_mut() else { return false };
        let sent_ns = (self.clock)();
        board::encode_into(frame, &mut self.tx);
        match write_frame(port, &self.tx) {
            Ok(()) => {
                if let Frame::SetThrottle { seq, .. } | Frame::Arm { seq } | Frame::Disarm { seq } = *frame {
                    self.sent[usize::from(seq) % self.sent.len()] = (seq, sent_ns);
                }
                true
            }
            Err(e) => {
                self.drop_link(format!("write failed: {e}"));
                false
            }
        }
    }

    fn drop_link(&mut self, reason: String) {
        self.port = None;
        self.link_error = Some(reason);
        self.writes_down = 0;
    }

    /// Reads until the ack of `seq` arrives or the wait ends; true if it came.
    fn wait_for_ack(&mut self, seq: u16, sent_ns: u64) -> bool {
        let deadline_ns = sent_ns + self.ack_wait.as_nanos() as u64;
        let mut buf = [0u8; 256];
        let mut acked = false;
        loop {
            let now_ns = (self.clock)();
            let Some(port) = self.port.as_mut() else { return acked };
            if acked && port.bytes_to_read().unwrap_or(0) == 0 {
                return true;
            }
            let left_ns = deadline_ns.saturating_sub(now_ns);
            if left_ns == 0 && !acked {
                break;
            }
            // Wait for bytes with poll(2) rather than a read timeout: the port's timed-out
            // read builds a boxed error, and this runs every cycle.
            let ready = match wait_readable(port.as_raw_fd(), left_ns.max(1)) {
                Ok(ready) => ready,
                Err(e) => {
                    self.drop_link(format!("poll failed: {e}"));
                    return acked;
                }
            };
            let read = if ready { port.read(&mut buf) } else { Err(ErrorKind::TimedOut.into()) };
            match read {
                Ok(0) => {
                    self.drop_link("the port closed".into());
                    return acked;
                }
                Ok(n) => {
                    let rx_ns = (self.clock)();
                    let mut frames = std::mem::take(&mut self.rx_frames);
                    frames.clear();
                    // A partial frame the line went quiet on is not continued by these bytes.
                    while self.deframer.pending() > 0 && rx_ns.saturating_sub(self.last_rx_ns) > PARTIAL_FRAME_NS {
                        self.deframer.expire_partial(|f| frames.push(f));
                    }
                    self.last_rx_ns = rx_ns;
                    self.deframer.push(&buf[..n], |f| frames.push(f));
                    for frame in frames.drain(..) {
                        acked |= self.on_frame(frame, seq, sent_ns, rx_ns);
                    }
                    self.rx_frames = frames;
                }
                Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::Interrupted | ErrorKind::WouldBlock) => {
                    if acked {
                        return true;
                    }
                    if (self.clock)() >= deadline_ns {
                        break;
                    }
                }
                Err(e) => {
                    self.drop_link(format!("read failed: {e}"));
                    return acked;
                }
            }
        }
        if self.deframer.pending() > 0 && (self.clock)().saturating_sub(self.last_rx_ns) > PARTIAL_FRAME_NS {
            let mut frames = Vec::new();
            self.deframer.expire_partial(|f| frames.push(f));
            for frame in frames {
                self.on_frame(frame, seq, sent_ns, self.last_rx_ns);
            }
        }
        acked
    }

    fn on_frame(&mut self, frame: Frame, want: u16, sent_ns: u64, rx_ns: u64) -> bool {
        match frame {
            Frame::Ack { seq, applied, flags } => {
                self.heard = true;
                let sent_ns = if seq == want { Some(sent_ns) } else { self.sent_at(seq) };
                // An ack of an earlier command (late) still tells what the board applied,
                // unless a newer command's ack is already in.
                let newer = self.last_ack.is_none_or(|a| seq.wrapping_sub(a.seq as u16) < u16::MAX / 2);
                if seq != want {
                    self.late_acks += 1;
                }
                if let (Some(sent_ns), true) = (sent_ns, newer) {
                    self.last_ack = Some(Acknowledgement {
                        seq: u64::from(seq),
                        applied_pct: applied.pct(),
                        round_trip_ns: rx_ns.saturating_sub(sent_ns),
                        armed: flags & board_flags::ARMED != 0,
                        idle_fallback: flags & board_flags::IDLE_FALLBACK != 0,
                    });
                }
                if flags & board_flags::ARMED == 0 {
                    // The board restarted (or was disarmed by someone else): arm it again.
                    self.need_arm = true;
                }
                seq == want
            }
            Frame::Status(s) => {
                self.heard = true;
                self.status = Some(s);
                false
            }
            // Commands are the PC's to send; a board never sends them.
            Frame::SetThrottle { .. } | Frame::Arm { .. } | Frame::Disarm { .. } => false,
        }
    }

    /// The board's latest status report.
    pub fn board_status(&self) -> Option<BoardStatus> {
        self.status
    }

    /// Rejections on the board-to-PC line, by kind.
    pub fn counters(&self) -> &board::Counters {
        self.deframer.counters()
    }

    /// Times the port was opened (1 + reopenings).
    pub fn opens(&self) -> u64 {
        self.opens
    }

    /// Acknowledgements that came after their wait (or for another command).
    pub fn late_acks(&self) -> u64 {
        self.late_acks
    }

    /// Why the link is down, while it is.
    pub fn link_error(&self) -> Option<&str> {
        if self.port.is_some() {
            None
        } else {
            self.link_error.as_deref().or(Some("not opened yet"))
        }
    }

    /// True while the port is open (after a link error it is closed until reopened).
    pub fn is_open(&self) -> bool {
        self.port.is_some()
    }
}

impl ThrottleOutput for ThrottleBoard {
    fn write(&mut self, throttle_pct: f64) -> Result<(), DeviceError> {
        let throttle = Throttle::from_pct(throttle_pct).ok_or_else(|| DeviceError::InvalidValue {
            device: self.describe(),
            reason: format!("throttle {throttle_pct} % is outside 0..100 or not a number"),
        })?;
        if self.port.is_none() {
            if self.writes_down.is_multiple_of(REOPEN_EVERY) {
                // A failed reopen is the silence the caller already sees; the
                // reason is kept for `link_error`.
                if let Err(e) = self.connect() {
                    self.link_error = Some(e.to_string());
                }
            }
            self.writes_down = self.writes_down.wrapping_add(1);
        } else if self.need_arm {
            self.arm()?;
        }
        let mut acked = false;
        self.heard = false;
        self.written_ns = None;
        if self.port.is_some() {
            let seq = self.take_seq();
            let sent_ns = (self.clock)();
            if self.send(&Frame::SetThrottle { seq, throttle }) {
                self.written_ns = Some((self.clock)());
                acked = self.wait_for_ack(seq, sent_ns);
            }
        }
        self.unacked = if acked { 0 } else { self.unacked.saturating_add(1) };
        // A late ack or a status report shows the board alive, if slow.
        self.silent = if self.heard { 0 } else { self.silent.saturating_add(1) };
        // Silent: close the port now and again every REOPEN_EVERY cycles
        // while it stays silent; the next write reopens it by path.
        let silent_for = self.silent.wrapping_sub(SILENT_AFTER);
        if self.silent >= SILENT_AFTER && silent_for.is_multiple_of(REOPEN_EVERY) && self.port.is_some() {
            self.drop_link(format!("nothing heard for {} commands", self.silent));
        }
        Ok(())
    }

    fn round_trip_ns(&self) -> Option<u64> {
        self.last_ack.map(|a| a.round_trip_ns)
    }

    fn acknowledged(&self) -> Option<Acknowledgement> {
        self.last_ack
    }

    fn written_ns(&self) -> Option<u64> {
        self.written_ns
    }

    fn unacked_writes(&self) -> u32 {
        self.unacked
    }

    fn silent_writes(&self) -> u32 {
        self.silent
    }

    fn stop(&mut self) {
        // The disarm is the last frame: nothing waits on it, so it is sent
        // again until acknowledged, for as long as the board's own watchdog
        // would take to idle the engine anyway (a set stopping all at once
        // keeps both ends busy for a few milliseconds).
        let until_ns = (self.clock)() + DISARM_WAIT.as_nanos() as u64;
        loop {
            let seq = self.take_seq();
            let sent_ns = (self.clock)();
            if !self.send(&Frame::Disarm { seq }) || self.wait_for_ack(seq, sent_ns) {
                break;
            }
            // A late ack of an earlier disarm says the same.
            if self.last_ack.is_some_and(|a| !a.armed) || (self.clock)() >= until_ns {
                break;
            }
        }
        self.port = None;
    }

    fn describe(&self) -> String {
        format!("throttle board on {} at {} baud", self.path.display(), self.baud)
    }
}

/// Polls the ECU on its own thread and hands each telemetry sample over a
/// channel, so the 100 Hz command path never waits on the 9600 baud line.
///
/// Every poll yields one sample: a fresh reading, or, when the ECU did not
/// answer validly within the poll period, the last reading flagged
/// [`ecu_flags::STALE`] (and [`ecu_flags::SILENT`] from the
/// [`SILENT_AFTER`]th unanswered poll on, when the port is also reopened).
pub struct EcuPoller {
    samples: Receiver<EcuTelemetry>,
    commands: Sender<PcCommand>,
    shared: Arc<Mutex<EcuShared>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    describe: String,
}

/// What the poller thread shares with its owner.
#[derive(Clone, Debug, Default)]
pub struct EcuShared {
    /// The ECU link's counters: polls, replies, garbage, refusals.
    pub counters: EcuCounters,
    /// Samples dropped because the owner did not take them.
    pub dropped: u64,
    /// Times the port was opened (1 plus the reopenings after link errors).
    pub opens: u64,
    /// Why the port is closed now; `None` while it is open.
    pub link_error: Option<String>,
    /// Telemetry replies that came after their poll's answer window: found
    /// waiting when the next poll was due, and dropped, so a late reply is
    /// never taken for the next poll's reading.
    pub late_replies: u64,
}

impl EcuPoller {
    /// Starts polling the ECU at `path` at `poll_hz` (the port is opened by the thread).
    pub fn spawn(path: impl Into<PathBuf>, baud: u32, poll_hz: f64, clock: fn() -> u64) -> Result<Self, DeviceError> {
        let path = path.into();
        let describe = format!("ECU on {} at {baud} baud", path.display());
        if !(poll_hz.is_finite() && poll_hz > 0.0) {
            return Err(DeviceError::InvalidValue { device: describe, reason: format!("poll rate {poll_hz} Hz") });
        }
        let (tx, rx) = crossbeam_channel::bounded(256);
        let (commands, command_rx) = crossbeam_channel::bounded(16);
        let shared = Arc::new(Mutex::new(EcuShared::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let worker = EcuWorker {
            path,
            baud,
            period_ns: (1e9 / poll_hz) as u64,
            clock,
            tx,
            commands: command_rx,
            shared: shared.clone(),
            stop: stop.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("ecu-poller".into())
            .spawn(move || worker.run())
            .map_err(|e| DeviceError::Io { device: describe.clone(), reason: format!("cannot start thread: {e}") })?;
        Ok(EcuPoller { samples: rx, commands, shared, stop, thread: Some(thread), describe })
    }

    /// Sends `command` (start, stop, throttle) before the next poll; its
    /// acknowledgement or refusal is counted, a refusal in the next samples'
    /// `refused`. False when the queue is full (the caller asks again later).
    pub fn send(&self, command: PcCommand) -> bool {
        self.commands.try_send(command).is_ok()
    }

    /// The samples polled since the last call, oldest first; never blocks.
    pub fn try_iter(&self) -> impl Iterator<Item = EcuTelemetry> + '_ {
        self.samples.try_iter()
    }

    /// The poller thread, to give it its own scheduling (it starts with its creator's).
    pub fn pthread(&self) -> Option<libc::pthread_t> {
        use std::os::unix::thread::JoinHandleExt;
        self.thread.as_ref().map(|t| t.as_pthread_t())
    }

    /// Counters and link state of the poller thread.
    pub fn shared(&self) -> EcuShared {
        self.shared.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// The link for messages, e.g. `ECU on /dev/ttyUSB0 at 9600 baud`.
    pub fn describe(&self) -> &str {
        &self.describe
    }
}

impl Drop for EcuPoller {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How often the ECU worker reads the battery voltage (`RFI`), ns.
const FUEL_PERIOD_NS: u64 = 200_000_000;

/// What polling the ECU at a rate costs its serial line, worked out from the
/// poller's own schedule (an `RAC` poll every period, an `RFI` after every
/// [`FUEL_PERIOD_NS`]'s worth of polls) and the longest lines the codec
/// accepts in practice; a pseudo-terminal has no baud rate, so the emulated
/// ECU never shows this, a real line at 9600 baud does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EcuLineBudget {
    /// `RFI` requests per second (the battery voltage).
    pub fuel_hz: f64,
    /// Share of the ECU-to-PC direction the echoes and replies take, 0..1
    /// (above 1 the replies fall behind without end).
    pub rx_share: f64,
    /// From a poll to its whole reply on an idle line, s: the poll sent, then
    /// the echo and the reply received.
    pub reply_s: f64,
    /// The same for the poll after an `RFI`, whose reply waits for the
    /// `RFI`'s to finish, s: the slowest reply.
    pub reply_after_fuel_s: f64,
    /// How long the poller waits for a reply, s (nine tenths of the period);
    /// a reply later than this makes the poll's sample stale.
    pub answer_window_s: f64,
}

impl EcuLineBudget {
    /// The longest telemetry reply in practice: full speed, a hot exhaust,
    /// a 12 V pump, the run state and full throttle (34 bytes with its `\r`).
    fn longest_reply() -> usize {
        ecu::encode_reply(&ecu::EcuReading {
            rpm: 125_000.0,
            egt_c: 799.9,
            pump_v: 12.34,
            state: 10,
            throttle_pct: 100.0,
        })
        .len()
    }

    /// JetCat's fuel-information reply with every field in use (the emulated
    /// ECU leaves the fuel fields at 0; a real one fills them): 38 bytes.
    const FUEL_REPLY: &'static str = "1,HS,OK,1234,12345,123456,12.34,12345\r";

    /// The budget of polling at `poll_hz` on a line at `baud` (8N1: ten bits
    /// a byte, each way).
    pub fn new(baud: u32, poll_hz: f64) -> Self {
        let byte_s = 10.0 / f64::from(baud.max(1));
        let period_ns = (1e9 / poll_hz) as u64;
        let fuel_every = (FUEL_PERIOD_NS / period_ns.max(1)).max(1);
        let fuel_hz = poll_hz / fuel_every as f64;
        let poll = ecu::POLL.len() as f64;
        let reply = poll + Self::longest_reply() as f64; // the echo, then the reply
        let fuel = ecu::FUEL_POLL.len() as f64 + Self::FUEL_REPLY.len() as f64;
        let period_s = period_ns as f64 * 1e-9;
        let reply_s = (poll + reply) * byte_s;
        // The ECU answers a command once it has it whole, and sends one line
        // at a time: after an RFI its line is busy until the RFI's reply is out.
        let busy_until_s = (poll + reply + fuel) * byte_s;
        let next_heard_s = (period_s + poll * byte_s).max(busy_until_s);
        EcuLineBudget {
            fuel_hz,
            rx_share: (poll_hz * reply + fuel_hz * fuel) * byte_s,
            reply_s,
            reply_after_fuel_s: next_heard_s + reply * byte_s - period_s,
            answer_window_s: period_s * 0.9,
        }
    }

    /// Every poll, the one after an `RFI` too, is answered within its window.
    pub fn fits(&self) -> bool {
        self.rx_share < 1.0 && self.reply_after_fuel_s <= self.answer_window_s
    }
}

struct EcuWorker {
    path: PathBuf,
    baud: u32,
    period_ns: u64,
    clock: fn() -> u64,
    tx: Sender<EcuTelemetry>,
    commands: Receiver<PcCommand>,
    shared: Arc<Mutex<EcuShared>>,
    stop: Arc<AtomicBool>,
}

impl EcuWorker {
    fn update(&self, f: impl FnOnce(&mut EcuShared)) {
        if let Ok(mut s) = self.shared.lock() {
            f(&mut s);
        }
    }

    fn run(self) {
        let mut port: Option<TTYPort> = None;
        let mut decoder = LineDecoder::new();
        let mut last = EcuTelemetry::default();
        let mut missed: u32 = 0;
        let mut off_condition: u32 = 0;
        let mut refused: u32 = 0;
        let mut battery_v = 0.0;
        // The battery voltage (`RFI`) about five times a second, after a poll.
        let fuel_every = (FUEL_PERIOD_NS / self.period_ns.max(1)).max(1);
        let mut polls: u64 = 0;
        let mut next_ns = (self.clock)();
        let mut buf = [0u8; 256];
        while !self.stop.load(Ordering::Relaxed) {
            let poll_ns = next_ns;
            next_ns += self.period_ns;
            if port.is_none() {
                match open_port(&self.path, self.baud) {
                    Ok(p) => {
                        let _ = p.clear(serialport::ClearBuffer::All);
                        port = Some(p);
                        self.update(|s| {
                            s.opens += 1;
                            s.link_error = None;
                        });
                    }
                    Err(e) => self.update(|s| s.link_error = Some(e.to_string())),
                }
            }
            // What came since the last poll's window closed: a late telemetry
            // reply is dropped (it answered the last poll, which was already
            // published stale), the status and battery replies are kept.
            if let Some(p) = port.as_mut() {
                let mut late = 0;
                let _ = p.set_timeout(Duration::ZERO);
                while let Ok(n @ 1..) = p.read(&mut buf) {
                    decoder.push_replies(&buf[..n], |reply| match reply {
                        EcuReply::Actual(_) => late += 1,
                        EcuReply::Status { off_condition: off } => off_condition = off,
                        EcuReply::Fuel { battery_v: v } => battery_v = v,
                        EcuReply::Refused(_) => refused = refused.saturating_add(1),
                        EcuReply::Ack => {}
                    });
                }
                // A reply still on its way is cut here: its tail is a bad
                // line, never this poll's reading.
                decoder.expire_partial();
                if late > 0 {
                    self.update(|s| s.late_replies += late);
                }
            }
            // Answer window: most of the period, leaving time to publish.
            let answer_by_ns = poll_ns + self.period_ns * 9 / 10;
            let mut reading = None;
            // Commands first (their echo and acknowledgement come before the
            // poll's reply), then the poll.
            let mut lines: Vec<u8> = self.commands.try_iter().flat_map(|c| c.encode().into_bytes()).collect();
            lines.extend_from_slice(ecu::POLL);
            let ask_fuel = polls.is_multiple_of(fuel_every);
            polls += 1;
            if ask_fuel {
                lines.extend_from_slice(ecu::FUEL_POLL);
            }
            let mut fuel = None;
            let mut status = None;
            let mut asked_status = false;
            if let Some(p) = port.as_mut() {
                if let Err(e) = p.write_all(&lines) {
                    self.update(|s| s.link_error = Some(format!("write failed: {e}")));
                    port = None;
                }
            }
            loop {
                // Not in run: the off condition too (`RSS`), once the reading is in.
                let want_status = reading.is_some_and(|(r, _): (ecu::EcuReading, u64)| {
                    r.state != u32::from(crate::ecu::state::EcuState::Run.code())
                });
                if want_status && !asked_status {
                    asked_status = true;
                    if let Some(p) = port.as_mut() {
                        if let Err(e) = p.write_all(ecu::STATUS_POLL) {
                            self.update(|s| s.link_error = Some(format!("write failed: {e}")));
                            port = None;
                        }
                    }
                }
                // The battery's reply is not waited for: it comes after the
                // telemetry's and is taken whenever it arrives (this poll's
                // read or the next), so it never delays a sample.
                let done = reading.is_some() && (!want_status || status.is_some());
                let Some(p) = port.as_mut().filter(|_| !done) else { break };
                let left_ns = answer_by_ns.saturating_sub((self.clock)());
                if left_ns == 0 || self.stop.load(Ordering::Relaxed) {
                    break;
                }
                let _ = p.set_timeout(Duration::from_nanos(left_ns));
                match p.read(&mut buf) {
                    Ok(0) => port = None,
                    Ok(n) => {
                        let received_ns = (self.clock)();
                        decoder.push_replies(&buf[..n], |reply| match reply {
                            EcuReply::Actual(r) => reading = Some((r, received_ns)),
                            EcuReply::Status { off_condition } => status = Some(off_condition),
                            EcuReply::Fuel { battery_v } => fuel = Some(battery_v),
                            EcuReply::Refused(_) => refused = refused.saturating_add(1),
                            EcuReply::Ack => {}
                        });
                    }
                    Err(e)
                        if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::Interrupted | ErrorKind::WouldBlock) => {
                    }
                    Err(e) => {
                        self.update(|s| s.link_error = Some(format!("read failed: {e}")));
                        port = None;
                    }
                }
            }
            if let Some(off) = status {
                off_condition = off;
            }
            if let Some(v) = fuel {
                battery_v = v;
            }
            let sample = match reading {
                Some((r, received_ns)) => {
                    missed = 0;
                    last = EcuTelemetry {
                        seq: 0,
                        stamp_ns: received_ns,
                        publish_ns: 0,
                        rpm: r.rpm,
                        egt_c: r.egt_c,
                        pump_v: r.pump_v,
                        throttle_pct: r.throttle_pct,
                        state: r.state,
                        flags: 0,
                        off_condition,
                        refused,
                        battery_v,
                    };
                    last
                }
                None => {
                    decoder.expire_partial();
                    missed = missed.saturating_add(1);
                    let mut flags = ecu_flags::STALE;
                    if missed >= SILENT_AFTER {
                        flags |= ecu_flags::SILENT;
                        if port.take().is_some() {
                            self.update(|s| s.link_error = Some(format!("no valid reply to {SILENT_AFTER} polls")));
                        }
                    }
                    EcuTelemetry { stamp_ns: (self.clock)(), flags, refused, ..last }
                }
            };
            let counters = *decoder.counters();
            let dropped = matches!(self.tx.try_send(sample), Err(TrySendError::Full(_)));
            self.update(|s| {
                s.counters = counters;
                s.dropped += u64::from(dropped);
            });
            // Sleep to the next poll in short steps, so a stop is seen promptly.
            loop {
                let now_ns = (self.clock)();
                if now_ns >= next_ns || self.stop.load(Ordering::Relaxed) {
                    break;
                }
                std::thread::sleep(Duration::from_nanos((next_ns - now_ns).min(20_000_000)));
            }
            // After a long stall, poll now rather than in a burst.
            let now_ns = (self.clock)();
            if now_ns > next_ns + self.period_ns {
                next_ns = now_ns;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polling_at_9600_baud_fits_at_10_hz_and_not_at_15() {
        let ten = EcuLineBudget::new(9600, 10.0);
        // 10 polls of 50 bytes (echo 8, longest reply 34, the poll 8 the other way).
        assert!((ten.reply_s - 0.0521).abs() < 1e-3, "{ten:?}");
        assert!(ten.fits() && ten.rx_share < 0.7, "{ten:?}");
        let fifteen = EcuLineBudget::new(9600, 15.0);
        assert_eq!(fifteen.fuel_hz, 5.0);
        assert!(fifteen.rx_share > 0.85 && fifteen.rx_share < 0.95, "{fifteen:?}");
        // The poll after an RFI is answered after its window: stale every third poll.
        assert!(fifteen.reply_after_fuel_s > fifteen.answer_window_s, "{fifteen:?}");
        assert!(!fifteen.fits());
        // Above about 17 Hz not even a lone reply fits in the window.
        let twenty = EcuLineBudget::new(9600, 20.0);
        assert!(twenty.reply_s > twenty.answer_window_s && twenty.rx_share > 1.0, "{twenty:?}");
        // A faster line takes the presets' 15 Hz easily.
        assert!(EcuLineBudget::new(57_600, 15.0).fits());
    }
}
