//! Sensing: force/torque CAN frames in, `bench/thrust` out; clocked by the sensor.

use jetbench_bus::{Publisher, Wake};
use jetbench_io::can::source::CanForceSource;
use jetbench_io::can::RejectCounts;
use jetbench_io::ForceSource;
use jetbench_msgs::{channels, ServiceId, Thrust};

use super::SensingStep;
use crate::runtime::clock::INPUT_DEADLINE;
use crate::runtime::{log_rejection, Context, Schedule, Service, ServiceError, Setup};

/// Sensing: calibrates each force reading into a thrust sample
/// ([`SensingStep`]). A sensor silent for one input deadline is reported in
/// `bench/health` (input overdue) every deadline until it is back; the first
/// sample after it carries `SENSOR_RESUMED`. The link reopens by itself.
pub struct SensingService {
    step: SensingStep,
    source: CanForceSource,
    thrust: Publisher<Thrust>,
    /// The frame rejections already counted and logged.
    seen: RejectCounts,
}

impl Service for SensingService {
    const ID: ServiceId = ServiceId::Sensing;
    type Inputs = ();

    fn new(setup: &Setup<'_>) -> Result<(Self, ()), ServiceError> {
        let config = setup.config;
        let interface =
            config.sensor.interface(config.bench.devices).map_err(|e| ServiceError::Setup(e.to_string()))?;
        let codec = config.sensor.codec().map_err(|e| ServiceError::Setup(e.to_string()))?;
        let source = CanForceSource::open(&interface, codec)?;
        tracing::info!("reading {}", source.describe());
        let mut step = SensingStep::new(&config.sensor).map_err(|e| ServiceError::Setup(format!("[sensor] {e}")))?;
        if config.bench.devices == crate::config::Devices::Sim {
            // The simulated bench's injected driver faults (`--inject nan:...`).
            step = step.with_faults(config.plant.faults().map_err(|e| ServiceError::Setup(e.to_string()))?);
        }
        let thrust = setup.bus.publisher(channels::THRUST)?;
        Ok((SensingService { step, source, thrust, seen: RejectCounts::default() }, ()))
    }

    fn schedule(&self) -> Schedule {
        Schedule::SelfPaced
    }

    fn process(&mut self, _wake: Wake, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        let reading = self.source.read(INPUT_DEADLINE)?;
        let start_ns = ctx.woke();
        let Some(reading) = reading else {
            // The sensor went quiet: say so every deadline.
            if self.step.silent(start_ns) {
                tracing::warn!("force sensor silent: no reading for {} ms", INPUT_DEADLINE.as_millis());
            }
            if self.step.silent_since_ns().is_some() {
                ctx.cycle(true)?;
            }
            return Ok(());
        };
        if let Some(since) = self.step.silent_since_ns() {
            let silent_ms = start_ns.saturating_sub(since) as f64 * 1e-6;
            tracing::info!("force sensor back after {:.0} ms", silent_ms + INPUT_DEADLINE.as_secs_f64() * 1e3);
        }
        match self.step.step(&reading, start_ns) {
            Ok(thrust) => {
                ctx.publish(&mut self.thrust, thrust, |t, ns| t.publish_ns = ns)?;
            }
            Err(e) => ctx.reject("force reading", &e),
        }
        let counts = *self.source.counts();
        for _ in self.seen.frames_rejected()..counts.frames_rejected() {
            ctx.health().error();
        }
        if counts != self.seen {
            log_rejection(counts.frames_rejected() + counts.sequence_jump, "CAN frames", &counts);
            self.seen = counts;
        }
        ctx.health().set_input_gaps(counts.lost_pairs);
        ctx.cycle(false)?;
        Ok(())
    }

    fn stop(&mut self, _inputs: &(), _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        let (frames, pairs) = self.source.frames_and_pairs();
        tracing::info!("force sensor: {frames} frames in, {pairs} readings; rejected: {}", self.source.counts());
        Ok(())
    }
}
