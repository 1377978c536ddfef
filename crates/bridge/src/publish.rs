//! The bench side: every bus channel published on Zenoh.

use std::fmt;

use jetbench_bus::tap::{Tap, TapSample};
use jetbench_bus::Bus;
use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample};
use jetbench_record::CdrMessage;
use zenoh::bytes::Encoding;
use zenoh::qos::CongestionControl;
use zenoh::Wait;

use crate::operator::{Gateway, GatewayCounts};
use crate::{key_for, open_session_with, BridgeError, Endpoint, Role};
use jetbench_control::operator::OperatorSettings;

/// What the bridge did, printed at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BridgeReport {
    /// Per channel: name, samples taken from the bus, samples lost on the bus (`seq` gaps).
    pub channels: Vec<jetbench_bus::tap::ChannelCount>,
    /// Samples handed to Zenoh.
    pub published: u64,
    /// Samples Zenoh refused (logged).
    pub failed: u64,
    /// The command gateway's counts, with `[operator]`.
    pub commands: Option<GatewayCounts>,
}

impl fmt::Display for BridgeReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "bridge: {} samples published, {} refused by Zenoh", self.published, self.failed)?;
        if let Some(c) = self.commands {
            writeln!(
                f,
                "  commands: {} forwarded, {} accepted, {} refused, {} undecided, {} malformed",
                c.forwarded, c.accepted, c.refused, c.undecided, c.malformed
            )?;
        }
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
    gateway: Option<Gateway>,
}

impl Bridge {
    /// Subscribes to every channel of `bus` and opens a Zenoh session
    /// listening on `endpoint`, publishing under `jetbench/<namespace>/`.
    /// With `operator`, it also listens on the operator's TLS endpoint (client
    /// certificates required), enforces the access control made from it and answers
    /// commands (see [`crate::operator`]).
    pub fn open(
        bus: &Bus,
        endpoint: &Endpoint,
        namespace: &str,
        operator: Option<&OperatorSettings>,
    ) -> Result<Bridge, BridgeError> {
        let tap = Tap::open(bus, Tap::DEPTH)?;
        let mut endpoints = vec![endpoint.clone()];
        let mut extra = Vec::new();
        if let Some(settings) = operator {
            settings.check()?;
            settings.check_files()?;
            endpoints.push(settings.tls_listen.parse()?);
            extra = crate::operator::session_settings(settings, namespace);
        }
        let session = open_session_with(Role::Listen, &endpoints, &extra)?;
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
        let gateway = match operator {
            Some(settings) => Some(Gateway::open(&session, bus, settings, namespace)?),
            None => None,
        };
        Ok(Bridge { tap, session, publishers, published: 0, failed: 0, gateway })
    }

    /// Forwards the control room's commands, publishes everything queued on the bus now,
    /// and answers the commands the control service decided; returns how many samples
    /// were taken.
    pub fn pump(&mut self) -> Result<usize, BridgeError> {
        let Bridge { tap, publishers, published, failed, gateway, .. } = self;
        if let Some(g) = gateway.as_mut() {
            g.forward(jetbench_record::clock::monotonic_ns());
        }
        let taken = tap.drain(&mut |sample| {
            if let Some(g) = gateway.as_mut().filter(|_| sample.channel == jetbench_msgs::channels::EVENTS.name) {
                if let Some(event) = <jetbench_msgs::Event as Sample>::from_bytes(sample.body) {
                    g.decided(&event);
                }
            }
            publish(publishers, published, failed, sample)
        })?;
        if let Some(g) = gateway.as_mut() {
            g.expire(jetbench_record::clock::monotonic_ns());
        }
        Ok(taken)
    }

    /// Closes the Zenoh session (remote subscribers see the bench leave).
    pub fn close(&self) {
        if let Err(e) = self.session.close().wait() {
            tracing::warn!("closing the Zenoh session: {e}");
        }
    }

    /// What the bridge published and lost so far, per channel, and its command gateway's counts.
    pub fn report(&self) -> BridgeReport {
        BridgeReport {
            channels: self.tap.counts(),
            published: self.published,
            failed: self.failed,
            commands: self.gateway.as_ref().map(Gateway::counts),
        }
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
