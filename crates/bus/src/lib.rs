//! Typed publish/subscribe over iceoryx2 shared memory.
//!
//! Every channel is an iceoryx2 publish-subscribe service paired with a
//! [doorbell](bell): a futex word in shared memory. A [`Publisher`] stamps
//! each sample with its own contiguous `seq`, writes it into shared memory
//! and rings; a [`Subscriber`] counts `seq` gaps per publisher, and consumers
//! sleep on their inputs' doorbells with a deadline ([`Bus::run`]) instead of
//! polling. The doorbell module says why it is not iceoryx2's event service.
//!
//! The same API runs over a second, copying transport, Unix domain sockets
//! ([`uds`], chosen with `JETBENCH_TRANSPORT=uds`): the baseline the zero-copy
//! bus is measured against, with everything else about a service unchanged.
//!
//! ```no_run
//! use jetbench_bus::{Bus, Flow, Wake};
//! use jetbench_msgs::{channels, Thrust};
//! use std::time::Duration;
//!
//! # fn main() -> Result<(), jetbench_bus::BusError> {
//! let bus = Bus::open("example")?;
//! let mut publisher = bus.publisher(channels::THRUST)?;
//! let subscriber = bus.subscriber(channels::THRUST, 16)?;
//! publisher.publish(Thrust { thrust_n: 40.0, ..Thrust::default() })?;
//! bus.run(&[(&subscriber, Some(Duration::from_millis(50)))], None, |wake| {
//!     if let Wake::Input(0) = wake {
//!         while let Ok(Some(thrust)) = subscriber.try_recv() {
//!             println!("{} N (seq {})", thrust.thrust_n, thrust.seq);
//!         }
//!     }
//!     Flow::Stop
//! })?;
//! # Ok(())
//! # }
//! ```
//!
//! Signals: the bus installs its own SIGINT/SIGTERM flag (iceoryx2's handling is
//! disabled, because its latch is reset on read and overwritten by any other
//! signal, e.g. SIGCHLD). Every wait returns when the flag is set, and
//! [`Bus::stop_requested`] tells loops to end.

use std::cell::{Cell, RefCell};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::prelude::*;
use jetbench_msgs::{Channel, Sample};

pub mod bell;
pub mod uds;

use bell::{Doorbell, Woke};

/// The longest any single wait blocks before the stop flag is checked again.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// Capacity limits shared by every process, so that `open_or_create` agrees.
/// (Publishers per channel come with the channel: [`Channel::max_publishers`].)
/// Every publish walks all subscriber slots and every receive all publisher
/// slots, in memory a 10 ms cycle finds cold, so they are kept to what a
/// channel needs.
pub mod limits {
    /// Subscribers per channel: its consumer, the recorder, the launcher's
    /// status line, `echo`, `hz`, and room for tests and tools.
    pub const MAX_SUBSCRIBERS: usize = 8;
    /// Deepest subscriber queue a channel allows; the recorder asks for this.
    pub const MAX_BUFFER: usize = 512;
    /// Nodes that may open one channel.
    pub const MAX_NODES: usize = 32;
}

/// Everything that can fail on the bus, with the channel concerned.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("invalid bus name {name:?}: {reason}")]
    InvalidName { name: String, reason: String },
    #[error("unknown transport {0:?}: {TRANSPORT_ENV} is iceoryx2 (the default) or uds")]
    InvalidTransport(String),
    #[error("cannot create the bus node {node:?}: {reason} (is /dev/shm writable?)")]
    NodeCreate { node: String, reason: String },
    #[error(
        "cannot open channel {channel}: {reason} (a process of an older build may still hold it; stop it and retry)"
    )]
    ServiceOpen { channel: String, reason: String },
    #[error("cannot create a port on {channel}: {reason}")]
    PortCreate { channel: String, reason: String },
    #[error("cannot publish on {channel}: {reason}")]
    Send { channel: String, reason: String },
    #[error("cannot receive on {channel}: {reason}")]
    Receive { channel: String, reason: String },
    #[error("cannot wait: {reason}")]
    Wait { reason: String },
    #[error("cannot install signal handlers: {0}")]
    Signal(#[from] std::io::Error),
}

fn stop_flag() -> &'static Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    FLAG.get_or_init(|| Arc::new(AtomicBool::new(false)))
}

/// Installs the SIGINT/SIGTERM flag once per process.
pub fn install_signal_flag() -> Result<(), BusError> {
    static INSTALLED: OnceLock<Result<(), String>> = OnceLock::new();
    let result = INSTALLED.get_or_init(|| {
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register(signal, Arc::clone(stop_flag())).map_err(|e| e.to_string())?;
        }
        Ok(())
    });
    result.clone().map_err(|e| BusError::Signal(std::io::Error::other(e)))
}

/// True once SIGINT or SIGTERM arrived (or [`request_stop`] was called).
pub fn stop_requested() -> bool {
    stop_flag().load(Ordering::Relaxed)
}

/// Asks every loop of this process to end, as a signal would.
pub fn request_stop() {
    stop_flag().store(true, Ordering::Relaxed);
}

/// Sets iceoryx2's log level from `IOX2_LOG_LEVEL`, defaulting to errors only
/// (its default level warns about the missing config file on every start).
fn quiet_iceoryx_log() {
    set_log_level_from_env_or(LogLevel::Error);
}

/// How samples travel between the processes of a service set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Transport {
    /// Shared in iceoryx2 shared memory, never copied (the default).
    Iceoryx2,
    /// Copied through Unix domain sockets ([`uds`]): the baseline.
    UnixSockets,
}

impl Transport {
    /// `iceoryx2` or `uds`, as [`TRANSPORT_ENV`] and `--transport` spell it.
    pub fn name(self) -> &'static str {
        match self {
            Transport::Iceoryx2 => "iceoryx2",
            Transport::UnixSockets => "uds",
        }
    }
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Transport {
    type Err = BusError;

    fn from_str(s: &str) -> Result<Self, BusError> {
        match s {
            "iceoryx2" | "" => Ok(Transport::Iceoryx2),
            "uds" => Ok(Transport::UnixSockets),
            _ => Err(BusError::InvalidTransport(s.into())),
        }
    }
}

/// Environment variable that chooses the [`Transport`] of every process of a
/// service set (`jetbench up --transport` sets it for the services it starts).
pub const TRANSPORT_ENV: &str = "JETBENCH_TRANSPORT";

/// The transport [`TRANSPORT_ENV`] chooses; iceoryx2 when it is unset.
pub fn transport() -> Result<Transport, BusError> {
    std::env::var(TRANSPORT_ENV).unwrap_or_default().parse()
}

/// Environment variable that names the bus namespace. Service sets in
/// different namespaces share nothing, so a test run cannot disturb a bench
/// that is running on the same machine. Unset: the default namespace.
pub const NAMESPACE_ENV: &str = "JETBENCH_BUS";

/// The bus namespace from [`NAMESPACE_ENV`], checked: letters, digits, `_`
/// and `-`, at most 32 characters.
pub fn namespace() -> Result<Option<String>, BusError> {
    let Ok(ns) = std::env::var(NAMESPACE_ENV) else { return Ok(None) };
    if ns.is_empty() {
        return Ok(None);
    }
    if ns.len() > 32 || !ns.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
        return Err(BusError::InvalidName {
            name: ns,
            reason: format!("{NAMESPACE_ENV} may hold only letters, digits, _ and -, at most 32 characters"),
        });
    }
    Ok(Some(ns))
}

/// The iceoryx2 configuration of this process's namespace: its files get
/// their own prefix.
fn bus_config() -> &'static Config {
    static CONFIG: OnceLock<Config> = OnceLock::new();
    CONFIG.get_or_init(|| {
        let mut config = Config::global_config().clone();
        if let Ok(Some(ns)) = namespace() {
            if let Ok(prefix) = FileName::new(format!("jb_{ns}_").as_bytes()) {
                config.global.prefix = prefix;
            }
        }
        config
    })
}

/// Removes the shared-memory resources of dead processes' nodes, and the
/// doorbells no process holds. Returns how many dead nodes were cleaned.
pub fn cleanup_dead_nodes() -> usize {
    let bells = bell::remove_unheld();
    if bells > 0 {
        tracing::debug!("removed {bells} doorbell file(s) nobody holds");
    }
    quiet_iceoryx_log();
    let mut cleaned = 0;
    let _ = Node::<ipc::Service>::list(bus_config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            match view.try_remove_stale_resources() {
                Ok(_) => cleaned += 1,
                Err(e) => tracing::warn!("could not clean a dead bus node: {e:?}"),
            }
        }
        CallbackProgression::Continue
    });
    cleaned
}

/// Node names of the live bus participants.
pub fn list_nodes() -> Vec<String> {
    quiet_iceoryx_log();
    let mut names = Vec::new();
    let _ = Node::<ipc::Service>::list(bus_config(), |state| {
        if let NodeState::<ipc::Service>::Alive(view) = state {
            if let Some(details) = view.details() {
                names.push(details.name().as_str().to_string());
            }
        }
        CallbackProgression::Continue
    });
    names.sort();
    names
}

/// Names of the publish-subscribe services that exist on this machine.
pub fn list_channels() -> Vec<String> {
    quiet_iceoryx_log();
    let mut names = Vec::new();
    let _ = ipc::Service::list(bus_config(), |service| {
        if matches!(
            service.static_details.messaging_pattern(),
            iceoryx2::service::static_config::messaging_pattern::MessagingPattern::PublishSubscribe(_)
        ) {
            names.push(service.static_details.name().as_str().to_string());
        }
        CallbackProgression::Continue
    });
    names.sort();
    names.dedup();
    names
}

/// One process's connection to the bus.
pub struct Bus {
    node: Node<ipc::Service>,
    name: String,
    transport: Transport,
}

impl Bus {
    /// Cleans up dead nodes, creates this process's node and installs the
    /// SIGINT/SIGTERM flag.
    pub fn open(node_name: &str) -> Result<Bus, BusError> {
        Self::open_with(node_name, transport()?)
    }

    /// As [`Bus::open`], on a chosen transport rather than [`TRANSPORT_ENV`]'s.
    pub fn open_with(node_name: &str, transport: Transport) -> Result<Bus, BusError> {
        quiet_iceoryx_log();
        install_signal_flag()?;
        namespace()?;
        let cleaned = cleanup_dead_nodes();
        if cleaned > 0 {
            tracing::info!("cleaned {cleaned} dead bus node(s) left by killed processes");
        }
        let name: NodeName = node_name
            .try_into()
            .map_err(|e| BusError::InvalidName { name: node_name.into(), reason: format!("{e:?}") })?;
        let node = NodeBuilder::new()
            .config(bus_config())
            .name(&name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| BusError::NodeCreate { node: node_name.into(), reason: format!("{e:?}") })?;
        Ok(Bus { node, name: node_name.to_string(), transport })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    fn socket_dir(&self, channel: &str) -> Result<std::path::PathBuf, BusError> {
        Ok(uds::channel_dir(namespace()?.as_deref(), channel))
    }

    /// See [`stop_requested`].
    pub fn stop_requested(&self) -> bool {
        stop_requested()
    }

    fn service_name(channel: &str) -> Result<ServiceName, BusError> {
        channel.try_into().map_err(|e| BusError::InvalidName { name: channel.into(), reason: format!("{e:?}") })
    }

    fn pubsub<T: Sample>(
        &self,
        channel: Channel<T>,
    ) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>, BusError> {
        self.node
            .service_builder(&Self::service_name(channel.name)?)
            .publish_subscribe::<T>()
            .max_publishers(channel.max_publishers)
            .max_subscribers(limits::MAX_SUBSCRIBERS)
            .subscriber_max_buffer_size(limits::MAX_BUFFER)
            .max_nodes(limits::MAX_NODES)
            .history_size(0)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| BusError::ServiceOpen { channel: channel.name.into(), reason: format!("{e:?}") })
    }

    fn doorbell(&self, channel: &str) -> Result<Doorbell, BusError> {
        let path = bell::path_of(namespace()?.as_deref(), channel);
        Doorbell::open(&path).map_err(|e| BusError::PortCreate {
            channel: channel.into(),
            reason: format!("doorbell {}: {e} (is /dev/shm writable?)", path.display()),
        })
    }

    /// Creates a publisher on `channel`. Its `seq` starts at 0.
    pub fn publisher<T: Sample>(&self, channel: Channel<T>) -> Result<Publisher<T>, BusError> {
        let port_err = |e: String| BusError::PortCreate { channel: channel.name.into(), reason: e };
        let port = match self.transport {
            Transport::Iceoryx2 => PublisherPort::Shared(
                self.pubsub(channel)?.publisher_builder().create().map_err(|e| port_err(format!("{e:?}")))?,
            ),
            Transport::UnixSockets => {
                check_socket_size::<T>(channel)?;
                let dir = self.socket_dir(channel.name)?;
                PublisherPort::Socket(uds::Outbox::open(&dir).map_err(|e| port_err(format!("{}: {e}", dir.display())))?)
            }
        };
        let bell = self.doorbell(channel.name)?;
        Ok(Publisher { port, bell, channel, next_seq: 0 })
    }

    /// Creates a subscriber on `channel` that queues up to `depth` samples
    /// (at most [`limits::MAX_BUFFER`]); older samples are dropped on overflow
    /// and show up as `seq` gaps. Every publish wakes it ([`Bus::run`]).
    pub fn subscriber<T: Sample>(&self, channel: Channel<T>, depth: usize) -> Result<Subscriber<T>, BusError> {
        self.make_subscriber(channel, depth, true)
    }

    /// A subscriber for a reader that polls on its own clock (the recorder, the
    /// launcher's status line): it never sleeps on the channel's doorbell, so
    /// publishers never wake it and it costs the control path no system call.
    /// It cannot be an input of [`Bus::run`]; size `depth` for the samples of
    /// one polling period and more.
    pub fn polled_subscriber<T: Sample>(&self, channel: Channel<T>, depth: usize) -> Result<Subscriber<T>, BusError> {
        self.make_subscriber(channel, depth, false)
    }

    fn make_subscriber<T: Sample>(
        &self,
        channel: Channel<T>,
        depth: usize,
        woken: bool,
    ) -> Result<Subscriber<T>, BusError> {
        let port_err = |e: String| BusError::PortCreate { channel: channel.name.into(), reason: e };
        let depth = depth.clamp(1, limits::MAX_BUFFER);
        let bell = self.doorbell(channel.name)?;
        let port = match self.transport {
            Transport::Iceoryx2 => SubscriberPort::Shared(
                self.pubsub(channel)?
                    .subscriber_builder()
                    .buffer_size(depth)
                    .create()
                    .map_err(|e| port_err(format!("{e:?}")))?,
            ),
            Transport::UnixSockets => {
                check_socket_size::<T>(channel)?;
                let dir = self.socket_dir(channel.name)?;
                SubscriberPort::Socket(
                    uds::Inbox::open(&dir, depth, woken, &bell)
                        .map_err(|e| port_err(format!("{}: {e}", dir.display())))?,
                )
            }
        };
        Ok(Subscriber {
            port,
            accounted: Cell::new(bell.rings()),
            bell,
            woken,
            channel,
            seq_tracks: RefCell::new(Vec::new()),
            received: Cell::new(0),
            gaps: Cell::new(0),
        })
    }

    /// Sleeps on the doorbells of `inputs` until the callback returns
    /// [`Flow::Stop`] or a stop is requested.
    ///
    /// Each input may carry a deadline: if it sends nothing for that long the
    /// callback gets [`Wake::Missed`], and again after each further deadline.
    /// `tick`, if given, wakes the loop periodically with [`Wake::Tick`] (on a
    /// fixed phase; ticks that could not run in time are skipped, not bunched).
    /// The input's rings are taken before the callback runs; the callback
    /// receives the samples itself.
    pub fn run<F>(
        &self,
        inputs: &[(&dyn Trigger, Option<Duration>)],
        tick: Option<Duration>,
        mut on_wake: F,
    ) -> Result<LoopExit, BusError>
    where
        F: FnMut(Wake) -> Flow,
    {
        let wait_err = |what: &str, e: String| BusError::Wait { reason: format!("{what}: {e}") };
        let wakers = inputs
            .iter()
            .map(|(trigger, _)| {
                trigger.waker().ok_or_else(|| {
                    wait_err("attach input", "a polled subscriber cannot wake a loop (use Bus::subscriber)".into())
                })
            })
            .collect::<Result<Vec<Waker>, BusError>>()?;
        let mut waiting = Waiting::new(&wakers).map_err(|e| wait_err("attach input", e))?;
        let start = Instant::now();
        let mut missed_at: Vec<Option<Instant>> = inputs.iter().map(|(_, d)| d.map(|d| start + d)).collect();
        let mut next_tick = tick.map(|t| start + t);
        loop {
            if stop_requested() {
                return Ok(LoopExit::Terminated);
            }
            // Bounds the time to notice a stop request, whatever the inputs do.
            let wake_at =
                missed_at.iter().flatten().chain(&next_tick).fold(Instant::now() + SIGNAL_POLL, |a, &b| a.min(b));
            // Interrupted: any signal (SIGCHLD included); the flag decides.
            if waiting.wait(wake_at).map_err(|e| wait_err("wait", e.to_string()))? == Woke::Interrupted {
                continue;
            }
            let now = Instant::now();
            for (i, waker) in wakers.iter().enumerate() {
                let deadline = inputs[i].1;
                let wake = if waker.take() {
                    Wake::Input(i)
                } else if missed_at[i].is_some_and(|at| now >= at) {
                    Wake::Missed(i)
                } else {
                    continue;
                };
                missed_at[i] = deadline.map(|d| now + d);
                if on_wake(wake) == Flow::Stop {
                    return Ok(LoopExit::Stopped);
                }
            }
            if let (Some(at), Some(period)) = (next_tick, tick) {
                if now >= at {
                    let mut next = at + period;
                    while next <= now {
                        next += period;
                    }
                    next_tick = Some(next);
                    if on_wake(Wake::Tick) == Flow::Stop {
                        return Ok(LoopExit::Stopped);
                    }
                }
            }
        }
    }

    /// Sleeps until `until` (monotonic), waking early only for a stop request.
    /// Returns false if a stop was requested.
    pub fn sleep_until(&self, until: Instant) -> bool {
        loop {
            if stop_requested() {
                return false;
            }
            let now = Instant::now();
            if now >= until {
                return true;
            }
            std::thread::sleep((until - now).min(SIGNAL_POLL));
        }
    }
}

/// Why a wake-up happened in [`Bus::run`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wake {
    /// Input `i` (index into the inputs slice) has new samples.
    Input(usize),
    /// Input `i` sent nothing within its deadline.
    Missed(usize),
    /// The periodic tick.
    Tick,
}

/// What the [`Bus::run`] callback wants next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    Continue,
    Stop,
}

/// Why [`Bus::run`] returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoopExit {
    /// The callback asked to stop.
    Stopped,
    /// SIGINT or SIGTERM.
    Terminated,
}

/// Something [`Bus::run`] can wait on.
pub trait Trigger {
    /// What wakes it; `None` for a polled subscriber.
    fn waker(&self) -> Option<Waker<'_>>;
}

/// What wakes a consumer: its channel's doorbell (iceoryx2) or its sockets.
#[derive(Clone, Copy)]
pub enum Waker<'a> {
    Bell(&'a Doorbell),
    Socket(&'a uds::Inbox),
}

impl Waker<'_> {
    /// True if it woke since the last call.
    fn take(&self) -> bool {
        match self {
            Waker::Bell(bell) => bell.take(),
            Waker::Socket(inbox) => inbox.take_ready(),
        }
    }
}

/// The inputs of one loop, on one transport.
enum Waiting<'a> {
    Bells(Vec<&'a Doorbell>),
    Sockets(Vec<&'a uds::Inbox>, Vec<libc::pollfd>),
}

impl<'a> Waiting<'a> {
    fn new(wakers: &[Waker<'a>]) -> Result<Self, String> {
        let bells: Vec<&Doorbell> =
            wakers.iter().filter_map(|w| if let Waker::Bell(b) = w { Some(*b) } else { None }).collect();
        let inboxes: Vec<&uds::Inbox> =
            wakers.iter().filter_map(|w| if let Waker::Socket(i) = w { Some(*i) } else { None }).collect();
        match (bells.is_empty(), inboxes.is_empty()) {
            (_, true) => Ok(Waiting::Bells(bells)),
            (true, false) => Ok(Waiting::Sockets(inboxes, Vec::with_capacity(64))),
            (false, false) => Err("the inputs of one loop must share a transport".into()),
        }
    }

    fn wait(&mut self, deadline: Instant) -> std::io::Result<Woke> {
        match self {
            Waiting::Bells(bells) => bell::wait_any(bells, deadline),
            Waiting::Sockets(inboxes, fds) => uds::wait_any(inboxes, deadline, fds),
        }
    }
}

/// Publishes samples of one type, stamping each with a contiguous `seq`.
pub struct Publisher<T: Sample> {
    port: PublisherPort<T>,
    bell: Doorbell,
    channel: Channel<T>,
    next_seq: u64,
}

impl<T: Sample> Publisher<T> {
    /// Writes `sample` into shared memory with the next `seq` and rings the
    /// channel's doorbell. Returns the `seq` given to the sample.
    pub fn publish(&mut self, mut sample: T) -> Result<u64, BusError> {
        let seq = self.next_seq;
        sample.set_seq(seq);
        let send_err = |e: String| BusError::Send { channel: self.channel.name.into(), reason: e };
        match &mut self.port {
            PublisherPort::Shared(publisher) => {
                let slot = publisher.loan_uninit().map_err(|e| send_err(format!("{e:?}")))?;
                slot.write_payload(sample).send().map_err(|e| send_err(format!("{e:?}")))?;
                self.next_seq += 1;
                self.bell.ring().map_err(|e| send_err(format!("ring: {e}")))?;
            }
            PublisherPort::Socket(outbox) => {
                outbox.send(sample.as_bytes(), &self.bell).map_err(|e| send_err(e.to_string()))?;
                self.next_seq += 1;
            }
        }
        Ok(seq)
    }

    /// The `seq` the next sample will get.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    pub fn channel(&self) -> Channel<T> {
        self.channel
    }
}

/// How a publisher's samples leave.
enum PublisherPort<T: Sample> {
    Shared(iceoryx2::port::publisher::Publisher<ipc::Service, T, ()>),
    Socket(uds::Outbox),
}

/// Where a subscriber's samples arrive.
enum SubscriberPort<T: Sample> {
    Shared(iceoryx2::port::subscriber::Subscriber<ipc::Service, T, ()>),
    Socket(uds::Inbox),
}

/// Refuses a sample type too large for the socket transport (none of the
/// service set's is).
fn check_socket_size<T: Sample>(channel: Channel<T>) -> Result<(), BusError> {
    if std::mem::size_of::<T>() > uds::MAX_SAMPLE_BYTES {
        return Err(BusError::PortCreate {
            channel: channel.name.into(),
            reason: format!(
                "{} is {} bytes; the socket transport carries at most {}",
                T::NAME,
                std::mem::size_of::<T>(),
                uds::MAX_SAMPLE_BYTES
            ),
        });
    }
    Ok(())
}

/// Receives samples of one type and counts lost ones from `seq` gaps.
pub struct Subscriber<T: Sample> {
    port: SubscriberPort<T>,
    /// The channel's doorbell. Every subscriber reads its ring count; only a
    /// woken one (not [`Bus::polled_subscriber`]) sleeps on it.
    bell: Doorbell,
    woken: bool,
    /// Rings accounted for: one per sample taken, and all of those read
    /// before a receive that found the queue empty. A publisher rings once
    /// per sample, after the sample is queued, so while the doorbell's count
    /// equals this no rung sample waits, and [`Subscriber::try_recv`] answers
    /// without asking iceoryx2 (whose receive locks, checks the publisher list
    /// and walks every connection slot). It never runs ahead of the count: a
    /// sample is only taken while the count is ahead of it.
    accounted: Cell<u32>,
    channel: Channel<T>,
    /// Next expected `seq` per publisher.
    seq_tracks: RefCell<Vec<(u128, u64)>>,
    received: Cell<u64>,
    gaps: Cell<u64>,
}

impl<T: Sample> Subscriber<T> {
    /// Takes the oldest queued sample, if any.
    pub fn try_recv(&self) -> Result<Option<T>, BusError> {
        let receive_err = |reason: String| BusError::Receive { channel: self.channel.name.into(), reason };
        let (publisher, value) = match &self.port {
            SubscriberPort::Shared(subscriber) => {
                let rings = self.bell.rings();
                if rings == self.accounted.get() {
                    return Ok(None);
                }
                let Some(sample) = subscriber.receive().map_err(|e| receive_err(format!("{e:?}")))? else {
                    // Rings without a sample here: samples published before this
                    // subscriber was connected, or dropped from a full queue.
                    self.accounted.set(rings);
                    return Ok(None);
                };
                self.accounted.set(self.accounted.get().wrapping_add(1));
                (sample.header().publisher_id().value(), *sample.payload())
            }
            SubscriberPort::Socket(inbox) => {
                let taken = inbox
                    .take(|publisher, bytes| (publisher, bytes.len(), T::from_bytes(bytes)))
                    .map_err(|e| receive_err(e.to_string()))?;
                match taken {
                    None => return Ok(None),
                    Some((publisher, _, Some(value))) => (u128::from(publisher), value),
                    Some((_, len, None)) => {
                        return Err(receive_err(format!(
                            "a message of {len} bytes is no {} sample ({} bytes): a publisher of another build?",
                            T::NAME,
                            std::mem::size_of::<T>()
                        )))
                    }
                }
            }
        };
        self.track(publisher, value.seq());
        self.received.set(self.received.get() + 1);
        Ok(Some(value))
    }

    fn track(&self, publisher: u128, seq: u64) {
        let mut tracks = self.seq_tracks.borrow_mut();
        match tracks.iter_mut().find(|(id, _)| *id == publisher) {
            Some((_, expected)) => {
                if seq > *expected {
                    self.gaps.set(self.gaps.get() + (seq - *expected));
                }
                *expected = seq + 1;
            }
            None => tracks.push((publisher, seq + 1)),
        }
    }

    /// Drains the queue and returns the newest sample, if any arrived.
    pub fn latest(&self) -> Result<Option<T>, BusError> {
        let mut newest = None;
        while let Some(sample) = self.try_recv()? {
            newest = Some(sample);
        }
        Ok(newest)
    }

    /// Blocks until a sample is queued or `timeout` passes (or a stop is
    /// requested); returns the oldest sample if one arrived.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Option<T>, BusError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(sample) = self.try_recv()? {
                return Ok(Some(sample));
            }
            let now = Instant::now();
            if now >= deadline || stop_requested() {
                return Ok(None);
            }
            let Some(waker) = self.waker() else {
                // Polled: look again shortly.
                std::thread::sleep((deadline - now).min(Duration::from_millis(1)));
                continue;
            };
            // Take first: a sample published from here on wakes the wait.
            if !waker.take() {
                let mut waiting = Waiting::new(&[waker])
                    .map_err(|e| BusError::Receive { channel: self.channel.name.into(), reason: e })?;
                // A signal cutting the wait short is fine: the stop flag decides what it meant.
                waiting.wait(deadline.min(now + SIGNAL_POLL)).map_err(|e| BusError::Receive {
                    channel: self.channel.name.into(),
                    reason: format!("wait: {e}"),
                })?;
            }
        }
    }

    /// Samples received so far.
    pub fn received(&self) -> u64 {
        self.received.get()
    }

    /// Samples lost so far (sum of `seq` gaps over all publishers).
    pub fn gaps(&self) -> u64 {
        self.gaps.get()
    }

    /// Publishers seen so far.
    pub fn publishers_seen(&self) -> usize {
        self.seq_tracks.borrow().len()
    }

    pub fn channel(&self) -> Channel<T> {
        self.channel
    }
}

impl<T: Sample> Trigger for Subscriber<T> {
    fn waker(&self) -> Option<Waker<'_>> {
        if !self.woken {
            return None;
        }
        Some(match &self.port {
            SubscriberPort::Shared(_) => Waker::Bell(&self.bell),
            SubscriberPort::Socket(inbox) => Waker::Socket(inbox),
        })
    }
}

impl<T: Sample> Drop for Subscriber<T> {
    fn drop(&mut self) {
        if let SubscriberPort::Socket(inbox) = &self.port {
            inbox.close(&self.bell);
        }
    }
}

/// A subscriber with its sample type erased, for code that handles every
/// channel alike (the recorder).
pub trait AnySubscriber: Trigger {
    fn channel_name(&self) -> &'static str;
    /// Takes every queued sample and hands `(seq, stamp_ns, bytes)` to `sink`.
    fn drain_raw(&self, sink: &mut dyn FnMut(u64, u64, &[u8])) -> Result<usize, BusError>;
    fn received(&self) -> u64;
    fn gaps(&self) -> u64;
}

impl<T: Sample> AnySubscriber for Subscriber<T> {
    fn channel_name(&self) -> &'static str {
        self.channel.name
    }

    fn drain_raw(&self, sink: &mut dyn FnMut(u64, u64, &[u8])) -> Result<usize, BusError> {
        let mut n = 0;
        while let Some(sample) = self.try_recv()? {
            sink(sample.seq(), sample.stamp_ns(), sample.as_bytes());
            n += 1;
        }
        Ok(n)
    }

    fn received(&self) -> u64 {
        Subscriber::received(self)
    }

    fn gaps(&self) -> u64 {
        Subscriber::gaps(self)
    }
}
