//! The writer thread: disk writes decoupled from the subscribers.
//!
//! Subscribers hand [`RawRecord`]s to a bounded crossbeam channel and never
//! block; the thread writes them and flushes a chunk at least once a second.
//! A full channel is counted by the sender ([`WriterHandle::send`]), not hidden.

use std::collections::BTreeMap;
use std::path::Path;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Sender, TrySendError};

use crate::{McapWriter, RecordError};

/// Largest sample a record slot holds; every `jetbench_msgs` type fits.
pub const MAX_SAMPLE_BYTES: usize = 128;

/// Longest time a written message may sit in an unflushed chunk: what a
/// recorder killed at the worst moment loses (plus the last 10 ms tick).
pub const FLUSH_EVERY: Duration = Duration::from_millis(500);

/// One sample on its way to disk; fixed size, so sending allocates nothing.
#[derive(Clone, Copy, Debug)]
pub struct RawRecord {
    /// The channel's topic.
    pub channel: &'static str,
    /// The MCAP message sequence number.
    pub seq: u64,
    /// When the recorder took it, ns (monotonic).
    pub log_time_ns: u64,
    /// The sample's own stamp, ns (monotonic).
    pub publish_time_ns: u64,
    /// Bytes used in `bytes`.
    pub len: usize,
    /// The CDR message, `len` bytes of it used.
    pub bytes: [u8; MAX_SAMPLE_BYTES],
}

impl RawRecord {
    /// `None` if the sample is larger than a slot.
    pub fn new(channel: &'static str, seq: u64, log_time_ns: u64, publish_time_ns: u64, data: &[u8]) -> Option<Self> {
        if data.len() > MAX_SAMPLE_BYTES {
            return None;
        }
        let mut bytes = [0; MAX_SAMPLE_BYTES];
        bytes[..data.len()].copy_from_slice(data);
        Some(RawRecord { channel, seq, log_time_ns, publish_time_ns, len: data.len(), bytes })
    }
}

/// What the writer thread did, returned when it ends.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriterStats {
    /// Messages written.
    pub written: u64,
    /// Times the file was flushed to disk.
    pub flushes: u64,
}

/// The sending side of the writer thread.
pub struct WriterHandle {
    sender: Option<Sender<RawRecord>>,
    thread: Option<JoinHandle<Result<WriterStats, RecordError>>>,
    /// Records refused because the channel was full.
    pub dropped_full: u64,
}

impl WriterHandle {
    /// Queues a record without blocking. Returns false (and counts it) if
    /// the queue is full; an error if the writer thread has died.
    pub fn send(&mut self, record: RawRecord) -> Result<bool, RecordError> {
        let Some(sender) = &self.sender else {
            return Err(RecordError::WriterGone("already finished".into()));
        };
        match sender.try_send(record) {
            Ok(()) => Ok(true),
            Err(TrySendError::Full(_)) => {
                self.dropped_full += 1;
                Ok(false)
            }
            Err(TrySendError::Disconnected(_)) => Err(self.finish_error()),
        }
    }

    /// Why the writer thread ended: its own error (e.g. [`RecordError::DiskFull`]).
    fn finish_error(&mut self) -> RecordError {
        self.sender = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(Err(e))) => e,
            Some(Err(_)) => RecordError::WriterGone("writer thread panicked".into()),
            _ => RecordError::WriterGone("writer thread ended".into()),
        }
    }

    /// True once the writer thread has ended (an error it met, such as a full
    /// disk, is returned by the next [`WriterHandle::send`]).
    pub fn has_stopped(&self) -> bool {
        self.thread.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// Closes the queue, waits until everything queued is written, and
    /// finishes the file.
    pub fn finish(mut self) -> Result<WriterStats, RecordError> {
        self.sender = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(RecordError::WriterGone("writer thread panicked".into())),
            None => Err(RecordError::WriterGone("already finished".into())),
        }
    }
}

/// Metadata records written at the start of a recording: name -> entries.
pub type MetadataRecords = Vec<(String, BTreeMap<String, String>)>;

/// Opens `path`, writes `metadata`, and starts the writer thread with a
/// queue of `capacity` records.
pub fn spawn_writer(path: &Path, capacity: usize, metadata: MetadataRecords) -> Result<WriterHandle, RecordError> {
    let mut writer = McapWriter::create(path).map_err(|e| e.classify_disk_full(0))?;
    for (name, entries) in metadata {
        writer.write_metadata(&name, entries).map_err(|e| e.classify_disk_full(0))?;
    }
    let (sender, receiver) = bounded(capacity);
    let thread = std::thread::Builder::new()
        .name("mcap-writer".into())
        .spawn(move || write_loop(writer, receiver))
        .map_err(|source| RecordError::Create { path: path.into(), source })?;
    Ok(WriterHandle { sender: Some(sender), thread: Some(thread), dropped_full: 0 })
}

/// Writes until the queue closes. An error ends the thread at once, logged
/// from here so that it is reported the moment it happens, not when the
/// recorder next hands a sample over.
fn write_loop(writer: McapWriter, receiver: Receiver<RawRecord>) -> Result<WriterStats, RecordError> {
    let mut stats = WriterStats::default();
    write_all(writer, &receiver, &mut stats).map_err(|e| {
        let e = e.classify_disk_full(stats.written);
        tracing::error!("{e}");
        e
    })?;
    Ok(stats)
}

fn write_all(
    mut writer: McapWriter,
    receiver: &Receiver<RawRecord>,
    stats: &mut WriterStats,
) -> Result<(), RecordError> {
    let mut last_flush = Instant::now();
    let mut unflushed = false;
    loop {
        let wait = FLUSH_EVERY.saturating_sub(last_flush.elapsed()).max(Duration::from_millis(10));
        match receiver.recv_timeout(wait) {
            Ok(r) => {
                writer.write_raw(r.channel, r.seq, r.log_time_ns, r.publish_time_ns, &r.bytes[..r.len])?;
                stats.written += 1;
                unflushed = true;
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if unflushed && last_flush.elapsed() >= FLUSH_EVERY {
            writer.flush()?;
            stats.flushes += 1;
            unflushed = false;
            last_flush = Instant::now();
        }
    }
    writer.finish()?;
    Ok(())
}
