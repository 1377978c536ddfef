//! The launcher behind `jetbench up`: starts the service processes in
//! dependency order ([`crate::runtime::supervise`]), waits until each is ready, shows a
//! live status line, and stops them all in order at the end, on Ctrl-C/SIGTERM,
//! or when one dies.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use jetbench_bus::{Bus, BusError, Flow, Subscriber};
use jetbench_msgs::{channels, Health, Sample, ServiceId};

use crate::config::{EngineSection, EngineStart};
use crate::runtime::lifecycle::{EngineWatch, Interrupts};
use crate::runtime::status::{self, EngineView, LiveLine, StatusView};
use crate::runtime::supervise::{describe_exit, SpawnOptions, StopOrder, Supervisor};

/// How long a service may take to create its ports.
const READY_TIMEOUT: Duration = Duration::from_secs(20);
/// How long a service may take to stop after SIGTERM before SIGKILL.
const STOP_TIMEOUT: Duration = Duration::from_secs(5);
/// How long the survivors run on after a service died, before they are
/// stopped: long enough for the fail-safe to act and be recorded (actuation
/// idles after `[actuation] idle_after_missed_cycles`, 3 by default, and the
/// board acknowledges; the board's own watchdog idles after 100 ms). Stopping
/// at once would take the simulated board away first, mid fail-safe.
const FAILSAFE_GRACE: Duration = Duration::from_millis(150);

/// Why `jetbench up` failed.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// A service's binary is not where the launcher looks.
    #[error("cannot find the service binary {path}: {hint}")]
    MissingBinary {
        /// Where it was looked for.
        path: PathBuf,
        /// How to build or point to it.
        hint: String,
    },
    /// The operating system refused to start a service.
    #[error("cannot start service `{service}`: {source}")]
    Spawn {
        /// The service's name.
        service: &'static str,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// A service started but never said it was ready.
    #[error("service `{service}` did not report ready within {timeout:?}; see its log above")]
    NotReady {
        /// The service's name.
        service: &'static str,
        /// How long the launcher waited.
        timeout: Duration,
    },
    /// A service exited during the run.
    #[error("service `{service}` {how}; the other services were stopped")]
    ServiceDied {
        /// The service's name.
        service: &'static str,
        /// Its exit status or signal, in words.
        how: String,
    },
    /// A service did not stop cleanly when asked.
    #[error("service `{service}` {how} while stopping")]
    StopFailed {
        /// The service's name.
        service: &'static str,
        /// Its exit status or signal, in words.
        how: String,
    },
    /// The test ended before its time: the ECU shut the engine down, or a
    /// limit tripped with the response `shutdown`.
    #[error("the test ended: {reason}")]
    TestEnded {
        /// The trip or the ECU's state, in words.
        reason: String,
    },
    /// The engine did not get to run.
    #[error("the engine did not run within {timeout_s} s (the ECU says {state}); {hint}")]
    NotRunning {
        /// How long the launcher waited, s.
        timeout_s: f64,
        /// The ECU's last state.
        state: String,
        /// What to check.
        hint: String,
    },
    /// The signal handler for Ctrl-C could not be installed.
    #[error("cannot count Ctrl-C: {0}")]
    Signals(std::io::Error),
    /// The bus could not be opened or used.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// Another set runs in this bus namespace.
    #[error(transparent)]
    Lock(#[from] jetbench_bus::lock::LockError),
    /// `[bench] group` cannot be used.
    #[error(transparent)]
    Group(#[from] jetbench_bus::access::GroupError),
}

jetbench_bus::from_bus_errors!(LaunchError);

/// What to launch.
#[derive(Clone, Debug)]
pub struct UpOptions {
    /// Bench config passed to every service; `None` is the built-in sim config.
    pub config: Option<PathBuf>,
    /// Run for this long once all services are ready; `None` until Ctrl-C.
    pub duration: Option<Duration>,
    /// Record every channel to this MCAP file.
    pub record: Option<PathBuf>,
    /// Folder of the `jetbench-<service>` binaries.
    pub bin_dir: PathBuf,
    /// Print the live status line.
    pub status: bool,
    /// Start sim-bench (the config's `[bench] devices = "sim"`); at the real bench the devices are real.
    pub simulated: bool,
    /// Ask every service for its `[rt]` settings (`--rt`), whatever `[rt] enabled` says.
    pub rt: bool,
    /// How samples travel between the services (set for each as `JETBENCH_TRANSPORT`).
    pub transport: jetbench_bus::Transport,
    /// Serve the Foxglove live view here (`HOST:PORT`): starts the viewer service.
    pub foxglove: Option<String>,
    /// Publish every channel on Zenoh, listening here (`tcp/HOST:PORT`): starts the bridge service.
    pub zenoh: Option<String>,
    /// The engine's lifecycle: how it starts, whether it cools down at the end.
    pub engine: EngineSection,
}

/// File name start of the config a launcher derives from its command line.
const DERIVED_PREFIX: &str = "jetbench-up-";

/// Where this launcher writes the config it derives from its command line (in
/// the temporary folder, named by its pid), once the derived configs of
/// launchers that were killed (SIGKILL leaves them behind) are removed.
pub fn derived_config_path() -> PathBuf {
    if let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) {
        for entry in entries.flatten() {
            let name = entry.file_name();
            let pid =
                name.to_str().and_then(|n| n.strip_prefix(DERIVED_PREFIX)?.strip_suffix(".toml")?.parse::<i32>().ok());
            if pid.is_some_and(|pid| !process_exists(pid)) {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
    std::env::temp_dir().join(format!("{DERIVED_PREFIX}{}.toml", std::process::id()))
}

/// Whether process `pid` exists (one of another user's counts).
fn process_exists(pid: i32) -> bool {
    // SAFETY: kill(pid, 0) sends nothing; it only asks whether the process exists.
    let answered = unsafe { libc::kill(pid, 0) } == 0;
    answered || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Start order: the recorder first so it sees every sample, then consumers
/// before producers, and the simulated bench (when `simulated`), which clocks the loop, last.
pub fn start_order(record: bool, simulated: bool) -> Vec<ServiceId> {
    UpOptions::order(&[(ServiceId::Recorder, record)], simulated)
}

impl UpOptions {
    /// The services this run starts, in order: the readers of every channel
    /// (recorder, viewer, bridge) first, so they see every sample, then
    /// consumers before producers, and the clocking simulated bench last.
    pub fn services(&self) -> Vec<ServiceId> {
        let readers = [
            (ServiceId::Recorder, self.record.is_some()),
            (ServiceId::Viewer, self.foxglove.is_some()),
            (ServiceId::Bridge, self.zenoh.is_some()),
        ];
        Self::order(&readers, self.simulated)
    }

    fn order(readers: &[(ServiceId, bool)], simulated: bool) -> Vec<ServiceId> {
        let mut order: Vec<ServiceId> = readers.iter().filter(|(_, on)| *on).map(|(id, _)| *id).collect();
        order.extend([ServiceId::Actuation, ServiceId::Control, ServiceId::Estimation, ServiceId::Sensing]);
        if simulated {
            order.push(ServiceId::SimBench);
        }
        order
    }
}

fn binary(bin_dir: &Path, id: ServiceId) -> Result<PathBuf, LaunchError> {
    let path = bin_dir.join(format!("jetbench-{}", id.name()));
    if path.is_file() {
        Ok(path)
    } else {
        Err(LaunchError::MissingBinary {
            path,
            hint: "build the workspace (`cargo build --release`) or set JETBENCH_BIN_DIR".into(),
        })
    }
}

/// The service processes of a run (index = position in `ids`, the start order).
#[derive(Default)]
struct Services {
    ids: Vec<ServiceId>,
    children: Supervisor,
    /// Why each service said it failed, if it did (its `failed: ...` line).
    failures: Vec<Option<String>>,
}

impl Services {
    fn spawn(&mut self, options: &UpOptions, id: ServiceId) -> Result<(), LaunchError> {
        let mut command = Command::new(binary(&options.bin_dir, id)?);
        if let Some(config) = &options.config {
            command.arg("--config").arg(config);
        }
        if options.rt {
            command.arg("--rt");
        }
        command.env(jetbench_bus::TRANSPORT_ENV, options.transport.name());
        let (flag, value) = match id {
            ServiceId::Recorder => ("--out", options.record.as_ref().map(|p| p.as_os_str())),
            ServiceId::Viewer => ("--listen", options.foxglove.as_deref().map(std::ffi::OsStr::new)),
            ServiceId::Bridge => ("--listen", options.zenoh.as_deref().map(std::ffi::OsStr::new)),
            _ => ("", None),
        };
        if let Some(value) = value {
            command.arg(flag).arg(value);
        }
        // In its own process group (as the supervisor starts every child): Ctrl-C
        // reaches only the launcher, which then stops the services in order (so the
        // recorder sees the last samples). Should the launcher die (SIGKILL), each
        // service gets SIGTERM from the kernel and stops safely on its own.
        // Their logs (stderr) come to the launcher, which prints them above the status line.
        let spawn =
            SpawnOptions { parent_death_signal: Some(libc::SIGTERM), stderr_lines: true, ..SpawnOptions::default() };
        let index = self
            .children
            .spawn(id.name(), &mut command, spawn)
            .map_err(|e| LaunchError::Spawn { service: id.name(), source: e.source })?;
        self.ids.push(id);
        self.failures.push(None);
        println!("started {} (pid {})", id.name(), self.children.pid(index));
        Ok(())
    }

    /// Prints what the services printed on stdout, attributed, waiting up to
    /// `wait` for the first line; returns the services that said `ready`.
    fn pump_lines(&mut self, wait: Duration) -> Vec<ServiceId> {
        let mut ready = Vec::new();
        let mut next = self.children.next_line(wait);
        while let Some((i, line)) = next {
            if line.trim() == "ready" {
                ready.push(self.ids[i]);
            } else if let Some(why) = line.strip_prefix(crate::runtime::FAILED_PREFIX) {
                self.failures[i] = Some(why.to_string());
            } else {
                status::say(&format!("{}: {line}", self.ids[i].name()));
            }
            next = self.children.try_line();
        }
        while let Some((i, line)) = self.children.try_err_line() {
            status::say_err(&format!("{}: {line}", self.ids[i].name()));
        }
        ready
    }

    /// The first service that has ended, as the error naming it (and why it
    /// said it failed, e.g. its disk is full).
    fn died(&mut self) -> Option<LaunchError> {
        let (i, status) = self.children.reap()?;
        // Its last words may still be in the pipe.
        self.pump_lines(Duration::from_millis(20));
        let how = match &self.failures[i] {
            Some(why) => format!("{}: {why}", describe_exit(status)),
            None => describe_exit(status),
        };
        Some(LaunchError::ServiceDied { service: self.ids[i].name(), how })
    }

    /// Stops the services safely, the engine first: control, so that actuation
    /// idles within its missed cycles and the board acknowledges; after
    /// [`FAILSAFE_GRACE`], actuation, which disarms the board; then the rest
    /// from the clocking sim-bench (which runs its engine down to idle) back,
    /// and the recorder last, so that all of it is recorded. Returns the first
    /// that did not stop cleanly.
    fn stop_all(&mut self) -> Option<(ServiceId, String)> {
        let index = |id| self.ids.iter().position(|&i| i == id);
        let (control, actuation, recorder) =
            (index(ServiceId::Control), index(ServiceId::Actuation), index(ServiceId::Recorder));
        let mut failure = None;
        if let Some(c) = control.filter(|&c| self.children.exited(c).is_none()) {
            failure = self.children.stop(StopOrder::InTurn(vec![c]), STOP_TIMEOUT);
            if actuation.is_some_and(|a| self.children.exited(a).is_none()) {
                std::thread::sleep(FAILSAFE_GRACE);
            }
        }
        let rest =
            (0..self.ids.len()).rev().filter(|&i| Some(i) != control && Some(i) != actuation && Some(i) != recorder);
        let order = actuation.into_iter().chain(rest).chain(recorder).collect();
        failure = failure.or(self.children.stop(StopOrder::InTurn(order), STOP_TIMEOUT));
        // Their last words may still be on the way from the pipes' readers.
        self.pump_lines(Duration::from_millis(50));
        failure.map(|(i, how)| (self.ids[i], how))
    }
}

/// Samples seen on each control-path channel since the launcher started.
#[derive(Clone, Copy, Debug, Default)]
struct ChannelCounts {
    thrust: u64,
    state: u64,
    reference: u64,
    command: u64,
    actuation: u64,
}

/// A service's heartbeat totals.
#[derive(Clone, Copy, Debug, Default)]
struct ServiceTotals {
    misses: u64,
    gaps: u64,
    flags: u32,
}

/// Slots for services by id (ids start at 1).
const SERVICE_SLOTS: usize = ServiceId::ALL.len() + 1;

/// What the status line is made from. Its subscribers are polled on the
/// launcher's 20 ms tick, so their queues never fill: a full queue would make
/// every publish on the control path take back its oldest sample.
struct Status {
    thrust: Subscriber<jetbench_msgs::Thrust>,
    state: Subscriber<jetbench_msgs::StateEstimate>,
    reference: Subscriber<jetbench_msgs::Reference>,
    command: Subscriber<jetbench_msgs::Command>,
    actuation: Subscriber<jetbench_msgs::Actuation>,
    health: Subscriber<Health>,
    counts: ChannelCounts,
    /// `counts` when the last line was made.
    printed: ChannelCounts,
    /// Heartbeat totals by service id, now and when the last line was made.
    services: [Option<ServiceTotals>; SERVICE_SLOTS],
    services_printed: [Option<ServiceTotals>; SERVICE_SLOTS],
    misses: status::MissWatch,
    view: StatusView,
}

impl Status {
    /// Samples one tick may bring per channel, with room for a late tick
    /// (six services share `bench/health`).
    const DEPTH: usize = 64;

    fn new(bus: &Bus) -> Result<Self, BusError> {
        Ok(Status {
            thrust: bus.polled_subscriber(channels::THRUST, Self::DEPTH)?,
            state: bus.polled_subscriber(channels::STATE, Self::DEPTH)?,
            reference: bus.polled_subscriber(channels::REFERENCE, Self::DEPTH)?,
            command: bus.polled_subscriber(channels::COMMAND, Self::DEPTH)?,
            actuation: bus.polled_subscriber(channels::ACTUATION, Self::DEPTH)?,
            health: bus.polled_subscriber(channels::HEALTH, 8 * Self::DEPTH)?,
            counts: ChannelCounts::default(),
            printed: ChannelCounts::default(),
            services: [None; SERVICE_SLOTS],
            services_printed: [None; SERVICE_SLOTS],
            misses: status::MissWatch::default(),
            view: StatusView::default(),
        })
    }

    fn drain_one<T: Sample>(sub: &Subscriber<T>, count: &mut u64, mut last: impl FnMut(&T)) -> Result<(), BusError> {
        while let Some(s) = sub.try_recv()? {
            *count += 1;
            last(&s);
        }
        Ok(())
    }

    /// Takes everything queued since the last tick.
    fn drain(&mut self) -> Result<(), BusError> {
        let view = &mut self.view;
        Self::drain_one(&self.thrust, &mut self.counts.thrust, |_| {})?;
        Self::drain_one(&self.state, &mut self.counts.state, |s| view.thrust_n = Some(s.thrust_n))?;
        Self::drain_one(&self.reference, &mut self.counts.reference, |r| view.target_n = Some(r.thrust_n))?;
        Self::drain_one(&self.command, &mut self.counts.command, |c| view.command_flags = Some(c.flags))?;
        Self::drain_one(&self.actuation, &mut self.counts.actuation, |a| {
            view.throttle_pct = Some(a.applied_pct);
            view.actuation_flags = Some(a.flags);
        })?;
        while let Some(h) = self.health.try_recv()? {
            if let Some(slot) = self.services.get_mut(h.service_id as usize) {
                *slot = Some(ServiceTotals { misses: h.deadline_misses, gaps: h.input_gaps, flags: h.flags });
            }
        }
        Ok(())
    }

    /// The line for the `window` since the last one, and the explanation of
    /// deadline misses when they rose.
    fn line(&mut self, elapsed: Duration, window: Duration, watch: &EngineWatch) -> (String, Option<String>) {
        let before = std::mem::replace(&mut self.printed, self.counts);
        let secs = window.as_secs_f64().max(1e-3);
        let counts = self.counts;
        let rate = |channel: &'static str, count: fn(&ChannelCounts) -> u64| status::ChannelRate {
            channel,
            hz: (count(&counts) - count(&before)) as f64 / secs,
        };
        let rates = [
            rate(channels::THRUST.name, |c| c.thrust),
            rate(channels::STATE.name, |c| c.state),
            rate(channels::REFERENCE.name, |c| c.reference),
            rate(channels::COMMAND.name, |c| c.command),
            rate(channels::ACTUATION.name, |c| c.actuation),
        ];
        let services_before = std::mem::replace(&mut self.services_printed, self.services);
        let mut windows = Vec::new();
        let mut totals = Vec::new();
        for id in ServiceId::ALL {
            let Some(now) = self.services[id as usize] else { continue };
            let then = services_before[id as usize].unwrap_or_default();
            windows.push(status::ServiceWindow {
                service: id,
                new_misses: now.misses.saturating_sub(then.misses),
                new_gaps: now.gaps.saturating_sub(then.gaps),
                flags: now.flags,
            });
            totals.push((id, now.misses));
        }
        let view = &mut self.view;
        view.elapsed_s = elapsed.as_secs_f64();
        view.health = status::judge_health(&rates, &windows);
        view.engine = match (watch.state(), watch.latest) {
            (Some(s), Some(t)) => Some(EngineView { state: s.to_string(), rpm: t.rpm, egt_c: t.egt_c }),
            _ => None,
        };
        view.last_trip.clone_from(&watch.last_trip);
        (view.line(), self.misses.update(view.elapsed_s, &totals))
    }
}

/// Runs the service set; returns when the duration ends or a stop is
/// requested, with every service stopped.
pub fn up(options: &UpOptions) -> Result<(), LaunchError> {
    jetbench_bus::install_signal_flag()?;
    let interrupts = Interrupts::install().map_err(LaunchError::Signals)?;
    jetbench_bus::access::restrict()?;
    if let Some(ns) = jetbench_bus::namespace()? {
        println!("bus namespace {ns} ({} is set)", jetbench_bus::NAMESPACE_ENV);
    }
    // One set per namespace, held by the services too until the last is gone.
    let lock = jetbench_bus::lock::NamespaceLock::acquire("jetbench up")?;
    lock.inherit().map_err(|source| jetbench_bus::lock::LockError::Io { path: lock.path().into(), source })?;
    let cleaned = jetbench_bus::cleanup_dead_nodes();
    if cleaned > 0 {
        println!("cleaned up {cleaned} bus node(s) left by a previous run");
    }
    if options.simulated {
        // A sim-bench killed last time may have left its pty links behind,
        // pointing at ptys the system may since have given to someone else:
        // actuation starts first and must not open those.
        for name in [crate::config::SIM_BOARD_LINK, crate::config::SIM_ECU_LINK] {
            let link = crate::config::sim_port_link(name);
            if std::fs::symlink_metadata(&link).is_ok_and(|m| m.file_type().is_symlink()) {
                let _ = std::fs::remove_file(&link);
            }
        }
    }
    let order = options.services();
    for id in &order {
        binary(&options.bin_dir, *id)?;
    }

    let mut services = Services::default();
    let result = start_and_supervise(options, &order, &mut services, &interrupts);
    if matches!(result, Err(LaunchError::ServiceDied { .. })) {
        std::thread::sleep(FAILSAFE_GRACE);
    }
    let stop_failure = services.stop_all();
    match (result, stop_failure) {
        (Err(e), _) => Err(e),
        (Ok(()), Some((id, how))) => Err(LaunchError::StopFailed { service: id.name(), how }),
        (Ok(()), None) => Ok(()),
    }
}

fn start_and_supervise(
    options: &UpOptions,
    order: &[ServiceId],
    services: &mut Services,
    interrupts: &Interrupts,
) -> Result<(), LaunchError> {
    for &id in order {
        services.spawn(options, id)?;
        let deadline = Instant::now() + READY_TIMEOUT;
        loop {
            if jetbench_bus::stop_requested() {
                return Ok(());
            }
            if let Some(died) = services.died() {
                return Err(died);
            }
            if services.pump_lines(Duration::from_millis(20)).contains(&id) {
                break;
            }
            if Instant::now() >= deadline {
                return Err(LaunchError::NotReady { service: id.name(), timeout: READY_TIMEOUT });
            }
        }
    }
    println!(
        "all {} services ready{}",
        services.ids.len(),
        match options.duration {
            Some(d) => format!("; running for {:.1} s once the engine runs", d.as_secs_f64()),
            None => "; Ctrl-C stops (idle, then shutdown); a second Ctrl-C shuts down at once".into(),
        }
    );

    let bus = Bus::open_with("jetbench-up", options.transport)?;
    let mut watch = EngineWatch::new(&bus)?;
    if let Some(failure) = wait_for_run(options, services, &mut watch)? {
        return Err(failure);
    }
    let result = run_engine(options, services, &bus, &mut watch);
    bring_down(options, services, &mut watch, interrupts)?;
    result?;
    match watch.outcome() {
        Some((reason, true)) => Err(LaunchError::TestEnded { reason }),
        Some((reason, false)) => {
            println!("test ended: {reason}");
            Ok(())
        }
        None => Ok(()),
    }
}

/// Until the ECU says run: starts the engine through it (`[engine] start =
/// "auto"`), or waits for someone to; shows the states as they come.
/// `Some(error)` when it did not get there (a stop, a death, the timeout).
fn wait_for_run(
    options: &UpOptions,
    services: &mut Services,
    watch: &mut EngineWatch,
) -> Result<Option<LaunchError>, LaunchError> {
    let engine = &options.engine;
    if engine.start == EngineStart::Running {
        return Ok(None);
    }
    let started = Instant::now();
    let timeout = Duration::from_secs_f64(engine.start_timeout_s);
    let mut asked: Option<Instant> = None;
    let mut shown = None;
    match engine.start {
        EngineStart::Auto => println!("starting the engine through the ECU"),
        _ => println!("waiting for the engine to run: start it from the ECU, or run `jetbench start`"),
    }
    loop {
        services.pump_lines(Duration::ZERO);
        if let Some(died) = services.died() {
            return Ok(Some(died));
        }
        watch.poll()?;
        if watch.state() != shown {
            shown = watch.state();
            if let (Some(s), Some(t)) = (shown, watch.latest) {
                println!("ECU {s}: {:.0} rpm, EGT {:.0} °C, pump {:.2} V", t.rpm, t.egt_c, t.pump_v);
            }
        }
        if watch.running() {
            println!("engine running after {:.1} s", started.elapsed().as_secs_f64());
            return Ok(None);
        }
        if jetbench_bus::stop_requested() || watch.ended.is_some() {
            return Ok(None);
        }
        let standby = watch.state() == Some(jetbench_io::ecu::state::EcuState::Standby);
        if engine.start == EngineStart::Auto && standby && asked.is_none_or(|t| t.elapsed() > Duration::from_secs(3)) {
            watch.command(jetbench_msgs::operator_commands::START)?;
            asked = Some(Instant::now());
        }
        if started.elapsed() >= timeout {
            return Ok(Some(LaunchError::NotRunning {
                timeout_s: engine.start_timeout_s,
                state: watch.state().map_or_else(|| "nothing (no reply)".to_string(), |s| s.to_string()),
                hint: match engine.start {
                    EngineStart::Auto => "see the ECU's events above".into(),
                    _ => "start it from the ECU, or set [engine] start = \"auto\"".into(),
                },
            }));
        }
        crate::runtime::lifecycle::tick();
    }
}

/// The end of a run: with `[engine] cool_down_at_end`, idle, shut down
/// through the ECU and record the cool-down until the engine is off (a
/// second Ctrl-C shuts down at once, a third stops waiting). Without it, a
/// test that ended keeps recording for a moment, so its idle is on record.
fn bring_down(
    options: &UpOptions,
    services: &mut Services,
    watch: &mut EngineWatch,
    interrupts: &Interrupts,
) -> Result<(), LaunchError> {
    watch.poll()?;
    if !options.engine.cool_down_at_end {
        if watch.ended.is_some() {
            std::thread::sleep(Duration::from_millis(300));
            watch.poll()?;
        }
        return Ok(());
    }
    if watch.ended.is_none() {
        let now = interrupts.count() >= 2;
        watch.command(if now {
            jetbench_msgs::operator_commands::STOP_NOW
        } else {
            jetbench_msgs::operator_commands::STOP
        })?;
    }
    println!("bringing the engine down: idle, shutdown, cool-down (Ctrl-C again: shut down at once)");
    let started = Instant::now();
    let timeout = Duration::from_secs_f64(options.engine.cool_down_timeout_s);
    let mut shown = watch.state();
    let mut stopped_now = false;
    let presses = interrupts.count();
    // Until the ECU reports the engine off; a reply is awaited at least briefly.
    while started.elapsed() < timeout {
        services.pump_lines(Duration::ZERO);
        if let Some(died) = services.died() {
            return Err(died);
        }
        watch.poll()?;
        if watch.state() != shown {
            shown = watch.state();
            if let (Some(s), Some(t)) = (shown, watch.latest) {
                println!("ECU {s}: {:.0} rpm, EGT {:.0} °C", t.rpm, t.egt_c);
            }
        }
        if !watch.engine_busy() && started.elapsed() > Duration::from_millis(500) {
            println!("engine off after {:.1} s", started.elapsed().as_secs_f64());
            return Ok(());
        }
        let count = interrupts.count();
        if count > presses && !stopped_now {
            println!("shutting down at once");
            watch.command(jetbench_msgs::operator_commands::STOP_NOW)?;
            stopped_now = true;
        }
        if count > presses + 1 {
            println!("no longer waiting for the cool-down");
            return Ok(());
        }
        crate::runtime::lifecycle::tick();
    }
    eprintln!(
        "the engine was not off within {:.0} s (the ECU says {})",
        options.engine.cool_down_timeout_s,
        watch.state().map_or_else(|| "nothing".to_string(), |s| s.to_string())
    );
    Ok(())
}

/// The run itself, from the engine running to the duration's end, a stop, a
/// death or the test's end.
fn run_engine(
    options: &UpOptions,
    services: &mut Services,
    bus: &Bus,
    watch: &mut EngineWatch,
) -> Result<(), LaunchError> {
    // No status line, no subscribers: a quiet run adds nothing to the control path.
    let mut status = if options.status { Some(Status::new(bus)?) } else { None };
    // On a terminal the line is redrawn in place every second; in a log it is a
    // line of its own every 5 s.
    let live = if options.status { LiveLine::start() } else { None };
    let status_every = if live.is_some() { Duration::from_secs(1) } else { Duration::from_secs(5) };
    let started = Instant::now();
    let mut last_status = started;
    let mut failure = None;
    bus.run(&[], Some(Duration::from_millis(20)), |_| {
        services.pump_lines(Duration::ZERO);
        if let Some(died) = services.died() {
            failure = Some(died);
            return Flow::Stop;
        }
        if let Err(e) = watch.poll() {
            failure = Some(e.into());
            return Flow::Stop;
        }
        if watch.ended.is_some() {
            return Flow::Stop;
        }
        let now = Instant::now();
        if let Some(status) = status.as_mut() {
            if status.drain().is_ok() && now - last_status >= status_every {
                let (line, misses) = status.line(now - started, now - last_status, watch);
                if let Some(misses) = misses {
                    status::say(&misses);
                }
                match &live {
                    Some(live) => live.set(line),
                    None => status::say_err(&line),
                }
                last_status = now;
            }
        }
        match options.duration {
            Some(d) if now - started >= d => Flow::Stop,
            _ => Flow::Continue,
        }
    })?;
    drop(live);
    match failure {
        Some(e) => Err(e),
        None => Ok(()),
    }
}
