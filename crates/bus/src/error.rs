//! What can fail on the bus: one error enum per operation, each keeping the
//! error it came from ([`std::error::Error::source`]), and [`BusError`] for
//! code that handles them all alike (`?` converts).

use std::path::PathBuf;

use iceoryx2::node::NodeCreationFailure;
use iceoryx2::port::publisher::PublisherCreateError;
use iceoryx2::port::subscriber::SubscriberCreateError;
use iceoryx2::port::{LoanError, ReceiveError as IceoryxReceiveError, SendError as IceoryxSendError};
use iceoryx2::prelude::SemanticStringError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenOrCreateError;
use iceoryx2::service::service_name::ServiceNameError;

use crate::env::{NAMESPACE_ENV, TRANSPORT_ENV};

/// The process's bus settings (its environment) are not usable.
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    /// `JETBENCH_NAMESPACE` holds characters a namespace may not (it names files in
    /// /dev/shm and folders).
    #[error("invalid bus namespace {value:?}: {NAMESPACE_ENV} may hold only letters, digits, _ and -, at most 32 characters")]
    Namespace {
        /// The variable's value.
        value: String,
    },
    /// `JETBENCH_TRANSPORT` names no transport.
    #[error("unknown transport {value:?}: {TRANSPORT_ENV} is iceoryx2 (the default) or uds")]
    Transport {
        /// The variable's value.
        value: String,
    },
}

/// [`Bus::open`](crate::Bus::open) failed.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The process's bus settings are not usable.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// iceoryx2 refuses the node name (the service's name).
    #[error("invalid bus node name {name:?}")]
    NodeName {
        /// The name given.
        name: String,
        /// iceoryx2's reason.
        #[source]
        source: SemanticStringError,
    },
    /// iceoryx2 could not create the node: usually /dev/shm is full or not writable.
    #[error("cannot create the bus node {node:?} (is /dev/shm writable?)")]
    Node {
        /// The node's name.
        node: String,
        /// iceoryx2's reason.
        #[source]
        source: NodeCreationFailure,
    },
    /// The stop flag could not be installed.
    #[error("cannot install the SIGINT/SIGTERM handlers")]
    Signal(#[source] std::io::Error),
}

/// A publisher or subscriber could not be created.
#[derive(Debug, thiserror::Error)]
pub enum PortError {
    /// The process's bus settings are not usable.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// iceoryx2 refuses the channel's name.
    #[error("invalid channel name {channel:?}")]
    ChannelName {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// iceoryx2's reason.
        #[source]
        source: ServiceNameError,
    },
    /// The channel exists with other settings or another sample type: a process of
    /// another build still holds it.
    #[error("cannot open channel {channel} (a process of an older build may still hold it; stop it and retry)")]
    Service {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// iceoryx2's reason.
        #[source]
        source: PublishSubscribeOpenOrCreateError,
    },
    /// iceoryx2 refused a publisher (a channel allows `Channel::max_publishers`).
    #[error("cannot create a publisher on {channel}")]
    Publisher {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// iceoryx2's reason.
        #[source]
        source: PublisherCreateError,
    },
    /// iceoryx2 refused a subscriber (a channel allows 8).
    #[error("cannot create a subscriber on {channel}")]
    Subscriber {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// iceoryx2's reason.
        #[source]
        source: SubscriberCreateError,
    },
    /// The channel's doorbell file could not be opened or mapped.
    #[error("cannot open the doorbell of {channel} at {} (is /dev/shm writable?)", path.display())]
    Doorbell {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// The doorbell file, in /dev/shm.
        path: PathBuf,
        /// The system's reason.
        #[source]
        source: std::io::Error,
    },
    /// The socket transport could not make or list the channel's folder or socket.
    #[error("cannot open the sockets of {channel} in {}", dir.display())]
    Socket {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// The channel's folder of sockets.
        dir: PathBuf,
        /// The system's reason.
        #[source]
        source: std::io::Error,
    },
    /// The sample type does not fit one socket message.
    #[error("{type_name} is {size} bytes; the socket transport carries at most {max}")]
    TooLarge {
        /// The sample type.
        type_name: &'static str,
        /// Its size, bytes.
        size: usize,
        /// The largest message the socket transport carries, bytes.
        max: usize,
    },
}

/// A sample could not be published.
#[derive(Debug, thiserror::Error)]
pub enum SendError {
    /// iceoryx2 could not lend a slot to write the sample into.
    #[error("cannot loan a sample slot on {channel}")]
    Loan {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// iceoryx2's reason.
        #[source]
        source: LoanError,
    },
    /// iceoryx2 could not deliver the sample.
    #[error("cannot publish on {channel}")]
    Send {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// iceoryx2's reason.
        #[source]
        source: IceoryxSendError,
    },
    /// The sample was queued but the doorbell could not wake its subscribers.
    #[error("cannot ring the doorbell of {channel}")]
    Ring {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// The system's reason.
        #[source]
        source: std::io::Error,
    },
    /// The socket transport could not send (a full queue is a gap, not this).
    #[error("cannot send on the sockets of {channel}")]
    Socket {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// The system's reason.
        #[source]
        source: std::io::Error,
    },
    /// The sample holds NaN or an infinity: it was not published (and used no `seq`).
    #[error("refused to publish on {channel}: field `{field}` is not a finite number")]
    NonFinite {
        /// The channel, e.g. `bench/thrust`.
        channel: &'static str,
        /// The first field that is not finite.
        field: &'static str,
    },
}

/// Samples could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum ReceiveError {
    /// iceoryx2 could not hand over a sample.
    #[error("cannot receive on {channel}")]
    Receive {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// iceoryx2's reason.
        #[source]
        source: IceoryxReceiveError,
    },
    /// The socket transport could not read.
    #[error("cannot read the sockets of {channel}")]
    Socket {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// The system's reason.
        #[source]
        source: std::io::Error,
    },
    /// A socket message of the wrong size: not this channel's sample type.
    #[error(
        "a message of {len} bytes on {channel} is no {type_name} sample ({size} bytes): a publisher of another build?"
    )]
    Malformed {
        /// The channel, e.g. `bench/thrust`.
        channel: String,
        /// The message's length, bytes.
        len: usize,
        /// The channel's sample type.
        type_name: &'static str,
        /// Its size, bytes.
        size: usize,
    },
}

/// A wait loop could not wait.
#[derive(Debug, thiserror::Error)]
pub enum WaitError {
    /// A polled subscriber was given as an input: nothing rings for it.
    #[error("a polled subscriber of {channel} cannot wake a loop (use Bus::subscriber)")]
    Polled {
        /// The polled subscriber's channel.
        channel: String,
    },
    /// Doorbells and sockets cannot be waited on together.
    #[error("the inputs of one loop must share a transport")]
    MixedTransports,
    /// More inputs than one wait takes.
    #[error("cannot wait on {count} inputs, at most {max}")]
    TooMany {
        /// Inputs given.
        count: usize,
        /// The most one wait takes.
        max: usize,
    },
    /// The kernel refused the wait.
    #[error("cannot wait")]
    Wait(#[source] std::io::Error),
}

/// Anything that failed on the bus.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// [`EnvError`]: the namespace or transport asked for.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// [`OpenError`]: joining the bus.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// [`PortError`]: a publisher or subscriber.
    #[error(transparent)]
    Port(#[from] PortError),
    /// [`SendError`]: a publish.
    #[error(transparent)]
    Send(#[from] SendError),
    /// [`ReceiveError`]: a take.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// [`WaitError`]: a wait.
    #[error(transparent)]
    Wait(#[from] WaitError),
}

/// Lets `?` turn every bus operation's error into `$target` through
/// [`BusError`], for an error enum that has a `#[from] BusError` variant:
///
/// ```
/// #[derive(Debug, thiserror::Error)]
/// enum AppError {
///     #[error(transparent)]
///     Bus(#[from] jetbench_bus::BusError),
/// }
/// jetbench_bus::from_bus_errors!(AppError);
///
/// fn open() -> Result<jetbench_bus::Bus, AppError> {
///     Ok(jetbench_bus::Bus::open("example")?) // an OpenError, converted
/// }
/// ```
#[macro_export]
macro_rules! from_bus_errors {
    ($target:ty) => {
        $crate::from_bus_errors!(@each $target: EnvError OpenError PortError SendError ReceiveError WaitError);
    };
    (@each $target:ty: $($error:ident)*) => {
        $(
            impl From<$crate::$error> for $target {
                fn from(e: $crate::$error) -> Self {
                    <$target>::from($crate::BusError::from(e))
                }
            }
        )*
    };
}
