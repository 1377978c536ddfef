//! The device side of the serial links: a throttle board and an ECU that
//! speak the same protocols as the real ones, each on its own
//! pseudo-terminal pair, for the simulated bench and the tests.
//!
//! The firmware logic ([`BoardFirmware`], [`EcuModel`]) is plain code with
//! time passed in; [`PtyBoard`] and [`PtyEcu`] run it on a thread behind the
//! master end of a pty pair and publish the slave end under a stable link
//! path, which the drivers open exactly like `/dev/ttyUSB0`.
//!
//! ```no_run
//! use jetbench_io::emulate::PtyBoard;
//! use jetbench_io::serial::ThrottleBoard;
//! use jetbench_io::ThrottleOutput;
//!
//! fn clock() -> u64 {
//!     std::time::UNIX_EPOCH.elapsed().map_or(0, |d| d.as_nanos() as u64)
//! }
//! let link = std::env::temp_dir().join("board-example");
//! let board = PtyBoard::spawn(&link, clock).unwrap();
//! let mut driver = ThrottleBoard::new(&link, 115_200, clock);
//! driver.write(40.0).unwrap();
//! assert_eq!(board.output_pct(clock()), Some(40.0));
//! ```

use std::io::{ErrorKind, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use serialport::{SerialPort, TTYPort};

use crate::board::{self, board_flags, BoardStatus, Deframer, Frame, Throttle};
use crate::ecu::emulator::{EcuCommand, EcuEmulator, Refused};
use crate::ecu::state::OffCondition;
use crate::ecu::{self, EcuReading, PcCommand};
use crate::DeviceError;

/// The board reports its status this often.
pub const STATUS_PERIOD_NS: u64 = 100_000_000;

/// The throttle board's firmware: frames in; acknowledgements, status and a
/// throttle output out.
///
/// It applies only valid set-throttle frames while armed, acknowledges every
/// valid command with its sequence number and the throttle it now outputs,
/// and idles by itself ([`board::WATCHDOG_NS`]) when valid frames stop.
#[derive(Clone, Debug, Default)]
pub struct BoardFirmware {
    deframer: Deframer,
    armed: bool,
    throttle: Throttle,
    last_valid_ns: Option<u64>,
    idle: bool,
    watchdog_trips: u32,
    next_status_ns: u64,
    last_rx_ns: u64,
}

/// A partial frame older than this is given up as truncated: a whole frame
/// takes 3.2 ms at 115200 baud, so a longer silence means its sender stopped.
pub const PARTIAL_FRAME_NS: u64 = 5_000_000;

impl BoardFirmware {
    /// Just powered up: disarmed, output 0, every counter 0.
    pub fn new() -> Self {
        Self::default()
    }

    /// Bytes from the PC received at `now_ns`: replies go to `replies`, and
    /// every applied set-throttle command is passed to `applied`.
    pub fn receive(
        &mut self,
        bytes: &[u8],
        now_ns: u64,
        replies: &mut Vec<u8>,
        mut applied: impl FnMut(u16, Throttle),
    ) {
        let mut frames = Vec::new();
        self.expire_stale(now_ns, &mut frames);
        self.last_rx_ns = now_ns;
        self.deframer.push(bytes, |f| frames.push(f));
        for frame in frames {
            let seq = match frame {
                Frame::SetThrottle { seq, throttle } => {
                    if self.armed {
                        self.throttle = throttle;
                        applied(seq, throttle);
                    }
                    seq
                }
                Frame::Arm { seq } => {
                    self.armed = true;
                    seq
                }
                Frame::Disarm { seq } => {
                    self.armed = false;
                    self.throttle = Throttle::default();
                    seq
                }
                // Replies are the board's to send; one coming in is ignored.
                Frame::Ack { .. } | Frame::Status(_) => continue,
            };
            self.last_valid_ns = Some(now_ns);
            self.idle = false;
            let output = self.output(now_ns).unwrap_or_default();
            replies.extend(board::encode(&Frame::Ack { seq, applied: output, flags: self.flags() }));
        }
    }

    /// Gives up a partial frame the line has been quiet on (so the next frame
    /// is not read as its continuation); frames behind it are kept.
    fn expire_stale(&mut self, now_ns: u64, frames: &mut Vec<Frame>) {
        while self.deframer.pending() > 0 && now_ns.saturating_sub(self.last_rx_ns) > PARTIAL_FRAME_NS {
            self.deframer.expire_partial(|f| frames.push(f));
        }
    }

    /// Runs the watchdog at `now_ns`, and appends a status frame when one is due.
    pub fn tick(&mut self, now_ns: u64, replies: &mut Vec<u8>) {
        if self.deframer.pending() > 0 && now_ns.saturating_sub(self.last_rx_ns) > PARTIAL_FRAME_NS {
            // Nothing but the partial is buffered; whatever it still holds is handled with the next bytes.
            self.receive(&[], now_ns, replies, |_, _| {});
        }
        let expired = self.last_valid_ns.is_none_or(|t| now_ns.saturating_sub(t) > board::WATCHDOG_NS);
        if expired && !self.idle {
            self.idle = true;
            if self.last_valid_ns.is_some() {
                self.watchdog_trips += 1;
            }
        }
        if now_ns >= self.next_status_ns {
            self.next_status_ns = now_ns + STATUS_PERIOD_NS;
            replies.extend(board::encode(&Frame::Status(self.status(now_ns))));
        }
    }

    /// The throttle the board drives at `now_ns`; `None` while disarmed or
    /// idling for lack of valid frames.
    pub fn output(&self, now_ns: u64) -> Option<Throttle> {
        let fresh = self.last_valid_ns.is_some_and(|t| now_ns.saturating_sub(t) <= board::WATCHDOG_NS);
        (self.armed && fresh).then_some(self.throttle)
    }

    fn flags(&self) -> u8 {
        let mut flags = 0;
        if self.armed {
            flags |= board_flags::ARMED;
        }
        if self.idle {
            flags |= board_flags::IDLE_FALLBACK;
        }
        flags
    }

    /// The status frame it would send at `now_ns`.
    pub fn status(&self, now_ns: u64) -> BoardStatus {
        let c = self.deframer.counters();
        BoardStatus {
            flags: self.flags(),
            applied: self.output(now_ns).unwrap_or_default(),
            valid_frames: c.frames as u32,
            rejected_frames: c.rejected() as u32,
            watchdog_trips: self.watchdog_trips,
        }
    }

    /// Rejections on the PC-to-board line, by kind.
    pub fn counters(&self) -> &board::Counters {
        self.deframer.counters()
    }

    /// True when armed (it outputs the commanded throttle).
    pub fn is_armed(&self) -> bool {
        self.armed
    }
}

/// Engine telemetry as the ECU would report it, following thrust.
///
/// - RPM: `rpm = IDLE_RPM + RPM_PER_SQRT_N · sqrt(max(T, 0))` (thrust of a
///   turbojet grows roughly with the square of shaft speed);
/// - EGT: first-order lag, time constant [`EGT_TAU_S`], towards
///   `EGT_IDLE_C + EGT_PER_N · T`;
/// - pump voltage: `PUMP_IDLE_V + PUMP_PER_PCT · (u − 25)`, u the throttle the engine follows;
/// - state: [`ECU_STATE_RUNNING`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EcuModel {
    reading: EcuReading,
}

/// Shaft speed at zero thrust, RPM (a small turbojet idles near 35 000).
pub const IDLE_RPM: f64 = 35_000.0;
/// Shaft speed per √N of thrust, RPM/√N.
pub const RPM_PER_SQRT_N: f64 = 8_000.0;
/// Exhaust gas temperature at zero thrust, °C.
pub const EGT_IDLE_C: f64 = 450.0;
/// Exhaust gas temperature rise per newton of thrust, °C/N.
pub const EGT_PER_N: f64 = 3.0;
/// Time constant of the exhaust temperature, s.
pub const EGT_TAU_S: f64 = 1.5;
/// Fuel-pump voltage at 25 % throttle, V.
pub const PUMP_IDLE_V: f64 = 0.8;
/// Fuel-pump voltage per % of throttle above 25 %, V/%.
pub const PUMP_PER_PCT: f64 = 0.05;
/// The state code the emulated ECU reports while the engine runs (JetCat's run, 11).
pub const ECU_STATE_RUNNING: u32 = crate::ecu::state::EcuState::Run as u32;

impl EcuModel {
    /// Settled at thrust `thrust_n` and throttle `throttle_pct`.
    pub fn settled(thrust_n: f64, throttle_pct: f64) -> Self {
        let mut m = EcuModel { reading: EcuReading::default() };
        m.reading.egt_c = Self::egt_target_c(thrust_n);
        m.step(thrust_n, throttle_pct, 0.0);
        m
    }

    fn egt_target_c(thrust_n: f64) -> f64 {
        (EGT_IDLE_C + EGT_PER_N * thrust_n.max(0.0)).clamp(ecu::EGT_MIN_C, ecu::EGT_MAX_C)
    }

    /// Advances `dt_s` with the engine at `thrust_n` and `throttle_pct`.
    pub fn step(&mut self, thrust_n: f64, throttle_pct: f64, dt_s: f64) {
        if !(thrust_n.is_finite() && throttle_pct.is_finite() && dt_s.is_finite()) {
            return;
        }
        let r = &mut self.reading;
        r.rpm = (IDLE_RPM + RPM_PER_SQRT_N * thrust_n.max(0.0).sqrt()).clamp(0.0, ecu::RPM_MAX).round();
        let alpha = if dt_s <= 0.0 { 0.0 } else { 1.0 - (-dt_s / EGT_TAU_S).exp() };
        r.egt_c += alpha * (Self::egt_target_c(thrust_n) - r.egt_c);
        let u = throttle_pct.clamp(0.0, ecu::THROTTLE_MAX_PCT);
        r.pump_v = (PUMP_IDLE_V + PUMP_PER_PCT * (u - 25.0)).clamp(0.0, ecu::PUMP_MAX_V);
        r.throttle_pct = u;
        r.state = ECU_STATE_RUNNING;
    }

    /// The reading as the ECU reports it: EGT to 0.1 °C, volts to 0.01 V, throttle to 0.1 %.
    pub fn reading(&self) -> EcuReading {
        let r = self.reading;
        EcuReading {
            rpm: r.rpm,
            egt_c: (r.egt_c * 10.0).round() / 10.0,
            pump_v: (r.pump_v * 100.0).round() / 100.0,
            state: r.state,
            throttle_pct: (r.throttle_pct * 10.0).round() / 10.0,
        }
    }
}

/// What the ECU firmware serves: telemetry, the off condition, and commands.
pub trait EcuDevice: Send {
    /// The telemetry a poll (`RAC`) answers with now.
    fn reading(&self) -> EcuReading;
    /// Why the engine is off, if it is (`RSS` answers with it).
    fn off_condition(&self) -> OffCondition;
    /// Applies a command from the PC; a refusal is answered with its number.
    fn command(&mut self, command: EcuCommand) -> Result<(), Refused>;
    /// The ECU's battery voltage, V (`RFI` answers with it): a healthy
    /// two-cell pack unless the device says otherwise.
    fn battery_v(&self) -> f64 {
        NOMINAL_BATTERY_V
    }
}

/// A charged two-cell lithium pack, the ECU's usual supply, V.
pub const NOMINAL_BATTERY_V: f64 = 7.4;

/// A device whose reading its owner sets; commands are accepted and queued
/// for the owner ([`PtyEcu::take_commands`]).
#[derive(Clone, Debug, Default)]
pub struct FixedEcu {
    /// The telemetry it answers every poll with.
    pub reading: EcuReading,
    /// The off condition it reports (`None`: no condition).
    pub off_condition: Option<OffCondition>,
    /// Commands received, oldest first, for the owner to take.
    pub commands: Vec<EcuCommand>,
}

impl EcuDevice for FixedEcu {
    fn reading(&self) -> EcuReading {
        self.reading
    }

    fn off_condition(&self) -> OffCondition {
        self.off_condition.unwrap_or(OffCondition::None)
    }

    fn command(&mut self, command: EcuCommand) -> Result<(), Refused> {
        self.commands.push(command);
        Ok(())
    }
}

/// The [`EcuEmulator`] with the clock its commands are stamped with.
pub struct ClockedEmulator {
    /// The emulated ECU.
    pub emulator: EcuEmulator,
    /// Seconds on the emulator's clock, read when a command arrives.
    pub clock: Box<dyn Fn() -> f64 + Send>,
}

impl EcuDevice for ClockedEmulator {
    fn reading(&self) -> EcuReading {
        self.emulator.reading()
    }

    fn off_condition(&self) -> OffCondition {
        self.emulator.off_condition()
    }

    fn battery_v(&self) -> f64 {
        self.emulator.battery_v()
    }

    fn command(&mut self, command: EcuCommand) -> Result<(), Refused> {
        let now = (self.clock)();
        self.emulator.command(command, now)
    }
}

/// The ECU's firmware: echoes every command line, as JetCat's ECU does, and
/// answers it: telemetry (`RAC`), the off condition (`RSS`), the battery
/// voltage (`RFI`), start and stop
/// (`TCO`) and throttle (`WPE`) acknowledged or refused with an error number.
#[derive(Clone, Debug, Default)]
pub struct EcuFirmware {
    line: Vec<u8>,
    /// Lines that were not a command this firmware knows.
    pub unknown_lines: u64,
    /// Telemetry polls (`RAC`) answered.
    pub polls: u64,
    /// Commands (start, stop, throttle) accepted and refused.
    pub accepted: u64,
    /// Commands refused with an error number.
    pub refused: u64,
}

impl EcuFirmware {
    /// Bytes from the PC; the echo and reply of each complete line go to `replies`.
    pub fn receive(&mut self, bytes: &[u8], device: &mut dyn EcuDevice, replies: &mut Vec<u8>) {
        for &b in bytes {
            if b == ecu::EOL {
                let line = std::mem::take(&mut self.line);
                if !line.iter().all(|b| b.is_ascii_whitespace()) {
                    self.answer(&line, device, replies);
                }
            } else if b == b'\n' && self.line.is_empty() {
                // The `\n` of a `\r\n` ending.
            } else if self.line.len() < ecu::MAX_LINE {
                self.line.push(b);
            }
        }
    }

    fn answer(&mut self, line: &[u8], device: &mut dyn EcuDevice, replies: &mut Vec<u8>) {
        let command = match ecu::parse_command(line) {
            Ok(command) => command,
            Err(ecu::CommandError::NotACommand(_)) => {
                self.unknown_lines += 1;
                return; // noise on the line: a real ECU stays silent
            }
            Err(e) => {
                self.unknown_lines += 1;
                replies.extend(line);
                replies.push(ecu::EOL);
                replies.extend(ecu::encode_refusal(e.code()).as_bytes());
                return;
            }
        };
        replies.extend(line);
        replies.push(ecu::EOL);
        let result = match command {
            PcCommand::ReadActual => {
                self.polls += 1;
                replies.extend(ecu::encode_reply(&device.reading()).as_bytes());
                return;
            }
            PcCommand::ReadStatus => {
                replies.extend(ecu::encode_status(device.off_condition().code()).as_bytes());
                return;
            }
            PcCommand::ReadFuel => {
                replies.extend(ecu::encode_fuel(device.battery_v(), 0).as_bytes());
                return;
            }
            PcCommand::Start => device.command(EcuCommand::Start),
            PcCommand::Stop => device.command(EcuCommand::Stop),
            PcCommand::Throttle(pct) => device.command(EcuCommand::Throttle(pct)),
        };
        match result {
            Ok(()) => {
                self.accepted += 1;
                replies.extend(ecu::ACK.as_bytes());
            }
            Err(refused) => {
                self.refused += 1;
                replies.extend(ecu::encode_refusal(refused.code()).as_bytes());
            }
        }
    }
}

/// A device thread behind the master end of a pty pair, with the slave end
/// published at a link path.
struct PtyHost {
    link: PathBuf,
    slave: Mutex<TTYPort>,
    master_writer: Mutex<TTYPort>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// Replaces `link` with a symlink to `target` (refusing to replace anything but a symlink).
fn publish_link(link: &Path, target: &Path) -> Result<(), DeviceError> {
    let err = |reason: String| DeviceError::Io { device: link.display().to_string(), reason };
    if let Some(dir) = link.parent() {
        std::fs::create_dir_all(dir).map_err(|e| err(format!("cannot create {}: {e}", dir.display())))?;
    }
    match std::fs::symlink_metadata(link) {
        Ok(m) if m.file_type().is_symlink() => {
            std::fs::remove_file(link).map_err(|e| err(format!("cannot replace the old link: {e}")))?
        }
        Ok(_) => return Err(err("exists and is not a symlink; refusing to replace it".into())),
        Err(_) => {}
    }
    // Link under a temporary name and rename, so a reader never sees a half-made link.
    let tmp = link.with_extension(format!("tmp{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp).map_err(|e| err(format!("cannot link to {}: {e}", target.display())))?;
    std::fs::rename(&tmp, link).map_err(|e| err(format!("cannot publish the link: {e}")))
}

impl PtyHost {
    /// Opens a pty pair, links its slave at `link` and runs `serve(master, stop)` on a thread.
    fn spawn(
        link: &Path,
        name: &str,
        serve: impl FnOnce(TTYPort, Arc<AtomicBool>) + Send + 'static,
    ) -> Result<Self, DeviceError> {
        let err = |reason: String| DeviceError::Io { device: format!("{name} emulator"), reason };
        // The driver opens the slave again by path (exclusively: `pair` takes
        // no lock on its slave handle, which only keeps the pty alive while
        // the driver reconnects).
        let (master, slave) = TTYPort::pair().map_err(|e| err(format!("cannot open a pty pair: {e}")))?;
        let slave_path = slave.name().ok_or_else(|| err("the pty slave has no name".into()))?;
        // The emulated device is its user's alone (devpts may give the tty group write access).
        std::fs::set_permissions(&slave_path, std::os::unix::fs::PermissionsExt::from_mode(0o600))
            .map_err(|e| err(format!("cannot restrict {slave_path}: {e}")))?;
        publish_link(link, Path::new(&slave_path))?;
        let master_writer = master.try_clone_native().map_err(|e| err(format!("cannot clone the pty master: {e}")))?;
        let stop = Arc::new(AtomicBool::new(false));
        let thread_stop = stop.clone();
        let thread = std::thread::Builder::new()
            .name(format!("{name}-emulator"))
            .spawn(move || serve(master, thread_stop))
            .map_err(|e| err(format!("cannot start the thread: {e}")))?;
        Ok(PtyHost {
            link: link.to_path_buf(),
            slave: Mutex::new(slave),
            master_writer: Mutex::new(master_writer),
            stop,
            thread: Some(thread),
        })
    }
}

impl Drop for PtyHost {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.link);
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Reads from `master` until `stop`, calling `on_bytes(bytes_or_empty, replies)`
/// at least every 10 ms and writing the replies back.
fn serve_loop(mut master: TTYPort, stop: Arc<AtomicBool>, mut on_bytes: impl FnMut(&[u8], &mut Vec<u8>)) {
    let _ = master.set_timeout(Duration::from_millis(10));
    let mut buf = [0u8; 512];
    let mut replies = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        let n = match master.read(&mut buf) {
            Ok(n) => n,
            Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::Interrupted | ErrorKind::WouldBlock) => 0,
            // EIO while no one holds the slave: wait for the driver to reopen it.
            Err(_) => {
                std::thread::sleep(Duration::from_millis(5));
                0
            }
        };
        replies.clear();
        on_bytes(&buf[..n], &mut replies);
        if !replies.is_empty() {
            let _ = master.write_all(&replies);
        }
    }
}

/// An emulated throttle board on a pty pair.
pub struct PtyBoard {
    firmware: Arc<Mutex<BoardFirmware>>,
    silent: Arc<AtomicBool>,
    applied_total: Arc<AtomicU64>,
    applied: Arc<Mutex<Vec<(u16, Throttle)>>>,
    host: PtyHost,
}

impl PtyBoard {
    /// Starts the board; its port is at `link` (a symlink to the pty slave).
    pub fn spawn(link: &Path, clock: fn() -> u64) -> Result<Self, DeviceError> {
        let firmware = Arc::new(Mutex::new(BoardFirmware::new()));
        let applied = Arc::new(Mutex::new(Vec::new()));
        let silent = Arc::new(AtomicBool::new(false));
        let applied_total = Arc::new(AtomicU64::new(0));
        let (fw, log, quiet, total) = (firmware.clone(), applied.clone(), silent.clone(), applied_total.clone());
        let host = PtyHost::spawn(link, "throttle-board", move |master, stop| {
            serve_loop(master, stop, |bytes, replies| {
                let now_ns = clock();
                let mut fw = lock(&fw);
                // A silent board (unplugged, unpowered) hears nothing and says nothing.
                if quiet.load(Ordering::Relaxed) {
                    fw.tick(now_ns, &mut Vec::new());
                    return;
                }
                if !bytes.is_empty() {
                    fw.receive(bytes, now_ns, replies, |seq, t| {
                        let mut log = lock(&log);
                        // Bounded: a long run keeps the newest commands.
                        if log.len() >= 1 << 16 {
                            log.drain(..1 << 15);
                        }
                        log.push((seq, t));
                        total.fetch_add(1, Ordering::Relaxed);
                    });
                }
                fw.tick(now_ns, replies);
            })
        })?;
        Ok(PtyBoard { firmware, silent, applied_total, applied, host })
    }

    /// The throttle the board drives at `now_ns`, %; `None` while idling or disarmed.
    pub fn output_pct(&self, now_ns: u64) -> Option<f64> {
        lock(&self.firmware).output(now_ns).map(Throttle::pct)
    }

    /// Stops (or resumes) hearing and answering, like a board that lost power or its cable.
    pub fn set_silent(&self, silent: bool) {
        self.silent.store(silent, Ordering::Relaxed);
    }

    /// Set-throttle commands applied since the start.
    pub fn applied_count(&self) -> u64 {
        self.applied_total.load(Ordering::Relaxed)
    }

    /// Every set-throttle command the board applied (sequence, value), oldest
    /// first (the newest 32768 to 65536 of them in a long run).
    pub fn applied(&self) -> Vec<(u16, Throttle)> {
        lock(&self.applied).clone()
    }

    /// A copy of the emulated board's firmware state (armed, output, counters).
    pub fn firmware(&self) -> BoardFirmware {
        lock(&self.firmware).clone()
    }

    /// Writes `bytes` into the PC-to-board line, as noise on the wire would
    /// arrive (through the same tty the driver writes to).
    pub fn inject_to_board(&self, bytes: &[u8]) -> std::io::Result<()> {
        lock(&self.host.slave).write_all(bytes)
    }

    /// Writes `bytes` into the board-to-PC line.
    pub fn inject_to_pc(&self, bytes: &[u8]) -> std::io::Result<()> {
        lock(&self.host.master_writer).write_all(bytes)
    }

    /// The path of the PC's end of the pty pair (what the config's device names).
    pub fn link(&self) -> &Path {
        &self.host.link
    }
}

/// An emulated ECU on a pty pair: answers polls with the reading the owner
/// sets ([`PtyEcu::spawn`]) or with an [`EcuEmulator`]'s ([`PtyEcu::emulated`]).
pub struct PtyEcu {
    fixed: Option<Arc<Mutex<FixedEcu>>>,
    emulated: Option<Arc<Mutex<ClockedEmulator>>>,
    silent: Arc<AtomicBool>,
    firmware: Arc<Mutex<EcuFirmware>>,
    host: PtyHost,
}

impl PtyEcu {
    /// An ECU that reports `initial` until [`PtyEcu::set_reading`]; commands are queued.
    pub fn spawn(link: &Path, initial: EcuReading) -> Result<Self, DeviceError> {
        let fixed = Arc::new(Mutex::new(FixedEcu { reading: initial, ..FixedEcu::default() }));
        let device = fixed.clone();
        let (silent, firmware, host) = Self::host(link, move |fw, bytes, replies| {
            fw.receive(bytes, &mut *lock(&device), replies);
        })?;
        Ok(PtyEcu { fixed: Some(fixed), emulated: None, silent, firmware, host })
    }

    /// An ECU run by `emulator`, its commands stamped by `clock` (seconds, the
    /// clock the owner steps it with through [`PtyEcu::step`]).
    pub fn emulated(
        link: &Path,
        emulator: EcuEmulator,
        clock: impl Fn() -> f64 + Send + 'static,
    ) -> Result<Self, DeviceError> {
        let emulated = Arc::new(Mutex::new(ClockedEmulator { emulator, clock: Box::new(clock) }));
        let device = emulated.clone();
        let (silent, firmware, host) = Self::host(link, move |fw, bytes, replies| {
            fw.receive(bytes, &mut *lock(&device), replies);
        })?;
        Ok(PtyEcu { fixed: None, emulated: Some(emulated), silent, firmware, host })
    }

    #[allow(clippy::type_complexity)]
    fn host(
        link: &Path,
        mut serve: impl FnMut(&mut EcuFirmware, &[u8], &mut Vec<u8>) + Send + 'static,
    ) -> Result<(Arc<AtomicBool>, Arc<Mutex<EcuFirmware>>, PtyHost), DeviceError> {
        let silent = Arc::new(AtomicBool::new(false));
        let firmware = Arc::new(Mutex::new(EcuFirmware::default()));
        let (s, fw) = (silent.clone(), firmware.clone());
        let host = PtyHost::spawn(link, "ecu", move |master, stop| {
            serve_loop(master, stop, |bytes, replies| {
                if !bytes.is_empty() && !s.load(Ordering::Relaxed) {
                    serve(&mut lock(&fw), bytes, replies);
                }
            })
        })?;
        Ok((silent, firmware, host))
    }

    /// The reading the next polls are answered with (an ECU made by [`PtyEcu::spawn`]).
    pub fn set_reading(&self, reading: EcuReading) {
        if let Some(fixed) = &self.fixed {
            lock(fixed).reading = reading;
        }
    }

    /// The off condition status requests are answered with (an ECU made by [`PtyEcu::spawn`]).
    pub fn set_off_condition(&self, off: OffCondition) {
        if let Some(fixed) = &self.fixed {
            lock(fixed).off_condition = Some(off);
        }
    }

    /// Commands received since the last call (an ECU made by [`PtyEcu::spawn`]).
    pub fn take_commands(&self) -> Vec<EcuCommand> {
        self.fixed.as_ref().map(|f| std::mem::take(&mut lock(f).commands)).unwrap_or_default()
    }

    /// Advances the emulator to its clock's now with the engine at `thrust_n`
    /// (an ECU made by [`PtyEcu::emulated`]).
    pub fn step(&self, thrust_n: f64) {
        if let Some(emulated) = &self.emulated {
            let mut e = lock(emulated);
            let now = (e.clock)();
            e.emulator.step(now, thrust_n);
        }
    }

    /// Runs `f` on the emulator (an ECU made by [`PtyEcu::emulated`]).
    pub fn with_emulator<T>(&self, f: impl FnOnce(&mut EcuEmulator) -> T) -> Option<T> {
        self.emulated.as_ref().map(|e| f(&mut lock(e).emulator))
    }

    /// Stops (or resumes) answering polls, like an ECU that lost power.
    pub fn set_silent(&self, silent: bool) {
        self.silent.store(silent, Ordering::Relaxed);
    }

    /// Commands accepted and refused so far.
    pub fn commands_accepted_refused(&self) -> (u64, u64) {
        let fw = lock(&self.firmware);
        (fw.accepted, fw.refused)
    }

    /// Telemetry polls answered so far.
    pub fn polls(&self) -> u64 {
        lock(&self.firmware).polls
    }

    /// Writes `bytes` into the ECU-to-PC line.
    pub fn inject_to_pc(&self, bytes: &[u8]) -> std::io::Result<()> {
        lock(&self.host.master_writer).write_all(bytes)
    }

    /// The path of the PC's end of the pty pair (what the config's device names).
    pub fn link(&self) -> &Path {
        &self.host.link
    }
}
