//! The live view: every bus channel, as it is published, to every client.

use std::fmt;

use jetbench_bus::tap::Tap;
use jetbench_bus::Bus;
use jetbench_record::clock::realtime_ns;
use jetbench_record::CdrMessage;

use crate::operator::FoxgloveGateway;
use crate::{ClientCounts, FoxgloveServer, ViewerError};

/// What the viewer did with one channel.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ChannelReport {
    /// Bus channel name, e.g. `bench/thrust`.
    pub channel: &'static str,
    /// Samples taken from the bus.
    pub received: u64,
    /// Samples lost on the bus before the viewer took them (`seq` gaps).
    pub gaps: u64,
    /// Samples handed to subscribed clients.
    pub sent: u64,
}

/// What the viewer did, printed at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LiveReport {
    /// Per channel served.
    pub channels: Vec<ChannelReport>,
    /// The Foxglove clients seen.
    pub clients: ClientCounts,
}

impl fmt::Display for LiveReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = self.clients;
        writeln!(f, "viewer: {} clients connected, {} subscriptions", c.connected, c.subscriptions)?;
        for ch in self.channels.iter().filter(|c| c.received > 0 || c.gaps > 0) {
            writeln!(
                f,
                "  /{:<16} {:>7} samples, {:>7} sent, {} lost on the bus",
                ch.channel, ch.received, ch.sent, ch.gaps
            )?;
        }
        Ok(())
    }
}

/// The bus, read on the viewer's own clock, served to Foxglove clients.
pub struct LiveView {
    tap: Tap,
    server: FoxgloveServer,
    /// Samples sent per channel, in the server's channel order.
    sent: Vec<u64>,
    /// The operator commands the server's services forward, if it offers any.
    gateway: Option<FoxgloveGateway>,
}

impl LiveView {
    /// Subscribes to every channel (polled, [`Tap::DEPTH`] deep).
    pub fn open(bus: &Bus, server: FoxgloveServer) -> Result<LiveView, ViewerError> {
        let tap = Tap::open(bus, Tap::DEPTH)?;
        let sent = vec![0; server.channels().names().count()];
        Ok(LiveView { tap, server, sent, gateway: None })
    }

    /// [`LiveView::open`] with the command `gateway` whose services `server` offers.
    pub fn with_gateway(bus: &Bus, server: FoxgloveServer, gateway: FoxgloveGateway) -> Result<LiveView, ViewerError> {
        let mut view = Self::open(bus, server)?;
        view.gateway = Some(gateway);
        Ok(view)
    }

    /// The Foxglove server the view serves through.
    pub fn server(&self) -> &FoxgloveServer {
        &self.server
    }

    /// Forwards the operator commands called now, sends everything queued on the bus,
    /// and answers the calls the control service decided; returns how many samples were
    /// taken.
    pub fn pump(&mut self) -> Result<usize, ViewerError> {
        let Self { tap, server, sent, gateway } = self;
        if let Some(g) = gateway.as_mut() {
            g.forward(jetbench_record::clock::monotonic_ns());
        }
        let taken = tap.drain(&mut |sample| {
            if let Some(g) = gateway.as_mut().filter(|_| sample.channel == jetbench_msgs::channels::EVENTS.name) {
                if let Some(event) = <jetbench_msgs::Event as jetbench_msgs::Sample>::from_bytes(sample.body) {
                    g.decided(&event);
                }
            }
            forward(server, sent, sample)
        })?;
        if let Some(g) = gateway.as_mut() {
            g.expire(jetbench_record::clock::monotonic_ns());
        }
        Ok(taken)
    }

    /// What the view did so far: per channel taken, lost and sent, and the clients.
    pub fn report(&self) -> LiveReport {
        report(&self.tap, &self.server, &self.sent)
    }

    /// Samples lost on the bus before the viewer took them, every channel.
    pub fn gaps(&self) -> u64 {
        self.tap.gaps()
    }

    /// Closes every client connection.
    pub fn stop(&mut self) {
        self.server.stop();
    }
}

/// One sample to the clients subscribed to its channel, stamped with the
/// wall-clock time it was taken from the bus (as the recording's `log_time`).
fn forward(server: &FoxgloveServer, sent: &mut [u64], sample: jetbench_bus::tap::TapSample<'_>) {
    let channels = server.channels();
    let (Some(index), Some(message)) = (channels.by_name(sample.channel), CdrMessage::new(sample.body)) else {
        return;
    };
    if channels.log(index, message.as_bytes(), realtime_ns()) {
        sent[index] += 1;
    }
}

fn report(tap: &Tap, server: &FoxgloveServer, sent: &[u64]) -> LiveReport {
    let channels = tap
        .counts()
        .into_iter()
        .map(|c| ChannelReport {
            channel: c.channel,
            received: c.received,
            gaps: c.gaps,
            sent: server.channels().by_name(c.channel).map_or(0, |i| sent[i]),
        })
        .collect();
    LiveReport { channels, clients: server.clients() }
}
