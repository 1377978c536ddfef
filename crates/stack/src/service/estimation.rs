//! Estimation: `bench/thrust` (and the newest `bench/actuation`, read with it) in, `bench/state` out.

use jetbench_bus::{Publisher, Subscriber, Wake};
use jetbench_msgs::{channels, Actuation, ServiceId, StateEstimate, Thrust};

use super::{publish_now, Context, Input, Service, ServiceError, Setup};
use crate::clock::INPUT_DEADLINE;
use crate::step;

/// Estimation: the EKF of `[T, Ṫ]` ([`step::Estimation`]) on every thrust
/// sample, predicting with the throttle the board last acknowledged.
pub struct Estimation {
    step: step::Estimation,
    /// Read with each thrust sample, never woken by: an actuation sample
    /// arrives mid-cycle and has nothing to start.
    actuation: Subscriber<Actuation>,
    state: Publisher<StateEstimate>,
}

impl Service for Estimation {
    const ID: ServiceId = ServiceId::Estimation;
    type Inputs = Input<Thrust>;

    fn new(setup: &Setup<'_>) -> Result<(Self, Self::Inputs), ServiceError> {
        let bus = setup.bus;
        let thrust = Input::new(bus.subscriber(channels::THRUST, 16)?, INPUT_DEADLINE);
        let estimation = Estimation {
            actuation: bus.polled_subscriber(channels::ACTUATION, 16)?,
            state: bus.publisher(channels::STATE)?,
            step: step::Estimation::new(setup.config.model_params()?, setup.config.estimator.observer_config()),
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
                    publish_now(&mut self.state, state, |s, ns| s.publish_ns = ns)?;
                }
                Err(e) => ctx.reject("thrust sample", &e),
            }
            Ok(())
        })
    }
}
