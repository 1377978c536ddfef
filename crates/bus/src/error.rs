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
    #[error("invalid bus namespace {value:?}: {NAMESPACE_ENV} may hold only letters, digits, _ and -, at most 32 characters")]
    Namespace { value: String },
    #[error("unknown transport {value:?}: {TRANSPORT_ENV} is iceoryx2 (the default) or uds")]
    Transport { value: String },
}

/// [`Bus::open`](crate::Bus::open) failed.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error(transparent)]
    Env(#[from] EnvError),
    #[error("invalid bus node name {name:?}")]
    NodeName {
        name: String,
        #[source]
        source: SemanticStringError,
    },
    #[error("cannot create the bus node {node:?} (is /dev/shm writable?)")]
    Node {
        node: String,
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
    #[error(transparent)]
    Env(#[from] EnvError),
    #[error("invalid channel name {channel:?}")]
    ChannelName {
        channel: String,
        #[source]
        source: ServiceNameError,
    },
    #[error("cannot open channel {channel} (a process of an older build may still hold it; stop it and retry)")]
    Service {
        channel: String,
        #[source]
        source: PublishSubscribeOpenOrCreateError,
    },
    #[error("cannot create a publisher on {channel}")]
    Publisher {
        channel: String,
        #[source]
        source: PublisherCreateError,
    },
    #[error("cannot create a subscriber on {channel}")]
    Subscriber {
        channel: String,
        #[source]
        source: SubscriberCreateError,
    },
    #[error("cannot open the doorbell of {channel} at {} (is /dev/shm writable?)", path.display())]
    Doorbell {
        channel: String,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot open the sockets of {channel} in {}", dir.display())]
    Socket {
        channel: String,
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{type_name} is {size} bytes; the socket transport carries at most {max}")]
    TooLarge { type_name: &'static str, size: usize, max: usize },
}

/// A sample could not be published.
#[derive(Debug, thiserror::Error)]
pub enum SendError {
    #[error("cannot loan a sample slot on {channel}")]
    Loan {
        channel: String,
        #[source]
        source: LoanError,
    },
    #[error("cannot publish on {channel}")]
    Send {
        channel: String,
        #[source]
        source: IceoryxSendError,
    },
    #[error("cannot ring the doorbell of {channel}")]
    Ring {
        channel: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot send on the sockets of {channel}")]
    Socket {
        channel: String,
        #[source]
        source: std::io::Error,
    },
    /// The sample holds NaN or an infinity: it was not published (and used no `seq`).
    #[error("refused to publish on {channel}: field `{field}` is not a finite number")]
    NonFinite { channel: &'static str, field: &'static str },
}

/// Samples could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum ReceiveError {
    #[error("cannot receive on {channel}")]
    Receive {
        channel: String,
        #[source]
        source: IceoryxReceiveError,
    },
    #[error("cannot read the sockets of {channel}")]
    Socket {
        channel: String,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "a message of {len} bytes on {channel} is no {type_name} sample ({size} bytes): a publisher of another build?"
    )]
    Malformed { channel: String, len: usize, type_name: &'static str, size: usize },
}

/// A wait loop could not wait.
#[derive(Debug, thiserror::Error)]
pub enum WaitError {
    /// A polled subscriber was given as an input: nothing rings for it.
    #[error("a polled subscriber of {channel} cannot wake a loop (use Bus::subscriber)")]
    Polled { channel: String },
    /// Doorbells and sockets cannot be waited on together.
    #[error("the inputs of one loop must share a transport")]
    MixedTransports,
    /// More inputs than one wait takes.
    #[error("cannot wait on {count} inputs, at most {max}")]
    TooMany { count: usize, max: usize },
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
