//! Device frames carried over the bus (`sim/force`, `sim/throttle`), for the
//! simulated bench on machines without CAN or serial hardware.

use std::time::Duration;

use jetbench_bus::{Bus, Publisher, Subscriber};
use jetbench_msgs::{channels, SimForceFrame, SimThrottleFrame};

use crate::{DeviceError, ForceReading, ForceSink, ForceSource, ThrottleInput, ThrottleOutput};

/// Frames the sensing side may queue before the oldest are dropped.
const FORCE_QUEUE: usize = 16;

/// Sensing's end of the simulated sensor.
pub struct BusForceSource {
    frames: Subscriber<SimForceFrame>,
}

impl BusForceSource {
    pub fn open(bus: &Bus) -> Result<Self, DeviceError> {
        Ok(BusForceSource { frames: bus.subscriber(channels::SIM_FORCE, FORCE_QUEUE)? })
    }
}

impl ForceSource for BusForceSource {
    fn read(&mut self, timeout: Duration) -> Result<Option<ForceReading>, DeviceError> {
        Ok(self.frames.recv_timeout(timeout)?.map(|f| ForceReading {
            force_n: f.force_n,
            torque_nm: f.torque_nm,
            counter: f.counter,
            status: f.status,
        }))
    }

    fn rejected(&self) -> u64 {
        self.frames.gaps()
    }

    fn describe(&self) -> String {
        format!("simulated sensor on {}", channels::SIM_FORCE.name)
    }
}

/// The simulated sensor's end: publishes frames.
pub struct BusForceSink {
    frames: Publisher<SimForceFrame>,
}

impl BusForceSink {
    pub fn open(bus: &Bus) -> Result<Self, DeviceError> {
        Ok(BusForceSink { frames: bus.publisher(channels::SIM_FORCE)? })
    }
}

impl ForceSink for BusForceSink {
    fn emit(&mut self, reading: &ForceReading, sampled_ns: u64) -> Result<(), DeviceError> {
        self.frames.publish(SimForceFrame {
            seq: 0,
            stamp_ns: sampled_ns,
            force_n: reading.force_n,
            torque_nm: reading.torque_nm,
            status: reading.status,
            counter: reading.counter,
        })?;
        Ok(())
    }
}

/// Actuation's end of the simulated throttle board.
pub struct BusThrottleOutput {
    frames: Publisher<SimThrottleFrame>,
    clock: fn() -> u64,
}

impl BusThrottleOutput {
    /// `clock` stamps each frame (monotonic ns).
    pub fn open(bus: &Bus, clock: fn() -> u64) -> Result<Self, DeviceError> {
        Ok(BusThrottleOutput { frames: bus.publisher(channels::SIM_THROTTLE)?, clock })
    }
}

impl ThrottleOutput for BusThrottleOutput {
    fn write(&mut self, throttle_pct: f64) -> Result<(), DeviceError> {
        if !throttle_pct.is_finite() {
            return Err(DeviceError::InvalidValue {
                device: self.describe(),
                reason: format!("throttle {throttle_pct} is not a number"),
            });
        }
        self.frames.publish(SimThrottleFrame { seq: 0, stamp_ns: (self.clock)(), throttle_pct, flags: 0 })?;
        Ok(())
    }

    fn describe(&self) -> String {
        format!("simulated throttle board on {}", channels::SIM_THROTTLE.name)
    }
}

/// The simulated board's end: receives throttle frames.
pub struct BusThrottleInput {
    frames: Subscriber<SimThrottleFrame>,
}

impl BusThrottleInput {
    pub fn open(bus: &Bus) -> Result<Self, DeviceError> {
        Ok(BusThrottleInput { frames: bus.subscriber(channels::SIM_THROTTLE, FORCE_QUEUE)? })
    }
}

impl ThrottleInput for BusThrottleInput {
    fn poll(&mut self) -> Result<Option<f64>, DeviceError> {
        // A board applies only valid frames; a NaN frame is ignored like a bad CRC.
        let mut newest = None;
        while let Some(frame) = self.frames.try_recv()? {
            if frame.throttle_pct.is_finite() {
                newest = Some(frame.throttle_pct);
            }
        }
        Ok(newest)
    }
}
