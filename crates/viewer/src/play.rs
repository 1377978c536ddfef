//! A recording served as the live view serves the bus, at its recorded pace
//! (like `ros2 bag play`), dated when it happened.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use jetbench_record::clock::{LogClock, TimeBase};
use jetbench_record::RecordError;

use crate::{FoxgloveServer, ViewerError};

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
    /// Messages handed to the server (whether or not a client was subscribed).
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
    pub fn open(path: &Path) -> Result<Player, ViewerError> {
        let bytes = std::fs::read(path).map_err(|source| RecordError::Read { path: path.into(), source })?;
        if !bytes.starts_with(mcap::MAGIC) {
            return Err(RecordError::NotMcap { path: path.into() }.into());
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

    pub fn time_base(&self) -> TimeBase {
        self.time_base
    }

    /// When the recording starts and ends, ns since the Unix epoch (`None`
    /// for a file without a summary, or monotonic times without an origin).
    pub fn span_unix_ns(&self) -> Option<(u64, u64)> {
        let (first, last) = self.log_span?;
        self.time_base.unix_ns(first).zip(self.time_base.unix_ns(last))
    }

    /// Plays the recording through `server` until its end (or forever with
    /// `looped`), stopping early on SIGINT/SIGTERM ([`jetbench_bus::stop_requested`]).
    pub fn play(&self, server: &FoxgloveServer, options: &PlayOptions) -> Result<PlayReport, ViewerError> {
        if !options.rate.is_finite() || options.rate <= 0.0 {
            return Err(ViewerError::Rate(options.rate));
        }
        let mut report = PlayReport::default();
        loop {
            let served = report.served;
            if !self.pass(server, options.rate, &mut report)? {
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
            // Clients start afresh: time goes back to the recording's start.
            server.clear_session();
        }
        Ok(report)
    }

    /// One pass over the file; false if it was stopped.
    fn pass(&self, server: &FoxgloveServer, rate: f64, report: &mut PlayReport) -> Result<bool, ViewerError> {
        let channels = server.channels();
        let start = Instant::now();
        let mut first_log_time = None;
        let mut last_time_sent = None;
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
            let index = channels.by_topic(&message.channel.topic).filter(|&i| channels.well_formed(i, &message.data));
            let Some(index) = index else {
                report.skipped += 1;
                if report.skipped <= 5 {
                    tracing::warn!(
                        "skipped a message on {} ({} bytes): not a sample of a bench channel",
                        message.channel.topic,
                        message.data.len()
                    );
                }
                continue;
            };
            let unix_ns = self.time_base.unix_ns(message.log_time).unwrap_or(message.log_time);
            channels.log(index, &message.data, unix_ns);
            report.served += 1;
            if last_time_sent.is_none_or(|t: u64| unix_ns.saturating_sub(t) >= TIME_EVERY_NS) {
                server.broadcast_time(unix_ns);
                last_time_sent = Some(unix_ns);
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
