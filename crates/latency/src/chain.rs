//! The machine's floor for `jetbench latency`: a bare event ping chained
//! through as many processes as the control path has.
//!
//! The control path is sensing → estimation → control → actuation: four
//! processes, three hand-overs. The floor chain runs four `jetbench
//! latency-stage` processes in that shape, each at the real-time settings of
//! the service it stands for, passing an eventfd ping on with no payload and
//! no work: what waking the next process costs on this machine, under the
//! same load and priorities, below which no pipeline can go.
//!
//! Stage 0 is clocked like a sensor: `clock_nanosleep(TIMER_ABSTIME)` at the
//! period; the time it wakes is the cycle's `t0` (the pipeline's "sensor frame
//! received"). Each later stage stamps the time it woke with the ping; stage
//! 3's is the cycle's end. No stage busy-waits: each blocks in `poll` or
//! `clock_nanosleep`, which is what makes SCHED_FIFO on two cores safe.
//! Stages keep their stamps in memory and send them to the parent on their
//! own pipe after the last cycle (the source's end marker comes a period
//! after it), so reporting never holds up a hand-over; the parent joins them
//! by cycle.
//!
//! ```no_run
//! use jetbench_latency::chain::{run_chain, ChainOptions};
//! use jetbench_stack::config::BenchConfig;
//! use std::time::Duration;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let config = BenchConfig::default_sim()?;
//! let mut options = ChainOptions::new(std::env::current_exe()?);
//! options.duration = Duration::from_secs(20);
//! options.rt = jetbench_latency::chain::stage_rt_requests(&config.rt, true);
//! let run = run_chain(&options)?;
//! let mut e2e_ns = run.e2e_ns();
//! e2e_ns.sort_unstable();
//! println!("{} cycles, {} lost, median {} µs", run.cycles.len(), run.lost, e2e_ns[e2e_ns.len() / 2] / 1000);
//! # Ok(())
//! # }
//! ```

use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::Command;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use jetbench_bus::stop_requested;
use jetbench_msgs::ServiceId;
use jetbench_stack::config::RtSection;
use jetbench_stack::runtime::clock::PERIOD;
use jetbench_stack::runtime::rt::{RtOutcome, RtRequest};
use jetbench_stack::runtime::supervise::{describe_exit, SpawnOptions, StopOrder, Supervisor};

mod stage;

pub use stage::{inherited_fd, run_stage, StageError, StageOptions};

/// Processes in the control path.
pub const STAGES: usize = 4;
/// Process-to-process hand-overs in the control path.
pub const HOPS: usize = STAGES - 1;
/// The service each stage stands for (its real-time settings are that service's).
pub const STAGE_SERVICES: [ServiceId; STAGES] =
    [ServiceId::Sensing, ServiceId::Estimation, ServiceId::Control, ServiceId::Actuation];

/// How long a stage may take to start and create its ports.
const READY_TIMEOUT: Duration = Duration::from_secs(20);
/// How long a stage may take to exit after SIGTERM before SIGKILL.
const STOP_TIMEOUT: Duration = Duration::from_secs(5);

/// The real-time request of each stage: that of the service it stands for
/// (`None` when `[rt]` is off and not forced, as `jetbench up --rt` forces it).
pub fn stage_rt_requests(rt: &RtSection, force: bool) -> Option<[RtRequest; STAGES]> {
    let requests: Vec<RtRequest> = STAGE_SERVICES.iter().filter_map(|&id| rt.request(id, force)).collect();
    requests.try_into().ok()
}

/// What [`run_chain`] runs.
#[derive(Clone, Debug)]
pub struct ChainOptions {
    /// How long the source runs: `duration / period` cycles.
    pub duration: Duration,
    /// The source's period (the control period, 10 ms).
    pub period: Duration,
    /// Real-time settings per stage (see [`stage_rt_requests`]); `None` runs
    /// every stage with the normal scheduler.
    pub rt: Option<[RtRequest; STAGES]>,
    /// The `jetbench` binary, whose hidden `latency-stage` command runs a stage.
    pub exe: PathBuf,
}

impl ChainOptions {
    /// 10 s at the control period, without real-time settings.
    pub fn new(exe: impl Into<PathBuf>) -> Self {
        ChainOptions { duration: Duration::from_secs(10), period: PERIOD, rt: None, exe: exe.into() }
    }

    /// The number of cycles the source sends.
    pub fn cycles(&self) -> Result<u64, ChainError> {
        if self.period.is_zero() || self.period > Duration::from_secs(1) {
            return Err(ChainError::Options(format!("the period must be within 0 and 1 s, not {:?}", self.period)));
        }
        let cycles = (self.duration.as_nanos() / self.period.as_nanos()) as u64;
        if cycles == 0 {
            return Err(ChainError::Options(format!(
                "a run of {:?} is shorter than one period ({:?})",
                self.duration, self.period
            )));
        }
        Ok(cycles)
    }
}

/// Why a chain run failed.
#[derive(Debug, thiserror::Error)]
pub enum ChainError {
    /// Options that leave nothing to run (what is wrong).
    #[error("invalid chain options: {0}")]
    Options(String),
    /// The eventfds or pipes linking the stages could not be made.
    #[error("cannot create the {what} of the latency chain: {source}")]
    Setup {
        /// What was being made.
        what: &'static str,
        /// The system's reason.
        source: std::io::Error,
    },
    /// A stage process did not start.
    #[error("cannot start chain stage {stage} ({service}) from {exe}: {source} (is it the jetbench binary?)")]
    Spawn {
        /// The stage, 0..=3.
        stage: usize,
        /// The service whose place it takes.
        service: &'static str,
        /// The binary run.
        exe: PathBuf,
        /// The system's reason.
        source: std::io::Error,
    },
    /// A stage did not say it was ready in time.
    #[error("chain stage {stage} ({service}) did not report ready within {timeout:?}; see its log above")]
    NotReady {
        /// The stage, 0..=3.
        stage: usize,
        /// The service whose place it takes.
        service: &'static str,
        /// How long it was given.
        timeout: Duration,
    },
    /// A stage exited before the run's end.
    #[error("chain stage {stage} ({service}) {how}; see its log above")]
    StageDied {
        /// The stage, 0..=3.
        stage: usize,
        /// The service whose place it takes.
        service: &'static str,
        /// How it ended (exit code or signal).
        how: String,
    },
    /// A stage kept running after the run's end.
    #[error("chain stage {stage} ({service}) did not finish within {timeout:?} of the run's end")]
    NotFinished {
        /// The stage, 0..=3.
        stage: usize,
        /// The service whose place it takes.
        service: &'static str,
        /// How long it was given.
        timeout: Duration,
    },
    /// A stage's report does not parse.
    #[error("chain stage {stage} ({service}) sent malformed output: {what}")]
    Protocol {
        /// The stage, 0..=3.
        stage: usize,
        /// The service whose place it takes.
        service: &'static str,
        /// What does not parse.
        what: String,
    },
    /// Not one cycle reached the last stage.
    #[error("the chain completed no cycle (the source sent {sent})")]
    NoRecords {
        /// Cycles the source sent.
        sent: u64,
    },
    /// SIGINT or SIGTERM stopped the run.
    #[error("the chain run was interrupted")]
    Interrupted,
}

/// One stage's stamps of one cycle, as a stage reports them. Stages carry
/// no payload: downstream stages number the cycles by counting pings (an
/// eventfd cannot lose one).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StageRecord {
    /// The cycle's number, counted from 0 by every stage alike.
    pub cycle: u64,
    /// When the stage woke with its ping (stage 0: its clock), ns.
    pub wake_ns: u64,
    /// When its output was sent (stage 3: the actuator's output ready), ns.
    pub sent_ns: u64,
    /// Stage 0 only: when it was scheduled to wake, ns.
    pub scheduled_ns: u64,
}

impl StageRecord {
    /// Bytes of a record on the result pipe.
    pub const BYTES: usize = 32;

    fn to_bytes(self) -> [u8; Self::BYTES] {
        let mut out = [0; Self::BYTES];
        for (i, v) in [self.cycle, self.wake_ns, self.sent_ns, self.scheduled_ns].iter().enumerate() {
            out[8 * i..8 * i + 8].copy_from_slice(&v.to_le_bytes());
        }
        out
    }

    fn from_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != Self::BYTES {
            return None;
        }
        let v = |i: usize| u64::from_le_bytes(bytes[8 * i..8 * i + 8].try_into().expect("8 bytes"));
        Some(StageRecord { cycle: v(0), wake_ns: v(1), sent_ns: v(2), scheduled_ns: v(3) })
    }
}

/// One cycle that went through every stage. Times are `CLOCK_MONOTONIC` ns,
/// comparable across the stage processes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChainCycle {
    /// The cycle's number, from 0.
    pub cycle: u64,
    /// When the source was scheduled to wake.
    pub scheduled_ns: u64,
    /// When each stage woke with the cycle's input (stage 0: `t0`).
    pub wake_ns: [u64; STAGES],
    /// When each stage had sent its output (stage 3: the actuator's output ready).
    pub sent_ns: [u64; STAGES],
}

impl ChainCycle {
    /// `t0`: the source woke (the pipeline's sensor frame received).
    pub fn t0_ns(&self) -> u64 {
        self.wake_ns[0]
    }

    /// End to end: from `t0` to the actuator's output ready, ns. Equals the
    /// sum of [`ChainCycle::hop_ns`] and [`ChainCycle::actuate_ns`].
    pub fn e2e_ns(&self) -> u64 {
        self.sent_ns[STAGES - 1].saturating_sub(self.t0_ns())
    }

    /// Hop `h`: from stage `h` waking to stage `h + 1` waking (stage `h`'s
    /// work, its send, and the wake-up of the next process), ns.
    pub fn hop_ns(&self) -> [u64; HOPS] {
        std::array::from_fn(|h| self.wake_ns[h + 1].saturating_sub(self.wake_ns[h]))
    }

    /// The last stage's own work: woke to output ready, ns.
    pub fn actuate_ns(&self) -> u64 {
        self.sent_ns[STAGES - 1].saturating_sub(self.wake_ns[STAGES - 1])
    }

    /// Each stage's work and send: woke to sent, ns. (A hand-over alone,
    /// `wake[h + 1] - sent[h]`, is not given: the next stage, on another CPU,
    /// may wake before the sender has read the clock.)
    pub fn work_ns(&self) -> [u64; STAGES] {
        std::array::from_fn(|k| self.sent_ns[k].saturating_sub(self.wake_ns[k]))
    }

    /// The source woke more than a period after its schedule, or the cycle
    /// took longer than a period end to end.
    pub fn late(&self, period: Duration) -> bool {
        let period_ns = period.as_nanos() as u64;
        self.t0_ns().saturating_sub(self.scheduled_ns) > period_ns || self.e2e_ns() > period_ns
    }
}

/// What one stage process reported about itself.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StageReport {
    /// 0 = the clocked source … 3 = the sink.
    pub stage: usize,
    /// The service whose place in the control path it takes (its CPU and priority).
    pub service: ServiceId,
    /// What it was asked to set.
    pub requested: Option<RtRequest>,
    /// What it set and what the kernel refused, with the reasons.
    pub rt: RtOutcome,
    /// Its scheduling policy once set up, e.g. `SCHED_FIFO`, and priority.
    pub policy: String,
    /// Its real-time priority (0 outside SCHED_FIFO).
    pub priority: i32,
    /// Cycles it handled.
    pub handled: u64,
    /// Inputs its step rejected (their cycles go no further).
    pub errors: u64,
}

impl StageReport {
    fn new(stage: usize, requested: Option<RtRequest>) -> Self {
        StageReport {
            stage,
            service: STAGE_SERVICES[stage],
            requested,
            rt: RtOutcome::default(),
            policy: String::new(),
            priority: 0,
            handled: 0,
            errors: 0,
        }
    }

    /// True when the stage ran under SCHED_FIFO.
    pub fn fifo(&self) -> bool {
        self.policy == "SCHED_FIFO"
    }
}

/// The outcome of [`run_chain`].
#[derive(Clone, Debug)]
pub struct ChainRun {
    /// The source's period (the bench's 10 ms).
    pub period: Duration,
    /// Cycles the source sent.
    pub sent: u64,
    /// Cycles that reached every stage, in order.
    pub cycles: Vec<ChainCycle>,
    /// Cycles the source sent that never reached the last stage.
    pub lost: u64,
    /// `|actual period - period|` of the source, one per cycle after the first, ns.
    pub period_jitter_ns: Vec<u64>,
    /// Cycles whose source woke more than a period late, or that took more
    /// than a period end to end.
    pub late: u64,
    /// One per stage, in chain order (empty for runs built from records alone).
    pub stages: Vec<StageReport>,
}

impl ChainRun {
    /// Joins the stages' records (index = stage) by cycle.
    pub fn from_records(
        period: Duration,
        records: &[Vec<StageRecord>; STAGES],
        stages: Vec<StageReport>,
    ) -> Result<ChainRun, ChainError> {
        let mut source = records[0].clone();
        source.sort_by_key(|r| r.cycle);
        source.dedup_by_key(|r| r.cycle);
        let by_cycle: HashMap<u64, usize> = source.iter().enumerate().map(|(i, r)| (r.cycle, i)).collect();
        let mut cycles: Vec<ChainCycle> = source
            .iter()
            .map(|r| ChainCycle {
                cycle: r.cycle,
                scheduled_ns: r.scheduled_ns,
                wake_ns: [r.wake_ns, 0, 0, 0],
                sent_ns: [r.sent_ns, 0, 0, 0],
            })
            .collect();
        let mut seen = vec![1u8; source.len()];
        for (k, stage) in records.iter().enumerate().skip(1) {
            for r in stage {
                if let Some(&i) = by_cycle.get(&r.cycle) {
                    cycles[i].wake_ns[k] = r.wake_ns;
                    cycles[i].sent_ns[k] = r.sent_ns;
                    seen[i] |= 1 << k;
                }
            }
        }
        let all = (1u8 << STAGES) - 1;
        let period_ns = period.as_nanos() as u64;
        let sent = source.len() as u64;
        let mut late = 0;
        for ((r, c), &s) in source.iter().zip(&cycles).zip(&seen) {
            if r.wake_ns.saturating_sub(r.scheduled_ns) > period_ns || (s == all && c.late(period)) {
                late += 1;
            }
        }
        let period_jitter_ns =
            source.windows(2).map(|w| w[1].wake_ns.saturating_sub(w[0].wake_ns).abs_diff(period_ns)).collect();
        let complete: Vec<ChainCycle> =
            cycles.into_iter().zip(seen).filter(|&(_, s)| s == all).map(|(c, _)| c).collect();
        if complete.is_empty() {
            return Err(ChainError::NoRecords { sent });
        }
        Ok(ChainRun {
            period,
            sent,
            lost: sent - complete.len() as u64,
            cycles: complete,
            period_jitter_ns,
            late,
            stages,
        })
    }

    /// End-to-end latency of every complete cycle, ns, in cycle order.
    pub fn e2e_ns(&self) -> Vec<u64> {
        self.cycles.iter().map(ChainCycle::e2e_ns).collect()
    }

    /// Hop `hop` (0..3) of every complete cycle, ns, in cycle order.
    pub fn hop_ns(&self, hop: usize) -> Vec<u64> {
        self.cycles.iter().map(|c| c.hop_ns()[hop]).collect()
    }
}

// ---------------------------------------------------------------------------
// The parent: start the stages, run, stop, join.

/// Runs one chain: starts the four stages (each applies its real-time request
/// first), waits until all are ready, lets the source run `duration`, waits for
/// the last cycle to reach the last stage, stops and reaps the stages, and
/// joins their records. Blocks for about `duration` plus start-up.
///
/// A SIGINT/SIGTERM flagged through `jetbench_bus` ends the run early with
/// [`ChainError::Interrupted`]; the stages are stopped either way, and get
/// SIGTERM from the kernel should this process (the calling thread) die.
pub fn run_chain(options: &ChainOptions) -> Result<ChainRun, ChainError> {
    let cycles = options.cycles()?;
    if !options.exe.is_file() {
        return Err(ChainError::Spawn {
            stage: 0,
            service: STAGE_SERVICES[0].name(),
            exe: options.exe.clone(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        });
    }
    let links = Links::new()?;
    let mut stages = Stages { children: Supervisor::new(), stages: Vec::with_capacity(STAGES) };
    for k in 0..STAGES {
        let (result_read, result_write) = pipe().map_err(|source| ChainError::Setup { what: "result pipe", source })?;
        let spec = SpawnSpec {
            stage: k,
            cycles,
            input: links.input(k),
            output: links.output(k),
            results: result_write.as_raw_fd(),
        };
        spawn_stage(options, &spec, &mut stages.children)?;
        // The child has its own copy; ours must go so the pipe ends when the child does.
        drop(result_write);
        let results = std::thread::spawn(move || {
            let mut bytes = Vec::new();
            File::from(result_read).read_to_end(&mut bytes).map(|_| bytes)
        });
        stages.stages.push(StageState {
            results: Some(results),
            report: StageReport::new(k, options.rt.as_ref().map(|r| r[k].clone())),
            ready: false,
            done: false,
        });
    }
    // The stages hold their ends.
    drop(links);

    stages.pump(
        READY_TIMEOUT,
        |s| s.ready,
        |s, timeout| ChainError::NotReady { stage: s.report.stage, service: s.report.service.name(), timeout },
    )?;
    if let Some(stdin) = stages.children.stdin(0) {
        writeln!(stdin, "{GO}").map_err(|_| stages.died(0))?;
    }
    let finish = options.duration + Duration::from_secs(10) + options.duration / 4;
    stages.pump(
        finish,
        |s| s.done,
        |s, timeout| ChainError::NotFinished { stage: s.report.stage, service: s.report.service.name(), timeout },
    )?;
    stages.stop()?;

    let mut records: [Vec<StageRecord>; STAGES] = Default::default();
    for (k, s) in stages.stages.iter_mut().enumerate() {
        let protocol = |what: String| ChainError::Protocol { stage: k, service: STAGE_SERVICES[k].name(), what };
        let bytes = s
            .results
            .take()
            .expect("joined once")
            .join()
            .map_err(|_| protocol("the result reader panicked".into()))?
            .map_err(|e| protocol(format!("cannot read its results: {e}")))?;
        if bytes.len() % StageRecord::BYTES != 0 {
            return Err(protocol(format!("{} bytes of results is not a whole number of records", bytes.len())));
        }
        records[k] = bytes.chunks_exact(StageRecord::BYTES).filter_map(StageRecord::from_bytes).collect();
    }
    let reports = stages.stages.iter().map(|s| s.report.clone()).collect();
    ChainRun::from_records(options.period, &records, reports)
}

/// The parent's side of the hand-overs: for hop `h`, the eventfd stage `h`
/// writes and stage `h + 1` reads.
struct Links {
    hops: Vec<OwnedFd>,
}

impl Links {
    fn new() -> Result<Links, ChainError> {
        let mut hops = Vec::new();
        for _ in 0..HOPS {
            // SAFETY: eventfd has no memory preconditions; the fd is checked and owned at once.
            let fd = unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) };
            hops.push(owned(fd).map_err(|source| ChainError::Setup { what: "eventfd", source })?);
        }
        Ok(Links { hops })
    }

    /// The fd stage `k` reads its input from.
    fn input(&self, k: usize) -> Option<RawFd> {
        self.hops.get(k.checked_sub(1)?).map(|fd| fd.as_raw_fd())
    }

    /// The fd stage `k` sends its output on.
    fn output(&self, k: usize) -> Option<RawFd> {
        self.hops.get(k).map(|fd| fd.as_raw_fd())
    }
}

fn owned(fd: RawFd) -> std::io::Result<OwnedFd> {
    if fd < 0 {
        Err(std::io::Error::last_os_error())
    } else {
        // SAFETY: `fd` was just returned by the kernel to us and nothing else owns it.
        Ok(unsafe { OwnedFd::from_raw_fd(fd) })
    }
}

/// A pipe, both ends close-on-exec: (read, write).
fn pipe() -> std::io::Result<(OwnedFd, OwnedFd)> {
    let mut fds = [-1; 2];
    // SAFETY: `fds` has room for the two descriptors pipe2 writes.
    if unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok((owned(fds[0])?, owned(fds[1])?))
}

struct SpawnSpec {
    stage: usize,
    cycles: u64,
    input: Option<RawFd>,
    output: Option<RawFd>,
    results: RawFd,
}

/// Protocol lines of a stage on its stdout, and the parent's go on the source's stdin.
const READY: &str = "ready";
const GO: &str = "go";
const DONE: &str = "done";
const RT: &str = "rt";

fn spawn_stage(options: &ChainOptions, spec: &SpawnSpec, children: &mut Supervisor) -> Result<(), ChainError> {
    let k = spec.stage;
    let mut command = Command::new(&options.exe);
    command.arg("latency-stage").args([
        "--stage",
        &k.to_string(),
        "--cycles",
        &spec.cycles.to_string(),
        "--period-ns",
        &(options.period.as_nanos() as u64).to_string(),
        "--result-fd",
        &spec.results.to_string(),
    ]);
    if let Some(fd) = spec.input {
        command.arg("--input-fd").arg(fd.to_string());
    }
    if let Some(fd) = spec.output {
        command.arg("--output-fd").arg(fd.to_string());
    }
    if let Some(rt) = &options.rt {
        let rt = &rt[k];
        if let Some(priority) = rt.priority {
            command.arg("--priority").arg(priority.to_string());
        }
        if !rt.cpus.is_empty() {
            let cpus: Vec<String> = rt.cpus.iter().map(usize::to_string).collect();
            command.arg("--cpus").arg(cpus.join(","));
        }
        if rt.lock_memory {
            command.arg("--lock-memory");
        }
    }
    let inherit = [spec.input.unwrap_or(-1), spec.output.unwrap_or(-1), spec.results];
    // SAFETY: runs between fork and exec and calls only fcntl, which is
    // async-signal-safe, on plain integers; it allocates nothing.
    unsafe {
        command.pre_exec(move || {
            for fd in inherit {
                if fd >= 0 && libc::fcntl(fd, libc::F_SETFD, 0) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
    // A stage must not outlive its parent: it would hold the chain's CPU at its priority.
    let spawn = SpawnOptions { stdin: k == 0, parent_death_signal: Some(libc::SIGTERM), ..SpawnOptions::default() };
    children.spawn(format!("latency stage {k} ({})", STAGE_SERVICES[k].name()), &mut command, spawn).map_err(|e| {
        ChainError::Spawn { stage: k, service: STAGE_SERVICES[k].name(), exe: options.exe.clone(), source: e.source }
    })?;
    Ok(())
}

/// What the parent knows of one stage.
struct StageState {
    results: Option<JoinHandle<std::io::Result<Vec<u8>>>>,
    report: StageReport,
    ready: bool,
    done: bool,
}

/// The running stages (index = stage); dropping them stops whatever still runs.
struct Stages {
    children: Supervisor,
    stages: Vec<StageState>,
}

impl Stages {
    /// Handles stage output until `reached` holds for every stage, failing
    /// when a stage ends, `timeout` passes, or a stop is requested.
    fn pump(
        &mut self,
        timeout: Duration,
        reached: impl Fn(&StageState) -> bool,
        overdue: impl Fn(&StageState, Duration) -> ChainError,
    ) -> Result<(), ChainError> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some((k, line)) = self.children.try_line() {
                self.handle_line(k, &line)?;
            }
            if self.stages.iter().all(&reached) {
                return Ok(());
            }
            if self.children.reap().is_some() {
                // The last lines of a stage that ended may still be on their way.
                std::thread::sleep(Duration::from_millis(20));
                while let Some((k, line)) = self.children.try_line() {
                    self.handle_line(k, &line)?;
                }
            }
            if let Some(k) = (0..STAGES).find(|&k| self.children.exited(k).is_some() && !reached(&self.stages[k])) {
                return Err(self.died(k));
            }
            if stop_requested() {
                return Err(ChainError::Interrupted);
            }
            if Instant::now() > deadline {
                let late = self.stages.iter().find(|s| !reached(s)).expect("one has not reached it");
                return Err(overdue(late, timeout));
            }
            if let Some((k, line)) = self.children.next_line(Duration::from_millis(100)) {
                self.handle_line(k, &line)?;
            }
        }
    }

    fn handle_line(&mut self, k: usize, line: &str) -> Result<(), ChainError> {
        let s = &mut self.stages[k];
        let protocol = |what: String| ChainError::Protocol { stage: k, service: STAGE_SERVICES[k].name(), what };
        let mut words = line.split_whitespace();
        match words.next() {
            Some(READY) => s.ready = true,
            Some(DONE) => {
                let mut count = || words.next().and_then(|w| w.parse::<u64>().ok());
                match (count(), count()) {
                    (Some(handled), Some(errors)) => {
                        s.report.handled = handled;
                        s.report.errors = errors;
                        s.done = true;
                    }
                    _ => return Err(protocol(format!("bad line {line:?}"))),
                }
            }
            Some(RT) => {
                let rest = |skip: usize| line.splitn(skip + 1, ' ').nth(skip).unwrap_or("").to_string();
                match words.next() {
                    Some("applied") => s.report.rt.applied.push(rest(2)),
                    Some("refused") => s.report.rt.refused.push(rest(2)),
                    Some("policy") => {
                        s.report.policy = words.next().unwrap_or("").to_string();
                        s.report.priority = words.next().and_then(|p| p.parse().ok()).unwrap_or(0);
                    }
                    _ => return Err(protocol(format!("bad line {line:?}"))),
                }
            }
            // Not protocol: pass it on, attributed.
            _ => eprintln!("{}: {line}", self.children.name(k)),
        }
        Ok(())
    }

    fn died(&mut self, k: usize) -> ChainError {
        let how = match self.children.exited(k) {
            Some(status) => format!("{} before the run ended", describe_exit(status)),
            None => "stopped listening to its parent".into(),
        };
        ChainError::StageDied { stage: k, service: STAGE_SERVICES[k].name(), how }
    }

    /// SIGTERM to every stage, then reaps them; SIGKILL for one that does not
    /// exit in time. The first that did not end cleanly is the error.
    fn stop(&mut self) -> Result<(), ChainError> {
        match self.children.stop(StopOrder::Together, STOP_TIMEOUT) {
            None => Ok(()),
            Some((k, how)) => Err(ChainError::StageDied { stage: k, service: STAGE_SERVICES[k].name(), how }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERIOD: Duration = Duration::from_millis(10);
    const MS: u64 = 1_000_000;

    /// Stage 0's record of cycle `c`, woken `late_ns` after its schedule.
    fn source(c: u64, late_ns: u64) -> StageRecord {
        let scheduled_ns = 1_000 * MS + c * 10 * MS;
        let t0 = scheduled_ns + late_ns;
        StageRecord { cycle: c, wake_ns: t0, sent_ns: t0 + 1_000, scheduled_ns }
    }

    fn downstream(src: &StageRecord, k: u64) -> StageRecord {
        let wake_ns = src.wake_ns + k * 20_000;
        StageRecord { cycle: src.cycle, wake_ns, sent_ns: wake_ns + 3_000, scheduled_ns: 0 }
    }

    /// The records of a chain that passed `src`, except where `keep(stage, record)` says no.
    fn chain_records(src: &[StageRecord], keep: impl Fn(usize, &StageRecord) -> bool) -> [Vec<StageRecord>; STAGES] {
        std::array::from_fn(|k| match k {
            0 => src.to_vec(),
            // Downstream stages report in any order.
            _ => src.iter().rev().filter(|r| keep(k, r)).map(|r| downstream(r, k as u64)).collect(),
        })
    }

    #[test]
    fn records_join_by_cycle_and_a_cycle_missing_downstream_is_lost() {
        let src: Vec<_> = (0..5).map(|c| source(c, 50_000)).collect();
        // Cycle 2 never reaches stage 2.
        let records = chain_records(&src, |k, r| k < 2 || r.cycle != 2);
        let run = ChainRun::from_records(PERIOD, &records, Vec::new()).unwrap();
        assert_eq!((run.sent, run.lost, run.late), (5, 1, 0));
        assert_eq!(run.cycles.iter().map(|c| c.cycle).collect::<Vec<_>>(), [0, 1, 3, 4]);
        for c in &run.cycles {
            assert_eq!(c.hop_ns(), [20_000; HOPS]);
            assert_eq!(c.e2e_ns(), 63_000);
            assert_eq!(c.e2e_ns(), c.hop_ns().iter().sum::<u64>() + c.actuate_ns());
            assert_eq!(c.work_ns(), [1_000, 3_000, 3_000, 3_000]);
        }
        assert_eq!(run.period_jitter_ns, [0; 4]);
        assert_eq!(run.hop_ns(2), [20_000; 4]);
    }

    #[test]
    fn late_wakes_slow_cycles_and_jitter_are_counted() {
        // Cycle 1 wakes 12 ms late (a late cycle), cycle 2 still 3 ms late;
        // cycle 3 takes 11 ms end to end (a late cycle).
        let src: Vec<_> = [0, 12 * MS, 3 * MS, 0].iter().enumerate().map(|(c, &l)| source(c as u64, l)).collect();
        let mut records = chain_records(&src, |_, _| true);
        // Reported in reverse order: cycle 3 is the first record of stage 3.
        records[3][0].sent_ns = src[3].wake_ns + 11 * MS;
        let run = ChainRun::from_records(PERIOD, &records, Vec::new()).unwrap();
        assert_eq!(run.late, 2);
        assert_eq!(run.period_jitter_ns, [12 * MS, 9 * MS, 3 * MS]);
        assert!(run.cycles[3].late(PERIOD) && !run.cycles[2].late(PERIOD));
    }

    #[test]
    fn no_complete_cycle_is_an_error() {
        let mut records: [Vec<StageRecord>; STAGES] = Default::default();
        records[0] = vec![source(0, 0)];
        let e = ChainRun::from_records(PERIOD, &records, Vec::new()).unwrap_err();
        assert!(matches!(e, ChainError::NoRecords { sent: 1 }), "{e}");
    }

    #[test]
    fn records_survive_the_pipe_format() {
        let r = StageRecord { cycle: 7, wake_ns: 2, sent_ns: u64::MAX - 1, scheduled_ns: 4 };
        assert_eq!(StageRecord::from_bytes(&r.to_bytes()), Some(r));
        assert_eq!(StageRecord::from_bytes(&[0; 31]), None);
    }

    #[test]
    fn stages_ask_for_their_services_real_time_settings() {
        let rt = RtSection::default();
        assert_eq!(stage_rt_requests(&rt, false), None);
        let requests = stage_rt_requests(&rt, true).expect("forced");
        let priorities: Vec<_> = requests.iter().map(|r| r.priority).collect();
        // Sensing, estimation, control, actuation: each above the one feeding it.
        assert_eq!(priorities, [Some(50), Some(60), Some(70), Some(80)]);
        assert_eq!(requests[0].cpus, rt.cpus.sensing);
    }

    #[test]
    fn a_run_shorter_than_a_period_is_refused() {
        let mut options = ChainOptions::new("/nonexistent");
        assert_eq!(options.cycles().unwrap(), 1000);
        options.duration = Duration::from_millis(5);
        assert!(matches!(options.cycles(), Err(ChainError::Options(_))));
    }
}
