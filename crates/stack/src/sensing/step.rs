//! Sensing's algorithm: a raw force/torque reading calibrated into a thrust
//! sample, the sensor's frame counter followed and its silences noticed.
//! Plain code that never touches the bus; [`super::SensingService`] wires it.

use jetbench_io::calib::{Calibration, CalibrationError};
use jetbench_io::ForceReading;
use jetbench_msgs::{sensor_status, thrust_flags, Thrust};

use crate::config::SensorSection;
use crate::inject::FaultPlan;
use crate::runtime::clock::PERIOD_NS;

/// Why sensing rejected a reading.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SensingError {
    /// A force component is NaN or infinite (`[Fx, Fy, Fz]`).
    #[error("force reading is not finite: {0:?}")]
    NonFinite([f64; 3]),
}

/// SensingStep: calibrates a force/torque reading into a thrust sample, and
/// keeps track of the sensor's frame counter and of silences.
#[derive(Debug, Clone)]
pub struct SensingStep {
    axis: usize,
    calibration: Calibration,
    last: Option<(u32, u64)>,
    frame_seq: u64,
    silent_since_ns: Option<u64>,
    /// Injected driver faults (the simulated bench only): readings made NaN.
    faults: FaultPlan,
}

impl SensingStep {
    /// With the section's calibration matrix, tare and thrust axis.
    pub fn new(sensor: &SensorSection) -> Result<Self, CalibrationError> {
        Ok(SensingStep {
            axis: sensor.thrust_axis.index(),
            calibration: sensor.calibration()?,
            last: None,
            frame_seq: 0,
            silent_since_ns: None,
            faults: FaultPlan::default(),
        })
    }

    /// With the `nan` faults of `plan` injected where a driver fault would put
    /// them: the decoded reading, before it is checked (see [`crate::inject`]).
    pub fn with_faults(mut self, plan: FaultPlan) -> Self {
        self.faults = plan;
        self
    }

    /// Frames since the previous reading, from the wrapping counter and the time.
    fn frames_since_last(&self, counter: u32, received_ns: u64) -> Option<u64> {
        let (last, last_ns) = self.last?;
        // The wire counter is 8 bits wide and wraps; after a long silence
        // the time since the last frame tells how many times it wrapped.
        let step = u64::from(counter.wrapping_sub(last) & 0xff);
        let elapsed = received_ns.saturating_sub(last_ns) / PERIOD_NS;
        let wraps = if elapsed > step + 128 { (elapsed - step + 128) / 256 } else { 0 };
        Some(step + 256 * wraps)
    }

    /// One reading (raw sensor units, N and N·m) received at `received_ns`:
    /// `calibrated = C · raw − tare`, thrust the calibrated force on the
    /// thrust axis. A counter jump sets `FRAME_GAP`; the first reading after
    /// [`SensingStep::silent`] sets `SENSOR_RESUMED`.
    pub fn step(&mut self, reading: &ForceReading, received_ns: u64) -> Result<Thrust, SensingError> {
        let frames = self.frames_since_last(reading.counter, received_ns);
        let mut reading = *reading;
        let frame = frames.map_or(0, |n| self.frame_seq + n.max(1));
        if !self.faults.is_empty() && self.faults.at(frame).nan {
            reading.force_n[self.axis] = f64::NAN;
        }
        if reading.force_n.iter().chain(&reading.torque_nm).any(|v| !v.is_finite()) {
            return Err(SensingError::NonFinite(reading.force_n));
        }
        let mut flags = 0;
        if let Some(frames) = frames {
            if frames != 1 {
                flags |= thrust_flags::FRAME_GAP;
            }
            self.frame_seq += frames.max(1);
        }
        self.last = Some((reading.counter, received_ns));
        if self.silent_since_ns.take().is_some() {
            flags |= thrust_flags::SENSOR_RESUMED;
        }
        if reading.status & (sensor_status::OVERLOAD | sensor_status::CALIBRATION_INVALID) != 0 {
            flags |= thrust_flags::SENSOR_STATUS;
        }
        let c = self.calibration.apply(&reading);
        let force_n = [c[0], c[1], c[2]];
        Ok(Thrust {
            seq: 0,
            stamp_ns: received_ns,
            publish_ns: 0,
            frame_seq: self.frame_seq,
            thrust_n: force_n[self.axis],
            force_n,
            torque_nm: [c[3], c[4], c[5]],
            status: reading.status,
            flags,
        })
    }

    /// No reading within the input deadline at `now_ns`. True when this
    /// starts a silence (so the service reports it once).
    pub fn silent(&mut self, now_ns: u64) -> bool {
        if self.last.is_none() || self.silent_since_ns.is_some() {
            return false;
        }
        self.silent_since_ns = Some(now_ns);
        true
    }

    /// Since when the sensor has been silent, if it is.
    pub fn silent_since_ns(&self) -> Option<u64> {
        self.silent_since_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sensing_flags_frame_gaps_and_rejects_nan() {
        let mut s = SensingStep::new(&SensorSection::default()).unwrap();
        let mut r = ForceReading { force_n: [40.0, 0.1, 0.2], counter: 254, ..ForceReading::default() };
        assert_eq!(s.step(&r, 1).unwrap().flags, 0);
        r.counter = 255;
        assert_eq!(s.step(&r, PERIOD_NS).unwrap().flags, 0);
        r.counter = 1; // wrapped past 0: frame 0 lost
        let t = s.step(&r, 3 * PERIOD_NS).unwrap();
        assert_ne!(t.flags & thrust_flags::FRAME_GAP, 0);
        assert_eq!(t.frame_seq, 3);
        assert_eq!(t.thrust_n, 40.0);
        r.force_n[0] = f64::NAN;
        assert!(s.step(&r, 4 * PERIOD_NS).is_err());
    }

    #[test]
    fn sensing_calibrates_and_reports_silence() {
        let mut section = SensorSection { tare: Some([1.0, 0.0, 0.0, 0.0, 0.0, 0.5]), ..SensorSection::default() };
        section.calibration[0][0] = 2.0;
        section.calibration[5][2] = 0.1; // Fz leaks into Tz
        let mut s = SensingStep::new(&section).unwrap();
        assert!(!s.silent(0), "no silence before the first reading");
        let r = ForceReading { force_n: [20.5, 0.0, 10.0], torque_nm: [0.0, 0.0, 0.25], counter: 7, status: 0 };
        let t = s.step(&r, 0).unwrap();
        assert!((t.thrust_n - 40.0).abs() < 1e-12, "2 * 20.5 - 1 = 40, got {}", t.thrust_n);
        assert!((t.torque_nm[2] - (0.25 + 1.0 - 0.5)).abs() < 1e-12);
        // Silent from 15 ms on; back after 3.0 s: counter 7 + 300 frames = 51 (mod 256).
        assert!(s.silent(15_000_000));
        assert!(!s.silent(25_000_000), "reported once per silence");
        let back = ForceReading { counter: (7 + 300) % 256, ..r };
        let t = s.step(&back, 3_000_000_000).unwrap();
        assert_eq!(t.flags, thrust_flags::FRAME_GAP | thrust_flags::SENSOR_RESUMED);
        assert_eq!(t.frame_seq, 300, "the counter wrapped once during the silence");
        let next = ForceReading { counter: back.counter + 1, ..r };
        assert_eq!(s.step(&next, 3_010_000_000).unwrap().flags, 0);
    }
}
