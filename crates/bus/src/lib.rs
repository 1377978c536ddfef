//! Typed publish/subscribe between the processes of a service set.
//!
//! Every channel is an iceoryx2 publish-subscribe service paired with a
//! [doorbell](bell): a futex word in shared memory. A [`Publisher`] stamps
//! each sample with its own contiguous `seq`, writes it into shared memory
//! and rings; a [`Subscriber`] counts `seq` gaps per publisher, and consumers
//! sleep on their inputs' doorbells with a deadline ([`Bus::run`]) instead of
//! polling. The same API runs over a second, copying transport, Unix domain
//! sockets ([`uds`], `JETBENCH_TRANSPORT=uds`): the baseline the zero-copy bus
//! is measured against.
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
//! One module per concern: [`signal`] (the stop flag every wait checks),
//! [`env`] (namespace and transport), [`access`] (who may touch a set's
//! files), [`lock`] (one set per namespace), [`node`] (who is on the bus, clean-up),
//! `iceoryx` and [`uds`] (the two transports), `transport` (the one place
//! that chooses between them), [`bell`] (doorbells), `wait` (the wait loop),
//! `port` (typed publishers and subscribers), [`tap`] (every channel, read as
//! the recorder reads it) and [`error`] (one error enum per operation).
#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

pub mod access;
pub mod bell;
pub mod env;
pub mod error;
mod iceoryx;
pub mod lock;
pub mod node;
mod port;
pub mod signal;
pub mod tap;
mod transport;
pub mod uds;
mod wait;

use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use jetbench_msgs::{Channel, Sample};

pub use env::{namespace, namespace_name, transport, Transport, NAMESPACE_ENV, TRANSPORT_ENV};
pub use error::{BusError, EnvError, OpenError, PortError, ReceiveError, SendError, WaitError};
pub use node::{cleanup_dead_nodes, list_channels, list_nodes};
pub use port::{AnySubscriber, Publisher, Subscriber};
pub use signal::{install_signal_flag, request_stop, sleep_until, stop_requested};
pub use transport::Waker;
pub use wait::{Flow, LoopExit, Trigger, Wake};

use bell::Doorbell;
use transport::{Inlet, Outlet, Site};

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

/// One process's connection to the bus.
pub struct Bus {
    node: Node<ipc::Service>,
    name: String,
    transport: Transport,
    namespace: Option<String>,
}

impl Bus {
    /// Cleans up nodes of dead processes, creates this process's node and
    /// installs the SIGINT/SIGTERM flag; samples travel as [`TRANSPORT_ENV`] says.
    pub fn open(node_name: &str) -> Result<Bus, OpenError> {
        Self::open_with(node_name, transport()?)
    }

    /// As [`Bus::open`], on a chosen transport rather than [`TRANSPORT_ENV`]'s.
    pub fn open_with(node_name: &str, transport: Transport) -> Result<Bus, OpenError> {
        iceoryx::quiet_log();
        install_signal_flag()?;
        let namespace = namespace()?;
        let cleaned = cleanup_dead_nodes();
        if cleaned > 0 {
            tracing::info!("cleaned {cleaned} dead bus node(s) left by killed processes");
        }
        let node = iceoryx::create_node(node_name)?;
        Ok(Bus { node, name: node_name.to_string(), transport, namespace })
    }

    /// The node's name, as given to [`Bus::open`] (the service's name: `sensing`, …).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// How samples travel: shared memory (iceoryx2) or copied through Unix sockets.
    pub fn transport(&self) -> Transport {
        self.transport
    }

    /// See [`stop_requested`].
    pub fn stop_requested(&self) -> bool {
        stop_requested()
    }

    fn doorbell(&self, channel: &str) -> Result<Doorbell, PortError> {
        let path = bell::path_of(self.namespace.as_deref(), channel);
        Doorbell::open(&path).map_err(|source| PortError::Doorbell { channel: channel.into(), path, source })
    }

    fn site(&self, channel: &str) -> Site<'_> {
        Site {
            transport: self.transport,
            node: &self.node,
            socket_dir: uds::channel_dir(self.namespace.as_deref(), channel),
        }
    }

    /// Creates a publisher on `channel`. Its `seq` starts at 0.
    pub fn publisher<T: Sample>(&self, channel: Channel<T>) -> Result<Publisher<T>, PortError> {
        let outlet = Outlet::open(&self.site(channel.name), channel)?;
        Ok(Publisher { outlet, bell: self.doorbell(channel.name)?, channel, next_seq: 0 })
    }

    /// Creates a subscriber on `channel` that queues up to `depth` samples
    /// (at most [`limits::MAX_BUFFER`]); older samples are dropped on overflow
    /// and show up as `seq` gaps. Every publish wakes it ([`Bus::run`]).
    pub fn subscriber<T: Sample>(&self, channel: Channel<T>, depth: usize) -> Result<Subscriber<T>, PortError> {
        self.make_subscriber(channel, depth, true)
    }

    /// A subscriber for a reader that polls on its own clock (the recorder, the
    /// launcher's status line): it never sleeps on the channel's doorbell, so
    /// publishers never wake it and it costs the control path no system call.
    /// It cannot be an input of [`Bus::run`]; size `depth` for the samples of
    /// one polling period and more.
    pub fn polled_subscriber<T: Sample>(&self, channel: Channel<T>, depth: usize) -> Result<Subscriber<T>, PortError> {
        self.make_subscriber(channel, depth, false)
    }

    fn make_subscriber<T: Sample>(
        &self,
        channel: Channel<T>,
        depth: usize,
        woken: bool,
    ) -> Result<Subscriber<T>, PortError> {
        let depth = depth.clamp(1, limits::MAX_BUFFER);
        let bell = self.doorbell(channel.name)?;
        let inlet = Inlet::open(&self.site(channel.name), channel, depth, woken, &bell)?;
        Ok(Subscriber::new(inlet, bell, woken, channel))
    }

    /// Sleeps on the wake-ups of `inputs` until the callback returns
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
        on_wake: F,
    ) -> Result<LoopExit, WaitError>
    where
        F: FnMut(Wake) -> Flow,
    {
        wait::run(inputs, tick, on_wake)
    }

    /// Sleeps until `until` (monotonic), waking early only for a stop request.
    /// Returns false if a stop was requested.
    pub fn sleep_until(&self, until: Instant) -> bool {
        sleep_until(until)
    }
}
