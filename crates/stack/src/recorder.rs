//! The recorder: every channel into one MCAP file.

use jetbench_bus::tap::Tap;
use jetbench_msgs::ServiceId;
use jetbench_record::clock::ClockOrigin;
use jetbench_record::meta::RunMetadata;
use jetbench_record::{spawn_writer, RawRecord, RecordError, WriterHandle};

use crate::config::OnRecordError;
use crate::runtime::clock::realtime_ns;
use crate::runtime::{ChannelReader, Context, ServiceError, Setup};

/// The recorder (run as [`Reader<RecorderService>`](crate::runtime::Reader)): every channel read
/// by a polled subscriber on the recorder's own clock ([`Tap`]), handed to a writer thread through a bounded queue that
/// never waits on the disk. `log_time` is the wall clock at receive (viewers
/// date the run when it happened); the samples keep their monotonic stamps,
/// which are also the messages' `publish_time`.
pub struct RecorderService {
    tap: Tap,
    /// `None` once finished, or once writing failed and the run goes on without it.
    writer: Option<WriterHandle>,
    on_error: OnRecordError,
    /// Why recording stopped while the run went on (`on_error = "continue"`).
    failed: Option<RecordError>,
}

/// Hands every sample queued on the bus to the writer, logged now; returns
/// how many there were.
fn drain(tap: &Tap, writer: &mut WriterHandle) -> Result<usize, ServiceError> {
    let log_time_ns = realtime_ns();
    let mut failure = None;
    let mut taken = 0;
    tap.drain(&mut |s| {
        taken += 1;
        if failure.is_some() {
            return;
        }
        match RawRecord::new(s.channel, s.seq, log_time_ns, s.stamp_ns, s.body) {
            Some(record) => {
                if let Err(e) = writer.send(record) {
                    failure = Some(e);
                }
            }
            None => {
                failure = Some(RecordError::SampleTooLarge {
                    channel: s.channel.into(),
                    size: s.body.len(),
                    max: jetbench_record::MAX_SAMPLE_BYTES,
                })
            }
        }
    })?;
    failure.map_or(Ok(taken), |e| Err(e.into()))
}

impl ChannelReader for RecorderService {
    const ID: ServiceId = ServiceId::Recorder;

    fn open(setup: &Setup<'_>) -> Result<Self, ServiceError> {
        let path = setup.output.ok_or_else(|| ServiceError::Setup("the recorder needs --out FILE.mcap".into()))?;
        // The deepest queue a channel allows: the recorder must never drop.
        let tap = Tap::open(setup.bus, Tap::DEPTH)?;
        // The config and the estimator's resolved model parameters, so that
        // `jetbench replay` reproduces the run even when its model file is gone;
        // and the clocks, so that every message is dated.
        let estimator = crate::replay::run_metadata(setup.config)?;
        let run = RunMetadata {
            config_toml: estimator.config_toml,
            model_toml: estimator.model_toml,
            ..RunMetadata::wall_clock(ClockOrigin::now())
        };
        let writer = spawn_writer(path, setup.config.recorder.queue, vec![run.record()])?;
        tracing::info!("recording {} channels to {}", tap.counts().len(), path.display());
        let on_error = setup.config.recorder.on_error;
        Ok(RecorderService { tap, writer: Some(writer), on_error, failed: None })
    }

    fn pump(&mut self, ctx: &mut Context<'_>) -> Result<usize, ServiceError> {
        match self.writer.as_mut().map(|writer| drain(&self.tap, writer)) {
            // Not recording (writing failed): the queues are emptied all the same.
            None => Ok(self.tap.drain(&mut |_| {})?),
            Some(Err(ServiceError::Record(e))) if self.on_error == OnRecordError::Continue => {
                tracing::error!(
                    "RECORDING STOPPED: {e}. The run goes on without recording ([recorder] on_error = \"continue\")"
                );
                ctx.reject("recording", &e);
                ctx.health().set_fallback(true);
                self.writer = None;
                self.failed = Some(e);
                Ok(0)
            }
            taken => taken.unwrap_or(Ok(0)),
        }
    }

    fn gaps(&self) -> u64 {
        self.tap.gaps()
    }

    /// Closes the file and prints what was recorded.
    fn finish(&mut self) -> Result<(), ServiceError> {
        let Some(writer) = self.writer.take() else {
            if let Some(e) = &self.failed {
                crate::runtime::status::say_err(&format!(
                    "recorder: the recording stopped early and the run went on without it: {e}"
                ));
            }
            return Ok(());
        };
        let dropped_full = writer.dropped_full;
        let stats = writer.finish()?;
        let report = RecorderReport {
            channels: self
                .tap
                .counts()
                .into_iter()
                .map(|c| ChannelReport { channel: c.channel, received: c.received, gaps: c.gaps })
                .collect(),
            written: stats.written,
            dropped_full,
        };
        // Not `eprint!`: with the launcher gone, stderr is a closed pipe, and the
        // recording is already closed and whole.
        crate::runtime::status::say_err(report.to_string().trim_end());
        if report.dropped_full > 0 {
            return Err(ServiceError::Dropped(report.dropped_full));
        }
        Ok(())
    }
}

/// Per-channel counts the recorder reports at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ChannelReport {
    /// The channel's topic.
    pub channel: &'static str,
    /// Samples taken from the bus.
    pub received: u64,
    /// Samples missing by their sequence numbers.
    pub gaps: u64,
}

/// What the recorder did, printed at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecorderReport {
    /// Every recorded channel.
    pub channels: Vec<ChannelReport>,
    /// Messages written to the file.
    pub written: u64,
    /// Samples dropped because the writer's queue was full.
    pub dropped_full: u64,
}

impl RecorderReport {
    /// Gaps over every channel.
    pub fn total_gaps(&self) -> u64 {
        self.channels.iter().map(|c| c.gaps).sum()
    }
}

impl std::fmt::Display for RecorderReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "recorder: {} messages written, {} dropped for a full queue", self.written, self.dropped_full)?;
        for c in self.channels.iter().filter(|c| c.received > 0 || c.gaps > 0) {
            let gaps = if c.gaps == 0 { "no gaps".to_string() } else { format!("{} lost (seq gaps)", c.gaps) };
            writeln!(f, "  /{:<16} {:>7} messages, {gaps}", c.channel, c.received)?;
        }
        Ok(())
    }
}
