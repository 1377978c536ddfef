//! The recorder: every channel into one MCAP file.

use jetbench_bus::{AnySubscriber, Bus, PortError, Wake};
use jetbench_msgs::{visit_channels, Channel, ChannelVisitor, Sample, ServiceId};
use jetbench_record::{spawn_writer, RawRecord, RecordError, WriterHandle};

use super::{Context, Schedule, Service, ServiceError, Setup};
use crate::clock::{monotonic_ns, realtime_ns, PERIOD};

/// The recorder: subscribers polled on the recorder's own clock hand every
/// sample to a writer thread through a bounded queue and never wait on the disk.
pub struct Recorder {
    subs: Vec<Box<dyn AnySubscriber>>,
    /// `None` once finished.
    writer: Option<WriterHandle>,
}

/// Polled subscribers of every channel, as deep as a channel allows.
fn subscribe_all(bus: &Bus) -> Result<Vec<Box<dyn AnySubscriber>>, PortError> {
    struct Subscribe<'a> {
        bus: &'a Bus,
        subs: Vec<Box<dyn AnySubscriber>>,
        error: Option<PortError>,
    }
    impl ChannelVisitor for Subscribe<'_> {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            // The deepest queue the channel allows: the recorder must never drop.
            // Polled on the recorder's own clock: publishing costs the control path no
            // wake-up of the recorder. The deepest queue holds 5 s at 100 Hz.
            match self.bus.polled_subscriber(channel, jetbench_bus::limits::MAX_BUFFER) {
                Ok(s) => self.subs.push(Box::new(s)),
                Err(e) => self.error = self.error.take().or(Some(e)),
            }
        }
    }
    let mut subscribe = Subscribe { bus, subs: Vec::new(), error: None };
    visit_channels(&mut subscribe);
    match subscribe.error {
        Some(e) => Err(e),
        None => Ok(subscribe.subs),
    }
}

/// Hands every sample queued on `sub` to the writer.
fn drain(sub: &dyn AnySubscriber, writer: &mut WriterHandle) -> Result<(), ServiceError> {
    let log_time_ns = monotonic_ns();
    let mut failure = None;
    sub.drain_raw(&mut |seq, stamp_ns, bytes| {
        if failure.is_some() {
            return;
        }
        match RawRecord::new(sub.channel_name(), seq, log_time_ns, stamp_ns, bytes) {
            Some(record) => {
                if let Err(e) = writer.send(record) {
                    failure = Some(e);
                }
            }
            None => {
                failure = Some(RecordError::SampleTooLarge {
                    channel: sub.channel_name().into(),
                    size: bytes.len(),
                    max: jetbench_record::MAX_SAMPLE_BYTES,
                })
            }
        }
    })?;
    failure.map_or(Ok(()), |e| Err(e.into()))
}

impl Service for Recorder {
    const ID: ServiceId = ServiceId::Recorder;
    type Inputs = ();

    fn new(setup: &Setup<'_>) -> Result<(Self, ()), ServiceError> {
        let path = setup.output.ok_or_else(|| ServiceError::Setup("the recorder needs --out FILE.mcap".into()))?;
        let subs = subscribe_all(setup.bus)?;
        // The config and the estimator's resolved model parameters, so that
        // `jetbench replay` reproduces the run even when its model file is gone.
        let mut run = crate::replay::run_metadata(setup.config)?;
        run.clock =
            "CLOCK_MONOTONIC; log_time is the recorder's receive time, publish_time the sample's stamp_ns".into();
        run.monotonic_ns_at_start = Some(monotonic_ns());
        run.realtime_ns_at_start = Some(realtime_ns());
        let writer = spawn_writer(path, setup.config.recorder.queue, vec![run.record()])?;
        tracing::info!("recording {} channels to {}", subs.len(), path.display());
        Ok((Recorder { subs, writer: Some(writer) }, ()))
    }

    fn schedule(&self) -> Schedule {
        Schedule::Tick(PERIOD)
    }

    fn process(&mut self, wake: Wake, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        if wake != Wake::Tick {
            return Ok(());
        }
        let Some(writer) = self.writer.as_mut() else { return Ok(()) };
        for sub in &self.subs {
            drain(sub.as_ref(), writer)?;
        }
        ctx.health().set_input_gaps(self.subs.iter().map(|s| s.gaps()).sum());
        ctx.cycle(false)?;
        Ok(())
    }

    /// Takes what arrived while stopping, closes the file and prints what was recorded.
    fn stop(&mut self, _inputs: &(), _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        let Some(mut writer) = self.writer.take() else { return Ok(()) };
        for sub in &self.subs {
            drain(sub.as_ref(), &mut writer)?;
        }
        let dropped_full = writer.dropped_full;
        let stats = writer.finish()?;
        let report = RecorderReport {
            channels: self
                .subs
                .iter()
                .map(|s| ChannelReport { channel: s.channel_name(), received: s.received(), gaps: s.gaps() })
                .collect(),
            written: stats.written,
            dropped_full,
        };
        eprint!("{report}");
        if report.dropped_full > 0 {
            return Err(ServiceError::Dropped(report.dropped_full));
        }
        Ok(())
    }
}

/// Per-channel counts the recorder reports at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ChannelReport {
    pub channel: &'static str,
    pub received: u64,
    pub gaps: u64,
}

/// What the recorder did, printed at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecorderReport {
    pub channels: Vec<ChannelReport>,
    pub written: u64,
    pub dropped_full: u64,
}

impl RecorderReport {
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
