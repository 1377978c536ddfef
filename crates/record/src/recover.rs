//! Rewriting a truncated or damaged recording as a valid, indexed MCAP file.
//!
//! A recorder killed mid-run (or stopped by a full disk) leaves a file with
//! no summary: every chunk flushed before is whole, the chunk being written is
//! cut off. [`recover`] reads the file record by record, keeps every schema,
//! channel, message, metadata record and attachment it can read (a damaged
//! chunk is skipped and counted, the records after it are read on), and writes
//! them into a new file with chunks, message indexes and a summary, as
//! `jetbench recover IN.mcap --out OUT.mcap` does.
//!
//! ```
//! use jetbench_msgs::{channels, Thrust};
//! use jetbench_record::recover::recover;
//! use jetbench_record::{McapWriter, Recording};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let dir = std::env::temp_dir();
//! let (whole, cut, fixed) = (dir.join("rec-doc-whole.mcap"), dir.join("rec-doc-cut.mcap"), dir.join("rec-doc-fixed.mcap"));
//! let mut writer = McapWriter::create(&whole)?;
//! writer.write_sample(channels::THRUST, 1, &Thrust::default())?;
//! writer.flush()?;
//! writer.finish()?;
//! let bytes = std::fs::read(&whole)?;
//! std::fs::write(&cut, &bytes[..bytes.len() - 100])?; // the summary is gone
//! let report = recover(&cut, &fixed)?;
//! assert_eq!((report.messages, report.data_lost()), (1, false));
//! assert!(!Recording::open(&fixed)?.truncated);
//! # Ok(())
//! # }
//! ```

use std::collections::BTreeSet;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use mcap::records::{op, Record};

use crate::RecordError;

/// Records that carry recorded data (a cut one loses it); the others are
/// indexes and statistics, rebuilt from the data.
const DATA_RECORDS: [u8; 6] = [op::SCHEMA, op::CHANNEL, op::MESSAGE, op::CHUNK, op::METADATA, op::ATTACHMENT];

/// What [`recover`] found and wrote.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecoverReport {
    /// Messages written to the new file.
    pub messages: u64,
    /// Metadata records copied.
    pub metadata: usize,
    /// Attachments copied.
    pub attachments: usize,
    /// Chunks read whole.
    pub chunks: usize,
    /// Chunks (or loose records) that could not be read: their messages are lost.
    pub damaged: usize,
    /// Messages whose channel (or whose channel's schema) was lost with a damaged chunk.
    pub orphaned: u64,
    /// Bytes at the end that do not make a whole record.
    pub cut_bytes: u64,
    /// Those bytes held a message or the start of a chunk (the one being written
    /// when the recorder stopped): its messages are lost.
    pub cut_data: bool,
    /// The input ended with its summary and footer (nothing to recover).
    pub complete: bool,
}

impl RecoverReport {
    /// True when the input held data that could not be carried over.
    pub fn data_lost(&self) -> bool {
        self.damaged > 0 || self.orphaned > 0 || self.cut_data
    }
}

impl std::fmt::Display for RecoverReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "recovered {} messages, {} metadata records, {} attachments from {} whole chunks",
            self.messages, self.metadata, self.attachments, self.chunks
        )?;
        if self.complete {
            writeln!(f, "the input was complete (summary and footer present)")?;
        }
        if self.damaged > 0 {
            writeln!(f, "{} damaged chunk(s) or record(s) skipped: their messages are lost", self.damaged)?;
        }
        if self.orphaned > 0 {
            writeln!(f, "{} messages dropped: their channel was defined in a damaged chunk", self.orphaned)?;
        }
        if self.cut_bytes > 0 {
            let what = if self.cut_data {
                "a chunk cut off while it was written: its messages are lost"
            } else {
                "part of the summary, which was rebuilt"
            };
            writeln!(f, "the file ends {} bytes into {what}", self.cut_bytes)?;
        }
        Ok(())
    }
}

/// Reads `input` as far as it goes and writes what it holds to `output` as a
/// complete, indexed MCAP file. Fails only when `input` is unreadable or not
/// MCAP at all, or `output` cannot be written.
pub fn recover(input: &Path, output: &Path) -> Result<RecoverReport, RecordError> {
    let bytes = std::fs::read(input).map_err(|source| RecordError::Read { path: input.into(), source })?;
    let Some(mut rest) = bytes.strip_prefix(mcap::MAGIC) else {
        return Err(RecordError::not_mcap(input, &bytes));
    };
    let file = File::create(output).map_err(|source| RecordError::Create { path: output.into(), source })?;
    let mut copy = Copy {
        writer: crate::write_options().create(BufWriter::new(file)).map_err(|e| mcap_error(output, e))?,
        output: output.into(),
        schemas: BTreeSet::new(),
        channels: BTreeSet::new(),
        report: RecoverReport::default(),
    };
    let mut in_summary = false;
    while !rest.is_empty() {
        if in_summary && rest == mcap::MAGIC {
            copy.report.complete = true;
            break;
        }
        let Some((opcode, body, after)) = split_record(rest) else {
            copy.report.cut_bytes = rest.len() as u64;
            copy.report.cut_data = !in_summary && DATA_RECORDS.contains(&rest[0]);
            break;
        };
        rest = after;
        match mcap::parse_record(opcode, body) {
            Ok(Record::DataEnd(_)) => in_summary = true,
            // The summary is rebuilt from the data; a schema or channel it
            // repeats is already known.
            Ok(_) if in_summary => {}
            Ok(Record::Chunk { header, data }) => copy.chunk(header, &data)?,
            Ok(record) => copy.record(record)?,
            Err(_) => copy.report.damaged += 1,
        }
    }
    let Copy { mut writer, report, .. } = copy;
    writer.finish().map_err(|e| mcap_error(output, e))?;
    Ok(report)
}

/// `(opcode, body, rest)` of the record at the start of `bytes`, or `None` if
/// it is not whole.
fn split_record(bytes: &[u8]) -> Option<(u8, &[u8], &[u8])> {
    let (&opcode, after_op) = bytes.split_first()?;
    let (len, after_len) = after_op.split_first_chunk::<8>()?;
    let len = usize::try_from(u64::from_le_bytes(*len)).ok()?;
    (len <= after_len.len()).then(|| (opcode, &after_len[..len], &after_len[len..]))
}

fn mcap_error(path: &Path, source: mcap::McapError) -> RecordError {
    RecordError::Mcap { path: path.into(), source }
}

/// The new file and what has been carried over to it.
struct Copy {
    writer: mcap::Writer<BufWriter<File>>,
    output: PathBuf,
    schemas: BTreeSet<u16>,
    channels: BTreeSet<u16>,
    report: RecoverReport,
}

impl Copy {
    /// A chunk's records, if it decompresses and parses; else it is counted damaged
    /// (the records read before the damage are kept).
    fn chunk(&mut self, header: mcap::records::ChunkHeader, data: &[u8]) -> Result<(), RecordError> {
        let records = match mcap::read::ChunkReader::new(header, data) {
            Ok(reader) => reader,
            Err(_) => {
                self.report.damaged += 1;
                return Ok(());
            }
        };
        for record in records {
            match record {
                Ok(record) => self.record(record)?,
                Err(_) => {
                    self.report.damaged += 1;
                    return Ok(());
                }
            }
        }
        self.report.chunks += 1;
        Ok(())
    }

    fn record(&mut self, record: Record<'_>) -> Result<(), RecordError> {
        let out = self.output.clone();
        let err = |e| mcap_error(&out, e);
        match record {
            Record::Schema { header, data } => {
                self.writer.add_schema_with_id(header.id, &header.name, &header.encoding, &data).map_err(err)?;
                self.schemas.insert(header.id);
            }
            // A channel whose schema was lost is left out; its messages are counted orphaned.
            Record::Channel(c) if c.schema_id == 0 || self.schemas.contains(&c.schema_id) => {
                self.writer
                    .add_channel_with_id(c.id, c.schema_id, &c.topic, &c.message_encoding, &c.metadata)
                    .map_err(err)?;
                self.channels.insert(c.id);
            }
            Record::Message { header, data } => {
                if self.channels.contains(&header.channel_id) {
                    self.writer.write_to_known_channel(&header, &data).map_err(err)?;
                    self.report.messages += 1;
                } else {
                    self.report.orphaned += 1;
                }
            }
            Record::Metadata(m) => {
                self.writer.write_metadata(&m).map_err(err)?;
                self.report.metadata += 1;
            }
            Record::Attachment { header, data, .. } => {
                let attachment = mcap::Attachment {
                    log_time: header.log_time,
                    create_time: header.create_time,
                    name: header.name,
                    media_type: header.media_type,
                    data,
                };
                self.writer.attach(&attachment).map_err(err)?;
                self.report.attachments += 1;
            }
            // Indexes, statistics and the like are rebuilt; the header is written anew.
            _ => {}
        }
        Ok(())
    }
}
