//! Estimation: `bench/thrust` (and the newest `bench/actuation`, read with it) in, `bench/state` out.

use jetbench_bus::{Publisher, Subscriber, Wake};
use jetbench_msgs::{channels, state_flags, Actuation, ServiceId, StateEstimate, Thrust};

use super::EstimationStep;
use crate::runtime::clock::INPUT_DEADLINE;
use crate::runtime::{Context, Input, Service, ServiceError, Setup};

/// Estimation: the EKF of `[T, Ṫ, d]` ([`EstimationStep`]) on every thrust
/// sample, predicting with the throttle the board last acknowledged.
pub struct EstimationService {
    step: EstimationStep,
    /// Read with each thrust sample, never woken by: an actuation sample
    /// arrives mid-cycle and has nothing to start.
    actuation: Subscriber<Actuation>,
    state: Publisher<StateEstimate>,
}

impl Service for EstimationService {
    const ID: ServiceId = ServiceId::Estimation;
    type Inputs = Input<Thrust>;

    fn new(setup: &Setup<'_>) -> Result<(Self, Self::Inputs), ServiceError> {
        let bus = setup.bus;
        let thrust = Input::new(bus.subscriber(channels::THRUST, 16)?, INPUT_DEADLINE);
        let estimation = EstimationService {
            actuation: bus.polled_subscriber(channels::ACTUATION, 16)?,
            state: bus.publisher(channels::STATE)?,
            step: {
                let (model, observer) = setup.config.estimator()?;
                EstimationStep::new(model, observer)
            },
        };
        Ok((estimation, thrust))
    }

    fn process(&mut self, wake: Wake, thrust: &Input<Thrust>, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        thrust.each_sample(wake, ctx, |sample, ctx| {
            if let Some(a) = self.actuation.latest()? {
                self.step.set_applied(a.applied_pct);
            }
            match self.step.step(&sample) {
                Ok(state) => {
                    ctx.publish(&mut self.state, state, |s, ns| s.publish_ns = ns)?;
                    report_gated(&state, &sample, ctx);
                }
                Err(e) => ctx.reject("thrust sample", &e),
            }
            Ok(())
        })
    }
}

/// Counts and logs a measurement the estimator's gate did not use (after the
/// estimate is out: the log never delays the control path).
fn report_gated(state: &StateEstimate, thrust: &Thrust, ctx: &mut Context<'_>) {
    let (seq, innovation_n) = (thrust.seq, state.innovation_n);
    if state.flags & state_flags::MEASUREMENT_REJECTED != 0 {
        ctx.reject(
            "implausible thrust (spike)",
            &format_args!("thrust seq {seq}: innovation {innovation_n:+.1} N fails the chi-square gate"),
        );
    }
    if state.flags & state_flags::SENSOR_STUCK != 0 {
        ctx.reject("stuck sensor", &format_args!("thrust seq {seq} repeats {:.2} N", thrust.thrust_n));
    }
    if state.flags & state_flags::FILTER_RESTARTED != 0 {
        ctx.reject(
            "estimator restart",
            &format_args!("thrust seq {seq}: restarted at {:.1} N after rejections in a row", thrust.thrust_n),
        );
    }
}
