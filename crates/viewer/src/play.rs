//! A recording played at its recorded pace (like `ros2 bag play`): published
//! on the bus, so every reader of a live set (`echo`, `hz`, the viewer, the
//! bridge, `record`) sees it as live, and/or served to Foxglove as the live view
//! serves the bus, dated when it happened.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use jetbench_record::clock::{LogClock, TimeBase};
use jetbench_record::RecordError;

use jetbench_bus::{Bus, BusError, Publisher};
use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample};

use crate::{FoxgloveServer, ViewerError};

/// Where played messages go: the bus ([`BusSink`]), a Foxglove server, or both.
pub trait PlaySink {
    /// Delivers one recorded message (a CDR message of `topic`) logged at
    /// `unix_ns`; false when it is not a sample of one of the sink's channels.
    fn deliver(&mut self, topic: &str, cdr: &[u8], unix_ns: u64) -> Result<bool, ViewerError>;
    /// The recording starts over (`--loop`).
    fn restart(&mut self) {}
}

impl PlaySink for &FoxgloveServer {
    fn deliver(&mut self, topic: &str, cdr: &[u8], unix_ns: u64) -> Result<bool, ViewerError> {
        let channels = self.channels();
        let Some(index) = channels.by_topic(topic).filter(|&i| channels.well_formed(i, cdr)) else {
            return Ok(false);
        };
        channels.log(index, cdr, unix_ns);
        Ok(true)
    }

    fn restart(&mut self) {
        // Clients start afresh: time goes back to the recording's start.
        self.clear_session();
    }
}

impl<A: PlaySink, B: PlaySink> PlaySink for (A, B) {
    fn deliver(&mut self, topic: &str, cdr: &[u8], unix_ns: u64) -> Result<bool, ViewerError> {
        let a = self.0.deliver(topic, cdr, unix_ns)?;
        let b = self.1.deliver(topic, cdr, unix_ns)?;
        Ok(a || b)
    }

    fn restart(&mut self) {
        self.0.restart();
        self.1.restart();
    }
}

/// Publishes played samples on this machine's bus, one publisher per bench
/// channel, as the services would (each publisher numbers its own `seq`).
pub struct BusSink {
    publishers: Vec<(String, Publish)>,
}

/// Publishes one CDR message as its channel's sample; false if it is not one.
type Publish = Box<dyn FnMut(&[u8]) -> Result<bool, BusError>>;

impl BusSink {
    /// A publisher on every bench channel of `bus`.
    pub fn new(bus: &Bus) -> Result<BusSink, ViewerError> {
        struct Make<'a> {
            bus: &'a Bus,
            sink: BusSink,
            error: Option<BusError>,
        }
        impl ChannelVisitor for Make<'_> {
            fn visit<T: Sample>(&mut self, channel: Channel<T>) {
                if self.error.is_some() {
                    return;
                }
                match self.bus.publisher(channel) {
                    Ok(publisher) => {
                        let mut publisher: Publisher<T> = publisher;
                        let publish = move |cdr: &[u8]| -> Result<bool, BusError> {
                            let Some(sample) = T::from_cdr(cdr) else { return Ok(false) };
                            publisher.publish(sample)?;
                            Ok(true)
                        };
                        self.sink.publishers.push((channel.topic(), Box::new(publish)));
                    }
                    Err(e) => self.error = Some(e.into()),
                }
            }
        }
        let mut make = Make { bus, sink: BusSink { publishers: Vec::new() }, error: None };
        visit_channels(&mut make);
        match make.error {
            Some(e) => Err(e.into()),
            None => Ok(make.sink),
        }
    }
}

impl PlaySink for BusSink {
    fn deliver(&mut self, topic: &str, cdr: &[u8], _unix_ns: u64) -> Result<bool, ViewerError> {
        match self.publishers.iter_mut().find(|(t, _)| t == topic) {
            Some((_, publish)) => Ok(publish(cdr)?),
            None => Ok(false),
        }
    }
}

/// The clock of a Foxglove server, sent along with the played messages.
struct Clocked<'a, S> {
    server: Option<&'a FoxgloveServer>,
    sink: S,
    last_time_sent: Option<u64>,
}

/// How a recording is played.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlayOptions {
    /// Speed factor: 1 plays in real time, 2 twice as fast.
    pub rate: f64,
    /// Start over at the end, until stopped.
    pub looped: bool,
}

impl Default for PlayOptions {
    fn default() -> Self {
        PlayOptions { rate: 1.0, looped: false }
    }
}

/// What a playback did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlayReport {
    /// Messages delivered (to the bus, or to the server whether or not a client was subscribed).
    pub served: u64,
    /// Times the recording was played to its end.
    pub passes: u64,
    /// Messages left out: a topic that is not a bus channel, or data that is
    /// not a CDR message of its channel's type.
    pub skipped: u64,
    /// The file ends early (a recorder that was killed): played up to its last complete chunk.
    pub truncated: bool,
}

/// An MCAP recording, read into memory (compressed, as on disk).
pub struct Player {
    path: PathBuf,
    bytes: Vec<u8>,
    time_base: TimeBase,
    /// First and last log time, from the file's summary.
    log_span: Option<(u64, u64)>,
}

/// Longest sleep between two looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(50);
/// How often the server's clock is sent to the clients during playback (60 Hz).
const TIME_EVERY_NS: u64 = 1_000_000_000 / 60;

impl Player {
    /// Reads the MCAP recording at `path` and works out how to date its messages; an
    /// error names the file and what is wrong with it (missing, not MCAP, truncated).
    pub fn open(path: &Path) -> Result<Player, ViewerError> {
        let bytes = std::fs::read(path).map_err(|source| RecordError::Read { path: path.into(), source })?;
        if !bytes.starts_with(mcap::MAGIC) {
            return Err(RecordError::not_mcap(path, &bytes).into());
        }
        let first_log_time = stream(path, &bytes)?.next().and_then(Result::ok).map(|m| m.log_time);
        let time_base = TimeBase::new(&jetbench_record::read_metadata(&bytes), first_log_time);
        if time_base.log_clock == LogClock::Monotonic && time_base.origin.is_none() {
            tracing::warn!(
                "{}: log times are monotonic and the file has no clock origin: it is shown dated 1970",
                path.display()
            );
        }
        let log_span = mcap::Summary::read(&bytes)
            .ok()
            .flatten()
            .and_then(|s| s.stats)
            .map(|s| (s.message_start_time, s.message_end_time));
        Ok(Player { path: path.into(), bytes, time_base, log_span })
    }

    /// How the recording's log times map to wall-clock time (what Foxglove shows).
    pub fn time_base(&self) -> TimeBase {
        self.time_base
    }

    /// When the recording starts and ends, ns since the Unix epoch (`None`
    /// for a file without a summary, or monotonic times without an origin).
    pub fn span_unix_ns(&self) -> Option<(u64, u64)> {
        let (first, last) = self.log_span?;
        self.time_base.unix_ns(first).zip(self.time_base.unix_ns(last))
    }

    /// Plays the recording to `sink` until its end (or forever with `looped`),
    /// stopping early on SIGINT/SIGTERM ([`jetbench_bus::stop_requested`]).
    /// With a Foxglove `server` among the sinks, pass it as `clock` too: its
    /// clients are sent the recording's time as it plays.
    pub fn play<S: PlaySink>(
        &self,
        sink: S,
        clock: Option<&FoxgloveServer>,
        options: &PlayOptions,
    ) -> Result<PlayReport, ViewerError> {
        if !options.rate.is_finite() || options.rate <= 0.0 {
            return Err(ViewerError::Rate(options.rate));
        }
        let mut report = PlayReport::default();
        let mut sink = Clocked { server: clock, sink, last_time_sent: None };
        loop {
            let served = report.served;
            if !self.pass(&mut sink, options.rate, &mut report)? {
                break;
            }
            report.passes += 1;
            if !options.looped {
                break;
            }
            if report.served == served {
                tracing::warn!("{}: nothing to play", self.path.display());
                break;
            }
            sink.sink.restart();
            sink.last_time_sent = None;
        }
        Ok(report)
    }

    /// One pass over the file; false if it was stopped.
    fn pass<S: PlaySink>(
        &self,
        sink: &mut Clocked<S>,
        rate: f64,
        report: &mut PlayReport,
    ) -> Result<bool, ViewerError> {
        let start = Instant::now();
        let mut first_log_time = None;
        for message in stream(&self.path, &self.bytes)? {
            let message = match message {
                Ok(m) => m,
                Err(e) => {
                    if !report.truncated {
                        tracing::warn!(
                            "{} ends early ({e}): played up to its last complete chunk",
                            self.path.display()
                        );
                    }
                    report.truncated = true;
                    break;
                }
            };
            let since_first_ns = message.log_time.saturating_sub(*first_log_time.get_or_insert(message.log_time));
            if !sleep_until(start + Duration::from_secs_f64(since_first_ns as f64 * 1e-9 / rate)) {
                return Ok(false);
            }
            let unix_ns = self.time_base.unix_ns(message.log_time).unwrap_or(message.log_time);
            if !sink.sink.deliver(&message.channel.topic, &message.data, unix_ns)? {
                report.skipped += 1;
                if report.skipped <= 5 {
                    tracing::warn!(
                        "skipped a message on {} ({} bytes): not a sample of a bench channel",
                        message.channel.topic,
                        message.data.len()
                    );
                }
                continue;
            }
            report.served += 1;
            if let Some(server) = sink.server {
                if sink.last_time_sent.is_none_or(|t: u64| unix_ns.saturating_sub(t) >= TIME_EVERY_NS) {
                    server.broadcast_time(unix_ns);
                    sink.last_time_sent = Some(unix_ns);
                }
            }
        }
        Ok(true)
    }
}

fn stream<'a>(path: &Path, bytes: &'a [u8]) -> Result<mcap::MessageStream<'a>, RecordError> {
    mcap::MessageStream::new_with_options(bytes, mcap::read::Options::IgnoreEndMagic.into())
        .map_err(|source| RecordError::Mcap { path: path.into(), source })
}

/// Sleeps until `due`, waking for a stop request; false if one came.
fn sleep_until(due: Instant) -> bool {
    loop {
        if jetbench_bus::stop_requested() {
            return false;
        }
        let now = Instant::now();
        if now >= due {
            return true;
        }
        std::thread::sleep((due - now).min(STOP_POLL));
    }
}
