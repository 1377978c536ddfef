//! Control's algorithm: the reference profile and the control law (or an
//! open-loop throttle profile) on each state estimate. Plain code that never
//! touches the bus; [`super::ControlService`] wires it.

use jetbench_control::{Controller, Law, Profile, ThrottleLimit};
use jetbench_model::{Params, State, STEP_S, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use jetbench_msgs::{command_flags, Command, Reference, StateEstimate};

/// The estimator's disturbance, recovered from a state estimate: its acceleration
/// less what `model` explains at the estimate and the throttle it assumed (the
/// estimator's model is the controller's, so this is its disturbance state, and
/// exactly 0 when that state is off). 0 when not finite.
pub fn disturbance(model: &Params, state: &StateEstimate) -> f64 {
    let d =
        state.thrust_accel_n_per_s2 - model.accel(state.thrust_n, state.thrust_rate_n_per_s, state.input_throttle_pct);
    if d.is_finite() {
        d
    } else {
        0.0
    }
}

/// How the control step computes the throttle.
#[derive(Debug)]
pub enum ControlLaw {
    /// A feedback law (FBL, SMC or MPC) tracking the reference profile.
    Closed(Box<Law>),
    /// A recorded throttle profile played open loop (identification campaigns):
    /// one value per 10 ms from the first estimate on, then idle. The published
    /// reference is the thrust `model` would settle to at that throttle.
    OpenLoop {
        /// Throttle per 10 ms cycle, %.
        throttle_pct: Vec<f64>,
        /// The model whose rest thrust is published as the reference.
        model: Params,
    },
}

/// ControlStep: the reference profile and the control law.
#[derive(Debug)]
pub struct ControlStep {
    law: ControlLaw,
    profile: Profile,
    start_ns: Option<u64>,
    fallbacks: u64,
}

impl ControlStep {
    /// A step that closes the loop with `law` on the reference `profile`.
    pub fn new(law: Law, profile: Profile) -> Self {
        ControlStep::with_law(ControlLaw::Closed(Box::new(law)), profile)
    }

    /// A step with any control law (closed loop or an open-loop throttle profile).
    pub fn with_law(law: ControlLaw, profile: Profile) -> Self {
        ControlStep { law, profile, start_ns: None, fallbacks: 0 }
    }

    /// True once an open-loop profile has been played to its end.
    pub fn finished(&self, profile_time_s: f64) -> bool {
        match &self.law {
            ControlLaw::OpenLoop { throttle_pct, .. } => profile_time_s / STEP_S >= throttle_pct.len() as f64 - 0.5,
            ControlLaw::Closed(_) => false,
        }
    }

    /// True when the law acts on the state estimate (a feedback law); an open-loop profile
    /// plays its throttle whatever the estimate says.
    pub fn closed_loop(&self) -> bool {
        matches!(self.law, ControlLaw::Closed(_))
    }

    /// Cycles whose command came from the fallback law (a failed MPC solve).
    pub fn fallbacks(&self) -> u64 {
        self.fallbacks
    }

    /// One state estimate: the reference at the estimate's time (the profile
    /// starts at the first estimate) and the throttle command.
    pub fn step(&mut self, state: &StateEstimate) -> Result<(Reference, Command), jetbench_control::ControlError> {
        let start_ns = *self.start_ns.get_or_insert(state.stamp_ns);
        let profile_time_s = state.stamp_ns.saturating_sub(start_ns) as f64 * 1e-9;
        let (r, c, controller, fallback, solve_s) = match &mut self.law {
            ControlLaw::Closed(law) => {
                let estimate = State::new(state.thrust_n, state.thrust_rate_n_per_s);
                let out = law.step_with_disturbance(
                    estimate,
                    disturbance(law.params(), state),
                    profile_time_s,
                    &self.profile,
                )?;
                let code = law.kind().code();
                (out.reference, out.command, code, out.fallback, out.solve_s)
            }
            ControlLaw::OpenLoop { throttle_pct, model } => {
                // Nearest profile sample: estimates arrive every 10 ms with some jitter.
                let k = (profile_time_s / STEP_S).round() as usize;
                let u = throttle_pct.get(k).copied().unwrap_or(THROTTLE_MIN_PCT);
                let r = jetbench_control::Reference {
                    thrust_n: model.stable_equilibrium(u).unwrap_or(f64::NAN),
                    thrust_rate_n_per_s: 0.0,
                    thrust_accel_n_per_s2: 0.0,
                };
                let applied = u.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT);
                let command = jetbench_control::ThrottleCommand {
                    throttle_pct: applied,
                    unclamped_pct: u,
                    virtual_input: model.v(applied),
                    saturated: applied != u,
                };
                (r, command, Controller::OpenLoop.code(), false, 0.0)
            }
        };
        let mut flags = 0;
        match c.limit() {
            Some(ThrottleLimit::Low) => flags |= command_flags::SATURATED_LOW,
            Some(ThrottleLimit::High) => flags |= command_flags::SATURATED_HIGH,
            None => {}
        }
        if fallback {
            self.fallbacks += 1;
            flags |= command_flags::FALLBACK;
        }
        let reference = Reference {
            seq: 0,
            stamp_ns: state.stamp_ns,
            publish_ns: 0,
            source_seq: state.seq,
            profile_time_s,
            thrust_n: r.thrust_n,
            thrust_rate_n_per_s: r.thrust_rate_n_per_s,
            thrust_accel_n_per_s2: r.thrust_accel_n_per_s2,
        };
        let command = Command {
            seq: 0,
            stamp_ns: state.stamp_ns,
            publish_ns: 0,
            source_seq: state.seq,
            throttle_pct: c.throttle_pct,
            unclamped_pct: c.unclamped_pct,
            virtual_input: c.virtual_input,
            flags,
            controller,
            solve_us: (solve_s * 1e6).round().min(u32::MAX as f64) as u32,
        };
        Ok((reference, command))
    }
}
