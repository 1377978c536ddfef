//! Typed ports: a [`Publisher`] stamps a contiguous `seq` on every sample; a
//! [`Subscriber`] counts the `seq` gaps per publisher. Both carry their
//! channel's doorbell, whatever the transport.

use std::cell::{Cell, RefCell};
use std::time::{Duration, Instant};

use jetbench_msgs::{Channel, Sample};

use crate::bell::Doorbell;
use crate::error::{BusError, ReceiveError, SendError};
use crate::signal::stop_requested;
use crate::transport::{Inlet, Outlet, Waker};
use crate::wait::{wait_for, Trigger};

/// Publishes samples of one type, stamping each with a contiguous `seq`.
pub struct Publisher<T: Sample> {
    pub(crate) outlet: Outlet<T>,
    pub(crate) bell: Doorbell,
    pub(crate) channel: Channel<T>,
    pub(crate) next_seq: u64,
}

impl<T: Sample> Publisher<T> {
    /// Publishes `sample` with the next `seq` and wakes the channel's woken
    /// subscribers. Returns the `seq` given to the sample. A sample with a NaN
    /// or infinite field is refused ([`SendError::NonFinite`]) and takes no `seq`.
    pub fn publish(&mut self, mut sample: T) -> Result<u64, SendError> {
        if let Some(field) = sample.non_finite_field() {
            return Err(SendError::NonFinite { channel: self.channel.name, field });
        }
        let seq = self.next_seq;
        sample.set_seq(seq);
        self.outlet.send(sample, &self.bell, self.channel.name)?;
        self.next_seq += 1;
        Ok(seq)
    }

    /// The `seq` the next sample will get.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// The channel this port is on.
    pub fn channel(&self) -> Channel<T> {
        self.channel
    }
}

/// Receives samples of one type and counts lost ones from `seq` gaps.
pub struct Subscriber<T: Sample> {
    pub(crate) inlet: Inlet<T>,
    /// The channel's doorbell. Every subscriber reads its ring count; only a
    /// woken one (not [`Bus::polled_subscriber`](crate::Bus::polled_subscriber)) sleeps on it.
    pub(crate) bell: Doorbell,
    pub(crate) woken: bool,
    /// Rings accounted for: one per sample taken, and all of those read
    /// before a receive that found the queue empty (see [`Inlet::take`]).
    pub(crate) accounted: Cell<u32>,
    pub(crate) channel: Channel<T>,
    /// Next expected `seq` per publisher.
    pub(crate) seq_tracks: RefCell<Vec<(u128, u64)>>,
    pub(crate) received: Cell<u64>,
    pub(crate) gaps: Cell<u64>,
}

impl<T: Sample> Subscriber<T> {
    pub(crate) fn new(inlet: Inlet<T>, bell: Doorbell, woken: bool, channel: Channel<T>) -> Self {
        Subscriber {
            inlet,
            accounted: Cell::new(bell.rings()),
            bell,
            woken,
            channel,
            seq_tracks: RefCell::new(Vec::new()),
            received: Cell::new(0),
            gaps: Cell::new(0),
        }
    }

    /// Takes the oldest queued sample, if any.
    pub fn try_recv(&self) -> Result<Option<T>, ReceiveError> {
        let Some((publisher, value)) = self.inlet.take(&self.bell, &self.accounted, self.channel.name)? else {
            return Ok(None);
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
    pub fn latest(&self) -> Result<Option<T>, ReceiveError> {
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
            match self.waker() {
                Some(waker) => wait_for(waker, deadline)?,
                // Polled: look again shortly.
                None => std::thread::sleep((deadline - now).min(Duration::from_millis(1))),
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

    /// The channel this port is on.
    pub fn channel(&self) -> Channel<T> {
        self.channel
    }
}

impl<T: Sample> Trigger for Subscriber<T> {
    fn waker(&self) -> Option<Waker<'_>> {
        self.woken.then(|| self.inlet.waker(&self.bell))
    }

    fn channel_name(&self) -> &'static str {
        self.channel.name
    }
}

impl<T: Sample> Drop for Subscriber<T> {
    fn drop(&mut self) {
        self.inlet.close(&self.bell);
    }
}

/// A subscriber with its sample type erased, for code that handles every
/// channel alike (the recorder).
pub trait AnySubscriber: Trigger {
    /// Takes every queued sample and hands `(seq, stamp_ns, bytes)` to `sink`.
    fn drain_raw(&self, sink: &mut dyn FnMut(u64, u64, &[u8])) -> Result<usize, ReceiveError>;
    /// Samples taken since the subscriber was created.
    fn received(&self) -> u64;
    /// Samples lost before they were taken: jumps of the publishers' `seq`.
    fn gaps(&self) -> u64;
}

impl<T: Sample> AnySubscriber for Subscriber<T> {
    fn drain_raw(&self, sink: &mut dyn FnMut(u64, u64, &[u8])) -> Result<usize, ReceiveError> {
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
