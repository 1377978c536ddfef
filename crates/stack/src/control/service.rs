//! Control: `bench/state` in, `bench/command` and `bench/reference` out.

use jetbench_bus::{Publisher, Wake};
use jetbench_msgs::{channels, command_flags, Command, Reference, ServiceId, StateEstimate};

use super::{ControlLaw, ControlStep};
use crate::runtime::clock::INPUT_DEADLINE;
use crate::runtime::{Context, Input, Service, ServiceError, Setup};

/// Control: the reference profile and the law ([`ControlStep`]) on every state estimate.
pub struct ControlService {
    step: ControlStep,
    reference: Publisher<Reference>,
    command: Publisher<Command>,
}

impl Service for ControlService {
    const ID: ServiceId = ServiceId::Control;
    type Inputs = Input<StateEstimate>;

    fn new(setup: &Setup<'_>) -> Result<(Self, Self::Inputs), ServiceError> {
        let (bus, config) = (setup.bus, setup.config);
        let state = Input::new(bus.subscriber(channels::STATE, 16)?, INPUT_DEADLINE);
        let law = config.control_law()?;
        match &law {
            ControlLaw::Closed(law) => tracing::info!("controller {} on model {}", law.kind(), config.model.model),
            ControlLaw::OpenLoop { throttle_pct, .. } => tracing::info!(
                "playing a {:.1} s throttle profile open loop",
                throttle_pct.len() as f64 * jetbench_model::STEP_S
            ),
        }
        let control = ControlService {
            step: ControlStep::with_law(law, config.reference.clone()),
            reference: bus.publisher(channels::REFERENCE)?,
            command: bus.publisher(channels::COMMAND)?,
        };
        Ok((control, state))
    }

    fn process(&mut self, wake: Wake, state: &Input<StateEstimate>, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        state.each_sample(wake, ctx, |estimate, ctx| {
            match self.step.step(&estimate) {
                Ok((reference, command)) => {
                    if command.flags & command_flags::FALLBACK != 0 {
                        ctx.reject("MPC solve", &"fell back to FBL for this cycle");
                    }
                    // The command first: it wakes actuation, the reference only the recorder.
                    ctx.publish(&mut self.command, command, |c, ns| c.publish_ns = ns)?;
                    ctx.publish(&mut self.reference, reference, |r, ns| r.publish_ns = ns)?;
                }
                Err(e) => ctx.reject("state estimate", &e),
            }
            Ok(())
        })
    }
}
