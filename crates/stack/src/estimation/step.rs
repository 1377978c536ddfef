//! Estimation's algorithm: the observer of `[T, Ṫ, d]` on each thrust sample,
//! predicting with the throttle the board last acknowledged, its verdict on the
//! measurement turned into flags. Plain code that never touches the bus;
//! [`super::EstimationService`] wires it.

use jetbench_estim::{EstimError, ObserverConfig, ThrustObserver, Verdict};
use jetbench_model::{Params, THROTTLE_MIN_PCT};
use jetbench_msgs::{state_flags, StateEstimate, Thrust};

/// EstimationStep: the EKF observer of `[T, Ṫ]` on thrust samples.
#[derive(Debug, Clone)]
pub struct EstimationStep {
    observer: ThrustObserver,
    applied_pct: Option<f64>,
}

impl EstimationStep {
    /// The observer of `params` with `config`, before any throttle was applied.
    pub fn new(params: Params, config: ObserverConfig) -> Self {
        EstimationStep { observer: ThrustObserver::new(params, config), applied_pct: None }
    }

    /// The throttle the actuator applied most recently, %.
    pub fn set_applied(&mut self, applied_pct: f64) {
        if applied_pct.is_finite() {
            self.applied_pct = Some(applied_pct);
        }
    }

    /// One thrust sample: predict with the last applied throttle, update. A
    /// measurement the observer's gate does not use (a spike, a stuck sensor) is
    /// flagged in the estimate ([`state_flags`]).
    pub fn step(&mut self, thrust: &Thrust) -> Result<StateEstimate, EstimError> {
        let mut flags = 0;
        let throttle_pct = self.applied_pct.unwrap_or_else(|| {
            flags |= state_flags::INPUT_ASSUMED;
            THROTTLE_MIN_PCT
        });
        let fallbacks_before = self.observer.fallbacks();
        let e = self.observer.step(thrust.thrust_n, throttle_pct)?;
        if self.observer.fallbacks() != fallbacks_before {
            flags |= state_flags::MODEL_FALLBACK;
        }
        flags |= match e.verdict {
            Verdict::Accepted => 0,
            Verdict::Rejected => state_flags::MEASUREMENT_REJECTED,
            Verdict::Stuck => state_flags::SENSOR_STUCK,
            Verdict::Restarted => state_flags::FILTER_RESTARTED,
        };
        if self.observer.settling() {
            flags |= state_flags::SETTLING;
        }
        Ok(StateEstimate {
            seq: 0,
            stamp_ns: thrust.stamp_ns,
            publish_ns: 0,
            source_seq: thrust.seq,
            thrust_n: e.thrust_n,
            thrust_rate_n_per_s: e.thrust_rate_n_per_s,
            thrust_accel_n_per_s2: e.thrust_accel_n_per_s2,
            input_throttle_pct: throttle_pct,
            innovation_n: e.innovation_n,
            thrust_var_n2: e.thrust_var_n2,
            thrust_rate_var_n2_per_s2: e.thrust_rate_var,
            flags,
        })
    }
}
