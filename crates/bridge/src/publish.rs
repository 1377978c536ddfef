//! The bench side: every bus channel published on Zenoh.

use std::fmt;

use jetbench_bus::tap::{Tap, TapSample};
use jetbench_bus::Bus;
use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample};
use jetbench_record::CdrMessage;
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zenoh::Wait;

use crate::{key_for, open_session, BridgeError, Endpoint, Role};

/// What the bridge did, printed at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BridgeReport {
    /// Per channel: name, samples taken from the bus, samples lost on the bus (`seq` gaps).
    pub channels: Vec<jetbench_bus::tap::ChannelCount>,
    /// Samples handed to Zenoh.
    pub published: u64,
    /// Samples Zenoh refused (logged).
    pub failed: u64,
}

impl fmt::Display for BridgeReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "bridge: {} samples published, {} refused by Zenoh", self.published, self.failed)?;
        for c in self.channels.iter().filter(|c| c.received > 0 || c.gaps > 0) {
            writeln!(f, "  /{:<16} {:>7} samples, {} lost on the bus", c.channel, c.received, c.gaps)?;
        }
        Ok(())
    }
}

/// One Zenoh publisher per bus channel, fed from the bus.
pub struct Bridge {
    tap: Tap,
    session: zenoh::Session,
    /// Bus channel name and its publisher, in channel order.
    publishers: Vec<(&'static str, zenoh::pubsub::Publisher<'static>)>,
    published: u64,
    failed: u64,
}

impl Bridge {
    /// Subscribes to every channel of `bus` and opens a Zenoh session
    /// listening on `endpoint`, publishing under `jetbench/<namespace>/`.
    pub fn open(bus: &Bus, endpoint: &Endpoint, namespace: &str) -> Result<Bridge, BridgeError> {
        let tap = Tap::open(bus, Tap::DEPTH)?;
        let session = open_session(Role::Listen, endpoint)?;
        struct Declare<'a> {
            session: &'a zenoh::Session,
            namespace: &'a str,
            publishers: Vec<(&'static str, zenoh::pubsub::Publisher<'static>)>,
            error: Option<BridgeError>,
        }
        impl ChannelVisitor for Declare<'_> {
            fn visit<T: Sample>(&mut self, channel: Channel<T>) {
                let key = key_for(self.namespace, channel.name);
                // A remote machine that cannot keep up loses samples; the bridge never waits for it.
                let declared = self
                    .session
                    .declare_publisher(key.clone())
                    .encoding(Encoding::APPLICATION_CDR.with_schema(T::schema_name()))
                    .congestion_control(CongestionControl::Drop)
                    .wait();
                match declared {
                    Ok(p) => self.publishers.push((channel.name, p)),
                    Err(source) => {
                        let e = BridgeError::Declare { what: "a publisher", key, source };
                        self.error = self.error.take().or(Some(e));
                    }
                }
            }
        }
        let mut declare = Declare { session: &session, namespace, publishers: Vec::new(), error: None };
        visit_channels(&mut declare);
        if let Some(e) = declare.error {
            return Err(e);
        }
        let publishers = declare.publishers;
        Ok(Bridge { tap, session, publishers, published: 0, failed: 0 })
    }

    /// Publishes everything queued on the bus now; returns how many samples were taken.
    pub fn pump(&mut self) -> Result<usize, BridgeError> {
        let Bridge { tap, publishers, published, failed, .. } = self;
        Ok(tap.drain(&mut |sample| publish(publishers, published, failed, sample))?)
    }

    /// Closes the Zenoh session (remote subscribers see the bench leave).
    pub fn close(&self) {
        if let Err(e) = self.session.close().wait() {
            tracing::warn!("closing the Zenoh session: {e}");
        }
    }

    pub fn report(&self) -> BridgeReport {
        BridgeReport { channels: self.tap.counts(), published: self.published, failed: self.failed }
    }

    /// Samples lost on the bus before the bridge took them, every channel.
    pub fn gaps(&self) -> u64 {
        self.tap.gaps()
    }
}

fn publish(
    publishers: &[(&'static str, zenoh::pubsub::Publisher<'static>)],
    published: &mut u64,
    failed: &mut u64,
    sample: TapSample<'_>,
) {
    let Some((_, publisher)) = publishers.iter().find(|(name, _)| *name == sample.channel) else { return };
    let Some(message) = CdrMessage::new(sample.body) else { return };
    match publisher.put(message.as_bytes()).wait() {
        Ok(()) => *published += 1,
        Err(e) => {
            *failed += 1;
            if *failed <= 5 || failed.is_multiple_of(1000) {
                tracing::warn!("Zenoh refused a sample of {} ({failed} so far): {e}", sample.channel);
            }
        }
    }
}
