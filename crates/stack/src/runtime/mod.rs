//! The service lifecycle, and the one runner every service process runs under.
//!
//! A service is a [`Service`]: created with its devices and bus ports
//! ([`Service::new`]), started ([`Service::start`]), woken cycle after cycle
//! ([`Service::process`]) and stopped ([`Service::stop`]), the lifecycle of a
//! copper-rs task. It holds its algorithm (a plain `…Step` struct beside it,
//! e.g. [`crate::estimation::EstimationStep`], that never touches IPC) and wires it to the bus; it never opens the bus,
//! announces itself, keeps its heartbeat or logs a rejection itself: [`run`]
//! does that for every service alike.
//!
//! [`run`] loads the bench config and applies the service's real-time settings
//! (before any thread starts, so every thread inherits them), opens the bus as
//! the service's node, creates the service, prints `ready` on stdout (the
//! launcher waits for it), and then wakes it as its [`Schedule`] says until
//! SIGINT/SIGTERM or an error. Consumers sleep on their input's doorbell with a
//! deadline; only sim-bench keeps time.
//!
//! ```no_run
//! use jetbench_bus::Wake;
//! use jetbench_msgs::{channels, ServiceId, StateEstimate};
//! use jetbench_stack::runtime::clock::INPUT_DEADLINE;
//! use jetbench_stack::runtime::{run, Context, Input, RunOptions, Service, ServiceError, Setup};
//!
//! /// Counts state estimates, one heartbeat per estimate.
//! struct Counter(u64);
//!
//! impl Service for Counter {
//!     const ID: ServiceId = ServiceId::Control;
//!     type Inputs = Input<StateEstimate>;
//!
//!     fn new(setup: &Setup<'_>) -> Result<(Self, Self::Inputs), ServiceError> {
//!         Ok((Counter(0), Input::new(setup.bus.subscriber(channels::STATE, 16)?, INPUT_DEADLINE)))
//!     }
//!
//!     fn process(&mut self, wake: Wake, input: &Self::Inputs, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
//!         if let Wake::Input(_) = wake {
//!             while input.subscriber.try_recv()?.is_some() {
//!                 self.0 += 1;
//!                 ctx.cycle(false)?;
//!             }
//!         }
//!         Ok(())
//!     }
//! }
//!
//! # fn main() -> Result<(), ServiceError> {
//! run::<Counter>(&RunOptions::default())
//! # }
//! ```

use std::cell::Cell;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use jetbench_bus::{Bus, BusError, Flow, LoopExit, Publisher, ReceiveError, SendError, Subscriber, Trigger, Wake};
use jetbench_io::DeviceError;
use jetbench_msgs::{Sample, ServiceId};
use jetbench_record::RecordError;

use crate::config::{BenchConfig, ConfigError};
use crate::runtime::clock::monotonic_ns;
use crate::runtime::health::HealthReporter;
use crate::sim_bench::SimError;

pub mod clock;
pub mod health;
pub mod launch;
pub mod lifecycle;
mod reader;
pub mod rt;
pub mod status;
pub mod supervise;

pub use reader::{ChannelReader, Reader};

/// Why a service stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// The bus: opening it, a port, a publish, a receive or a wait.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The bench config does not load.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A device: the CAN sensor, the throttle board, the ECU, their emulators.
    #[error(transparent)]
    Device(#[from] DeviceError),
    /// A model file does not load, or the simulated engine diverged.
    #[error(transparent)]
    Model(#[from] jetbench_model::ModelError),
    /// The simulated sensor's settings are unusable.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The recording cannot be written.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// The control law or its throttle profile cannot be set up.
    #[error(transparent)]
    ControlSetup(#[from] crate::config::ControlSetupError),
    /// A setting that the config checks cannot catch (e.g. a CAN interface this
    /// machine does not have), with what to do.
    #[error("{0}")]
    Setup(String),
    /// The recorder's disk writer fell behind and samples were dropped.
    #[error("{0} samples were dropped because the disk writer fell behind")]
    Dropped(u64),
    /// The error of a service defined in another crate (the viewer, the bridge).
    #[error(transparent)]
    Other(Box<dyn std::error::Error + Send + Sync>),
}

jetbench_bus::from_bus_errors!(ServiceError);

/// What a service is created with.
pub struct Setup<'a> {
    /// The bench config.
    pub config: &'a BenchConfig,
    /// The bus, opened by the runner.
    pub bus: &'a Bus,
    /// The file a service writes (the recorder's MCAP file).
    pub output: Option<&'a Path>,
    /// Where a service that serves other machines listens (the viewer's
    /// `HOST:PORT`, the bridge's Zenoh endpoint); its default if `None`.
    pub listen: Option<&'a str>,
}

/// How the runner wakes a service.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Schedule {
    /// By its [`Inputs`]: [`Wake::Input`] when a sample was published,
    /// [`Wake::Missed`] when none came within the input's deadline.
    Inputs,
    /// Every period, on a fixed phase ([`Wake::Tick`]); ticks that could not
    /// run in time are skipped, not bunched. Inputs still wake it.
    Tick(Duration),
    /// By itself: [`Service::process`] is called again as soon as it returns
    /// ([`Wake::Tick`]) and blocks in its device read or on its own clock,
    /// never longer than a deadline, so a stop is noticed.
    SelfPaced,
}

/// The inputs whose publishes wake a service, owned by the runner beside it
/// so that the wait loop can hold them while the service is woken.
pub trait Inputs {
    /// Each woken input with the deadline after which a missed cycle is reported.
    fn triggers(&self) -> Vec<(&dyn Trigger, Option<Duration>)>;
}

/// No woken input (a service paced by a clock or a device).
impl Inputs for () {
    fn triggers(&self) -> Vec<(&dyn Trigger, Option<Duration>)> {
        Vec::new()
    }
}

/// One woken input: every publish on its channel wakes the service, and a
/// cycle without one within `deadline` is reported as missed.
pub struct Input<T: Sample> {
    /// The channel's subscriber.
    pub subscriber: Subscriber<T>,
    /// How long after the cycle's start a sample may come.
    pub deadline: Duration,
    /// A sample has arrived: before the first, a silent input is the expected
    /// start, not a missed cycle.
    started: Cell<bool>,
}

impl<T: Sample> Input<T> {
    /// An input that has not seen a sample yet.
    pub fn new(subscriber: Subscriber<T>, deadline: Duration) -> Self {
        Input { subscriber, deadline, started: Cell::new(false) }
    }

    /// True once a sample has arrived.
    pub fn started(&self) -> bool {
        self.started.get()
    }

    /// The cycle of a service that handles each sample as one cycle: on
    /// [`Wake::Input`] every queued sample goes to `handle` and closes a cycle;
    /// on [`Wake::Missed`] (once started) a missed cycle is reported.
    pub fn each_sample(
        &self,
        wake: Wake,
        ctx: &mut Context<'_>,
        mut handle: impl FnMut(T, &mut Context<'_>) -> Result<(), ServiceError>,
    ) -> Result<(), ServiceError> {
        match wake {
            Wake::Input(_) => {
                while let Some(sample) = self.subscriber.try_recv()? {
                    self.started.set(true);
                    handle(sample, ctx)?;
                    ctx.health().set_input_gaps(self.subscriber.gaps());
                    ctx.cycle(false)?;
                }
            }
            Wake::Missed(_) if self.started() => ctx.cycle(true)?,
            _ => {}
        }
        Ok(())
    }

    /// Takes the newest queued sample (the rest are older), marking the input started.
    pub fn latest(&self) -> Result<Option<T>, ReceiveError> {
        let latest = self.subscriber.latest()?;
        if latest.is_some() {
            self.started.set(true);
        }
        Ok(latest)
    }
}

impl<T: Sample> Inputs for Input<T> {
    fn triggers(&self) -> Vec<(&dyn Trigger, Option<Duration>)> {
        vec![(&self.subscriber as &dyn Trigger, Some(self.deadline))]
    }
}

/// A service: created, started, woken cycle after cycle, stopped.
pub trait Service: Sized {
    /// Which service this is: its bus node, its heartbeat's sender, its `[rt]` settings.
    const ID: ServiceId;
    /// Its woken inputs (`()` for none).
    type Inputs: Inputs;

    /// Opens its devices, creates its ports and its step state. Nothing runs yet.
    fn new(setup: &Setup<'_>) -> Result<(Self, Self::Inputs), ServiceError>;

    /// How it is woken.
    fn schedule(&self) -> Schedule {
        Schedule::Inputs
    }

    /// Once, after `ready` was announced and before the first wake-up.
    fn start(&mut self, _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        Ok(())
    }

    /// One wake-up. [`Context::cycle`] publishes the heartbeat of each cycle it completed.
    fn process(&mut self, wake: Wake, inputs: &Self::Inputs, ctx: &mut Context<'_>) -> Result<(), ServiceError>;

    /// Once at the end, whatever ended the loop (a stop request or an error):
    /// release the devices, report what happened.
    fn stop(&mut self, _inputs: &Self::Inputs, _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        Ok(())
    }
}

/// Rejections of one kind counted so far, and when to log them.
#[derive(Clone, Copy)]
struct Rejections {
    what: &'static str,
    count: u64,
}

/// What the runner hands a service while it runs: the bus, the heartbeat and
/// the rejection log, and when the current wake-up began.
pub struct Context<'a> {
    bus: &'a Bus,
    health: HealthReporter,
    wake_ns: u64,
    /// Per kind; a service has a handful, so a short list never reallocates in a cycle.
    rejections: Vec<Rejections>,
}

impl<'a> Context<'a> {
    fn new(bus: &'a Bus, health: HealthReporter) -> Self {
        Context { bus, health, wake_ns: monotonic_ns(), rejections: Vec::with_capacity(8) }
    }

    /// The bus.
    pub fn bus(&self) -> &'a Bus {
        self.bus
    }

    /// When the current wake-up began (`CLOCK_MONOTONIC` ns).
    pub fn wake_ns(&self) -> u64 {
        self.wake_ns
    }

    /// Marks now as the start of the current cycle (a self-paced service, once
    /// its device or clock woke it) and returns it.
    pub fn woke(&mut self) -> u64 {
        self.wake_ns = monotonic_ns();
        self.wake_ns
    }

    /// Publishes the heartbeat of a cycle that began at [`Context::wake_ns`] and
    /// ends now; `late` marks a cycle whose input missed its deadline.
    pub fn cycle(&mut self, late: bool) -> Result<(), BusError> {
        self.health.cycle(self.wake_ns, monotonic_ns(), late)
    }

    /// Counts a rejected input or a failed operation of kind `what`, and logs
    /// its first few occurrences, then every 1000th.
    pub fn reject(&mut self, what: &'static str, error: &dyn std::fmt::Display) {
        self.health.error();
        let count = match self.rejections.iter_mut().find(|r| r.what == what) {
            Some(r) => {
                r.count += 1;
                r.count
            }
            None => {
                self.rejections.push(Rejections { what, count: 1 });
                1
            }
        };
        log_rejection(count, what, error);
    }

    /// Publishes `sample` with `publish_ns` stamped (by `set`) right before it
    /// leaves. A sample holding NaN or an infinity is refused by the bus; that
    /// is counted and logged as a rejection here, and the service runs on.
    pub fn publish<T: Sample>(
        &mut self,
        publisher: &mut Publisher<T>,
        mut sample: T,
        set: fn(&mut T, u64),
    ) -> Result<(), SendError> {
        set(&mut sample, monotonic_ns());
        match publisher.publish(sample) {
            Err(e @ SendError::NonFinite { .. }) => {
                self.reject("non-finite sample", &e);
                Ok(())
            }
            result => result.map(drop),
        }
    }

    /// The heartbeat: error counts, input gaps, the fallback flag.
    pub fn health(&mut self) -> &mut HealthReporter {
        &mut self.health
    }
}

/// Logs the first few occurrences of a recurring error, then every 1000th.
pub fn log_rejection(count: u64, what: &str, error: &dyn std::fmt::Display) {
    if count <= 5 || count.is_multiple_of(1000) {
        tracing::warn!("{what} rejected ({count} so far): {error}");
    }
}

/// Tells the launcher this process's ports exist.
pub fn announce_ready() {
    announce("ready");
}

/// Tells the launcher why this process is about to stop with an error (it
/// names the reason when it reports the death, e.g. a full disk).
pub fn announce_failure(error: &dyn std::fmt::Display) {
    announce(&format!("{FAILED_PREFIX}{error}"));
}

/// The line a service prints on stdout before it stops with an error.
pub const FAILED_PREFIX: &str = "failed: ";

fn announce(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

/// The process that started this one, as it was when the service started.
static PARENT_PID: std::sync::OnceLock<u32> = std::sync::OnceLock::new();

/// True when the process that started this service (the launcher) is gone:
/// the parent-death signal stopped the service, and it is on its own.
pub fn launcher_gone() -> bool {
    // SAFETY: getppid has no preconditions.
    PARENT_PID.get().is_some_and(|&pid| unsafe { libc::getppid() } as u32 != pid)
}

/// How [`run`] starts a service.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Bench config; the built-in simulated bench if `None`.
    pub config: Option<PathBuf>,
    /// `[rt] enabled = true` for this run (`--rt`).
    pub rt: bool,
    /// The file the service writes (`--out` of the recorder).
    pub output: Option<PathBuf>,
    /// Where it listens (`--listen` of the viewer and the bridge).
    pub listen: Option<String>,
}

/// Runs service `S` until SIGINT/SIGTERM or its first error.
pub fn run<S: Service>(options: &RunOptions) -> Result<(), ServiceError> {
    // SAFETY: getppid has no preconditions.
    PARENT_PID.get_or_init(|| unsafe { libc::getppid() } as u32);
    // Before anything is created: the set's files are its user's (or group's) only.
    jetbench_bus::access::restrict().map_err(|e| ServiceError::Setup(e.to_string()))?;
    let mut config = BenchConfig::load_or_default(options.config.as_deref())?;
    // `--rt` is `[rt] enabled = true` for this run: the service's own threads follow it.
    config.rt.enabled |= options.rt;
    if let Some(request) = config.rt.request(S::ID, false) {
        crate::runtime::rt::apply(&request).log(S::ID.name());
    }
    let bus = Bus::open(S::ID.name())?;
    let setup =
        Setup { config: &config, bus: &bus, output: options.output.as_deref(), listen: options.listen.as_deref() };
    let (mut service, inputs) = S::new(&setup)?;
    let mut ctx = Context::new(&bus, HealthReporter::new(&bus, S::ID)?);
    announce_ready();
    let result = service.start(&mut ctx).and_then(|()| wake_until_stopped(&mut service, &inputs, &mut ctx));
    let stopped = service.stop(&inputs, &mut ctx);
    result.and(stopped)
}

fn wake_until_stopped<S: Service>(
    service: &mut S,
    inputs: &S::Inputs,
    ctx: &mut Context<'_>,
) -> Result<(), ServiceError> {
    let bus = ctx.bus;
    let tick = match service.schedule() {
        Schedule::SelfPaced => {
            while !bus.stop_requested() {
                ctx.woke();
                service.process(Wake::Tick, inputs, ctx)?;
            }
            return Ok(());
        }
        Schedule::Inputs => None,
        Schedule::Tick(period) => Some(period),
    };
    let mut failure = None;
    let exit = bus.run(&inputs.triggers(), tick, |wake| {
        ctx.woke();
        match service.process(wake, inputs, ctx) {
            Ok(()) => Flow::Continue,
            Err(e) => {
                failure = Some(e);
                Flow::Stop
            }
        }
    })?;
    match (failure, exit) {
        (Some(e), _) => Err(e),
        (None, LoopExit::Stopped | LoopExit::Terminated) => Ok(()),
    }
}
