//! Plausibility of each measurement before the filter uses it.
//!
//! Two faults a force sensor has at a bench, and the test for each:
//! - **A spike** (a frame corrupted, a knock on the stand): the measurement
//!   lies far outside what the filter expects. Its normalised innovation
//!   squared `ν²/S` (innovation `ν` = measurement − predicted thrust, N; `S` its
//!   predicted variance, N²: the thrust variance of the prediction plus the
//!   measurement noise) follows a chi-square law with one degree of freedom
//!   when the model and the noise levels are right. A measurement with
//!   `ν²/S > chi2_threshold` is rejected: the filter keeps its prediction for
//!   that cycle. The default 25 is five standard deviations, which honest
//!   Gaussian noise exceeds with probability 5.7e-7 (about once every five hours
//!   at 100 Hz); a 30 N spike on a 7 N² sensor is more than 9 of them.
//! - **A stuck sensor** (a frozen driver, a cable that repeats the last frame):
//!   the measurement repeats bit for bit. A sensor whose noise is larger than
//!   its resolution (7 N² against 0.01 N here) repeats a reading in about one
//!   cycle in a thousand, and ten in a row practically never, so
//!   `stuck_after_samples` identical readings in a row mark it stuck; its
//!   readings are not used until one differs.
//!
//! The gate must not lock the filter out of a change that is real (a model far
//! off, a filter started on a bad first sample): after `max_rejections` in a row
//! the filter restarts at the measurement and says so.

use crate::EstimError;

/// Settings of the measurement gate (part of [`crate::ObserverConfig`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GateConfig {
    /// Largest accepted normalised innovation squared `ν²/S` (chi-square, one
    /// degree of freedom); 25 is five standard deviations. Infinite turns the gate off.
    pub chi2_threshold: f64,
    /// Rejections in a row after which the filter restarts at the measurement.
    pub max_rejections: u32,
    /// Bit-identical measurements in a row that mark the sensor stuck; 0 turns
    /// the test off (for a noise-free simulated sensor, which repeats at rest).
    pub stuck_after_samples: u32,
}

impl Default for GateConfig {
    /// Five standard deviations; a restart after 5 rejections in a row (50 ms:
    /// spikes are single samples); stuck after 10 identical readings (100 ms).
    fn default() -> Self {
        GateConfig { chi2_threshold: 25.0, max_rejections: 5, stuck_after_samples: 10 }
    }
}

impl GateConfig {
    pub(crate) fn validate(&self) -> Result<(), EstimError> {
        if self.chi2_threshold.is_nan() || self.chi2_threshold <= 0.0 {
            return Err(EstimError::InvalidConfig {
                name: "chi2_threshold",
                value: self.chi2_threshold,
                requirement: "> 0",
            });
        }
        if self.max_rejections == 0 {
            return Err(EstimError::InvalidConfig { name: "max_rejections", value: 0.0, requirement: ">= 1" });
        }
        Ok(())
    }
}

/// What the gate did with one measurement.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Verdict {
    /// Used to correct the prediction.
    #[default]
    Accepted,
    /// Too far from the prediction: not used this cycle.
    Rejected,
    /// The sensor repeats itself: not used while it does.
    Stuck,
    /// Rejected too often in a row: the filter restarted at this measurement.
    Restarted,
}

/// The gate's memory between cycles; plain integers and bits, so a step stays
/// deterministic and allocation-free.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Gate {
    /// Bits of the previous measurement, and how many in a row had them.
    last_bits: Option<u64>,
    repeats: u32,
    rejections_in_a_row: u32,
}

impl Gate {
    /// Judges `measurement_n` with normalised innovation squared `nis`.
    pub(crate) fn judge(&mut self, config: &GateConfig, measurement_n: f64, nis: f64) -> Verdict {
        let bits = measurement_n.to_bits();
        self.repeats = if self.last_bits == Some(bits) { self.repeats.saturating_add(1) } else { 1 };
        self.last_bits = Some(bits);
        if config.stuck_after_samples > 0 && self.repeats >= config.stuck_after_samples {
            // A stuck reading is no evidence of a jump: the run of rejections ends.
            self.rejections_in_a_row = 0;
            return Verdict::Stuck;
        }
        if nis <= config.chi2_threshold {
            self.rejections_in_a_row = 0;
            return Verdict::Accepted;
        }
        self.rejections_in_a_row += 1;
        if self.rejections_in_a_row > config.max_rejections {
            self.rejections_in_a_row = 0;
            Verdict::Restarted
        } else {
            Verdict::Rejected
        }
    }

    /// Remembers the first measurement (it initialises the filter unjudged).
    pub(crate) fn first(&mut self, measurement_n: f64) {
        *self = Gate { last_bits: Some(measurement_n.to_bits()), repeats: 1, rejections_in_a_row: 0 };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_single_outlier_is_rejected_and_a_lasting_jump_restarts() {
        let config = GateConfig::default();
        let mut gate = Gate::default();
        gate.first(10.0);
        assert_eq!(gate.judge(&config, 10.5, 1.0), Verdict::Accepted);
        assert_eq!(gate.judge(&config, 40.0, 100.0), Verdict::Rejected);
        assert_eq!(gate.judge(&config, 10.7, 2.0), Verdict::Accepted);
        let verdicts: Vec<_> = (0..6).map(|k| gate.judge(&config, 60.0 + f64::from(k), 300.0)).collect();
        assert_eq!(verdicts[..5], [Verdict::Rejected; 5]);
        assert_eq!(verdicts[5], Verdict::Restarted);
    }

    #[test]
    fn identical_readings_mark_the_sensor_stuck_until_one_differs() {
        let config = GateConfig::default();
        let mut gate = Gate::default();
        gate.first(33.25);
        let verdicts: Vec<_> = (1..12).map(|_| gate.judge(&config, 33.25, 0.5)).collect();
        assert_eq!(verdicts[..8], [Verdict::Accepted; 8], "nine identical readings are not yet stuck");
        assert_eq!(verdicts[8..], [Verdict::Stuck; 3], "the tenth is");
        assert_eq!(gate.judge(&config, 33.26, 0.5), Verdict::Accepted);
        let off = GateConfig { stuck_after_samples: 0, ..config };
        assert!((0..50).all(|_| gate.judge(&off, 1.0, 0.0) == Verdict::Accepted));
    }
}
