//! Every bus channel, read as the recorder reads it: one polled subscriber
//! per channel, drained on the reader's own clock.
//!
//! Publishers never wake a polled subscriber, so a reader of every channel
//! (the recorder, the live viewer, the bridge to other machines) costs the
//! control path no system call, and a reader that stalls loses only its own
//! queued samples, counted from `seq` gaps.
//!
//! ```no_run
//! use jetbench_bus::Bus;
//! use jetbench_bus::tap::Tap;
//!
//! # fn main() -> Result<(), jetbench_bus::BusError> {
//! let bus = Bus::open("my-tool")?;
//! let tap = Tap::open(&bus, Tap::DEPTH)?;
//! tap.drain(&mut |sample| println!("/{} seq {} ({} bytes)", sample.channel, sample.seq, sample.body.len()))?;
//! println!("{} samples lost", tap.gaps());
//! # Ok(())
//! # }
//! ```

use crate::{AnySubscriber, Bus, PortError, ReceiveError};
use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample};

/// One sample taken from the bus.
#[derive(Clone, Copy, Debug)]
pub struct TapSample<'a> {
    /// Bus channel name, e.g. `bench/thrust`.
    pub channel: &'static str,
    /// The publisher's sequence number: consecutive on a channel, so a jump is a
    /// sample lost before it was taken.
    pub seq: u64,
    /// When the sample was taken at its source, ns on the bench's monotonic clock.
    pub stamp_ns: u64,
    /// The sample's bytes: its CDR body.
    pub body: &'a [u8],
}

/// What a tap took from one channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ChannelCount {
    /// Bus channel name, e.g. `bench/thrust`.
    pub channel: &'static str,
    /// Samples taken.
    pub received: u64,
    /// Samples lost before they were taken (`seq` gaps).
    pub gaps: u64,
}

/// A polled subscriber on every channel of the service set.
pub struct Tap {
    subs: Vec<Box<dyn AnySubscriber>>,
}

impl Tap {
    /// The deepest queue a channel allows: 5 s of samples at 100 Hz.
    pub const DEPTH: usize = crate::limits::MAX_BUFFER;

    /// Subscribes to every channel with queues of `depth` samples.
    pub fn open(bus: &Bus, depth: usize) -> Result<Tap, PortError> {
        struct Subscribe<'a> {
            bus: &'a Bus,
            depth: usize,
            subs: Vec<Box<dyn AnySubscriber>>,
            error: Option<PortError>,
        }
        impl ChannelVisitor for Subscribe<'_> {
            fn visit<T: Sample>(&mut self, channel: Channel<T>) {
                match self.bus.polled_subscriber(channel, self.depth) {
                    Ok(s) => self.subs.push(Box::new(s)),
                    Err(e) => self.error = self.error.take().or(Some(e)),
                }
            }
        }
        let mut subscribe = Subscribe { bus, depth, subs: Vec::new(), error: None };
        visit_channels(&mut subscribe);
        match subscribe.error {
            Some(e) => Err(e),
            None => Ok(Tap { subs: subscribe.subs }),
        }
    }

    /// Takes every queued sample of every channel, in channel order; returns how many.
    pub fn drain(&self, sink: &mut dyn FnMut(TapSample<'_>)) -> Result<usize, ReceiveError> {
        let mut taken = 0;
        for sub in &self.subs {
            let channel = sub.channel_name();
            taken += sub.drain_raw(&mut |seq, stamp_ns, body| sink(TapSample { channel, seq, stamp_ns, body }))?;
        }
        Ok(taken)
    }

    /// Per-channel counts, in channel order.
    pub fn counts(&self) -> Vec<ChannelCount> {
        self.subs
            .iter()
            .map(|s| ChannelCount { channel: s.channel_name(), received: s.received(), gaps: s.gaps() })
            .collect()
    }

    /// Samples lost on every channel so far.
    pub fn gaps(&self) -> u64 {
        self.subs.iter().map(|s| s.gaps()).sum()
    }
}
