//! The zero-copy transport: iceoryx2 publish-subscribe services in shared
//! memory, one per channel, in the bus namespace's own files.
//!
//! Services are opened with the same capacity limits by every process (so
//! `open_or_create` agrees), a history of 0 and safe overflow: a subscriber
//! whose queue is full loses its oldest sample, which it counts as a `seq` gap.

use std::sync::OnceLock;

use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use jetbench_msgs::{Channel, Sample};

use crate::error::{OpenError, PortError, ReceiveError, SendError};
use crate::limits;

/// A channel's publisher in shared memory.
pub(crate) type SharedPublisher<T> = IoxPublisher<ipc::Service, T, ()>;
/// A channel's subscriber in shared memory.
pub(crate) type SharedSubscriber<T> = IoxSubscriber<ipc::Service, T, ()>;

/// Sets iceoryx2's log level from `IOX2_LOG_LEVEL`, defaulting to errors only
/// (its default level warns about the missing config file on every start).
pub(crate) fn quiet_log() {
    set_log_level_from_env_or(LogLevel::Error);
}

/// The iceoryx2 configuration of this process's namespace: its files get
/// their own prefix (`jb_default_` without a namespace), so no other iceoryx2
/// program on the machine shares them.
pub(crate) fn config() -> &'static Config {
    static CONFIG: OnceLock<Config> = OnceLock::new();
    CONFIG.get_or_init(|| {
        let mut config = Config::global_config().clone();
        if let Ok(prefix) = FileName::new(prefix().as_bytes()) {
            config.global.prefix = prefix;
        }
        config
    })
}

fn prefix() -> String {
    format!("jb_{}_", crate::env::namespace_name().unwrap_or_else(|_| "default".into()))
}

/// Closes iceoryx2's node counter of this namespace to other users: iceoryx2
/// opens that one segment to everyone (so that any user's node gets a unique
/// id), and the namespace's prefix makes it the set's alone. It holds no samples.
fn tighten_node_counter() {
    let prefix = prefix();
    let Ok(entries) = std::fs::read_dir("/dev/shm") else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with(&prefix) && name.ends_with("global_mgmt") {
            if let Err(e) = crate::access::tighten(&entry.path()) {
                tracing::debug!("cannot restrict {}: {e}", entry.path().display());
            }
        }
    }
}

/// Creates this process's node (iceoryx2's signal handling off: see [`crate::signal`]).
pub(crate) fn create_node(node_name: &str) -> Result<Node<ipc::Service>, OpenError> {
    let name: NodeName =
        node_name.try_into().map_err(|source| OpenError::NodeName { name: node_name.into(), source })?;
    let node = NodeBuilder::new()
        .config(config())
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|source| OpenError::Node { node: node_name.into(), source })?;
    tighten_node_counter();
    Ok(node)
}

fn service<T: Sample>(
    node: &Node<ipc::Service>,
    channel: Channel<T>,
) -> Result<PortFactory<ipc::Service, T, ()>, PortError> {
    let name: ServiceName =
        channel.name.try_into().map_err(|source| PortError::ChannelName { channel: channel.name.into(), source })?;
    node.service_builder(&name)
        .publish_subscribe::<T>()
        .max_publishers(channel.max_publishers)
        .max_subscribers(limits::MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(limits::MAX_BUFFER)
        .max_nodes(limits::MAX_NODES)
        .history_size(0)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|source| PortError::Service { channel: channel.name.into(), source })
}

pub(crate) fn publisher<T: Sample>(
    node: &Node<ipc::Service>,
    channel: Channel<T>,
) -> Result<SharedPublisher<T>, PortError> {
    service(node, channel)?
        .publisher_builder()
        .create()
        .map_err(|source| PortError::Publisher { channel: channel.name.into(), source })
}

pub(crate) fn subscriber<T: Sample>(
    node: &Node<ipc::Service>,
    channel: Channel<T>,
    depth: usize,
) -> Result<SharedSubscriber<T>, PortError> {
    service(node, channel)?
        .subscriber_builder()
        .buffer_size(depth)
        .create()
        .map_err(|source| PortError::Subscriber { channel: channel.name.into(), source })
}

/// Writes `sample` into a loaned slot and sends it (the caller rings).
pub(crate) fn send<T: Sample>(publisher: &SharedPublisher<T>, sample: T, channel: &str) -> Result<(), SendError> {
    let slot = publisher.loan_uninit().map_err(|source| SendError::Loan { channel: channel.into(), source })?;
    slot.write_payload(sample).send().map_err(|source| SendError::Send { channel: channel.into(), source })?;
    Ok(())
}

/// The oldest queued sample and its publisher's id.
pub(crate) fn receive<T: Sample>(
    subscriber: &SharedSubscriber<T>,
    channel: &str,
) -> Result<Option<(u128, T)>, ReceiveError> {
    let sample = subscriber.receive().map_err(|source| ReceiveError::Receive { channel: channel.into(), source })?;
    Ok(sample.map(|s| (s.header().publisher_id().value(), *s.payload())))
}
