//! The remote side: a bench's channels read over a Zenoh session, every
//! payload checked before it is believed.

use std::collections::HashMap;
use std::fmt;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, TrySendError};
use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample, CDR_HEADER};
use jetbench_record::clock::{realtime_ns, ClockOrigin};
use jetbench_record::meta::RunMetadata;
use jetbench_record::{spawn_writer, CdrMessage, RawRecord};
use zenoh::Wait;

use crate::{key_for, open_session, BridgeError, Endpoint, Role, KEY_PREFIX};

/// Why a payload is not a sample of its channel.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PayloadError {
    /// Shorter than the CDR header.
    #[error("{len} bytes, too short for the 4-byte CDR header")]
    Short {
        /// The payload's length in bytes.
        len: usize,
    },
    /// A CDR header other than little-endian plain CDR.
    #[error("CDR header {found:02x?} is not little-endian plain CDR (00 01 00 00)")]
    Header {
        /// The header's four bytes.
        found: [u8; 4],
    },
    /// The body's size differs from the channel's sample.
    #[error("a {name} sample has {expected} bytes after the header, this payload {len}")]
    Size {
        /// The sample type's name.
        name: &'static str,
        /// The body's length in bytes.
        len: usize,
        /// The sample's size in bytes.
        expected: usize,
    },
}

/// The body of a CDR message of `expected` body bytes, checked.
fn check_payload<'a>(payload: &'a [u8], name: &'static str, expected: usize) -> Result<&'a [u8], PayloadError> {
    let header: [u8; 4] =
        payload.get(..4).and_then(|h| h.try_into().ok()).ok_or(PayloadError::Short { len: payload.len() })?;
    if header != CDR_HEADER {
        return Err(PayloadError::Header { found: header });
    }
    let body = &payload[4..];
    if body.len() != expected {
        return Err(PayloadError::Size { name, len: body.len(), expected });
    }
    Ok(body)
}

/// Decodes a payload published by the bridge (an MCAP message's data) as a `T`.
pub fn decode_payload<T: Sample>(payload: &[u8]) -> Result<T, PayloadError> {
    let body = check_payload(payload, T::NAME, std::mem::size_of::<T>())?;
    T::from_bytes(body).ok_or(PayloadError::Size { name: T::NAME, len: body.len(), expected: std::mem::size_of::<T>() })
}

/// What a channel's payloads must look like.
#[derive(Clone, Copy, Debug)]
struct Spec {
    channel: &'static str,
    type_name: &'static str,
    body_len: usize,
    /// Offset of a `service_id: uint32` field: channels with one publisher
    /// per service (`bench/health`) count `seq` per service.
    stream_offset: Option<usize>,
}

fn specs(only: Option<&str>) -> Vec<Spec> {
    struct Collect(Vec<Spec>);
    impl ChannelVisitor for Collect {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            let stream_offset = T::FIELDS
                .iter()
                .find(|f| f.name == "service_id" && f.ros_type.to_string() == "uint32")
                .map(|f| f.offset);
            self.0.push(Spec {
                channel: channel.name,
                type_name: T::NAME,
                body_len: std::mem::size_of::<T>(),
                stream_offset,
            });
        }
    }
    let mut collect = Collect(Vec::new());
    visit_channels(&mut collect);
    collect.0.retain(|s| only.is_none_or(|name| s.channel == name));
    collect.0
}

/// One sample received from a remote bench, checked.
#[derive(Clone, Copy)]
pub struct RemoteSample {
    /// Bus channel name, e.g. `bench/thrust`.
    pub channel: &'static str,
    /// The publisher's sequence number on its channel (a jump means samples were lost).
    pub seq: u64,
    /// When the sample was measured on the bench, ns on the bench's monotonic clock.
    pub stamp_ns: u64,
    /// When it arrived here, ns since the Unix epoch (this machine's clock).
    pub received_unix_ns: u64,
    /// The payload as received: the CDR message.
    pub message: CdrMessage,
}

impl RemoteSample {
    /// The sample's bytes, after the CDR header.
    pub fn body(&self) -> &[u8] {
        &self.message.as_bytes()[CDR_HEADER.len()..]
    }
}

/// What arrived on one channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ChannelCounts {
    /// Bus channel name, e.g. `bench/thrust`.
    pub channel: &'static str,
    /// Well-formed samples.
    pub received: u64,
    /// Payloads that are not a sample of the channel (logged, skipped).
    pub malformed: u64,
    /// Samples missing between those received (`seq` gaps, per service for `bench/health`).
    pub gaps: u64,
}

/// A payload as it arrived, before it is checked.
struct Arrival {
    /// Index into the specs, or the key that matched none.
    channel: Result<usize, String>,
    payload: Vec<u8>,
    received_unix_ns: u64,
}

/// A Zenoh session connected to a remote bench.
pub struct RemoteBench {
    session: zenoh::Session,
    namespace: String,
    endpoint: Endpoint,
}

impl RemoteBench {
    /// Connects to a bridge at `endpoint` (e.g. `tcp/192.0.2.10:7447`) and
    /// reads the bench with bus namespace `namespace` (`default` for a bus
    /// without `JETBENCH_BUS`). Fails if nothing answers within 5 s.
    pub fn connect(endpoint: &Endpoint, namespace: &str) -> Result<RemoteBench, BridgeError> {
        let session = open_session(Role::Connect, endpoint)?;
        Ok(RemoteBench { session, namespace: namespace.into(), endpoint: endpoint.clone() })
    }

    /// Every channel of the bench, queued up to `depth` samples (the oldest
    /// are kept; what does not fit is counted in [`RemoteTap::dropped`]).
    pub fn subscribe_all(&self, depth: usize) -> Result<RemoteTap, BridgeError> {
        RemoteTap::open(self, None, depth)
    }

    /// One channel of the bench, as typed samples.
    pub fn subscribe<T: Sample>(&self, channel: Channel<T>, depth: usize) -> Result<RemoteSubscriber<T>, BridgeError> {
        let tap = RemoteTap::open(self, Some(channel.name), depth)?;
        Ok(RemoteSubscriber { tap, _type: std::marker::PhantomData })
    }

    /// `zenoh tcp/HOST:PORT, namespace NS`: where samples come from.
    pub fn describe(&self) -> String {
        format!("zenoh {}, namespace {}", self.endpoint, self.namespace)
    }
}

/// Samples of every channel (or one) of a remote bench, checked and counted.
pub struct RemoteTap {
    _subscriber: zenoh::pubsub::Subscriber<()>,
    inbox: Receiver<Arrival>,
    dropped: Arc<AtomicU64>,
    specs: Vec<Spec>,
    counts: Vec<ChannelCounts>,
    /// Next expected `seq` per (channel, service).
    next_seq: HashMap<(usize, u32), u64>,
    unknown: u64,
}

impl RemoteTap {
    fn open(bench: &RemoteBench, only: Option<&'static str>, depth: usize) -> Result<RemoteTap, BridgeError> {
        if let Some(name) = only.filter(|name| !jetbench_msgs::channel_names().contains(name)) {
            return Err(BridgeError::UnknownChannel(name.into()));
        }
        let specs = specs(only);
        let prefix = format!("{KEY_PREFIX}/{}/", bench.namespace);
        let key = only.map_or_else(|| format!("{KEY_PREFIX}/{}/**", bench.namespace), |c| key_for(&bench.namespace, c));
        let (sender, inbox) = bounded(depth.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        let names: Vec<&'static str> = specs.iter().map(|s| s.channel).collect();
        let callback_dropped = dropped.clone();
        // Runs on Zenoh's thread: never waits; a full inbox drops and counts.
        let callback = move |sample: zenoh::sample::Sample| {
            let key = sample.key_expr().as_str();
            let channel = key
                .strip_prefix(&prefix)
                .and_then(|name| names.iter().position(|n| *n == name))
                .ok_or_else(|| key.to_string());
            let arrival =
                Arrival { channel, payload: sample.payload().to_bytes().into_owned(), received_unix_ns: realtime_ns() };
            if let Err(TrySendError::Full(_)) = sender.try_send(arrival) {
                callback_dropped.fetch_add(1, Ordering::Relaxed);
            }
        };
        let subscriber = bench
            .session
            .declare_subscriber(key.clone())
            .callback(callback)
            .wait()
            .map_err(|source| BridgeError::Declare { what: "a subscriber", key, source })?;
        let counts = specs.iter().map(|s| ChannelCounts { channel: s.channel, ..ChannelCounts::default() }).collect();
        Ok(RemoteTap { _subscriber: subscriber, inbox, dropped, specs, counts, next_seq: HashMap::new(), unknown: 0 })
    }

    /// The next well-formed sample, waiting at most `timeout`. Malformed
    /// payloads and keys that are not channels are counted, logged and skipped.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Option<RemoteSample> {
        let deadline = Instant::now() + timeout;
        loop {
            let arrival = match self.inbox.recv_deadline(deadline) {
                Ok(a) => a,
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return None,
            };
            if let Some(sample) = self.check(arrival) {
                return Some(sample);
            }
        }
    }

    fn check(&mut self, arrival: Arrival) -> Option<RemoteSample> {
        let index = match arrival.channel {
            Ok(i) => i,
            Err(key) => {
                self.unknown += 1;
                if self.unknown <= 5 {
                    tracing::warn!("ignored a sample on {key}: not a jetbench channel of this build");
                }
                return None;
            }
        };
        let spec = self.specs[index];
        let counts = &mut self.counts[index];
        let body = match check_payload(&arrival.payload, spec.type_name, spec.body_len) {
            Ok(body) => body,
            Err(e) => {
                counts.malformed += 1;
                if counts.malformed <= 5 || counts.malformed.is_multiple_of(1000) {
                    tracing::warn!("malformed payload on {} ({} so far): {e}", spec.channel, counts.malformed);
                }
                return None;
            }
        };
        let word = |at: usize| u64::from_le_bytes(body[at..at + 8].try_into().unwrap_or_default());
        let (seq, stamp_ns) = (word(0), word(8));
        let stream =
            spec.stream_offset.map_or(0, |at| u32::from_le_bytes(body[at..at + 4].try_into().unwrap_or_default()));
        let expected = self.next_seq.insert((index, stream), seq + 1);
        counts.gaps += expected.map_or(0, |e| seq.saturating_sub(e));
        counts.received += 1;
        let message = CdrMessage::new(body)?;
        Some(RemoteSample { channel: spec.channel, seq, stamp_ns, received_unix_ns: arrival.received_unix_ns, message })
    }

    /// Per-channel counts, in channel order.
    pub fn counts(&self) -> &[ChannelCounts] {
        &self.counts
    }

    /// Samples that arrived while the inbox was full, lost here.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Malformed payloads on every channel.
    pub fn malformed(&self) -> u64 {
        self.counts.iter().map(|c| c.malformed).sum()
    }
}

/// Typed samples of one channel of a remote bench.
pub struct RemoteSubscriber<T: Sample> {
    tap: RemoteTap,
    _type: std::marker::PhantomData<fn() -> T>,
}

impl<T: Sample> RemoteSubscriber<T> {
    /// The next well-formed sample, waiting at most `timeout`.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Option<T> {
        self.tap.recv_timeout(timeout).and_then(|s| T::from_bytes(s.body()))
    }

    /// Received, malformed and missing samples of the channel; inbox drops.
    pub fn counts(&self) -> (ChannelCounts, u64) {
        (self.tap.counts[0], self.tap.dropped())
    }
}

/// What a remote recording got.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RemoteRecordReport {
    /// What arrived, per channel.
    pub channels: Vec<ChannelCounts>,
    /// Messages written to the file.
    pub written: u64,
    /// Samples lost in this machine's inbox (arrived faster than written).
    pub dropped: u64,
    /// Samples refused by the file writer's full queue.
    pub dropped_full: u64,
}

impl fmt::Display for RemoteRecordReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "remote recording: {} messages written, {} lost in the inbox, {} for a full disk queue",
            self.written, self.dropped, self.dropped_full
        )?;
        for c in self.channels.iter().filter(|c| c.received > 0 || c.malformed > 0) {
            writeln!(
                f,
                "  /{:<16} {:>7} messages, {} missing (seq gaps), {} malformed",
                c.channel, c.received, c.gaps, c.malformed
            )?;
        }
        Ok(())
    }
}

/// Records every sample of `tap` into a normal jetbench MCAP file at `path`
/// (log time: wall clock at arrival here; publish time: the sample's
/// stamp), for `duration` or until SIGINT/SIGTERM.
pub fn record_remote(
    tap: &mut RemoteTap,
    path: &Path,
    duration: Option<Duration>,
    source: &str,
) -> Result<RemoteRecordReport, BridgeError> {
    let (name, mut entries) = RunMetadata::wall_clock(ClockOrigin::now()).record();
    entries.insert("source".into(), source.into());
    let mut writer = spawn_writer(path, 4096, vec![(name, entries)])?;
    let end = duration.map(|d| Instant::now() + d);
    while !jetbench_bus::stop_requested() {
        let now = Instant::now();
        let wait = match end {
            Some(end) if now >= end => break,
            Some(end) => (end - now).min(Duration::from_millis(50)),
            None => Duration::from_millis(50),
        };
        if let Some(s) = tap.recv_timeout(wait) {
            if let Some(record) = RawRecord::new(s.channel, s.seq, s.received_unix_ns, s.stamp_ns, s.body()) {
                writer.send(record)?;
            }
        }
    }
    let dropped_full = writer.dropped_full;
    let stats = writer.finish()?;
    Ok(RemoteRecordReport {
        channels: tap.counts().to_vec(),
        written: stats.written,
        dropped: tap.dropped(),
        dropped_full,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_msgs::{channels, Health, Thrust};

    #[test]
    fn payloads_are_checked_before_they_are_believed() {
        let thrust = Thrust { seq: 3, thrust_n: 41.5, ..Thrust::default() };
        let mut payload = CDR_HEADER.to_vec();
        payload.extend_from_slice(thrust.as_bytes());
        assert_eq!(decode_payload::<Thrust>(&payload), Ok(thrust));
        assert_eq!(decode_payload::<Thrust>(&payload[..3]), Err(PayloadError::Short { len: 3 }));
        let size = std::mem::size_of::<Thrust>();
        assert_eq!(
            decode_payload::<Thrust>(&payload[..payload.len() - 1]),
            Err(PayloadError::Size { name: "Thrust", len: size - 1, expected: size })
        );
        payload[1] = 0; // big-endian CDR
        assert!(matches!(decode_payload::<Thrust>(&payload), Err(PayloadError::Header { .. })));
        let health = Health::default();
        let mut payload = CDR_HEADER.to_vec();
        payload.extend_from_slice(health.as_bytes());
        assert!(decode_payload::<Thrust>(&payload).is_err(), "a Health sample is no Thrust sample");
    }

    #[test]
    fn health_counts_seq_per_service() {
        let specs = specs(Some(channels::HEALTH.name));
        assert_eq!(specs.len(), 1);
        assert_eq!(specs[0].stream_offset, Some(std::mem::offset_of!(Health, service_id)));
        assert_eq!(super::specs(Some(channels::THRUST.name))[0].stream_offset, None);
    }
}
