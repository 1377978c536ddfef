//! A stage of the floor chain: the `jetbench latency-stage` process.
//!
//! It applies its real-time request first, reports the outcome and `ready`
//! on stdout, passes pings on until the last cycle went through (then
//! reports `done` and stays until SIGTERM) or until SIGTERM. Every blocking
//! call lasts at most [`SIGNAL_POLL`], so a stop is noticed.

use std::fs::File;
use std::io::Write;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, FromRawFd, OwnedFd, RawFd};
use std::time::Duration;

use jetbench_bus::{stop_requested, OpenError};

use jetbench_stack::runtime::clock::{monotonic_ns, STALL};
use jetbench_stack::runtime::rt::RtRequest;

use super::{StageRecord, DONE, GO, READY, RT, STAGES};

/// The longest any blocking call of a stage lasts before the stop flag is checked.
const SIGNAL_POLL: Duration = Duration::from_millis(50);
/// Records a stage holds before it must write some mid-run: 40 MB, over
/// 2.5 h at 100 Hz. Shorter runs report once, after their last cycle.
const MAX_HELD_RECORDS: u64 = 1 << 20;
/// Added to an eventfd to say "no more cycles"; the remainder counts pings.
const EVENTFD_END: u64 = 1 << 40;

/// What one stage process runs (parsed by `jetbench latency-stage`).
#[derive(Debug)]
pub struct StageOptions {
    /// 0 = the clocked source (standing for sensing) … 3 = the sink (actuation).
    pub stage: usize,
    /// Cycles the source sends.
    pub cycles: u64,
    /// The source's period (the bench's 10 ms).
    pub period: Duration,
    /// The eventfd the ping comes in on (stages 1–3).
    pub input: Option<OwnedFd>,
    /// The eventfd the ping goes out on (stages 0–2).
    pub output: Option<OwnedFd>,
    /// The pipe the stage's records go to.
    pub results: OwnedFd,
    /// Real-time settings to apply first.
    pub rt: Option<RtRequest>,
}

/// Why a stage failed.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    /// A stage number outside 0..=3 (the number given).
    #[error("stage {0} does not exist: stages are numbered 0 to 3")]
    NoSuchStage(usize),
    /// An eventfd the stage needs was not passed on its command line.
    #[error("stage {stage} needs {what}, which was not passed")]
    MissingFd {
        /// The stage, 0..=3.
        stage: usize,
        /// Which descriptor, e.g. `--input`.
        what: &'static str,
    },
    /// A descriptor number that is not open here: the stage was not started by the chain.
    #[error("fd {fd} is not open in this process: {source} (latency-stage runs only under `jetbench latency`)")]
    BadFd {
        /// The descriptor number.
        fd: RawFd,
        /// The system's reason.
        source: std::io::Error,
    },
    /// The stage's bus settings do not open (it takes the bus's stop flag).
    #[error(transparent)]
    Bus(#[from] OpenError),
    /// A read, write or wait on the stage's descriptors failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: &'static str,
        /// The system's reason.
        source: std::io::Error,
    },
}

/// Takes ownership of an fd this process inherited from [`run_chain`](super::run_chain).
///
/// # Safety
/// `fd` must be a descriptor nothing else in this process owns or will close:
/// call it once per fd, at start-up, on the numbers the parent passed.
pub unsafe fn inherited_fd(fd: RawFd) -> Result<OwnedFd, StageError> {
    // SAFETY: F_GETFD only queries the descriptor's flags.
    if fd < 0 || unsafe { libc::fcntl(fd, libc::F_GETFD) } < 0 {
        let source = std::io::Error::last_os_error();
        return Err(StageError::BadFd { fd, source });
    }
    // SAFETY: the fd is open, and the caller guarantees nothing else owns it.
    let owned = unsafe { OwnedFd::from_raw_fd(fd) };
    // Not passed on to anything this stage might start.
    // SAFETY: plain fcntl on an fd we own.
    unsafe { libc::fcntl(owned.as_raw_fd(), libc::F_SETFD, libc::FD_CLOEXEC) };
    Ok(owned)
}

/// How a stage's loop ended.
enum End {
    /// The last cycle went through (the source's count, or the end marker).
    Finished,
    /// SIGTERM/SIGINT before that.
    Stopped,
}

/// Runs one stage: applies its real-time request, reports the outcome and
/// `ready` on stdout, passes the pings on until the last cycle went through
/// (then reports `done` and waits for SIGTERM) or until SIGTERM.
pub fn run_stage(options: StageOptions) -> Result<(), StageError> {
    let StageOptions { stage, cycles, period, input, output, results, rt } = options;
    if stage >= STAGES {
        return Err(StageError::NoSuchStage(stage));
    }
    jetbench_bus::install_signal_flag()?;
    let outcome = rt.as_ref().map(jetbench_stack::runtime::rt::apply).unwrap_or_default();
    let needs = |fd: Option<OwnedFd>, needed: bool, what| match (fd, needed) {
        (Some(fd), true) => Ok(Some(fd)),
        (None, true) => Err(StageError::MissingFd { stage, what }),
        (_, false) => Ok(None),
    };
    let input = needs(input, stage > 0, "--input-fd")?;
    let output = needs(output, stage < STAGES - 1, "--output-fd")?;
    let mut stage_run = StageRun {
        stage,
        cycles,
        period_ns: (period.as_nanos() as u64).max(1),
        results: ResultWriter::new(results, cycles),
        handled: 0,
    };
    for applied in &outcome.applied {
        say(&format!("{RT} applied {applied}"));
    }
    for refused in &outcome.refused {
        say(&format!("{RT} refused {refused}"));
    }
    let (policy, priority) = jetbench_stack::runtime::rt::current_policy();
    say(&format!("{RT} policy {policy} {priority}"));
    let end = stage_run.eventfd(input, output)?;
    stage_run.results.flush()?;
    if let End::Finished = end {
        say(&format!("{DONE} {} 0", stage_run.handled));
        // Stay until stopped, as every stage does: the parent stops them together.
        while !stop_requested() {
            std::thread::sleep(SIGNAL_POLL);
        }
    }
    Ok(())
}

fn io_error(what: &'static str) -> impl FnOnce(std::io::Error) -> StageError {
    move |source| StageError::Io { what, source }
}

/// One protocol line on stdout.
fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

/// Holds a stage's records in memory and writes them to the result pipe once
/// the last cycle has gone through, so reporting never competes with a cycle
/// (on a shared CPU, a higher-priority stage writing to the parent would hold
/// up the next stage).
struct ResultWriter {
    pipe: File,
    batch: Vec<u8>,
    held_bytes: usize,
}

impl ResultWriter {
    /// Room for `cycles` records (at most [`MAX_HELD_RECORDS`]), touched now
    /// so that no page fault lands in a cycle.
    fn new(fd: OwnedFd, cycles: u64) -> Self {
        let held_bytes = (cycles.clamp(1, MAX_HELD_RECORDS) as usize + 1) * StageRecord::BYTES;
        let mut batch = vec![1u8; held_bytes];
        batch.clear();
        ResultWriter { pipe: File::from(fd), batch, held_bytes }
    }

    /// Keeps a record (after the cycle's output went out); writes what it
    /// holds only when full, in a run longer than it can hold.
    fn push(&mut self, record: StageRecord) -> Result<(), StageError> {
        if self.batch.len() + StageRecord::BYTES > self.held_bytes {
            self.flush()?;
        }
        self.batch.extend_from_slice(&record.to_bytes());
        Ok(())
    }

    fn flush(&mut self) -> Result<(), StageError> {
        self.pipe.write_all(&self.batch).map_err(io_error("cannot report to the parent"))?;
        self.batch.clear();
        Ok(())
    }
}

/// Waits until `fd` is ready for `events`, at most [`SIGNAL_POLL`]; false on
/// a timeout or a signal (the caller checks the stop flag).
fn wait_fd(fd: BorrowedFd, events: libc::c_short) -> std::io::Result<bool> {
    let mut pfd = libc::pollfd { fd: fd.as_raw_fd(), events, revents: 0 };
    // SAFETY: one valid pollfd.
    let rc = unsafe { libc::poll(&mut pfd, 1, SIGNAL_POLL.as_millis() as libc::c_int) };
    if rc < 0 {
        let e = std::io::Error::last_os_error();
        return if e.kind() == std::io::ErrorKind::Interrupted { Ok(false) } else { Err(e) };
    }
    Ok(rc > 0)
}

fn would_block(e: &std::io::Error) -> bool {
    matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted)
}

/// Adds `value` to an eventfd.
fn eventfd_add(fd: BorrowedFd, value: u64) -> Result<(), StageError> {
    let bytes = value.to_ne_bytes();
    // SAFETY: writes 8 bytes from a live buffer.
    let n = unsafe { libc::write(fd.as_raw_fd(), bytes.as_ptr().cast(), bytes.len()) };
    if n != 8 {
        return Err(StageError::Io { what: "cannot ping the next stage", source: std::io::Error::last_os_error() });
    }
    Ok(())
}

/// Takes an eventfd's count, if any.
fn eventfd_take(fd: BorrowedFd) -> Result<Option<u64>, StageError> {
    let mut bytes = [0u8; 8];
    // SAFETY: reads at most 8 bytes into a live buffer.
    let n = unsafe { libc::read(fd.as_raw_fd(), bytes.as_mut_ptr().cast(), bytes.len()) };
    if n == 8 {
        return Ok(Some(u64::from_ne_bytes(bytes)));
    }
    let e = std::io::Error::last_os_error();
    if would_block(&e) {
        Ok(None)
    } else {
        Err(StageError::Io { what: "cannot read the ping", source: e })
    }
}

/// The source's clock: `clock_nanosleep(TIMER_ABSTIME)` at the period.
struct Schedule {
    period_ns: u64,
    next_ns: u64,
    cycle: u64,
    cycles: u64,
}

/// One wake-up of the source.
struct Tick {
    cycle: u64,
    scheduled_ns: u64,
    t0_ns: u64,
}

impl Schedule {
    fn start(period_ns: u64, cycles: u64) -> Self {
        Schedule { period_ns, next_ns: monotonic_ns() + period_ns, cycle: 0, cycles }
    }

    /// Sleeps until the slot after the last cycle; false if a stop came first.
    fn wait_end(&mut self) -> bool {
        !stop_requested() && sleep_until_ns(self.next_ns)
    }

    /// Sleeps until the next cycle is due; `None` once every cycle ran or a
    /// stop was requested. After a stall it restarts the schedule instead of
    /// sending the missed cycles back to back.
    fn wait(&mut self) -> Option<Tick> {
        if self.cycle >= self.cycles || !sleep_until_ns(self.next_ns) {
            return None;
        }
        let t0_ns = monotonic_ns();
        let tick = Tick { cycle: self.cycle, scheduled_ns: self.next_ns, t0_ns };
        self.cycle += 1;
        self.next_ns = if t0_ns > self.next_ns + STALL.as_nanos() as u64 {
            t0_ns + self.period_ns
        } else {
            self.next_ns + self.period_ns
        };
        Some(tick)
    }
}

/// `clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)` until `target_ns`, in
/// steps of at most [`SIGNAL_POLL`]; false if a stop was requested.
fn sleep_until_ns(target_ns: u64) -> bool {
    let poll_ns = SIGNAL_POLL.as_nanos() as u64;
    loop {
        if stop_requested() {
            return false;
        }
        let now = monotonic_ns();
        if now >= target_ns {
            return true;
        }
        let until = target_ns.min(now + poll_ns);
        let ts = libc::timespec { tv_sec: (until / 1_000_000_000) as _, tv_nsec: (until % 1_000_000_000) as _ };
        // SAFETY: a valid timespec; no remainder is asked for with TIMER_ABSTIME.
        // An interruption (EINTR) just goes round the loop.
        unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) };
    }
}

/// Waits for the parent's go on stdin; false if the parent went away or a stop came.
fn wait_for_go() -> Result<bool, StageError> {
    let stdin = std::io::stdin();
    let mut line = Vec::new();
    loop {
        if stop_requested() {
            return Ok(false);
        }
        if !wait_fd(stdin.as_fd(), libc::POLLIN).map_err(io_error("cannot wait for the parent"))? {
            continue;
        }
        let mut byte = [0u8; 1];
        // SAFETY: reads at most one byte into a live buffer.
        match unsafe { libc::read(stdin.as_raw_fd(), byte.as_mut_ptr().cast(), 1) } {
            1 if byte[0] == b'\n' => return Ok(line == GO.as_bytes()),
            1 => line.push(byte[0]),
            0 => return Ok(false),
            _ => {
                let e = std::io::Error::last_os_error();
                if !would_block(&e) {
                    return Err(StageError::Io { what: "cannot read from the parent", source: e });
                }
            }
        }
    }
}

struct StageRun {
    stage: usize,
    cycles: u64,
    period_ns: u64,
    results: ResultWriter,
    /// Cycles passed on.
    handled: u64,
}

impl StageRun {
    /// The eventfd chain: the source pings at the period, every other stage
    /// wakes on its eventfd and pings the next; no payload, no work.
    fn eventfd(&mut self, input: Option<OwnedFd>, output: Option<OwnedFd>) -> Result<End, StageError> {
        say(READY);
        if self.stage == 0 {
            let output = output.expect("checked by run_stage");
            if !wait_for_go()? {
                return Ok(End::Stopped);
            }
            let mut schedule = Schedule::start(self.period_ns, self.cycles);
            while let Some(tick) = schedule.wait() {
                eventfd_add(output.as_fd(), 1)?;
                let sent_ns = monotonic_ns();
                self.source_record(&tick, sent_ns)?;
            }
            if !schedule.wait_end() {
                return Ok(End::Stopped);
            }
            eventfd_add(output.as_fd(), EVENTFD_END)?;
            return Ok(End::Finished);
        }
        let input = input.expect("checked by run_stage");
        loop {
            if !wait_fd(input.as_fd(), libc::POLLIN).map_err(io_error("cannot wait for the ping"))? {
                if stop_requested() {
                    return Ok(End::Stopped);
                }
                continue;
            }
            let Some(count) = eventfd_take(input.as_fd())? else { continue };
            let wake_ns = monotonic_ns();
            // Usually one ping; more only if this stage fell behind. All of
            // them woke it now.
            for _ in 0..count % EVENTFD_END {
                if let Some(output) = &output {
                    eventfd_add(output.as_fd(), 1)?;
                }
                let sent_ns = monotonic_ns();
                let cycle = self.handled;
                self.handled += 1;
                self.results.push(StageRecord { cycle, wake_ns, sent_ns, scheduled_ns: 0 })?;
            }
            if count >= EVENTFD_END {
                if let Some(output) = &output {
                    eventfd_add(output.as_fd(), EVENTFD_END)?;
                }
                return Ok(End::Finished);
            }
        }
    }

    fn source_record(&mut self, tick: &Tick, sent_ns: u64) -> Result<(), StageError> {
        self.handled += 1;
        self.results.push(StageRecord {
            cycle: tick.cycle,
            wake_ns: tick.t0_ns,
            sent_ns,
            scheduled_ns: tick.scheduled_ns,
        })
    }
}
