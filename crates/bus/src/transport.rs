//! The choice of transport, made here and nowhere else: every port, every
//! take and every wait goes to iceoryx2 ([`crate::iceoryx`]) or to the Unix
//! sockets ([`crate::uds`]) through the enums of this module.

use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::time::Instant;

use iceoryx2::prelude::*;
use jetbench_msgs::{Channel, Sample};

use crate::bell::{self, Doorbell, Woke};
use crate::env::Transport;
use crate::error::{PortError, ReceiveError, SendError, WaitError};
use crate::iceoryx::{self, SharedPublisher, SharedSubscriber};
use crate::uds;

/// Where a channel's ports are made: the transport, this process's node
/// (iceoryx2) and the channel's socket folder (Unix sockets).
pub(crate) struct Site<'a> {
    pub(crate) transport: Transport,
    pub(crate) node: &'a Node<ipc::Service>,
    pub(crate) socket_dir: PathBuf,
}

/// Where a publisher's samples go.
pub(crate) enum Outlet<T: Sample> {
    Shared(SharedPublisher<T>),
    Socket(uds::Outbox),
}

impl<T: Sample> Outlet<T> {
    pub(crate) fn open(site: &Site<'_>, channel: Channel<T>) -> Result<Self, PortError> {
        Ok(match site.transport {
            Transport::Iceoryx2 => Outlet::Shared(iceoryx::publisher(site.node, channel)?),
            Transport::UnixSockets => {
                check_socket_size::<T>()?;
                let dir = &site.socket_dir;
                Outlet::Socket(uds::Outbox::open(dir).map_err(|source| socket_error(channel.name, dir, source))?)
            }
        })
    }

    /// Sends `sample` and wakes its woken subscribers.
    pub(crate) fn send(&mut self, sample: T, bell: &Doorbell, channel: &str) -> Result<(), SendError> {
        match self {
            Outlet::Shared(publisher) => {
                iceoryx::send(publisher, sample, channel)?;
                bell.ring().map_err(|source| SendError::Ring { channel: channel.into(), source })
            }
            Outlet::Socket(outbox) => outbox
                .send(sample.as_bytes(), bell)
                .map_err(|source| SendError::Socket { channel: channel.into(), source }),
        }
    }
}

/// Where a subscriber's samples arrive.
pub(crate) enum Inlet<T: Sample> {
    Shared(SharedSubscriber<T>),
    Socket(uds::Inbox),
}

impl<T: Sample> Inlet<T> {
    /// A subscriber queueing `depth` samples; `woken` if publishes wake it.
    pub(crate) fn open(
        site: &Site<'_>,
        channel: Channel<T>,
        depth: usize,
        woken: bool,
        bell: &Doorbell,
    ) -> Result<Self, PortError> {
        Ok(match site.transport {
            Transport::Iceoryx2 => Inlet::Shared(iceoryx::subscriber(site.node, channel, depth)?),
            Transport::UnixSockets => {
                check_socket_size::<T>()?;
                let dir = &site.socket_dir;
                let inbox = uds::Inbox::open(dir, depth, woken, bell)
                    .map_err(|source| socket_error(channel.name, dir, source))?;
                Inlet::Socket(inbox)
            }
        })
    }

    /// Takes the oldest queued sample with its publisher's id.
    ///
    /// In shared memory the channel's doorbell says whether anything new was
    /// published: a publisher rings once per sample, after the sample is
    /// queued, so while the ring count equals the rings `accounted` for, no
    /// rung sample waits, and the answer needs no iceoryx2 receive (which
    /// locks, checks the publisher list and walks every connection slot). It
    /// never runs ahead of the count: a sample is only taken while the count
    /// is ahead of it.
    pub(crate) fn take(
        &self,
        bell: &Doorbell,
        accounted: &Cell<u32>,
        channel: &str,
    ) -> Result<Option<(u128, T)>, ReceiveError> {
        match self {
            Inlet::Shared(subscriber) => {
                let rings = bell.rings();
                if rings == accounted.get() {
                    return Ok(None);
                }
                let Some(taken) = iceoryx::receive(subscriber, channel)? else {
                    // Rings without a sample here: samples published before this
                    // subscriber was connected, or dropped from a full queue.
                    accounted.set(rings);
                    return Ok(None);
                };
                accounted.set(accounted.get().wrapping_add(1));
                Ok(Some(taken))
            }
            Inlet::Socket(inbox) => {
                let taken = inbox
                    .take(|publisher, bytes| (publisher, bytes.len(), T::from_bytes(bytes)))
                    .map_err(|source| ReceiveError::Socket { channel: channel.into(), source })?;
                match taken {
                    None => Ok(None),
                    Some((publisher, _, Some(value))) => Ok(Some((u128::from(publisher), value))),
                    Some((_, len, None)) => Err(ReceiveError::Malformed {
                        channel: channel.into(),
                        len,
                        type_name: T::NAME,
                        size: std::mem::size_of::<T>(),
                    }),
                }
            }
        }
    }

    /// What wakes a consumer of this inlet.
    pub(crate) fn waker<'a>(&'a self, bell: &'a Doorbell) -> Waker<'a> {
        match self {
            Inlet::Shared(_) => Waker::Bell(bell),
            Inlet::Socket(inbox) => Waker::Socket(inbox),
        }
    }

    /// Leaves the channel: socket publishers stop sending here.
    pub(crate) fn close(&self, bell: &Doorbell) {
        if let Inlet::Socket(inbox) = self {
            inbox.close(bell);
        }
    }
}

fn socket_error(channel: &str, dir: &Path, source: std::io::Error) -> PortError {
    PortError::Socket { channel: channel.into(), dir: dir.to_path_buf(), source }
}

/// Refuses a sample type too large for the socket transport (none of the
/// service set's is).
fn check_socket_size<T: Sample>() -> Result<(), PortError> {
    let size = std::mem::size_of::<T>();
    if size > uds::MAX_SAMPLE_BYTES {
        return Err(PortError::TooLarge { type_name: T::NAME, size, max: uds::MAX_SAMPLE_BYTES });
    }
    Ok(())
}

/// What wakes a consumer: its channel's doorbell (iceoryx2) or its sockets.
#[derive(Clone, Copy)]
pub enum Waker<'a> {
    /// The channel's futex doorbell (iceoryx2 transport).
    Bell(&'a Doorbell),
    /// The subscriber's sockets (Unix-socket transport).
    Socket(&'a uds::Inbox),
}

impl Waker<'_> {
    /// True if it woke since the last call.
    pub(crate) fn take(&self) -> bool {
        match self {
            Waker::Bell(bell) => bell.take(),
            Waker::Socket(inbox) => inbox.take_ready(),
        }
    }
}

/// The inputs of one wait, on one transport.
pub(crate) enum Waiting<'a> {
    Bells(Vec<&'a Doorbell>),
    Sockets(Vec<&'a uds::Inbox>, Vec<libc::pollfd>),
}

impl<'a> Waiting<'a> {
    pub(crate) fn new(wakers: &[Waker<'a>]) -> Result<Self, WaitError> {
        let bells: Vec<&Doorbell> =
            wakers.iter().filter_map(|w| if let Waker::Bell(b) = w { Some(*b) } else { None }).collect();
        let inboxes: Vec<&uds::Inbox> =
            wakers.iter().filter_map(|w| if let Waker::Socket(i) = w { Some(*i) } else { None }).collect();
        if wakers.len() > bell::MAX_WAIT {
            return Err(WaitError::TooMany { count: wakers.len(), max: bell::MAX_WAIT });
        }
        match (bells.is_empty(), inboxes.is_empty()) {
            (_, true) => Ok(Waiting::Bells(bells)),
            (true, false) => Ok(Waiting::Sockets(inboxes, Vec::with_capacity(64))),
            (false, false) => Err(WaitError::MixedTransports),
        }
    }

    /// Sleeps until an input woke, `deadline` passed, or a signal came.
    pub(crate) fn wait(&mut self, deadline: Instant) -> Result<Woke, WaitError> {
        match self {
            Waiting::Bells(bells) => bell::wait_any(bells, deadline),
            Waiting::Sockets(inboxes, fds) => uds::wait_any(inboxes, deadline, fds),
        }
        .map_err(WaitError::Wait)
    }
}
