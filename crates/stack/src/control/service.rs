//! Control: `bench/state`, `bench/ecu` and `bench/operator` in; `bench/command`,
//! `bench/reference` and `bench/events` out.

use jetbench_bus::{Publisher, Subscriber, Wake};
use jetbench_control::{Controller, Profile};
use jetbench_msgs::{
    channels, command_flags, state_flags, Command, EcuTelemetry, Event, OperatorCommand, Reference, ServiceId,
    StateEstimate,
};

use super::engine::{EngineSupervisor, LawChange, ProfileSource};
use super::{ControlLaw, ControlStep};
use crate::config::BenchConfig;
use crate::runtime::clock::{monotonic_ns, INPUT_DEADLINE};
use crate::runtime::{Context, Input, Service, ServiceError, Setup};

/// Control: the reference profile and the law ([`ControlStep`]) on every state
/// estimate, gated by the engine supervisor ([`EngineSupervisor`]): the ECU's
/// state, the limits and the operator's commands.
pub struct ControlService {
    step: ControlStep,
    config: BenchConfig,
    profile: Profile,
    engine: EngineSupervisor,
    ecu: Subscriber<EcuTelemetry>,
    operator: Subscriber<OperatorCommand>,
    reference: Publisher<Reference>,
    command: Publisher<Command>,
    events: Publisher<Event>,
    /// The law was reset since its last command: that command carries
    /// `command_flags::LAW_RESET`, so a replay resets its law there too.
    law_reset: bool,
}

impl Service for ControlService {
    const ID: ServiceId = ServiceId::Control;
    type Inputs = Input<StateEstimate>;

    fn new(setup: &Setup<'_>) -> Result<(Self, Self::Inputs), ServiceError> {
        let (bus, config) = (setup.bus, setup.config);
        let state = Input::new(bus.subscriber(channels::STATE, 16)?, INPUT_DEADLINE);
        let law = config.control_law()?;
        match &law {
            ControlLaw::Closed(law) => {
                tracing::info!("controller {} on model {}", law.kind(), config.model.model);
                if law.kind() == Controller::Mpc && config.control.mpc.integral_rad_per_s == 0.0 {
                    let off_model = config.bench.devices == crate::config::Devices::Bench
                        || config.plant.model != config.model.model;
                    if off_model {
                        tracing::warn!(
                            "the engine is not the model {} and [control.mpc] integral_rad_per_s is 0: whatever \
                             the model has wrong stays on every hold as an offset; set it to 2.0",
                            config.model.model
                        );
                    }
                }
            }
            ControlLaw::OpenLoop { throttle_pct, .. } => tracing::info!(
                "playing a {:.1} s throttle profile open loop",
                throttle_pct.len() as f64 * jetbench_model::STEP_S
            ),
        }
        if config.bench.devices == crate::config::Devices::Bench {
            jetbench_model::plausibility::check(&config.model_params()?).map_err(|why| {
                ServiceError::Setup(format!("[model] model {} is refused for a real engine: {why}", config.model.model))
            })?;
        }
        let limits = config.limits().map_err(|e| ServiceError::Setup(e.to_string()))?;
        let params = config.model_params()?;
        let profiles = ProfileSource {
            configured: config.reference.clone(),
            idle_n: params.stable_equilibrium(jetbench_model::THROTTLE_MIN_PCT).unwrap_or(0.0),
            max_n: params.stable_equilibrium(jetbench_model::THROTTLE_MAX_PCT).unwrap_or(0.0),
        };
        tracing::info!(
            "engine: start {:?}, reference {:?}; limits: {}",
            config.engine.start,
            config.engine.reference,
            describe_limits(&limits)
        );
        let control = ControlService {
            step: ControlStep::with_law(law, config.reference.clone()),
            config: config.clone(),
            profile: config.reference.clone(),
            engine: match &config.operator {
                Some(operator) => EngineSupervisor::new(&config.engine, limits, profiles).with_lease(operator.lease()),
                None => EngineSupervisor::new(&config.engine, limits, profiles),
            },
            // Polled every cycle: ECU samples come at 10–50 Hz, commands rarely.
            ecu: bus.polled_subscriber(channels::ECU, 64)?,
            operator: bus.polled_subscriber(channels::OPERATOR, 64)?,
            reference: bus.publisher(channels::REFERENCE)?,
            command: bus.publisher(channels::COMMAND)?,
            events: bus.publisher(channels::EVENTS)?,
            law_reset: false,
        };
        Ok((control, state))
    }

    fn process(&mut self, wake: Wake, state: &Input<StateEstimate>, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        // Woken by estimates, the sensor's silence is judged once they are all
        // taken (at the end); otherwise none is waiting, and it is judged now.
        let waiting = matches!(wake, Wake::Input(_));
        self.supervise(ctx, waiting)?;
        if let Wake::Missed(_) = wake {
            // No throttle command is due: the operator's commands act now.
            self.take_operator(ctx)?;
            // No estimate (the sensor is silent, or not yet heard): while the
            // engine is gated, or a trip has just held it, idle is commanded
            // anyway, carrying what the ECU is asked.
            if !self.engine.is_free() || !self.engine.free() {
                let now = monotonic_ns();
                let (throttle_pct, flags) = self.engine.gate_idle(now);
                // Computed from no estimate: its stamp is its own, never a state's.
                let command =
                    Command { stamp_ns: now, throttle_pct, unclamped_pct: throttle_pct, flags, ..Command::default() };
                ctx.publish(&mut self.command, command, |c, ns| c.publish_ns = ns)?;
                self.publish_events(ctx)?;
            }
        }
        state.each_sample(wake, ctx, |estimate, ctx| {
            self.engine.on_thrust(estimate.stamp_ns, estimate.thrust_n);
            self.engine.on_settling(self.step.closed_loop() && estimate.flags & state_flags::SETTLING != 0);
            // Newer estimates may still wait behind this one.
            self.engine.check_before_estimates(monotonic_ns());
            match self.engine.take_law_change() {
                LawChange::None => {}
                LawChange::Reset => self.reset_law()?,
                LawChange::Profile(profile) => {
                    self.profile = profile;
                    self.reset_law()?;
                }
            }
            if self.engine.passes() && !self.engine.is_free() {
                // The law's output reaches the engine again (the ECU reached run, a
                // trip was cleared, a hold or stop ended, the estimate settled): it
                // starts afresh, never with what it integrated while its output was
                // held.
                self.reset_law()?;
            }
            match self.step.step(&estimate) {
                Ok((reference, mut command)) => {
                    if std::mem::take(&mut self.law_reset) {
                        command.flags |= command_flags::LAW_RESET;
                    }
                    if command.flags & command_flags::FALLBACK != 0 {
                        ctx.reject("MPC solve", &"fell back to FBL for this cycle");
                    }
                    let (throttle_pct, flags) =
                        self.engine.gate(monotonic_ns(), command.throttle_pct, reference.thrust_n);
                    command.throttle_pct = throttle_pct;
                    command.flags |= flags;
                    // The command first: it wakes actuation, the reference only the recorder.
                    ctx.publish(&mut self.command, command, |c, ns| c.publish_ns = ns)?;
                    ctx.publish(&mut self.reference, reference, |r, ns| r.publish_ns = ns)?;
                }
                Err(e) => ctx.reject("state estimate", &e),
            }
            self.publish_events(ctx)
        })?;
        if waiting {
            // The operator's commands once this cycle's throttle is out, so the
            // loop never waits for them (or for the events that answer them):
            // they act from the next estimate, 10 ms later at 100 Hz.
            self.take_operator(ctx)?;
            // Every waiting estimate taken: the sensor's age is what it seems.
            self.engine.check(monotonic_ns());
            self.publish_events(ctx)?;
        }
        Ok(())
    }
}

impl ControlService {
    /// Takes the ECU's samples and checks the limits (the sensor's silence
    /// only when no estimate is `waiting`): a trip acts on this cycle's command.
    fn supervise(&mut self, ctx: &mut Context<'_>, waiting: bool) -> Result<(), ServiceError> {
        while let Some(t) = self.ecu.try_recv()? {
            self.engine.on_ecu(monotonic_ns(), &t);
        }
        if waiting {
            self.engine.check_before_estimates(monotonic_ns());
        } else {
            self.engine.check(monotonic_ns());
        }
        self.publish_events(ctx)
    }

    /// Takes the operator's commands (each answered by an event).
    fn take_operator(&mut self, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        while let Some(c) = self.operator.try_recv()? {
            self.engine.on_command(monotonic_ns(), &c);
        }
        self.publish_events(ctx)
    }

    fn publish_events(&mut self, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        for event in self.engine.take_events() {
            ctx.publish(&mut self.events, event, |e, ns| e.publish_ns = ns)?;
        }
        Ok(())
    }

    /// The law afresh (integral, shaper, predictor, profile time), tracking `self.profile`.
    fn reset_law(&mut self) -> Result<(), ServiceError> {
        self.step = ControlStep::with_law(self.config.control_law()?, self.profile.clone());
        self.law_reset = true;
        Ok(())
    }
}

fn describe_limits(limits: &crate::limits::Limits) -> String {
    let set: Vec<String> = crate::limits::LimitKind::ALL
        .iter()
        .filter_map(|k| {
            limits.get(*k).map(|l| format!("{} {} {} ({}, {} s)", k.key(), l.limit, k.unit(), l.response, l.hold_s))
        })
        .collect();
    if set.is_empty() {
        "none".into()
    } else {
        set.join(", ")
    }
}
