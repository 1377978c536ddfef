//! A stage of a reference chain: the `jetbench latency-stage` process.
//!
//! It applies its real-time request first, reports the outcome and `ready`
//! on stdout, runs its part of the chain until the last cycle went through
//! (then reports `done` and stays until SIGTERM) or until SIGTERM. Every
//! blocking call lasts at most [`SIGNAL_POLL`], so a stop is noticed.

use std::fmt;
use std::fs::File;
use std::io::Write;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, FromRawFd, OwnedFd, RawFd};
use std::path::PathBuf;
use std::time::Duration;

use jetbench_bus::{stop_requested, Bus, BusError, Flow, LoopExit, Wake};
use jetbench_msgs::{Actuation, Channel, Command as CommandSample, Sample, StateEstimate, Thrust};

use super::{StageRecord, Transport, DONE, GO, RT, STAGES, STAGE_SERVICES};
use crate::clock::monotonic_ns;
use crate::config::{BenchConfig, ConfigError};
use crate::rt::RtRequest;
use crate::step::{Actuator, Control, Estimation, Sensing, SimBench};

/// The longest any blocking call of a stage lasts before the stop flag is checked.
const SIGNAL_POLL: Duration = Duration::from_millis(50);
/// How far behind its schedule the source may fall before it restarts the
/// schedule instead of catching up (as sim-bench's sensor does).
const STALL_NS: u64 = 100_000_000;
/// Records a stage holds before it must write some mid-run: 40 MB, over
/// 2.5 h at 100 Hz. Shorter runs report once, after their last cycle.
const MAX_HELD_RECORDS: u64 = 1 << 20;
/// Added to an eventfd to say "no more cycles"; the remainder counts pings.
const EVENTFD_END: u64 = 1 << 40;

/// What one stage process runs (parsed by `jetbench latency-stage`).
#[derive(Debug)]
pub struct StageOptions {
    pub transport: Transport,
    /// 0 = sensing (the clocked source) … 3 = actuation (the sink).
    pub stage: usize,
    /// Cycles the source sends.
    pub cycles: u64,
    pub period: Duration,
    /// Names the run's private channels (iceoryx2).
    pub run_id: String,
    /// Where the input comes from (stages 1–3 of eventfd and uds chains).
    pub input: Option<OwnedFd>,
    /// Where the output goes (stages 0–2 of eventfd and uds chains).
    pub output: Option<OwnedFd>,
    /// The pipe the stage's records go to.
    pub results: OwnedFd,
    pub config: Option<PathBuf>,
    /// Real-time settings to apply first.
    pub rt: Option<RtRequest>,
}

/// Why a stage failed.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error("stage {0} does not exist: stages are numbered 0 to 3")]
    NoSuchStage(usize),
    #[error("stage {stage} of a {transport} chain needs {what}, which was not passed")]
    MissingFd { stage: usize, transport: Transport, what: &'static str },
    #[error("fd {fd} is not open in this process: {source} (latency-stage runs only under `jetbench latency`)")]
    BadFd { fd: RawFd, source: std::io::Error },
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error("cannot set up the {what}: {reason}")]
    Setup { what: &'static str, reason: String },
    #[error("{what}: {source}")]
    Io { what: &'static str, source: std::io::Error },
    #[error("the input link sent a message of {len} bytes, not one {expected} sample")]
    Malformed { len: usize, expected: &'static str },
    #[error("the previous stage closed the link before the last cycle (did it die?)")]
    UpstreamClosed,
}

/// Takes ownership of an fd this process inherited from [`run_chain`].
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

/// Counts of one stage.
#[derive(Default)]
struct Counts {
    handled: u64,
    errors: u64,
}

/// Runs one stage: applies its real-time request, reports the outcome and
/// `ready` on stdout, runs its part of the chain until the last cycle went
/// through (then reports `done` and waits for SIGTERM) or until SIGTERM.
pub fn run_stage(options: StageOptions) -> Result<(), StageError> {
    let StageOptions { transport, stage, cycles, period, run_id, input, output, results, config, rt } = options;
    if stage >= STAGES {
        return Err(StageError::NoSuchStage(stage));
    }
    jetbench_bus::install_signal_flag()?;
    let outcome = rt.as_ref().map(crate::rt::apply).unwrap_or_default();
    let config = BenchConfig::load_or_default(config.as_deref())?;
    let needs = |fd: Option<OwnedFd>, needed: bool, what| match (fd, needed) {
        (Some(fd), true) => Ok(Some(fd)),
        (None, true) => Err(StageError::MissingFd { stage, transport, what }),
        (_, false) => Ok(None),
    };
    let fds = transport != Transport::Iceoryx;
    let input = needs(input, fds && stage > 0, "--input-fd")?;
    let output = needs(output, fds && stage < STAGES - 1, "--output-fd")?;
    let mut stage_run = StageRun {
        stage,
        cycles,
        period_ns: (period.as_nanos() as u64).max(1),
        results: ResultWriter::new(results, cycles),
        counts: Counts::default(),
    };
    let say_rt = || {
        for applied in &outcome.applied {
            say(&format!("{RT} applied {applied}"));
        }
        for refused in &outcome.refused {
            say(&format!("{RT} refused {refused}"));
        }
        let (policy, priority) = crate::rt::current_policy();
        say(&format!("{RT} policy {policy} {priority}"));
    };
    let end = match transport {
        Transport::EventFd => {
            say_rt();
            stage_run.eventfd(input, output)?
        }
        Transport::Uds | Transport::Iceoryx => {
            let bus = match transport {
                Transport::Iceoryx => Some(Bus::open(&format!("latency-{}", STAGE_SERVICES[stage].name()))?),
                _ => None,
            };
            let mut links = Hop { run_id: &run_id, bus: bus.as_ref(), input, output };
            say_rt();
            match stage {
                0 => stage_run.source(&config, links.outlet(0)?)?,
                1 => {
                    let mut step = Estimation::new(
                        config.model_params().map_err(|e| setup("estimator", e))?,
                        config.estimator.observer_config(),
                    );
                    stage_run.relay(links.inlet(0)?, Some(links.outlet(1)?), bus.as_ref(), |t: &Thrust| {
                        step.step(t).map_err(|e| e.to_string())
                    })?
                }
                2 => {
                    let law = config.control_law().map_err(|e| setup("control law", e))?;
                    let mut step = Control::with_law(law, config.reference.clone());
                    stage_run.relay(links.inlet(1)?, Some(links.outlet(2)?), bus.as_ref(), |s: &StateEstimate| {
                        step.step(s).map(|(_, command)| command).map_err(|e| e.to_string())
                    })?
                }
                _ => {
                    let mut step = Actuator::new(config.actuation.idle_after_missed_cycles);
                    stage_run.relay(links.inlet(2)?, None::<Outlet<Actuation>>, bus.as_ref(), |c: &CommandSample| {
                        Ok(step.on_command(c))
                    })?
                }
            }
        }
    };
    stage_run.results.flush()?;
    if let End::Finished = end {
        say(&format!("{DONE} {} {}", stage_run.counts.handled, stage_run.counts.errors));
        // Stay until stopped: with iceoryx2, the next stage may not have taken
        // the last sample yet, and a departing publisher takes its samples along.
        while !stop_requested() {
            std::thread::sleep(SIGNAL_POLL);
        }
    }
    Ok(())
}

fn setup(what: &'static str, reason: impl fmt::Display) -> StageError {
    StageError::Setup { what, reason: reason.to_string() }
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

/// Sends one message on a socket, waiting (in [`SIGNAL_POLL`] steps) while
/// the receiver's queue is full. False if a stop came first.
fn send_message(fd: BorrowedFd, bytes: &[u8]) -> Result<bool, StageError> {
    loop {
        // SAFETY: sends from a live buffer of `bytes.len()` bytes.
        let n = unsafe {
            libc::send(fd.as_raw_fd(), bytes.as_ptr().cast(), bytes.len(), libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL)
        };
        if n == bytes.len() as isize {
            return Ok(true);
        }
        let e = std::io::Error::last_os_error();
        if !would_block(&e) {
            return Err(StageError::Io { what: "cannot send to the next stage", source: e });
        }
        if stop_requested() {
            return Ok(false);
        }
        wait_fd(fd, libc::POLLOUT).map_err(io_error("cannot wait for the next stage"))?;
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
        self.next_ns =
            if t0_ns > self.next_ns + STALL_NS { t0_ns + self.period_ns } else { self.next_ns + self.period_ns };
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

/// A payload stage's links: the run's private channels, or its sockets.
struct Hop<'a> {
    run_id: &'a str,
    bus: Option<&'a Bus>,
    input: Option<OwnedFd>,
    output: Option<OwnedFd>,
}

/// The name of hop `h`'s private channel.
fn hop_channel<T: Sample>(run_id: &str, hop: usize) -> Channel<T> {
    let name = ["thrust", "state", "command"][hop];
    // Leaked once per stage process: channel names are `&'static str`.
    Channel::new(Box::leak(format!("latency/{run_id}/{name}").into_boxed_str()))
}

impl Hop<'_> {
    fn outlet<T: Sample>(&mut self, hop: usize) -> Result<Outlet<T>, StageError> {
        match (self.bus, self.output.take()) {
            (Some(bus), _) => Ok(Outlet::Bus(Box::new(bus.publisher(hop_channel(self.run_id, hop))?))),
            (None, Some(fd)) => Ok(Outlet::Socket { fd, seq: 0 }),
            (None, None) => unreachable!("checked by run_stage"),
        }
    }

    fn inlet<T: Sample>(&mut self, hop: usize) -> Result<Inlet<T>, StageError> {
        match (self.bus, self.input.take()) {
            // As deep as the services' subscribers.
            (Some(bus), _) => Ok(Inlet::Bus(Box::new(bus.subscriber(hop_channel(self.run_id, hop), 16)?))),
            (None, Some(fd)) => Ok(Inlet::Socket(fd)),
            (None, None) => unreachable!("checked by run_stage"),
        }
    }
}

/// Where a payload stage sends its samples.
enum Outlet<T: Sample> {
    /// Copied through a Unix socket, with a contiguous `seq` as a publisher would give.
    Socket {
        fd: OwnedFd,
        seq: u64,
    },
    Bus(Box<jetbench_bus::Publisher<T>>),
}

impl<T: Sample> Outlet<T> {
    /// False if a stop came before the sample could go.
    fn send(&mut self, mut sample: T) -> Result<bool, StageError> {
        match self {
            Outlet::Socket { fd, seq } => {
                sample.set_seq(*seq);
                *seq += 1;
                send_message(fd.as_fd(), sample.as_bytes())
            }
            Outlet::Bus(publisher) => {
                publisher.publish(sample)?;
                Ok(true)
            }
        }
    }

    /// The end marker: a sample with `stamp_ns = 0` (no cycle has that `t0`).
    fn end(&mut self) -> Result<bool, StageError> {
        self.send(T::default())
    }
}

/// Where a payload stage takes its samples from.
enum Inlet<T: Sample> {
    Socket(OwnedFd),
    Bus(Box<jetbench_bus::Subscriber<T>>),
}

/// What became of one input.
enum Handled {
    Next,
    /// The end marker went through.
    Last,
}

struct StageRun {
    stage: usize,
    cycles: u64,
    period_ns: u64,
    results: ResultWriter,
    counts: Counts,
}

impl StageRun {
    /// The eventfd chain: the source pings at the period, every other stage
    /// wakes on its eventfd and pings the next; no payload, no work.
    fn eventfd(&mut self, input: Option<OwnedFd>, output: Option<OwnedFd>) -> Result<End, StageError> {
        crate::service::announce_ready();
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
                let cycle = self.counts.handled;
                self.counts.handled += 1;
                self.results.push(StageRecord { cycle, stamp_ns: 0, wake_ns, sent_ns, scheduled_ns: 0 })?;
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
        self.counts.handled += 1;
        self.results.push(StageRecord {
            cycle: tick.cycle,
            stamp_ns: tick.t0_ns,
            wake_ns: tick.t0_ns,
            sent_ns,
            scheduled_ns: tick.scheduled_ns,
        })
    }

    /// The sample-carrying source: a simulated engine's force reading per
    /// cycle, calibrated by the real sensing step at `t0` and sent on.
    fn source(&mut self, config: &BenchConfig, mut out: Outlet<Thrust>) -> Result<End, StageError> {
        let plant = config.plant().map_err(|e| setup("simulated engine", e))?;
        let p = &config.plant;
        let mut sim = SimBench::new(&plant, p.noise_var_n2, p.seed, p.initial_throttle_pct)
            .map_err(|e| setup("simulated engine", e))?;
        let mut sensing = Sensing::new(&config.sensor).map_err(|e| setup("sensor calibration", e))?;
        // A slow throttle sine, so the estimator and the law see a moving engine.
        let period_s = self.period_ns as f64 * 1e-9;
        let throttle_pct = |cycle: u64| 50.0 + 25.0 * (std::f64::consts::TAU * cycle as f64 * period_s / 8.0).sin();
        let mut next_reading = |cycle: u64, now_ns: u64| {
            sim.step_driven(now_ns, throttle_pct(cycle))
                .map(|(reading, _)| reading)
                .map_err(|e| setup("simulated engine", e))
        };
        crate::service::announce_ready();
        if !wait_for_go()? {
            return Ok(End::Stopped);
        }
        let mut reading = next_reading(0, monotonic_ns())?;
        let mut schedule = Schedule::start(self.period_ns, self.cycles);
        while let Some(tick) = schedule.wait() {
            match sensing.step(&reading, tick.t0_ns) {
                Ok(thrust) => {
                    if !out.send(thrust)? {
                        return Ok(End::Stopped);
                    }
                }
                Err(e) => {
                    self.counts.errors += 1;
                    tracing::warn!("cycle {}: force reading rejected: {e}", tick.cycle);
                }
            }
            let sent_ns = monotonic_ns();
            self.source_record(&tick, sent_ns)?;
            // The next frame, off the critical path: the sensor's work, not sensing's.
            reading = next_reading(tick.cycle + 1, sent_ns)?;
        }
        // The end marker one period on, when the last cycle has gone through:
        // every stage reports after it, never during a cycle.
        if !schedule.wait_end() || !out.end()? {
            return Ok(End::Stopped);
        }
        Ok(End::Finished)
    }

    /// A sample-carrying stage after the source: takes each input, runs the
    /// real step, sends the result on (the last stage sends nothing: its
    /// "sent" is the actuator's output ready).
    fn relay<I: Sample, O: Sample>(
        &mut self,
        inlet: Inlet<I>,
        mut outlet: Option<Outlet<O>>,
        bus: Option<&Bus>,
        mut step: impl FnMut(&I) -> Result<O, String>,
    ) -> Result<End, StageError> {
        crate::service::announce_ready();
        let mut handle = |input: I, wake_ns: u64| -> Result<Handled, StageError> {
            if input.stamp_ns() == 0 {
                if let Some(out) = outlet.as_mut() {
                    out.end()?;
                }
                return Ok(Handled::Last);
            }
            match step(&input) {
                Ok(output) => {
                    if let Some(out) = outlet.as_mut() {
                        if !out.send(output)? {
                            return Ok(Handled::Last);
                        }
                    }
                }
                Err(e) => {
                    self.counts.errors += 1;
                    if self.counts.errors <= 5 {
                        tracing::warn!("input rejected: {e}");
                    }
                }
            }
            let sent_ns = monotonic_ns();
            self.counts.handled += 1;
            self.results.push(StageRecord {
                cycle: StageRecord::NO_CYCLE,
                stamp_ns: input.stamp_ns(),
                wake_ns,
                sent_ns,
                scheduled_ns: 0,
            })?;
            Ok(Handled::Next)
        };
        let last = match inlet {
            Inlet::Socket(fd) => consume_socket(fd.as_fd(), &mut handle)?,
            Inlet::Bus(subscriber) => {
                let bus = bus.expect("a bus inlet comes with its bus");
                let mut failure = None;
                let mut last = false;
                // As the services consume: asleep on the doorbell, with the input deadline.
                let inputs: [(&dyn jetbench_bus::Trigger, Option<Duration>); 1] =
                    [(&*subscriber, Some(crate::service::INPUT_DEADLINE))];
                let exit = bus.run(&inputs, None, |wake| {
                    if !matches!(wake, Wake::Input(_)) {
                        return Flow::Continue;
                    }
                    loop {
                        let result = subscriber.try_recv().map_err(StageError::from).and_then(|sample| match sample {
                            Some(sample) => handle(sample, monotonic_ns()).map(Some),
                            None => Ok(None),
                        });
                        match result {
                            Ok(Some(Handled::Next)) => {}
                            Ok(None) => return Flow::Continue,
                            Ok(Some(Handled::Last)) => {
                                last = true;
                                return Flow::Stop;
                            }
                            Err(e) => {
                                failure = Some(e);
                                return Flow::Stop;
                            }
                        }
                    }
                })?;
                if let Some(e) = failure {
                    return Err(e);
                }
                last && exit == LoopExit::Stopped
            }
        };
        Ok(if last && !stop_requested() { End::Finished } else { End::Stopped })
    }
}

/// Takes samples from a socket until the end marker (true) or a stop (false).
fn consume_socket<I: Sample>(
    fd: BorrowedFd,
    handle: &mut dyn FnMut(I, u64) -> Result<Handled, StageError>,
) -> Result<bool, StageError> {
    // Room for any sample type, so an oversized message shows as one.
    let mut buf = [0u8; 512];
    loop {
        if !wait_fd(fd, libc::POLLIN).map_err(io_error("cannot wait for the previous stage"))? {
            if stop_requested() {
                return Ok(false);
            }
            continue;
        }
        // SAFETY: receives at most `buf.len()` bytes into a live buffer.
        let n = unsafe { libc::recv(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len(), libc::MSG_DONTWAIT) };
        let wake_ns = monotonic_ns();
        if n == 0 {
            return Err(StageError::UpstreamClosed);
        }
        if n < 0 {
            let e = std::io::Error::last_os_error();
            if would_block(&e) {
                continue;
            }
            return Err(StageError::Io { what: "cannot receive from the previous stage", source: e });
        }
        let n = n as usize;
        let sample = I::from_bytes(&buf[..n]).ok_or(StageError::Malformed { len: n, expected: I::NAME })?;
        if let Handled::Last = handle(sample, wake_ns)? {
            return Ok(true);
        }
    }
}
