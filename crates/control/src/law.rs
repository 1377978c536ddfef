//! The control law a bench config chooses, behind one `step`.

use std::fmt;
use std::str::FromStr;

use jetbench_model::{DelaySplit, Params, Plant, PlantEngine, State, STEP_S};
use serde::{Deserialize, Serialize};

use crate::mpc::PREDICTION_SUBSTEPS;
use crate::throttle::resting_throttle;
use crate::{
    ControlError, Fbl, FblGains, Mpc, MpcSettings, Profile, Reference, ReferenceShaper, ShaperSettings, Smc, SmcGains,
    ThrottleCommand,
};

/// The law that computes the throttle: the one enum of the bench config
/// (`[control] controller`), the command line (`--controller`) and the wire
/// (`jetbench_msgs::Command::controller` carries [`Controller::code`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
#[repr(u32)]
pub enum Controller {
    /// A recorded throttle profile played open loop (identification campaigns).
    OpenLoop = 0,
    /// Feedback linearisation (the study).
    #[default]
    Fbl = 1,
    /// Sliding mode (the study).
    Smc = 2,
    /// Model predictive control with the throttle limits and the model's effects.
    Mpc = 3,
}

impl Controller {
    /// Every controller, by code.
    pub const ALL: [Controller; 4] = [Controller::OpenLoop, Controller::Fbl, Controller::Smc, Controller::Mpc];
    /// The feedback laws ([`Law`]), in the order reports list them.
    pub const LAWS: [Controller; 3] = [Controller::Fbl, Controller::Smc, Controller::Mpc];

    /// The name used in configs and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Controller::OpenLoop => "open-loop",
            Controller::Fbl => "fbl",
            Controller::Smc => "smc",
            Controller::Mpc => "mpc",
        }
    }

    /// Its code on the wire (`jetbench_msgs::Command::controller`).
    pub const fn code(self) -> u32 {
        self as u32
    }

    /// The controller of a wire code; `None` for a code this build does not know.
    pub fn from_code(code: u32) -> Option<Controller> {
        Self::ALL.into_iter().find(|c| c.code() == code)
    }

    /// The name of a wire code, `"unknown"` for codes this build does not know.
    pub fn name_of_code(code: u32) -> &'static str {
        Self::from_code(code).map_or("unknown", Controller::name)
    }

    /// True for the feedback laws, false for open loop.
    pub fn is_feedback(self) -> bool {
        self != Controller::OpenLoop
    }
}

impl fmt::Display for Controller {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Controller {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| format!("unknown controller '{s}'; choose fbl, smc, mpc or open-loop"))
    }
}

/// The tunables of every law, as the `[control]` section of a bench config gives them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LawSettings {
    /// FBL gains (also the MPC's fallback).
    pub fbl: FblGains,
    /// SMC gains.
    pub smc: SmcGains,
    /// MPC settings.
    pub mpc: MpcSettings,
    /// Reference shaping for FBL and SMC.
    pub shaping: ShaperSettings,
}

impl LawSettings {
    /// Checks every law's settings, the unused laws' too (a typo in a gain is found before
    /// the day that law is chosen). The error names the sub-table (`fbl`, `smc`, `mpc`,
    /// `shaping`) and the key.
    pub fn validate(&self) -> Result<(), LawSettingsError> {
        let at = |table: &'static str| move |error: ControlError| LawSettingsError { table, error };
        self.fbl.validate().map_err(at("fbl"))?;
        self.smc.validate().map_err(at("smc"))?;
        self.mpc.validate().map_err(at("mpc"))?;
        self.shaping.validate().map_err(at("shaping"))
    }
}

/// A bad setting of [`LawSettings`], with the sub-table of `[control]` it is in.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("[control.{table}] {error}")]
pub struct LawSettingsError {
    /// `fbl`, `smc`, `mpc` or `shaping`.
    pub table: &'static str,
    /// What is wrong, naming the key.
    pub error: ControlError,
}

/// One control cycle's result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LawOutput {
    /// The profile's reference now: what the bench is asked to track.
    pub reference: Reference,
    /// The command.
    pub command: ThrottleCommand,
    /// True when the chosen law failed this cycle and FBL computed the command.
    pub fallback: bool,
    /// Time the law took to compute, s (the MPC's optimisation; 0 for FBL and SMC).
    pub solve_s: f64,
}

enum Inner {
    Fbl(Fbl),
    Smc(Smc),
    Mpc(Box<Mpc>),
}

/// A controller tracking a profile. FBL and SMC follow the profile through a
/// [`ReferenceShaper`] (when enabled), so they are never asked for thrust the throttle
/// cannot give; the MPC sees the profile itself, over its whole horizon, and the limits.
///
/// When the model has an input delay, FBL and SMC act on a prediction (a Smith-type
/// predictor): the state the engine will be in once this command reaches it, from the
/// model fed with the commands still in flight, tracked against the reference at that
/// time. The MPC predicts through every input-side effect itself.
///
/// ```
/// use jetbench_control::{Controller, Law, LawSettings, Profile};
/// use jetbench_model::{Effects, Plant, Preset, STEP_S};
///
/// let plant = Plant::new(Preset::P100Diesel.params(), Effects::none());
/// let profile = Profile::default();
/// let mut law = Law::new(Controller::Mpc, &plant, &LawSettings::default())?;
/// let mut engine = plant.at_equilibrium(25.0);
/// for k in 0..400 {
///     let out = law.step(engine.state(), k as f64 * STEP_S, &profile)?;
///     engine.step(out.command.throttle_pct)?;
/// }
/// assert!((engine.state().thrust_n - 50.0).abs() < 1.0);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct Law {
    kind: Controller,
    shaper: ReferenceShaper,
    inner: Inner,
    predictor: Option<DelayPredictor>,
    started: bool,
}

impl fmt::Debug for Law {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Law").field("kind", &self.kind).finish()
    }
}

impl Law {
    /// The feedback law `kind` for the controller model `plant`. FBL and SMC use its
    /// ten parameters; the MPC uses its effects too. Open loop is no feedback law:
    /// [`ControlError::NotAFeedbackLaw`].
    pub fn new(kind: Controller, plant: &Plant, settings: &LawSettings) -> Result<Self, ControlError> {
        let inner = match kind {
            Controller::Fbl => Inner::Fbl(Fbl::new(plant.params, settings.fbl)),
            Controller::Smc => Inner::Smc(Smc::new(plant.params, settings.smc)),
            Controller::Mpc => Inner::Mpc(Box::new(Mpc::new(plant.clone(), settings.mpc, settings.fbl))),
            Controller::OpenLoop => return Err(ControlError::NotAFeedbackLaw),
        };
        let predictor = match kind {
            Controller::Fbl | Controller::Smc => DelayPredictor::new(plant),
            Controller::Mpc | Controller::OpenLoop => None,
        };
        Ok(Self {
            kind,
            shaper: ReferenceShaper::new(plant.params, settings.shaping),
            inner,
            predictor,
            started: false,
        })
    }

    /// Which law this is.
    pub fn kind(&self) -> Controller {
        self.kind
    }

    /// The ten parameters of the controller's model.
    pub fn params(&self) -> &Params {
        self.shaper.params()
    }

    /// How far ahead FBL and SMC predict through the model's input delay, s: the
    /// cycles a command takes to reach the engine in full
    /// ([`DelaySplit::cycles_to_full_effect`]). 0 without a delay, and for the MPC
    /// (which predicts through the delay itself).
    pub fn prediction_lead_s(&self) -> f64 {
        self.predictor.as_ref().map_or(0.0, DelayPredictor::lead_s)
    }

    /// Throttle for the state estimate at `t_s` seconds into `profile`. Each call is one
    /// 10 ms cycle.
    pub fn step(&mut self, state: State, t_s: f64, profile: &Profile) -> Result<LawOutput, ControlError> {
        self.step_with_disturbance(state, 0.0, t_s, profile)
    }

    /// [`Law::step`] with the observer's disturbance estimate, N/s²: FBL cancels it
    /// ([`Fbl::step_with_disturbance`]); SMC's switching term and the MPC's correction
    /// towards the estimate absorb model error their own way and do not use it.
    pub fn step_with_disturbance(
        &mut self,
        state: State,
        disturbance_n_per_s2: f64,
        t_s: f64,
        profile: &Profile,
    ) -> Result<LawOutput, ControlError> {
        let reference = profile.at(t_s);
        if !self.started && state.thrust_n.is_finite() && state.thrust_rate_n_per_s.is_finite() {
            // At rest: an observer's first rate estimates are still settling.
            self.shaper.start_at(state.thrust_n, 0.0);
            self.started = true;
        }
        let (command, fallback, solve_s) = match &mut self.inner {
            Inner::Mpc(mpc) => {
                let out = mpc.step(state, t_s, profile)?;
                (out.command, out.fallback, out.solve_s)
            }
            inner => {
                let (at, lead_s) = match self.predictor.as_mut() {
                    Some(p) => (p.predict(state, t_s), p.lead_s()),
                    None => (state, 0.0),
                };
                let shaped = self.shaper.step(&profile.at(t_s + lead_s));
                let command = match inner {
                    Inner::Fbl(fbl) => fbl.step_with_disturbance(at, disturbance_n_per_s2, &shaped)?,
                    Inner::Smc(smc) => smc.step(at, &shaped)?,
                    Inner::Mpc(_) => unreachable!("handled above"),
                };
                if let Some(p) = self.predictor.as_mut() {
                    p.sent(command.throttle_pct);
                }
                (command, false, 0.0)
            }
        };
        Ok(LawOutput { reference, command, fallback, solve_s })
    }
}

/// Predicts the engine's state one input delay ahead from the commands in flight. Its
/// model is a coarse [`PlantEngine`], so the prediction runs the model's whole
/// [`jetbench_model::ThrottlePath`] (the delay, and the rate limit and the lag the
/// commands in flight meet on the way).
struct DelayPredictor {
    plant: Plant,
    /// Whole 10 ms steps the delay spans (rounded up: [`DelaySplit::cycles_to_full_effect`]).
    steps: usize,
    shadow: Option<PlantEngine>,
    scratch: Option<PlantEngine>,
    last_pct: f64,
}

impl DelayPredictor {
    /// `None` when the model has no input delay.
    fn new(plant: &Plant) -> Option<Self> {
        let steps = DelaySplit::of(plant.effects.input_delay_s()).cycles_to_full_effect();
        (steps > 0).then(|| Self { plant: plant.clone(), steps, shadow: None, scratch: None, last_pct: 0.0 })
    }

    /// How far ahead the prediction looks, s.
    fn lead_s(&self) -> f64 {
        self.steps as f64 * STEP_S
    }

    /// The state `lead_s` from now; `now` itself if the model diverges on the way.
    fn predict(&mut self, now: State, t_s: f64) -> State {
        let shadow = match self.shadow.as_mut() {
            Some(shadow) => shadow,
            None => {
                self.last_pct = resting_throttle(&self.plant.params, now.thrust_n);
                self.shadow.insert(self.plant.coarse_engine(now, self.last_pct, t_s, PREDICTION_SUBSTEPS))
            }
        };
        shadow.set_state(now);
        let scratch = self.scratch.get_or_insert_with(|| shadow.clone());
        scratch.clone_from(shadow);
        // Over the delay the engine sees commands already sent; what is fed here only
        // enters the model's history.
        for _ in 0..self.steps {
            if scratch.step(self.last_pct).is_err() {
                return now;
            }
        }
        scratch.state()
    }

    /// The command sent this cycle.
    fn sent(&mut self, throttle_pct: f64) {
        self.last_pct = throttle_pct;
        if let Some(shadow) = self.shadow.as_mut() {
            if shadow.step(throttle_pct).is_err() {
                self.shadow = None;
            }
        }
    }
}
