//! The Foxglove live view of the bench, and recordings served the same way.
//!
//! Every bus channel is advertised as the recording has it: topic
//! `/bench/...`, message encoding `cdr`, schema encoding `ros2msg`, schema
//! `jetbench_msgs/msg/<Type>` with the same text, so the Foxglove app (or any
//! client of its WebSocket protocol) decodes the samples with no custom code.
//!
//! ```no_run
//! use jetbench_bus::Bus;
//! use jetbench_viewer::{FoxgloveServer, LiveView, ServerOptions};
//!
//! # fn main() -> Result<(), jetbench_viewer::ViewerError> {
//! let bus = Bus::open("viewer")?;
//! let server = FoxgloveServer::start("127.0.0.1:8765", &ServerOptions::default())?;
//! let mut view = LiveView::open(&bus, server)?;
//! while !jetbench_bus::stop_requested() {
//!     view.pump()?; // everything published since the last call, to every subscribed client
//!     std::thread::sleep(jetbench_stack::runtime::clock::PERIOD); // once a bench cycle, like the recorder
//! }
//! eprint!("{}", view.report());
//! # Ok(())
//! # }
//! ```
//!
//! The viewer is a process of its own that reads the bus through polled
//! subscribers on its own 10 ms clock ([`jetbench_bus::tap`]): publishers
//! never wait for it or wake it. Between it and each client, the SDK keeps a
//! bounded backlog ([`ServerOptions::backlog`]) and drops the oldest messages
//! of a client that does not keep up; the bus queues in front of it are
//! bounded too, and what they lose is counted ([`LiveReport`]).
#![doc = include_str!("../README.md")]

mod channels;
mod live;
pub mod operator;
mod play;
mod server;
mod service;

pub use channels::BenchChannels;
pub use live::{ChannelReport, LiveReport, LiveView};
pub use play::{BusSink, PlayOptions, PlayReport, PlaySink, Player};
pub use server::{parse_listen, ClientCounts, FoxgloveServer, ServerOptions, DEFAULT_ADDR};
pub use service::Viewer;

use jetbench_bus::BusError;
use jetbench_record::RecordError;

/// Why the viewer could not start or serve.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// A listen address that is not `HOST:PORT`.
    #[error("invalid listen address {addr:?}: {reason} (expected HOST:PORT, e.g. 127.0.0.1:8765, or 0.0.0.0:8765 for other machines)")]
    Address {
        /// The address as given.
        addr: String,
        /// Why it does not parse.
        reason: String,
    },
    /// The WebSocket server could not start.
    #[error("cannot serve Foxglove on {addr}: {source} (is the port in use?)")]
    Start {
        /// The address it tried.
        addr: String,
        /// What the Foxglove SDK said.
        source: foxglove::FoxgloveError,
    },
    /// A channel could not be advertised to clients.
    #[error("cannot advertise channel {topic}: {source}")]
    Channel {
        /// The channel's topic.
        topic: String,
        /// What the Foxglove SDK said.
        source: foxglove::FoxgloveError,
    },
    /// A playback rate that is not a positive number.
    #[error("playback rate {0} must be a positive number (1 = real time)")]
    Rate(f64),
    /// Reading the live bus.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// Reading the recording to play.
    #[error(transparent)]
    Record(#[from] RecordError),
}

jetbench_bus::from_bus_errors!(ViewerError);
