//! MCAP recording of bus channels, and reading recordings back.
//!
//! One MCAP channel per bus channel, topic `/bench/...`, message encoding
//! `cdr`, schema encoding `ros2msg`, schema name `jetbench_msgs/msg/<Type>`.
//! A sample is written as the CDR header `00 01 00 00` plus its bytes, which
//! is its CDR encoding (see `jetbench_msgs`). Chunks are zstd-compressed.
//!
//! ```
//! use jetbench_msgs::{channels, Thrust};
//! use jetbench_record::{McapWriter, Recording};
//!
//! # fn main() -> Result<(), jetbench_record::RecordError> {
//! let path = std::env::temp_dir().join("jetbench-doc-example.mcap");
//! let mut writer = McapWriter::create(&path)?;
//! let thrust = Thrust { thrust_n: 12.5, stamp_ns: 1_000, ..Thrust::default() };
//! writer.write_sample(channels::THRUST, 1_000, &thrust)?;
//! writer.finish()?;
//!
//! let recording = Recording::open(&path)?;
//! assert_eq!(recording.samples(channels::THRUST), vec![thrust]);
//! # Ok(())
//! # }
//! ```
#![doc = include_str!("../README.md")]

pub mod clock;
pub mod meta;
pub mod recover;
pub mod series;
mod thread;

pub use thread::{spawn_writer, MetadataRecords, RawRecord, WriterHandle, WriterStats, MAX_SAMPLE_BYTES};

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample, CDR_HEADER};

/// Message encoding of every recorded channel.
pub const MESSAGE_ENCODING: &str = "cdr";
/// Schema encoding of every recorded channel.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// MCAP profile: samples are ROS 2 CDR messages.
pub const PROFILE: &str = "ros2";

/// Why a recording could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file could not be created, written or flushed.
    #[error("cannot create {path}: {source}")]
    Create {
        /// The recording being written.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The file could not be opened or read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The recording being read.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The MCAP library rejected a record while writing or reading.
    #[error("MCAP error in {path}: {source}")]
    Mcap {
        /// The recording concerned.
        path: PathBuf,
        /// The MCAP library's error.
        source: mcap::McapError,
    },
    /// The file is something else than MCAP.
    #[error("{path} is not an MCAP file (it does not start with the MCAP magic bytes); {what}")]
    NotMcap {
        /// The file that was given.
        path: PathBuf,
        /// What its first bytes look like instead (a CSV, a TOML file, ...).
        what: &'static str,
    },
    /// A message was logged on a topic that was not registered first.
    #[error("channel {0} is not registered in this recording")]
    UnknownChannel(String),
    /// A sample does not fit the fixed-size slot the recorder copies it into.
    #[error("sample of {channel} is {size} bytes, larger than the {max}-byte record slot")]
    SampleTooLarge {
        /// The channel's topic.
        channel: String,
        /// The sample's size in bytes.
        size: usize,
        /// The slot's size in bytes.
        max: usize,
    },
    /// The background writer thread ended (its error, or why it is gone).
    #[error("the recorder's writer thread stopped: {0}")]
    WriterGone(String),
    /// The disk holding the recording is full (or its quota or the file size
    /// limit is reached): nothing more can be written.
    #[error(
        "the disk holding {path} is full ({source}): recording stopped after {written} messages; everything \
         flushed before is in the file (`jetbench recover {path} --out FIXED.mcap`, on another disk, rewrites it whole)"
    )]
    DiskFull {
        /// The recording being written.
        path: PathBuf,
        /// Messages written before the disk filled.
        written: u64,
        /// What the operating system said.
        source: std::io::Error,
    },
}

impl RecordError {
    /// [`RecordError::NotMcap`] for a file whose content is `bytes`, saying what it looks like instead.
    pub fn not_mcap(path: &Path, bytes: &[u8]) -> RecordError {
        let what = if bytes.is_empty() {
            "it is empty (0 bytes): a recording that never started writing, or a copy that failed"
        } else if looks_like_text(bytes) {
            "it is text: a CSV `time_s,throttle_pct,thrust_n` is read by identify, diagnose, export and simulate, \
             whatever its name"
        } else {
            "nor is it text (CSV): a damaged download or another format; a recording cut short keeps its start, so \
             this is not one"
        };
        RecordError::NotMcap { path: path.into(), what }
    }

    /// This error as [`RecordError::DiskFull`] when it is one (a write that
    /// failed for lack of space), `written` messages into the file.
    pub fn classify_disk_full(self, written: u64) -> RecordError {
        let io = match &self {
            RecordError::Mcap { source: mcap::McapError::Io(io), .. } | RecordError::Create { source: io, .. } => io,
            _ => return self,
        };
        let full = matches!(
            io.kind(),
            std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded | std::io::ErrorKind::FileTooLarge
        );
        match self {
            RecordError::Mcap { path, source: mcap::McapError::Io(source) } | RecordError::Create { path, source }
                if full =>
            {
                RecordError::DiskFull { path, written, source }
            }
            other => other,
        }
    }
}

/// A sample as its CDR message, the 4-byte header `00 01 00 00` plus its
/// bytes, in a fixed buffer: what an MCAP message, a Foxglove message and a
/// Zenoh payload carry.
#[derive(Clone, Copy)]
pub struct CdrMessage {
    len: usize,
    bytes: [u8; 4 + MAX_SAMPLE_BYTES],
}

impl CdrMessage {
    /// `None` if `body` is larger than [`MAX_SAMPLE_BYTES`].
    pub fn new(body: &[u8]) -> Option<Self> {
        if body.len() > MAX_SAMPLE_BYTES {
            return None;
        }
        let mut bytes = [0; 4 + MAX_SAMPLE_BYTES];
        bytes[..4].copy_from_slice(&CDR_HEADER);
        bytes[4..4 + body.len()].copy_from_slice(body);
        Some(CdrMessage { len: 4 + body.len(), bytes })
    }

    /// The message's bytes: the CDR header, then the sample.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// The software version this process writes into the header of each MCAP file
/// (`jetbench <version>`), set once by the program at its start.
static SOFTWARE: std::sync::OnceLock<&'static str> = std::sync::OnceLock::new();

/// Names the software that writes this process's recordings: the version
/// `jetbench --version` prints, with its commit and build date. Set once, at
/// the start of the program (later calls are ignored); without it the header
/// names the release only.
pub fn set_software_version(version: &'static str) {
    let _ = SOFTWARE.set(version);
}

/// The `library` field of every MCAP header this process writes.
pub fn software() -> String {
    format!("jetbench {}", SOFTWARE.get().copied().unwrap_or(env!("CARGO_PKG_VERSION")))
}

/// How every jetbench MCAP file is written: zstd chunks, the `ros2` profile,
/// the library named with its version and commit ([`set_software_version`]).
pub(crate) fn write_options() -> mcap::WriteOptions {
    mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)).profile(PROFILE).library(software())
}

/// Writes bus samples into an MCAP file with every channel registered up front.
pub struct McapWriter {
    writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    /// Bus channel name -> MCAP channel id.
    ids: HashMap<&'static str, u16>,
    messages: u64,
}

impl McapWriter {
    /// Creates `path`, writes the header, and registers the schema and
    /// channel of every bus channel (so empty channels are visible too).
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        let file = File::create(path).map_err(|source| RecordError::Create { path: path.into(), source })?;
        let mcap_err = |source| RecordError::Mcap { path: path.into(), source };
        let writer = write_options().create(BufWriter::new(file)).map_err(mcap_err)?;

        struct Register<'a> {
            writer: mcap::Writer<BufWriter<File>>,
            ids: &'a mut HashMap<&'static str, u16>,
            error: Option<mcap::McapError>,
        }
        impl ChannelVisitor for Register<'_> {
            fn visit<T: Sample>(&mut self, channel: Channel<T>) {
                if self.error.is_some() {
                    return;
                }
                let result =
                    self.writer.add_schema(&T::schema_name(), SCHEMA_ENCODING, T::schema_text().as_bytes()).and_then(
                        |schema| self.writer.add_channel(schema, &channel.topic(), MESSAGE_ENCODING, &BTreeMap::new()),
                    );
                match result {
                    Ok(id) => {
                        self.ids.insert(channel.name, id);
                    }
                    Err(e) => self.error = Some(e),
                }
            }
        }
        let mut ids = HashMap::new();
        let mut register = Register { writer, ids: &mut ids, error: None };
        visit_channels(&mut register);
        if let Some(e) = register.error {
            return Err(mcap_err(e));
        }
        Ok(McapWriter { writer: register.writer, path: path.into(), ids, messages: 0 })
    }

    fn mcap_err(&self, source: mcap::McapError) -> RecordError {
        RecordError::Mcap { path: self.path.clone(), source }
    }

    /// Writes one sample's raw bytes on the bus channel `channel_name`.
    /// `log_time_ns` is the time the recorder received it, on the clock the
    /// recording declares (see [`clock`]).
    pub fn write_raw(
        &mut self,
        channel_name: &str,
        seq: u64,
        log_time_ns: u64,
        publish_time_ns: u64,
        bytes: &[u8],
    ) -> Result<(), RecordError> {
        let id = *self.ids.get(channel_name).ok_or_else(|| RecordError::UnknownChannel(channel_name.into()))?;
        let message = CdrMessage::new(bytes).ok_or_else(|| RecordError::SampleTooLarge {
            channel: channel_name.into(),
            size: bytes.len(),
            max: MAX_SAMPLE_BYTES,
        })?;
        let header = mcap::records::MessageHeader {
            channel_id: id,
            // MCAP sequence numbers are 32-bit; the full seq is in the body.
            sequence: seq as u32,
            log_time: log_time_ns,
            publish_time: publish_time_ns,
        };
        self.writer.write_to_known_channel(&header, message.as_bytes()).map_err(|e| self.mcap_err(e))?;
        self.messages += 1;
        Ok(())
    }

    /// Writes a typed sample; `publish_time` is the sample's `stamp_ns`.
    pub fn write_sample<T: Sample>(
        &mut self,
        channel: Channel<T>,
        log_time_ns: u64,
        sample: &T,
    ) -> Result<(), RecordError> {
        self.write_raw(channel.name, sample.seq(), log_time_ns, sample.stamp_ns(), sample.as_bytes())
    }

    /// Records free-form key/value metadata (run configuration, clock origin).
    pub fn write_metadata(&mut self, name: &str, entries: BTreeMap<String, String>) -> Result<(), RecordError> {
        let metadata = mcap::records::Metadata { name: name.into(), metadata: entries };
        self.writer.write_metadata(&metadata).map_err(|e| self.mcap_err(e))
    }

    /// Closes the current chunk and flushes it to the file, so that a crash
    /// after this point loses nothing written before it.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.writer.flush().map_err(|e| self.mcap_err(e))?;
        Ok(())
    }

    /// Messages written so far.
    pub fn messages(&self) -> u64 {
        self.messages
    }

    /// Writes the summary and closes the file.
    pub fn finish(mut self) -> Result<u64, RecordError> {
        self.writer.finish().map_err(|e| self.mcap_err(e))?;
        let mut inner = self.writer.into_inner();
        inner.flush().map_err(|source| RecordError::Create { path: self.path.clone(), source })?;
        Ok(self.messages)
    }
}

/// One recorded message.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordedMessage {
    /// The channel's topic (`bench/state`, ...).
    pub topic: String,
    /// The ROS 2 message type of its schema (`jetbench_msgs/msg/BenchState`, ...).
    pub schema_name: String,
    /// When the recorder logged it, ns on the bench's monotonic clock.
    pub log_time_ns: u64,
    /// The sample's own stamp, ns on the same clock.
    pub publish_time_ns: u64,
    /// The CDR message (header plus body).
    pub data: Vec<u8>,
}

impl RecordedMessage {
    /// `sample` as the recorder logs it on `channel`: the CDR header plus its
    /// bytes, logged at `log_time_ns`, published at its `stamp_ns`.
    pub fn of_sample<T: Sample>(channel: Channel<T>, log_time_ns: u64, sample: &T) -> RecordedMessage {
        let mut data = Vec::with_capacity(CDR_HEADER.len() + std::mem::size_of::<T>());
        data.extend_from_slice(&CDR_HEADER);
        data.extend_from_slice(sample.as_bytes());
        RecordedMessage {
            topic: channel.topic(),
            schema_name: T::schema_name(),
            log_time_ns,
            publish_time_ns: sample.stamp_ns(),
            data,
        }
    }
}

/// A recording read into memory.
#[derive(Clone, Debug, Default)]
pub struct Recording {
    /// Every message, in the order of the file.
    pub messages: Vec<RecordedMessage>,
    /// The file ended early (e.g. the recorder was killed): the messages up to
    /// the last complete chunk are present.
    pub truncated: bool,
    /// Metadata records by name.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
}

impl Recording {
    /// Reads every message of an MCAP file. A file cut off mid-write is read
    /// up to its last complete record and flagged `truncated`.
    pub fn open(path: &Path) -> Result<Recording, RecordError> {
        let bytes = std::fs::read(path).map_err(|source| RecordError::Read { path: path.into(), source })?;
        if !bytes.starts_with(mcap::MAGIC) {
            return Err(RecordError::not_mcap(path, &bytes));
        }
        let mut recording = Recording::default();
        let stream = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
            .map_err(|source| RecordError::Mcap { path: path.into(), source })?;
        for message in stream {
            match message {
                Ok(m) => recording.messages.push(RecordedMessage {
                    topic: m.channel.topic.clone(),
                    schema_name: m.channel.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default(),
                    log_time_ns: m.log_time,
                    publish_time_ns: m.publish_time,
                    data: m.data.into_owned(),
                }),
                Err(_) => {
                    recording.truncated = true;
                    break;
                }
            }
        }
        if !recording.truncated && !bytes.ends_with(mcap::MAGIC) {
            recording.truncated = true;
        }
        recording.metadata = read_metadata(&bytes);
        Ok(recording)
    }

    /// How to read this recording's `log_time`s as wall-clock time.
    pub fn time_base(&self) -> clock::TimeBase {
        clock::TimeBase::new(&self.metadata, self.messages.first().map(|m| m.log_time_ns))
    }

    /// Decoded samples of one channel, in recorded order. Messages whose
    /// size does not match the type are skipped (see [`Recording::malformed`]).
    pub fn samples<T: Sample>(&self, channel: Channel<T>) -> Vec<T> {
        let topic = channel.topic();
        self.messages.iter().filter(|m| m.topic == topic).filter_map(|m| T::from_cdr(&m.data)).collect()
    }

    /// Messages on `channel` that do not decode as its type.
    pub fn malformed<T: Sample>(&self, channel: Channel<T>) -> usize {
        let topic = channel.topic();
        self.messages.iter().filter(|m| m.topic == topic && T::from_cdr(&m.data).is_none()).count()
    }

    /// Message count per topic.
    pub fn counts(&self) -> BTreeMap<String, usize> {
        let mut counts = BTreeMap::new();
        for m in &self.messages {
            *counts.entry(m.topic.clone()).or_insert(0) += 1;
        }
        counts
    }
}

/// The metadata records of an MCAP file's bytes, by name: through the
/// summary's index, or, in a file cut off before its summary (a recorder
/// killed mid-run), read from the records before the cut (the recorder writes
/// its metadata first).
pub fn read_metadata(bytes: &[u8]) -> BTreeMap<String, BTreeMap<String, String>> {
    let mut metadata = BTreeMap::new();
    if let Ok(Some(summary)) = mcap::Summary::read(bytes) {
        for index in &summary.metadata_indexes {
            if let Ok(m) = mcap::read::metadata(bytes, index) {
                metadata.insert(m.name, m.metadata);
            }
        }
        return metadata;
    }
    let Ok(reader) = mcap::read::LinearReader::new_with_options(bytes, mcap::read::Options::IgnoreEndMagic.into())
    else {
        return metadata;
    };
    reader
        .map_while(Result::ok)
        .filter_map(|record| match record {
            mcap::records::Record::Metadata(m) => Some((m.name, m.metadata)),
            _ => None,
        })
        .collect()
}

/// True when `bytes` start as UTF-8 text without NUL bytes (as a CSV does), judged
/// on the first 4 KiB.
pub fn looks_like_text(bytes: &[u8]) -> bool {
    let head = &bytes[..bytes.len().min(4096)];
    if head.contains(&0) {
        return false;
    }
    match std::str::from_utf8(head) {
        Ok(_) => true,
        // A character cut at the 4 KiB boundary is still text.
        Err(e) => e.error_len().is_none(),
    }
}

/// Counts missing `seq` numbers in samples of one publisher.
pub fn seq_gaps<T: Sample>(samples: &[T]) -> u64 {
    samples.windows(2).map(|w| w[1].seq().saturating_sub(w[0].seq() + 1)).sum()
}

/// One channel of a recording at a glance (`jetbench info`).
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelSummary {
    /// The channel's topic.
    pub topic: String,
    /// Messages on it.
    pub messages: usize,
    /// Messages per second of log time.
    pub rate_hz: f64,
    /// Samples lost between publisher and recorder (per publisher: `bench/health` has one per service).
    pub seq_gaps: u64,
}

impl Recording {
    /// Every channel with samples, in registry order: messages, rate and `seq` gaps.
    pub fn summary(&self) -> Vec<ChannelSummary> {
        struct Summary<'a> {
            recording: &'a Recording,
            channels: Vec<ChannelSummary>,
        }
        impl ChannelVisitor for Summary<'_> {
            fn visit<T: Sample>(&mut self, channel: Channel<T>) {
                let samples = self.recording.samples(channel);
                if samples.is_empty() {
                    return;
                }
                // Rate on the recorder's receive time: every sample has one.
                let topic = channel.topic();
                let times: Vec<u64> =
                    self.recording.messages.iter().filter(|m| m.topic == topic).map(|m| m.log_time_ns).collect();
                let span_s = times.last().zip(times.first()).map_or(0, |(l, f)| l.saturating_sub(*f)) as f64 * 1e-9;
                let rate_hz = if span_s > 0.0 { (times.len() - 1) as f64 / span_s } else { 0.0 };
                // bench/health has one publisher per service: gaps are per publisher.
                let seq_gaps = if channel.name == jetbench_msgs::channels::HEALTH.name {
                    let health = self.recording.samples(jetbench_msgs::channels::HEALTH);
                    jetbench_msgs::ServiceId::ALL
                        .iter()
                        .map(|id| {
                            let mine: Vec<_> = health.iter().copied().filter(|h| h.service_id == *id as u32).collect();
                            seq_gaps(&mine)
                        })
                        .sum()
                } else {
                    seq_gaps(&samples)
                };
                self.channels.push(ChannelSummary { topic, messages: samples.len(), rate_hz, seq_gaps });
            }
        }
        let mut summary = Summary { recording: self, channels: Vec::new() };
        visit_channels(&mut summary);
        summary.channels
    }
}
