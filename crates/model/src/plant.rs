//! The engine model with its effects, stepped 10 ms at a time: what a bench recording
//! is a measurement of.
//!
//! ```
//! use jetbench_model::{Effects, Plant, Preset};
//!
//! let effects = Effects::new([
//!     "input_delay:delay_s=0.1".parse()?,
//!     "stand_resonance:frequency_hz=4,damping_ratio=0.05".parse()?,
//! ])?;
//! let plant = Plant::new(Preset::P100Diesel.params(), effects);
//! let mut engine = plant.at_equilibrium(30.0);
//! for _ in 0..1000 {
//!     engine.step(80.0)?;
//! }
//! // Settled: the sensor reads the engine's rest thrust at 80 %.
//! assert!((engine.measured_n() - plant.rest_thrust_n(80.0)).abs() < 0.05);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Integration: the throttle path (delay, rate limit, lag) always runs at 1 kHz
//! ([`SUBSTEPS`] ticks per [`STEP_S`]); the engine is integrated by classic RK4 with
//! `substeps` steps per [`STEP_S`], each holding the throttle map `v(u)` averaged over
//! its ticks. With the reference 10 substeps that is RK4 at 1 kHz with the throttle of
//! each tick; with 1 substep (what a fit uses) it is within 0.01 N of it on any effect
//! (the bound the tests hold it to), ten times cheaper. The sensor side
//! (play band, resonance, drift bias) and the thrust history follow the engine thrust
//! at the end of every substep, the linear states by exact first-order-hold updates.

use crate::discrepancy::{DiscrepancyLaw, Histories};
use crate::engine::rk4_step_lanes;
use crate::throttle_path::{ThrottlePath, Window};
use crate::turbojet::{Turbojet, TurbojetParams, TurbojetSample};
use crate::{
    rk4_step, EffectKind, Effects, ModelError, Params, State, DIVERGENCE_RATE_N_PER_S, DIVERGENCE_THRUST_N, STEP_S,
    SUBSTEPS,
};

/// The engine model with its effects.
///
/// The engine is the ten-parameter model of [`Plant::params`], or, when
/// [`Plant::turbojet`] is set, a physically based turbojet
/// ([`crate::turbojet`]) that is not the model: the simulated bench's engine out of
/// the model's class. Either way the throttle path, the gain drift and the sensor-side
/// effects apply to it alike; a discrepancy (extra terms of the ten-parameter model)
/// and an acceleration schedule (a bound on its thrust rate) have nothing to act on in a
/// turbojet and are ignored there ([`Plant::turbojet_conflict`] says so before a run).
#[derive(Clone, Debug, PartialEq)]
pub struct Plant {
    /// The ten coefficients (not used to step a turbojet plant).
    pub params: Params,
    /// What the ten coefficients leave out.
    pub effects: Effects,
    /// The turbojet that replaces the ten-parameter engine, if any.
    pub turbojet: Option<TurbojetParams>,
}

/// Most plants [`Plant::free_runs_in_lockstep`] steps side by side (fewer in pairs):
/// enough independent chains of operations to fill a core's floating-point units.
pub const LOCKSTEP_LANES: usize = 4;

/// Where the slow states of a [`Plant`] start, relative to the default start
/// ([`SlowStart::SETTLED`]): the sensor drift's bias, the discrepancy's thrust history, and
/// where the stand's frame sits in the bearings' play band.
///
/// A recording starts some time after the sensor was tared and after the engine was
/// started, so none of these is in general where [`Plant::engine`] puts it (the bias at 0,
/// the history at the initial thrust, the frame on the thrust). The bias and the history
/// are linear first-order states, so a start away from the default decays with the state's
/// own time constant; the frame stays where it is until the thrust pushes it to an edge of
/// the band (an engine that rose to its first throttle left it at the bottom):
///
/// ```text
/// b(0) = bias_n                      ḃ = (gain·T − b)/time_constant_s       (sensor_drift)
/// H(0) = T(0) + history_offset_n     Ḣ = (T − H)/history_time_constant_s    (discrepancy)
/// F(0) = T(0) + play_position·force_n   F = clamp(F, T − force_n, T + force_n)  (bearing_friction)
/// ```
///
/// A state the plant does not have (no sensor drift, no thrust-history term, no play)
/// ignores its start. The other states of the model are fast (the throttle path, the
/// stand) or not states at all (a gain drift is a function of the time since the
/// recording's start).
///
/// ```
/// use jetbench_model::{Effects, Plant, Preset, SlowStart};
///
/// let plant = Plant::new(Preset::P100Diesel.params(), Effects::new(["sensor_drift:gain=0.04,time_constant_s=30".parse()?])?);
/// let at_rest = plant.at_equilibrium(60.0);
/// // The sensor was tared a while ago: 2 N of bias already at the start.
/// let warm = plant.engine_from(at_rest.state(), SlowStart { bias_n: 2.0, ..SlowStart::SETTLED }, 60.0, 0.0);
/// assert!((warm.measured_n() - at_rest.measured_n() - 2.0).abs() < 1e-12);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SlowStart {
    /// The sensor drift's bias at the start, N (0: just after a tare).
    pub bias_n: f64,
    /// The thrust history's distance from the initial thrust at the start, N (0: settled
    /// at the initial thrust; negative: the engine has run lower, or was cold).
    pub history_offset_n: f64,
    /// Where the stand's frame sits in the bearings' play band at the start, as a fraction
    /// of the band: −1 at its bottom (the frame trails a rise), 0 on the thrust, +1 at its
    /// top (it trails a fall). Held to [−1, 1].
    pub play_position: f64,
}

impl SlowStart {
    /// The default start: the bias zero as just after a tare, the history settled, the
    /// frame on the thrust.
    pub const SETTLED: Self = Self { bias_n: 0.0, history_offset_n: 0.0, play_position: 0.0 };
}

/// One 10 ms step of a [`PlantEngine`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantSample {
    /// The engine's state after the step.
    pub state: State,
    /// The force the sensor reads (before noise), N.
    pub measured_n: f64,
    /// The throttle the engine followed at the end of the step, %.
    pub engine_throttle_pct: f64,
}

impl Plant {
    /// The engine of `params` with `effects` (use [`Effects::none`] for the ten
    /// parameters alone).
    pub fn new(params: Params, effects: Effects) -> Self {
        Self { params, effects, turbojet: None }
    }

    /// The turbojet of `params` with `effects` (its ten coefficients are all zero and
    /// not used).
    pub fn with_turbojet(params: TurbojetParams, effects: Effects) -> Self {
        Self { params: Params::from_array([0.0; 10]), effects, turbojet: Some(params) }
    }

    /// Which effect cannot run on this plant's engine and why, if one cannot: a
    /// discrepancy names terms of the ten-parameter model, which a turbojet does not have;
    /// an acceleration schedule bounds the ten-parameter model's thrust rate, and a
    /// turbojet has its own fuel schedule.
    pub fn turbojet_conflict(&self) -> Option<(EffectKind, String)> {
        self.turbojet?;
        if self.effects.get(EffectKind::Discrepancy).is_some() {
            return Some((
                EffectKind::Discrepancy,
                "the discrepancy effect adds terms to the ten-parameter model; a turbojet plant has no such \
                 terms (use the catalogue's other effects)"
                    .to_owned(),
            ));
        }
        self.effects.get(EffectKind::AccelSchedule).map(|_| {
            (
                EffectKind::AccelSchedule,
                "accel_schedule bounds the ten-parameter model's thrust rate; a turbojet plant paces its spool \
                 with its own fuel schedule ([turbojet] accel_margin, decel_margin)"
                    .to_owned(),
            )
        })
    }

    /// A stepping simulator started at `initial` with every effect at rest for the
    /// throttle `u0_pct` (the [`crate::ThrottlePath`] settled at it, sensor bias zero as just
    /// after a tare, the stand at rest, the thrust history at the initial thrust:
    /// [`SlowStart::SETTLED`]), `t0_s` seconds after the start of the recording.
    /// [`Plant::engine_from`] starts the slow states elsewhere.
    pub fn engine(&self, initial: State, u0_pct: f64, t0_s: f64) -> PlantEngine {
        PlantEngine::new(self, initial, SlowStart::SETTLED, u0_pct, t0_s, SUBSTEPS)
    }

    /// Like [`Plant::engine`], with the slow states started at `slow` (see [`SlowStart`]):
    /// a recording that begins while they are still on their way.
    pub fn engine_from(&self, initial: State, slow: SlowStart, u0_pct: f64, t0_s: f64) -> PlantEngine {
        PlantEngine::new(self, initial, slow, u0_pct, t0_s, SUBSTEPS)
    }

    /// Like [`Plant::engine`], integrating with `substeps` RK4 steps per [`STEP_S`]
    /// instead of 10 (1, 2, 5 or 10: a request in between takes the next smaller one):
    /// a cheaper simulator for a controller's prediction or a fit, accurate to a few
    /// hundredths of a newton on this model with 1.
    pub fn coarse_engine(&self, initial: State, u0_pct: f64, t0_s: f64, substeps: usize) -> PlantEngine {
        PlantEngine::new(self, initial, SlowStart::SETTLED, u0_pct, t0_s, substeps)
    }

    /// The thrust at rest for `u0_pct`, effects included (a discrepancy moves it): the
    /// ten-parameter stable equilibrium, refined by Newton's method on the whole
    /// acceleration with the thrust history at rest too.
    pub fn rest_thrust_n(&self, u0_pct: f64) -> f64 {
        if let Some(turbojet) = &self.turbojet {
            return turbojet.rest_thrust_n(u0_pct);
        }
        let thrust_n = self.params.stable_equilibrium(u0_pct).unwrap_or(0.0);
        let Some(e) = self.effects.get(EffectKind::Discrepancy) else { return thrust_n };
        let law = DiscrepancyLaw::new(e.values());
        let p = &self.params;
        let accel = |t: f64| {
            let (g, v) = (p.g(t, 0.0), p.v(u0_pct));
            let (below, above) = DiscrepancyLaw::hinges(v, p.v(law.knot_below_pct), p.v(law.knot_above_pct));
            p.f(t, 0.0) + g * v + law.accel(t, 0.0, g, v, below, above, Histories { thrust_n: t, throttle: v })
        };
        let mut t = thrust_n;
        for _ in 0..30 {
            let (a, h) = (accel(t), 1e-4 * t.abs().max(1.0));
            let slope = (accel(t + h) - a) / h;
            if !(slope.is_finite() && slope < 0.0) {
                return thrust_n;
            }
            let next = t - a / slope;
            if !next.is_finite() {
                return thrust_n;
            }
            if (next - t).abs() < 1e-10 * t.abs().max(1.0) {
                return next;
            }
            t = next;
        }
        t
    }

    /// A stepping simulator at rest at the stable equilibrium for `u0_pct`, at time 0.
    pub fn at_equilibrium(&self, u0_pct: f64) -> PlantEngine {
        let thrust_n = self.rest_thrust_n(u0_pct);
        self.engine(State { thrust_n, thrust_rate_n_per_s: 0.0 }, u0_pct, 0.0)
    }

    /// Free run: `out[0]` is the measured force at `initial`, `out[k + 1]` follows with
    /// `u_pct[k]` held for [`STEP_S`]. On divergence the rest is NaN and the time of
    /// divergence (s from the run start) is returned.
    pub fn free_run(&self, t0_s: f64, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        self.free_run_with(SUBSTEPS, t0_s, initial, u_pct, out)
    }

    /// [`Plant::free_run`] with `substeps` RK4 steps per [`STEP_S`] (see
    /// [`Plant::coarse_engine`]).
    pub fn free_run_with(
        &self,
        substeps: usize,
        t0_s: f64,
        initial: State,
        u_pct: &[f64],
        out: &mut Vec<f64>,
    ) -> Option<f64> {
        self.free_run_from(substeps, t0_s, initial, SlowStart::SETTLED, u_pct, out)
    }

    /// [`Plant::free_run_with`] with the slow states started at `slow` (see [`SlowStart`]).
    pub fn free_run_from(
        &self,
        substeps: usize,
        t0_s: f64,
        initial: State,
        slow: SlowStart,
        u_pct: &[f64],
        out: &mut Vec<f64>,
    ) -> Option<f64> {
        let engine = self.run_engine(substeps, t0_s, initial, slow, u_pct);
        Self::run_stepping(engine, u_pct, out, |engine, _, u| engine.step(u))
    }

    /// The engine a free run of `u_pct` starts with.
    fn run_engine(&self, substeps: usize, t0_s: f64, initial: State, slow: SlowStart, u_pct: &[f64]) -> PlantEngine {
        PlantEngine::new(self, initial, slow, u_pct.first().copied().unwrap_or(0.0), t0_s, substeps)
    }

    /// The free run behind [`Plant::free_run_from`] and [`Plant::free_run_keeping`], each
    /// step `k` taken by `step`.
    #[inline(always)]
    fn run_stepping(
        mut engine: PlantEngine,
        u_pct: &[f64],
        out: &mut Vec<f64>,
        mut step: impl FnMut(&mut PlantEngine, usize, f64) -> Result<PlantSample, ModelError>,
    ) -> Option<f64> {
        out.clear();
        out.push(engine.measured_n());
        for (k, &u) in u_pct.iter().enumerate().take(u_pct.len().saturating_sub(1)) {
            match step(&mut engine, k, u) {
                Ok(s) => out.push(s.measured_n),
                Err(_) => {
                    out.resize(u_pct.len(), f64::NAN);
                    return Some((k + 1) as f64 * STEP_S);
                }
            }
        }
        None
    }

    /// This plant without its sensor-side effects ([`EffectKind::is_sensor_side`]): two
    /// plants with the same engine side drive the sensor with the same engine thrust.
    pub fn engine_side(&self) -> Plant {
        let mut effects = self.effects.clone();
        for kind in EffectKind::ALL.into_iter().filter(|k| k.is_sensor_side()) {
            effects = effects.without(kind);
        }
        Plant { params: self.params, effects, turbojet: self.turbojet }
    }

    /// [`Plant::free_run_from`] that also keeps the engine's path: the thrust at the end
    /// of every substep, in `thrust_n` (up to a divergence), so that
    /// [`Plant::replay_sensor`] can run another sensor side on it without stepping the
    /// engine again.
    #[allow(clippy::too_many_arguments)]
    pub fn free_run_recorded(
        &self,
        substeps: usize,
        t0_s: f64,
        initial: State,
        slow: SlowStart,
        u_pct: &[f64],
        out: &mut Vec<f64>,
        thrust_n: &mut Vec<f64>,
    ) -> Option<f64> {
        self.free_run_keeping(substeps, t0_s, initial, slow, u_pct, out, Some(thrust_n), None)
    }

    /// What fixes this plant's drives ([`DriveTrack`]) with `substeps` RK4 steps per
    /// [`STEP_S`]; `None` when it has none worth keeping (no input delay, rate limit or
    /// actuator lag: the drive is the throttle map of the throttle held; or a turbojet,
    /// which follows its throttle tick by tick).
    pub fn drive_key(&self, substeps: usize) -> Option<DriveKey> {
        if self.turbojet.is_some() {
            return None;
        }
        PlantEngine::new(self, State::default(), SlowStart::SETTLED, 0.0, 0.0, substeps).drive_key()
    }

    /// [`Plant::free_run_from`] that keeps what the next run may reuse: the engine's path in
    /// `thrust_n`, as [`Plant::free_run_recorded`] does, and the drives in `drives`. The
    /// drives are read from there when it holds this plant's ([`Plant::drive_key`]) over
    /// these throttles (any plant's, other parameters and effects aside), and are run and
    /// kept there otherwise. The readings are the same, bit for bit, either way: the
    /// drives do not depend on the engine's state.
    #[allow(clippy::too_many_arguments)]
    pub fn free_run_keeping(
        &self,
        substeps: usize,
        t0_s: f64,
        initial: State,
        slow: SlowStart,
        u_pct: &[f64],
        out: &mut Vec<f64>,
        thrust_n: Option<&mut Vec<f64>>,
        drives: Option<&mut DriveTrack>,
    ) -> Option<f64> {
        let engine = self.run_engine(substeps, t0_s, initial, slow, u_pct);
        let mut thrust_n = thrust_n;
        if let Some(path) = thrust_n.as_deref_mut() {
            path.clear();
        }
        let (Some(key), Some(track)) = (engine.drive_key(), drives) else {
            return Self::run_stepping(engine, u_pct, out, |e, _, u| {
                e.step_keeping(u, DriveSource::Path, thrust_n.as_deref_mut())
            });
        };
        let steps = u_pct.len().saturating_sub(1);
        let per_step = engine.substeps;
        if track.holds(key, &u_pct[..steps], steps * per_step) {
            let kept = &track.drives;
            return Self::run_stepping(engine, u_pct, out, |e, k, u| {
                e.step_keeping(u, DriveSource::Kept(&kept[k * per_step..(k + 1) * per_step]), thrust_n.as_deref_mut())
            });
        }
        track.key = Some(key);
        track.u_pct.clear();
        track.u_pct.extend_from_slice(&u_pct[..steps]);
        track.drives.clear();
        let to = &mut track.drives;
        Self::run_stepping(engine, u_pct, out, |e, _, u| {
            e.step_keeping(u, DriveSource::Recording(to), thrust_n.as_deref_mut())
        })
    }

    /// [`Plant::free_run_from`] of several plants over the same throttles, up to
    /// [`LOCKSTEP_LANES`] of them stepped in lockstep (one step of each in turn), each
    /// from its own start into its own `out`, with what each run returns (its
    /// divergence) in `diverged_s`. Every reading is the same, bit for bit, as a run of
    /// the plant alone: each plant's engine takes the same operations in the same order.
    /// A run is a chain of dependent operations that keeps a core's units mostly idle;
    /// the chains of independent plants, side by side, overlap (on a 600 s diagnosis,
    /// about a third less time per step for two).
    ///
    /// The plants read their drives from `drives` when it holds every plant's (one
    /// [`DriveKey`] over these throttles); each runs its own throttle path otherwise.
    /// `drives` is only read.
    #[allow(clippy::too_many_arguments)]
    pub fn free_runs_in_lockstep(
        plants: &[&Plant],
        substeps: usize,
        t0_s: f64,
        starts: &[(State, SlowStart)],
        u_pct: &[f64],
        drives: Option<&DriveTrack>,
        outs: &mut [Vec<f64>],
        diverged_s: &mut [Option<f64>],
    ) {
        let count = plants.len().min(starts.len()).min(outs.len()).min(diverged_s.len());
        let (outs, diverged_s) = (&mut outs[..count], &mut diverged_s[..count]);
        if plants[..count].iter().any(|p| p.turbojet.is_some()) {
            for i in 0..count {
                let (state, slow) = starts[i];
                diverged_s[i] = plants[i].free_run_from(substeps, t0_s, state, slow, u_pct, &mut outs[i]);
            }
            return;
        }
        let steps = u_pct.len().saturating_sub(1);
        let engines: Vec<PlantEngine> =
            (0..count).map(|i| plants[i].run_engine(substeps, t0_s, starts[i].0, starts[i].1, u_pct)).collect();
        // One key for all, and held: what every plant's own path would give.
        let kept = drives.filter(|track| {
            engines.iter().all(|engine| {
                engine.drive_key().is_some_and(|key| track.holds(key, &u_pct[..steps], steps * engine.substeps))
            })
        });
        match kept {
            Some(track) => {
                let per_step = engines.first().map_or(1, |e| e.substeps);
                let kept = &track.drives;
                Self::run_lanes(engines, u_pct, outs, diverged_s, |_, k, i, _| kept[k * per_step + i]);
            }
            None => Self::run_lanes(engines, u_pct, outs, diverged_s, |engine, _, i, held| match held {
                Some(held) => held,
                None => engine.shaped_drive(i),
            }),
        }
    }

    /// The free runs of [`Plant::free_runs_in_lockstep`]: [`LOCKSTEP_LANES`] engines at a
    /// time stepped by [`PlantEngine::step_lanes`], one alone where fewer are left (the
    /// last of an odd count, or those beside one that diverged).
    #[inline(always)]
    fn run_lanes(
        engines: Vec<PlantEngine>,
        u_pct: &[f64],
        outs: &mut [Vec<f64>],
        diverged_s: &mut [Option<f64>],
        drive: impl Fn(&mut PlantEngine, usize, usize, Option<Drive>) -> Drive + Copy,
    ) {
        let steps = u_pct.len().saturating_sub(1);
        for (engine, (out, diverged_s)) in engines.iter().zip(outs.iter_mut().zip(diverged_s.iter_mut())) {
            out.clear();
            out.push(engine.measured_n());
            *diverged_s = None;
        }
        // Steps from `from` of one engine alone, as [`Plant::run_stepping`] takes them.
        let alone = |mut engine: PlantEngine, from: usize, out: &mut Vec<f64>| -> Option<f64> {
            for (k, &u) in u_pct.iter().enumerate().take(steps).skip(from) {
                let [stepped] = PlantEngine::step_lanes(std::array::from_mut(&mut engine), u, k, drive);
                if !stepped {
                    out.resize(u_pct.len(), f64::NAN);
                    return Some((k + 1) as f64 * STEP_S);
                }
                out.push(engine.measured_n());
            }
            None
        };
        // The widest groups first; a remainder of two or three still goes in pairs.
        let mut at = 0;
        while at < engines.len() {
            let (engines, outs, diverged_s) = (&engines[at..], &mut outs[at..], &mut diverged_s[at..]);
            at += match engines.len() {
                1 => {
                    diverged_s[0] = alone(engines[0].clone(), 0, &mut outs[0]);
                    1
                }
                2 | 3 => Self::run_group::<2>(engines, u_pct, outs, diverged_s, drive, &alone),
                _ => Self::run_group::<LOCKSTEP_LANES>(engines, u_pct, outs, diverged_s, drive, &alone),
            };
        }
    }

    /// The first `N` runs of [`Plant::run_lanes`] in lockstep, those beside one that
    /// diverges carried on by `alone` from the next step. Returns `N`.
    #[inline(always)]
    fn run_group<const N: usize>(
        engines: &[PlantEngine],
        u_pct: &[f64],
        outs: &mut [Vec<f64>],
        diverged_s: &mut [Option<f64>],
        drive: impl Fn(&mut PlantEngine, usize, usize, Option<Drive>) -> Drive + Copy,
        alone: &impl Fn(PlantEngine, usize, &mut Vec<f64>) -> Option<f64>,
    ) -> usize {
        let mut lanes: [PlantEngine; N] = std::array::from_fn(|l| engines[l].clone());
        for (k, &u) in u_pct.iter().enumerate().take(u_pct.len().saturating_sub(1)) {
            let stepped = PlantEngine::step_lanes(&mut lanes, u, k, drive);
            if stepped.iter().all(|s| *s) {
                for (engine, out) in lanes.iter().zip(outs.iter_mut()) {
                    out.push(engine.measured_n());
                }
                continue;
            }
            // A lane diverged: it stops there, the others carry on alone.
            for (lane, engine) in lanes.iter().enumerate() {
                if stepped[lane] {
                    outs[lane].push(engine.measured_n());
                    diverged_s[lane] = alone(engine.clone(), k + 1, &mut outs[lane]);
                } else {
                    outs[lane].resize(u_pct.len(), f64::NAN);
                    diverged_s[lane] = Some((k + 1) as f64 * STEP_S);
                }
            }
            break;
        }
        N
    }

    /// The reading of this plant along an engine path kept by [`Plant::free_run_recorded`]
    /// of a plant with the same engine side ([`Plant::engine_side`]), from the same
    /// `initial` state and thrust-history start, over its first `len` samples: the same
    /// values, bit for bit, as [`Plant::free_run_from`] of this plant, which steps the
    /// engine again. `diverged_s` is what the recorded run returned (its samples from then
    /// on are NaN). Not for a turbojet plant (its path is not recorded).
    #[allow(clippy::too_many_arguments)]
    pub fn replay_sensor(
        &self,
        substeps: usize,
        initial: State,
        slow: SlowStart,
        thrust_n: &[f64],
        len: usize,
        diverged_s: Option<f64>,
        out: &mut Vec<f64>,
    ) {
        let mut engine = PlantEngine::new(self, initial, slow, 0.0, 0.0, substeps);
        out.clear();
        if len == 0 {
            return;
        }
        out.push(engine.measured_n());
        let mut t_start = initial.thrust_n;
        for step in thrust_n.chunks_exact(engine.substeps).take(len - 1) {
            for &t in step {
                engine.sense(t_start, t);
                t_start = t;
            }
            out.push(engine.measured_n());
        }
        debug_assert!(diverged_s.is_some() || out.len() == len, "the path covers the run unless it diverged");
        out.resize(len, f64::NAN);
    }
}

/// The throttle map for a throttle the engine follows, `u_pct`, %: `v(u)` and the
/// discrepancy's hinges.
#[inline(always)]
fn drive_of(params: &Params, discrepancy: Option<&Discrepancy>, u_pct: f64) -> Drive {
    let v = params.v(u_pct);
    match discrepancy {
        Some(disc) if disc.law.has_hinges() => {
            let (below, above) = DiscrepancyLaw::hinges(v, disc.v_below, disc.v_above);
            Drive { v, below, above }
        }
        _ => Drive { v, below: 0.0, above: 0.0 },
    }
}

/// The thrust at which an `accel_schedule`'s rates hold, N.
pub const SCHEDULE_REFERENCE_N: f64 = 100.0;
/// The least `(T + offset_n)/SCHEDULE_REFERENCE_N` an `accel_schedule` uses: an engine
/// below its offset still moves.
pub const SCHEDULE_FLOOR: f64 = 0.05;

/// The thrust-rate bounds of an `accel_schedule` effect:
/// `−down·s^exponent ≤ Ṫ ≤ up·s^exponent`, `s = max((T + offset)/100 N, 0.05)`.
///
/// The plant holds its thrust rate within them after every integration step; an observer
/// that predicts with the model's ten parameters holds its predicted rate within them too
/// (`Effects::rate_schedule`).
///
/// ```
/// use jetbench_model::{Effects, RateSchedule};
///
/// let effects = Effects::new(["accel_schedule:up_n_per_s=200,down_n_per_s=300,exponent=1,offset_n=0".parse()?])?;
/// let schedule: RateSchedule = effects.rate_schedule().expect("the model is paced");
/// assert_eq!(schedule.bound(50.0, 500.0), 100.0); // up to 200 N/s · (50 N / 100 N)
/// assert_eq!(schedule.bound(50.0, -20.0), -20.0); // within the bounds: as it was
/// assert_eq!(schedule.bound_slope(50.0, 500.0), 2.0); // the upper bound grows 2 N/s per N
/// # Ok::<(), jetbench_model::ModelError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateSchedule {
    up_n_per_s: f64,
    down_n_per_s: f64,
    exponent: f64,
    offset_n: f64,
}

impl RateSchedule {
    /// From an `accel_schedule`'s values, in the order of its keys.
    pub(crate) fn new(values: &[f64]) -> Self {
        Self { up_n_per_s: values[0], down_n_per_s: values[1], exponent: values[2], offset_n: values[3] }
    }

    /// `s^exponent` at `thrust_n`, and `s` itself.
    #[inline(always)]
    fn scale(&self, thrust_n: f64) -> (f64, f64) {
        let s = ((thrust_n + self.offset_n) / SCHEDULE_REFERENCE_N).max(SCHEDULE_FLOOR);
        (s.powf(self.exponent), s)
    }

    /// `rate_n_per_s` held within the bounds at `thrust_n` (a rate that is not a number
    /// stays one, for the divergence check).
    #[inline(always)]
    pub fn bound(&self, thrust_n: f64, rate_n_per_s: f64) -> f64 {
        let (scale, _) = self.scale(thrust_n);
        rate_n_per_s.clamp(-self.down_n_per_s * scale, self.up_n_per_s * scale)
    }

    /// How [`RateSchedule::bound`] of `rate_n_per_s` moves with the thrust, (N/s)/N: the
    /// slope of the bound it is held at, 0 within the bounds (or below the floor, where the
    /// bounds do not move).
    pub fn bound_slope(&self, thrust_n: f64, rate_n_per_s: f64) -> f64 {
        let (scale, s) = self.scale(thrust_n);
        let (lo, hi) = (-self.down_n_per_s * scale, self.up_n_per_s * scale);
        let at = if rate_n_per_s > hi {
            hi
        } else if rate_n_per_s < lo {
            lo
        } else {
            return 0.0;
        };
        if s <= SCHEDULE_FLOOR {
            return 0.0;
        }
        at * self.exponent / (s * SCHEDULE_REFERENCE_N)
    }
}

/// A linear first-order state `ẋ = (u − x)/τ` advanced over `h` with `u` moving
/// linearly from `u0` to `u1` (exact first-order hold).
#[derive(Clone, Copy, Debug, PartialEq)]
struct FirstOrder {
    /// `e^(−h/τ)`.
    decay: f64,
    /// `τ·(1 − e^(−h/τ))/h`.
    ramp: f64,
}

impl FirstOrder {
    fn new(time_constant_s: f64, h: f64) -> Self {
        let decay = (-h / time_constant_s).exp();
        Self { decay, ramp: time_constant_s * (1.0 - decay) / h }
    }

    fn advance(&self, x: f64, u0: f64, u1: f64) -> f64 {
        self.decay * x + u1 - self.decay * u0 - (u1 - u0) * self.ramp
    }
}

/// The stand: the sensor reads the frame force `F` through `ẍ = ω²(F − x) − 2ζω·ẋ`,
/// advanced exactly over a substep with `F` moving linearly.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stand {
    /// Transition matrix of `(x − F_p, ẋ − Ḟ)` over a substep.
    phi: [[f64; 2]; 2],
    /// `2ζ/ω`, s: how far the reading trails a ramp, per N/s.
    lag_s: f64,
    h: f64,
}

impl Stand {
    fn new(frequency_hz: f64, damping_ratio: f64, h: f64) -> Self {
        let omega = 2.0 * std::f64::consts::PI * frequency_hz;
        // exp(A·h) for A = [[0, 1], [−ω², −2ζω]]: e^(sh)·((C − s·S)·I + S·A) with s the
        // real part of the eigenvalues and d² = s² − ω² their spread.
        let s = -damping_ratio * omega;
        let d2 = s * s - omega * omega;
        let (c, sn) = if d2 < 0.0 {
            let w = (-d2).sqrt();
            ((w * h).cos(), (w * h).sin() / w)
        } else if d2 > 0.0 {
            let w = d2.sqrt();
            ((w * h).cosh(), (w * h).sinh() / w)
        } else {
            (1.0, h)
        };
        let e = (s * h).exp();
        let phi = [[e * (c - s * sn), e * sn], [-e * omega * omega * sn, e * (c + s * sn)]];
        Self { phi, lag_s: 2.0 * damping_ratio / omega, h }
    }

    /// Advances `(x, ẋ)` while the frame force moves from `f0` to `f1`.
    fn advance(&self, x: f64, xd: f64, f0: f64, f1: f64) -> (f64, f64) {
        let slope = (f1 - f0) / self.h;
        let (y, q) = (x - f0 + self.lag_s * slope, xd - slope);
        let [[a, b], [c, d]] = self.phi;
        (a * y + b * q + f1 - self.lag_s * slope, c * y + d * q + slope)
    }
}

/// The discrepancy with what the inner loop needs precomputed.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Discrepancy {
    law: DiscrepancyLaw,
    /// `v(knot_below_pct)`, `v(knot_above_pct)`.
    v_below: f64,
    v_above: f64,
    history: FirstOrder,
    throttle_history: FirstOrder,
}

/// The plant stepped 10 ms at a time (see the module docs; with [`SUBSTEPS`] it
/// reproduces [`crate::Engine`] bit for bit when there is no effect). It holds no heap
/// memory, so a controller may copy its model every cycle.
#[derive(Clone, Debug)]
pub struct PlantEngine {
    params: Params,
    state: State,
    substeps: usize,
    /// Throttle-path ticks per substep.
    ticks: usize,
    t0_s: f64,
    steps: u64,
    failed: bool,
    /// Input delay, rate limit and actuator lag.
    path: ThrottlePath,
    // Effect parameters, flattened for the inner loop (None: effect absent).
    gain_per_s: f64,
    discrepancy: Option<Discrepancy>,
    schedule: Option<RateSchedule>,
    play_n: Option<f64>,
    stand: Option<Stand>,
    drift: Option<(f64, FirstOrder)>,
    /// The turbojet that replaces the ten-parameter engine, if any.
    turbojet: Option<Turbojet>,
    // Effect states.
    frame_n: f64,
    sensor_n: f64,
    sensor_rate_n_per_s: f64,
    bias_n: f64,
    history_n: f64,
    /// The discrepancy's throttle-map history (settled at the start: `v(u0)`).
    throttle_history: f64,
}

/// The throttle map over one substep: `v(u)` and the discrepancy's hinges, averaged.
#[derive(Clone, Copy, Debug, Default)]
struct Drive {
    v: f64,
    below: f64,
    above: f64,
}

/// Where a step's drives come from.
enum DriveSource<'a> {
    /// The throttle path, run now.
    Path,
    /// The throttle path, run now, each drive appended here.
    Recording(&'a mut Vec<Drive>),
    /// Kept from an earlier run of the same drives: this step's, one per substep. The path
    /// is not run, so [`PlantSample::engine_throttle_pct`] is not meaningful (a free run
    /// reports readings alone).
    Kept(&'a [Drive]),
}

/// What fixes the drives of a plant's engine over given throttles, bit for bit: the
/// throttle path's settings (input delay, rate limit, actuator lag), the throttle map's
/// curvature `B_UU`, the discrepancy's hinges (where it has them) and the substeps. The
/// rest of a plant (the other parameters, a gain drift, the sensor side, a discrepancy's
/// other terms) acts after the drive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DriveKey {
    substeps: usize,
    path: [Option<u64>; 4],
    b_uu: u64,
    hinges: Option<[u64; 2]>,
}

/// The drives of one free run (the throttle map `v(u)` and the discrepancy's hinges the
/// engine integrates over each substep, from the throttle path), kept by
/// [`Plant::free_run_keeping`] so that a run of any plant with the same [`DriveKey`] over
/// the same throttles reads them instead of running the path again: a rate limit or a
/// lag is a chain of [`SUBSTEPS`] ticks per step, a sixth of a fit's time on 600 s
/// recordings.
#[derive(Clone, Debug, Default)]
pub struct DriveTrack {
    key: Option<DriveKey>,
    /// The throttles of the run they were kept from (those the steps took), %.
    u_pct: Vec<f64>,
    /// One per substep, up to the end of that run (or a little past a divergence).
    drives: Vec<Drive>,
}

impl DriveTrack {
    /// True when this holds `plant`'s drives with `substeps` RK4 steps per [`STEP_S`] over a
    /// run of `u_pct` (see [`Plant::free_run_keeping`]): a run of it would read them.
    pub fn holds_run_of(&self, plant: &Plant, substeps: usize, u_pct: &[f64]) -> bool {
        let engine = plant.run_engine(substeps, 0.0, State::default(), SlowStart::SETTLED, u_pct);
        let steps = u_pct.len().saturating_sub(1);
        engine.drive_key().is_some_and(|key| self.holds(key, &u_pct[..steps], steps * engine.substeps))
    }

    /// True when this holds `count` drives of `key` over throttles starting with `u_pct`
    /// (compared bit for bit).
    fn holds(&self, key: DriveKey, u_pct: &[f64], count: usize) -> bool {
        self.key == Some(key)
            && self.drives.len() >= count
            && self.u_pct.len() >= u_pct.len()
            && self.u_pct.iter().zip(u_pct).all(|(a, b)| a.to_bits() == b.to_bits())
    }
}

impl PlantEngine {
    fn new(plant: &Plant, initial: State, slow: SlowStart, u0_pct: f64, t0_s: f64, substeps: usize) -> Self {
        // A turbojet's pump and governor are stiffer than the model: always 1 kHz.
        let substeps = if plant.turbojet.is_some() { SUBSTEPS } else { substeps };
        let substeps = [10, 5, 2, 1].into_iter().find(|&d| d <= substeps.max(1)).unwrap_or(1);
        let ticks = SUBSTEPS / substeps;
        let h = STEP_S / substeps as f64;
        let values = |kind: EffectKind| plant.effects.get(kind).map(|e| e.values());
        let mut path = ThrottlePath::new(&plant.effects);
        path.start_at(u0_pct);
        let p = plant.params;
        let drift = values(EffectKind::SensorDrift).map(|v| (v[0], FirstOrder::new(v[1], h)));
        let play_n = values(EffectKind::BearingFriction).map(|v| v[0]);
        // The stand at rest on the frame, wherever the play left it.
        let frame_n = initial.thrust_n + play_n.map_or(0.0, |play| play * slow.play_position.clamp(-1.0, 1.0));
        let discrepancy = values(EffectKind::Discrepancy).filter(|_| plant.turbojet.is_none()).map(|v| {
            let law = DiscrepancyLaw::new(v);
            Discrepancy {
                law,
                v_below: p.v(law.knot_below_pct),
                v_above: p.v(law.knot_above_pct),
                history: FirstOrder::new(law.history_time_constant_s, h),
                throttle_history: FirstOrder::new(law.throttle_history_time_constant_s, h),
            }
        });
        Self {
            params: p,
            state: initial,
            substeps,
            ticks,
            t0_s,
            steps: 0,
            failed: false,
            path,
            gain_per_s: values(EffectKind::GainDrift).map_or(0.0, |v| v[0] / 60.0),
            discrepancy,
            schedule: values(EffectKind::AccelSchedule).filter(|_| plant.turbojet.is_none()).map(RateSchedule::new),
            play_n,
            stand: values(EffectKind::StandResonance).map(|v| Stand::new(v[0], v[1], h)),
            drift,
            turbojet: plant.turbojet.map(|params| Turbojet::at_thrust(params, initial.thrust_n, u0_pct)),
            frame_n,
            sensor_n: frame_n,
            sensor_rate_n_per_s: 0.0,
            // A state the plant does not have stays at its default, so that the reading
            // of a plant without a drift never carries a bias.
            bias_n: if drift.is_some() { slow.bias_n } else { 0.0 },
            history_n: initial.thrust_n + if discrepancy.is_some() { slow.history_offset_n } else { 0.0 },
            throttle_history: if discrepancy.is_some() { p.v(u0_pct) } else { 0.0 },
        }
    }

    /// Where the slow states are now, relative to the engine's thrust (see [`SlowStart`]):
    /// an engine started from this, the state and the throttle it follows carries on as
    /// this one does.
    pub fn slow_states(&self) -> SlowStart {
        let play_position = match self.play_n {
            Some(play) if play > 0.0 => ((self.frame_n - self.state.thrust_n) / play).clamp(-1.0, 1.0),
            _ => 0.0,
        };
        SlowStart { bias_n: self.bias_n, history_offset_n: self.history_n - self.state.thrust_n, play_position }
    }

    /// The engine's state.
    pub fn state(&self) -> State {
        self.state
    }

    /// The force the sensor reads now (before noise), N.
    pub fn measured_n(&self) -> f64 {
        (if self.stand.is_some() { self.sensor_n } else { self.frame_n }) + self.bias_n
    }

    /// Replaces the engine's thrust and rate, keeping the throttle history and the
    /// effects' states: how a controller re-anchors its model on a fresh state estimate.
    /// Clears a divergence.
    pub fn set_state(&mut self, state: State) {
        self.state = state;
        if let Some(turbojet) = &mut self.turbojet {
            turbojet.set_thrust(state.thrust_n);
        }
        self.frame_n = state.thrust_n;
        self.failed = false;
    }

    /// What the turbojet does now (its spool speed and exhaust temperature, what its ECU
    /// reports), when the plant is one.
    pub fn turbojet(&self) -> Option<TurbojetSample> {
        self.turbojet.as_ref().map(Turbojet::sample)
    }

    /// Time since the start of the recording, s.
    pub fn time_s(&self) -> f64 {
        self.t0_s + self.steps as f64 * STEP_S
    }

    /// Advances one [`STEP_S`] with `throttle_pct` commanded; fails like
    /// [`crate::Engine::step`] on divergence or a non-finite throttle.
    pub fn step(&mut self, throttle_pct: f64) -> Result<PlantSample, ModelError> {
        self.step_with(throttle_pct, DriveSource::Path, |_| {})
    }

    /// [`PlantEngine::step`] with its drives from `drives`, appending the engine's thrust
    /// at the end of each substep to `thrust_n` when given (only for a step that does not
    /// diverge).
    #[inline(always)]
    fn step_keeping(
        &mut self,
        throttle_pct: f64,
        drives: DriveSource<'_>,
        thrust_n: Option<&mut Vec<f64>>,
    ) -> Result<PlantSample, ModelError> {
        let Some(thrust_n) = thrust_n else { return self.step_with(throttle_pct, drives, |_| {}) };
        let mark = thrust_n.len();
        let sample = self.step_with(throttle_pct, drives, |t| thrust_n.push(t));
        if sample.is_err() {
            thrust_n.truncate(mark);
        }
        sample
    }

    /// What fixes this engine's drives, if it has any worth keeping (see [`Plant::drive_key`]).
    fn drive_key(&self) -> Option<DriveKey> {
        (self.turbojet.is_none() && self.path.shapes()).then(|| DriveKey {
            substeps: self.substeps,
            path: self.path.settings(),
            b_uu: self.params.b_uu.to_bits(),
            hinges: self.discrepancy.filter(|d| d.law.has_hinges()).map(|d| [d.v_below.to_bits(), d.v_above.to_bits()]),
        })
    }

    /// [`PlantEngine::step`] with its drives from `drives`, handing each substep's thrust to
    /// `substep_thrust_n`.
    #[inline(always)]
    fn step_with(
        &mut self,
        throttle_pct: f64,
        mut drives: DriveSource<'_>,
        mut substep_thrust_n: impl FnMut(f64),
    ) -> Result<PlantSample, ModelError> {
        if !throttle_pct.is_finite() {
            return Err(ModelError::InvalidThrottle { throttle_pct });
        }
        if self.failed {
            return Err(self.diverged(self.time_s()));
        }
        if let Some(engine) = self.turbojet {
            return self.step_turbojet(engine, throttle_pct);
        }
        let h = STEP_S / self.substeps as f64;
        self.path.push(throttle_pct);
        let shaped = self.path.shapes();
        let held = if shaped { Drive::default() } else { self.drive_of(throttle_pct) };
        let p = self.params;
        let (mut t, mut d) = (self.state.thrust_n, self.state.thrust_rate_n_per_s);
        for i in 0..self.substeps {
            let mut drive = match &mut drives {
                DriveSource::Kept(kept) => kept[i],
                DriveSource::Path => {
                    if shaped {
                        self.shaped_drive(i)
                    } else {
                        held
                    }
                }
                DriveSource::Recording(to) => {
                    let drive = if shaped { self.shaped_drive(i) } else { held };
                    to.push(drive);
                    drive
                }
            };
            if self.gain_per_s != 0.0 {
                let t_mid = self.t0_s + self.steps as f64 * STEP_S + (i as f64 + 0.5) * h;
                drive.v *= 1.0 - self.gain_per_s * t_mid;
            }
            let t_start = t;
            (t, d) = match self.discrepancy {
                None => rk4_step(t, d, h, |t, d| p.f(t, d) + p.g(t, d) * drive.v),
                Some(disc) => {
                    let history = Histories { thrust_n: self.history_n, throttle: self.throttle_history };
                    let step = rk4_step(t, d, h, |t, d| {
                        let g = p.g(t, d);
                        disc.law.total(p.f(t, d) + g * drive.v, t, d, g, drive.v, drive.below, drive.above, history)
                    });
                    self.throttle_history = disc.throttle_history.advance(self.throttle_history, drive.v, drive.v);
                    step
                }
            };
            if let Some(schedule) = self.schedule {
                d = schedule.bound(t, d);
            }
            if !(t.is_finite() && d.is_finite() && t.abs() <= DIVERGENCE_THRUST_N && d.abs() <= DIVERGENCE_RATE_N_PER_S)
            {
                self.failed = true;
                let at = self.time_s() + (i + 1) as f64 * h;
                return Err(self.diverged(at));
            }
            self.sense(t_start, t);
            substep_thrust_n(t);
        }
        self.state = State { thrust_n: t, thrust_rate_n_per_s: d };
        self.steps += 1;
        Ok(PlantSample {
            state: self.state,
            measured_n: self.measured_n(),
            engine_throttle_pct: if shaped { self.path.followed_pct() } else { throttle_pct },
        })
    }

    /// [`PlantEngine::step_with`] of `N` ten-parameter engines with the same substeps, at
    /// step `k` of their runs, each lane's operations those of a step alone (the same
    /// values, bit for bit) and the lanes' RK4 stages side by side
    /// ([`crate::engine::rk4_step_lanes`]). Each substep's drive comes from
    /// `drive(engine, k, substep, held)`, `held` being the throttle map of the throttle
    /// held when the engine has no throttle path to run. Returns which lanes stepped; one
    /// that diverged is failed, its state where it was.
    #[inline(always)]
    fn step_lanes<const N: usize>(
        lanes: &mut [PlantEngine; N],
        throttle_pct: f64,
        k: usize,
        drive: impl Fn(&mut PlantEngine, usize, usize, Option<Drive>) -> Drive,
    ) -> [bool; N] {
        if !throttle_pct.is_finite() {
            return [false; N];
        }
        let mut held = [None; N];
        let (mut t, mut d) = ([0.0; N], [0.0; N]);
        for l in 0..N {
            let engine = &mut lanes[l];
            engine.path.push(throttle_pct);
            held[l] = (!engine.path.shapes()).then(|| engine.drive_of(throttle_pct));
            (t[l], d[l]) = (engine.state.thrust_n, engine.state.thrust_rate_n_per_s);
        }
        let substeps = lanes[0].substeps;
        let h = STEP_S / substeps as f64;
        let mut stepped = [true; N];
        let mut drives = [Drive::default(); N];
        for i in 0..substeps {
            for l in 0..N {
                let engine = &mut lanes[l];
                let mut lane_drive = drive(engine, k, i, held[l]);
                if engine.gain_per_s != 0.0 {
                    let t_mid = engine.t0_s + engine.steps as f64 * STEP_S + (i as f64 + 0.5) * h;
                    lane_drive.v *= 1.0 - engine.gain_per_s * t_mid;
                }
                drives[l] = lane_drive;
            }
            let t_start = t;
            let engines = &*lanes;
            (t, d) = rk4_step_lanes(t, d, h, |l, t, d| {
                let (p, drive) = (&engines[l].params, drives[l]);
                match engines[l].discrepancy {
                    None => p.f(t, d) + p.g(t, d) * drive.v,
                    Some(disc) => {
                        let g = p.g(t, d);
                        let history =
                            Histories { thrust_n: engines[l].history_n, throttle: engines[l].throttle_history };
                        disc.law.total(p.f(t, d) + g * drive.v, t, d, g, drive.v, drive.below, drive.above, history)
                    }
                }
            });
            for l in 0..N {
                if !stepped[l] {
                    continue;
                }
                if let Some(schedule) = lanes[l].schedule {
                    d[l] = schedule.bound(t[l], d[l]);
                }
                let (t, d) = (t[l], d[l]);
                if !(t.is_finite()
                    && d.is_finite()
                    && t.abs() <= DIVERGENCE_THRUST_N
                    && d.abs() <= DIVERGENCE_RATE_N_PER_S)
                {
                    lanes[l].failed = true;
                    stepped[l] = false;
                    continue;
                }
                if let Some(disc) = lanes[l].discrepancy {
                    let v = drives[l].v;
                    lanes[l].throttle_history = disc.throttle_history.advance(lanes[l].throttle_history, v, v);
                }
                lanes[l].sense(t_start[l], t);
            }
        }
        for l in 0..N {
            if stepped[l] {
                lanes[l].state = State { thrust_n: t[l], thrust_rate_n_per_s: d[l] };
                lanes[l].steps += 1;
            }
        }
        stepped
    }

    /// [`PlantEngine::step`] of a turbojet plant: the throttle path tick by tick, one RK4
    /// step of the turbojet per tick, the gain drift as a sagging combustion efficiency.
    fn step_turbojet(&mut self, mut engine: Turbojet, throttle_pct: f64) -> Result<PlantSample, ModelError> {
        let h = STEP_S / SUBSTEPS as f64;
        self.path.push(throttle_pct);
        let shaped = self.path.shapes();
        for i in 0..SUBSTEPS {
            let u = if shaped { self.path.tick(i) } else { throttle_pct };
            if self.gain_per_s != 0.0 {
                let t_mid = self.t0_s + self.steps as f64 * STEP_S + (i as f64 + 0.5) * h;
                engine.set_efficiency(1.0 - self.gain_per_s * t_mid);
            }
            let t_start = engine.params().thrust_at_speed_n(engine.state().speed);
            engine.substep(u, h);
            let t = engine.params().thrust_at_speed_n(engine.state().speed);
            if !t.is_finite() {
                self.failed = true;
                let at = self.time_s() + (i + 1) as f64 * h;
                return Err(self.diverged(at));
            }
            self.sense(t_start, t);
        }
        let sample = engine.sample();
        self.turbojet = Some(engine);
        self.state = State { thrust_n: sample.thrust_n, thrust_rate_n_per_s: sample.thrust_rate_n_per_s };
        self.steps += 1;
        Ok(PlantSample {
            state: self.state,
            measured_n: self.measured_n(),
            engine_throttle_pct: if shaped { self.path.followed_pct() } else { throttle_pct },
        })
    }

    /// The throttle map for a throttle the engine follows.
    fn drive_of(&self, u_pct: f64) -> Drive {
        drive_of(&self.params, self.discrepancy.as_ref(), u_pct)
    }

    /// Runs the throttle path over the ticks of substep `i` and averages the throttle
    /// map over them (a pure delay over a substep of several ticks in closed form).
    fn shaped_drive(&mut self, i: usize) -> Drive {
        if self.path.is_pure_delay() && self.ticks > 1 {
            return match self.path.window(i * self.ticks, self.ticks) {
                Window::Held(u) => self.drive_of(u),
                Window::Spans { early, late, early_weight: w } => {
                    let (late, early) = (self.drive_of(late), self.drive_of(early));
                    Drive {
                        v: w * early.v + (1.0 - w) * late.v,
                        below: w * early.below + (1.0 - w) * late.below,
                        above: w * early.above + (1.0 - w) * late.above,
                    }
                }
            };
        }
        if self.ticks == 1 {
            let u = self.path.tick(i);
            return self.drive_of(u);
        }
        let mut sum = Drive::default();
        let (params, discrepancy) = (self.params, self.discrepancy);
        self.path.ticks(i * self.ticks, self.ticks, |u| {
            let drive = drive_of(&params, discrepancy.as_ref(), u);
            sum.v += drive.v;
            sum.below += drive.below;
            sum.above += drive.above;
        });
        let n = self.ticks as f64;
        Drive { v: sum.v / n, below: sum.below / n, above: sum.above / n }
    }

    /// The sensor side and the thrust history, after the engine moved from `t0` to `t1`
    /// over a substep.
    #[inline(always)]
    fn sense(&mut self, t0: f64, t1: f64) {
        let frame_before = self.frame_n;
        match self.play_n {
            Some(play) => self.frame_n = self.frame_n.clamp(t1 - play, t1 + play),
            None => self.frame_n = t1,
        }
        if let Some(stand) = self.stand {
            (self.sensor_n, self.sensor_rate_n_per_s) =
                stand.advance(self.sensor_n, self.sensor_rate_n_per_s, frame_before, self.frame_n);
        }
        if let Some((gain, bias)) = self.drift {
            self.bias_n = bias.advance(self.bias_n, gain * t0, gain * t1);
        }
        if let Some(disc) = self.discrepancy {
            self.history_n = disc.history.advance(self.history_n, t0, t1);
        }
    }

    fn diverged(&self, time_s: f64) -> ModelError {
        ModelError::Diverged {
            time_s,
            thrust_n: self.state.thrust_n,
            thrust_rate_n_per_s: self.state.thrust_rate_n_per_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Effect, Engine, Preset};

    fn effect(s: &str) -> Effect {
        s.parse().unwrap()
    }

    fn with(spec: &[&str]) -> Effects {
        Effects::new(spec.iter().map(|s| effect(s))).unwrap()
    }

    fn step_input() -> Vec<f64> {
        steps(1600)
    }

    /// 30 % for 1 s, 90 % until 8 s, then 40 % for the rest of `rows`.
    fn steps(rows: usize) -> Vec<f64> {
        (0..rows)
            .map(|k| {
                if k < 100 {
                    30.0
                } else if k < 800 {
                    90.0
                } else {
                    40.0
                }
            })
            .collect()
    }

    fn run_with(plant: &Plant, u: &[f64], substeps: usize) -> Vec<f64> {
        let initial = State { thrust_n: plant.rest_thrust_n(u[0]), thrust_rate_n_per_s: 0.0 };
        let mut out = Vec::new();
        assert!(plant.free_run_with(substeps, 0.0, initial, u, &mut out).is_none());
        out
    }

    fn run(plant: &Plant, u: &[f64]) -> Vec<f64> {
        run_with(plant, u, SUBSTEPS)
    }

    #[test]
    fn a_frame_started_in_the_play_band_stays_there_until_the_thrust_moves_it() {
        // 30 % held, then 90 %: a frame started at the bottom of a 2 N band reads 2 N low
        // through the hold, and from the first rise on it trails by the band as from the
        // middle; a place outside the band is held to its edge.
        let p = Preset::P100Diesel.params();
        let plant = Plant::new(p, with(&["bearing_friction:force_n=2"]));
        let u: Vec<f64> = (0..600).map(|k| if k < 300 { 30.0 } else { 90.0 }).collect();
        let initial = State { thrust_n: plant.rest_thrust_n(30.0), thrust_rate_n_per_s: 0.0 };
        let read = |place: f64| {
            let mut out = Vec::new();
            let slow = SlowStart { play_position: place, ..SlowStart::SETTLED };
            assert!(plant.free_run_from(SUBSTEPS, 0.0, initial, slow, &u, &mut out).is_none());
            out
        };
        let (centred, bottom, beyond) = (read(0.0), read(-1.0), read(-3.0));
        for k in 0..300 {
            assert!((centred[k] - initial.thrust_n).abs() < 1e-9, "row {k}: on the thrust");
            assert!((bottom[k] - initial.thrust_n + 2.0).abs() < 1e-9, "row {k}: the band below it");
        }
        assert_eq!(bottom, beyond, "held to the band");
        for k in 400..600 {
            assert!((bottom[k] - centred[k]).abs() < 1e-9, "row {k}: the rise pushed both to the band's bottom");
        }
        // Where the engine is now in the band: what a run that carries on would start from.
        let mut engine = plant.engine_from(initial, SlowStart { play_position: -1.0, ..SlowStart::SETTLED }, 30.0, 0.0);
        assert!((engine.slow_states().play_position + 1.0).abs() < 1e-12);
        for _ in 0..100 {
            assert!(engine.step(90.0).is_ok());
        }
        assert!((engine.slow_states().play_position + 1.0).abs() < 1e-9, "trailing the rise");
    }

    #[test]
    fn a_slower_spool_down_leaves_the_run_up_and_the_rest_alone() {
        // 30 % → 90 % → 40 %: the run-up as the plain engine's until the thrust first falls (its
        // overshoot settles slower), the run-down slower, the same thrust at rest after each.
        let p = Preset::P100Diesel.params();
        let u = steps(3000);
        let plain = run(&Plant::new(p, Effects::none()), &u);
        let slow = run(&Plant::new(p, with(&["discrepancy:spool_down=-0.4"])), &u);
        let first_fall = (100..800).find(|&k| plain[k + 1] < plain[k]).unwrap_or(800);
        assert!(first_fall > 200, "the run-up lasts: {first_fall}");
        for k in 0..first_fall {
            assert!((slow[k] - plain[k]).abs() < 1e-9, "row {k}: the run-up differs, {} vs {}", slow[k], plain[k]);
        }
        let (top, bottom) = (plain[799], plain[2999]);
        assert!(
            (slow[799] - top).abs() < 0.05 && (slow[2999] - bottom).abs() < 0.01,
            "{top} {bottom}: {} {}",
            slow[799],
            slow[2999]
        );
        // Half-way down: the plain engine gets there first.
        let half = 0.5 * (top + bottom);
        let reach = |y: &[f64]| (800..3000).find(|&k| y[k] <= half).unwrap();
        let (fast, late) = (reach(&plain), reach(&slow));
        assert!(late > fast + 5, "half-way down at row {late}, the plain engine at {fast}");
        // Faster: the other way.
        let quick = run(&Plant::new(p, with(&["discrepancy:spool_down=0.5"])), &u);
        assert!(reach(&quick) < fast, "{} vs {fast}", reach(&quick));
    }

    #[test]
    fn without_effects_the_plant_is_the_engine_bit_for_bit() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let sim = run(&Plant::new(p, Effects::none()), &u);
        let mut engine = Engine::at_equilibrium(p, u[0]);
        for (k, &uk) in u.iter().enumerate().take(u.len() - 1) {
            assert_eq!(engine.step(uk).unwrap().thrust_n.to_bits(), sim[k + 1].to_bits(), "row {k}");
        }
    }

    #[test]
    fn one_substep_follows_the_reference_for_every_effect() {
        // A campaign-like input: steps, a ramp and a fast sine.
        let u: Vec<f64> = (0..6000)
            .map(|k| {
                let t = k as f64 * STEP_S;
                match k / 1000 {
                    0 => 30.0,
                    1 => 95.0,
                    2 => 40.0 + 50.0 * (t - 20.0) / 10.0,
                    3 => 60.0 + 20.0 * (2.0 * std::f64::consts::PI * 1.5 * t).sin(),
                    4 => 28.0,
                    _ => 75.0,
                }
            })
            .collect();
        for (preset, spec) in [
            (Preset::P100Diesel, vec![]),
            (Preset::P100Diesel, vec!["input_delay:delay_s=0.137"]),
            (Preset::P220Kerosene, vec!["actuator_lag:time_constant_s=0.25"]),
            (Preset::P100Diesel, vec!["rate_limit:up_pct_per_s=40,down_pct_per_s=80"]),
            (Preset::P220Kerosene, vec!["sensor_drift:gain=0.04,time_constant_s=30"]),
            (Preset::P100Diesel, vec!["gain_drift:per_minute=0.01"]),
            (Preset::P100Diesel, vec!["bearing_friction:force_n=1.5"]),
            (Preset::P100Diesel, vec!["stand_resonance:frequency_hz=4,damping_ratio=0.05"]),
            (Preset::P220Kerosene, vec!["stand_resonance:frequency_hz=30,damping_ratio=0.02"]),
            (Preset::P100Diesel, vec!["discrepancy:map_below=1,knot_below_pct=45"]),
            (Preset::P220Kerosene, vec!["discrepancy:gain_history_per_n=-0.0004,history_time_constant_s=40,B_TT=2e-6"]),
            (Preset::P100Diesel, vec!["input_delay:delay_s=0.08", "rate_limit:up_pct_per_s=60,down_pct_per_s=90"]),
        ] {
            let plant = Plant::new(preset.params(), with(&spec));
            let (fine, coarse) = (run(&plant, &u), run_with(&plant, &u, 1));
            let worst = fine.iter().zip(&coarse).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            assert!(worst < 0.01, "{spec:?}: 1 substep within {worst:.4} N of 10");
        }
    }

    #[test]
    fn a_coarse_engine_follows_the_fine_one_and_a_copy_reanchors() {
        let plant = Plant::new(Preset::P100Diesel.params(), with(&["input_delay:delay_s=0.05"]));
        let u = step_input();
        let mut fine = plant.at_equilibrium(u[0]);
        let mut coarse = plant.coarse_engine(fine.state(), u[0], 0.0, 2);
        for &u in &u {
            let (a, b) = (fine.step(u).unwrap(), coarse.step(u).unwrap());
            assert!((a.state.thrust_n - b.state.thrust_n).abs() < 0.05, "{:?} vs {:?}", a.state, b.state);
        }
        // A copy keeps the throttle history; a new state replaces thrust and rate only.
        let mut copy = plant.at_equilibrium(25.0);
        copy.clone_from(&fine);
        let state = State { thrust_n: 30.0, thrust_rate_n_per_s: 5.0 };
        copy.set_state(state);
        fine.set_state(state);
        for _ in 0..20 {
            assert_eq!(copy.step(40.0).unwrap(), fine.step(40.0).unwrap());
        }
    }

    #[test]
    fn a_delay_of_whole_rows_shifts_the_response() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        let delayed = run(&Plant::new(p, with(&["input_delay:delay_s=0.07"])), &u);
        for k in 0..u.len() - 7 {
            assert!((delayed[k + 7] - nominal[k]).abs() < 1e-9, "row {k}: {} vs {}", delayed[k + 7], nominal[k]);
        }
    }

    #[test]
    fn lag_and_rate_limit_slow_the_step_and_friction_holds_a_band() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        for spec in ["actuator_lag:time_constant_s=0.3", "rate_limit:up_pct_per_s=40,down_pct_per_s=80"] {
            let slow = run(&Plant::new(p, with(&[spec])), &u);
            assert!(slow[150] < nominal[150] - 1.0, "{spec}: {} vs {}", slow[150], nominal[150]);
            assert!(
                (slow[799] - nominal[799]).abs() < 0.5,
                "{spec} settles to the same thrust: {} vs {}",
                slow[799],
                nominal[799]
            );
        }
        let friction = run(&Plant::new(p, with(&["bearing_friction:force_n=2"])), &u);
        let gaps: Vec<f64> = friction.iter().zip(&nominal).map(|(m, t)| m - t).collect();
        assert!(gaps.iter().all(|g| g.abs() <= 2.0 + 1e-9));
        assert!((gaps[150] + 2.0).abs() < 1e-9, "rising: the frame trails by the band ({})", gaps[150]);
        assert!((gaps[850] - 2.0).abs() < 1e-9, "falling: it trails from above ({})", gaps[850]);
    }

    #[test]
    fn an_acceleration_schedule_paces_the_steps_within_its_bounds_and_leaves_the_rest_alone() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        let (up, down, exponent, offset) = (150.0, 80.0, 1.5, 5.0);
        let spec = format!("accel_schedule:up_n_per_s={up},down_n_per_s={down},exponent={exponent},offset_n={offset}");
        let plant = Plant::new(p, with(&[spec.as_str()]));
        let mut engine =
            plant.engine(State { thrust_n: plant.rest_thrust_n(u[0]), thrust_rate_n_per_s: 0.0 }, u[0], 0.0);
        let (mut at_bound, mut states) = (0, Vec::new());
        for &throttle in &u {
            let state = engine.step(throttle).expect("a paced engine stays bounded").state;
            let scale = ((state.thrust_n + offset) / SCHEDULE_REFERENCE_N).max(SCHEDULE_FLOOR).powf(exponent);
            let d = state.thrust_rate_n_per_s;
            assert!(
                d <= up * scale + 1e-9 && d >= -down * scale - 1e-9,
                "Ṫ {d} outside the bounds at {}",
                state.thrust_n
            );
            at_bound += usize::from((d - up * scale).abs() < 1e-9 || (d + down * scale).abs() < 1e-9);
            states.push(state);
        }
        assert!(at_bound > 20, "both steps run on the schedule for a while ({at_bound} cycles)");
        // On the way up and on the way down it lags the engine alone.
        let lag = |rows: std::ops::Range<usize>, sign: f64| {
            rows.map(|k| sign * (nominal[k] - states[k].thrust_n)).fold(f64::NEG_INFINITY, f64::max)
        };
        assert!(lag(100..800, 1.0) > 5.0, "the step up lags by {} N at most", lag(100..800, 1.0));
        assert!(lag(800..1600, -1.0) > 5.0, "the step down lags by {} N at most", lag(800..1600, -1.0));
        // Rest points are the engine's: before the steps and 8 s after the step down.
        for k in [99, 1599] {
            assert!(
                (states[k].thrust_n - nominal[k]).abs() < 0.05,
                "rest at row {k}: {} vs {}",
                states[k].thrust_n,
                nominal[k]
            );
        }
        let turbojet = Plant::with_turbojet(crate::turbojet::TurbojetParams::p100(), with(&[spec.as_str()]));
        assert!(turbojet.turbojet_conflict().is_some_and(|(kind, _)| kind == EffectKind::AccelSchedule));
    }

    #[test]
    fn sensor_drift_settles_to_its_gain_and_gain_drift_sags() {
        let p = Preset::P100Diesel.params();
        let u = vec![90.0; 30_000];
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        let warm = run(&Plant::new(p, with(&["sensor_drift:gain=0.05,time_constant_s=20"])), &u);
        let bias = warm[29_999] - nominal[29_999];
        assert!((bias - 0.05 * nominal[29_999]).abs() < 0.01, "{bias}");
        let sag = run(&Plant::new(p, with(&["gain_drift:per_minute=0.01"])), &u);
        assert!(sag[29_999] < nominal[29_999] - 1.0 && (sag[100] - nominal[100]).abs() < 0.1);
    }

    #[test]
    fn a_started_slow_state_gives_the_reading_it_should() {
        let p = Preset::P220Kerosene.params();
        let u = step_input();
        let initial = State { thrust_n: Plant::new(p, Effects::none()).rest_thrust_n(u[0]), thrust_rate_n_per_s: 0.0 };
        let from = |plant: &Plant, slow: SlowStart, substeps: usize| {
            let mut out = Vec::new();
            assert!(plant.free_run_from(substeps, 0.0, initial, slow, &u, &mut out).is_none());
            out
        };
        // A bias started at b₀ adds b₀·e^(−t/τ) to the reading, and nothing else.
        let drift = Plant::new(p, with(&["sensor_drift:gain=0.04,time_constant_s=30"]));
        for substeps in [1, SUBSTEPS] {
            let (tared, warm) = (
                from(&drift, SlowStart::SETTLED, substeps),
                from(&drift, SlowStart { bias_n: 3.0, ..SlowStart::SETTLED }, substeps),
            );
            for (k, (a, b)) in tared.iter().zip(&warm).enumerate() {
                let expected = 3.0 * (-(k as f64) * STEP_S / 30.0).exp();
                assert!((b - a - expected).abs() < 1e-9, "row {k}: {} vs {expected}", b - a);
            }
        }
        // A history below the thrust (a cold engine) gives more thrust at first, through the
        // engine, the gap fading with the history's time constant (at a steady throttle).
        let soak = Plant::new(p, with(&["discrepancy:gain_history_per_n=-0.0004,history_time_constant_s=10"]));
        let steady = vec![60.0; 6000];
        let t60 = State { thrust_n: soak.rest_thrust_n(60.0), thrust_rate_n_per_s: 0.0 };
        let steady_from = |slow: SlowStart| {
            let mut out = Vec::new();
            assert!(soak.free_run_from(1, 0.0, t60, slow, &steady, &mut out).is_none());
            out
        };
        let (settled, cold) =
            (steady_from(SlowStart::SETTLED), steady_from(SlowStart { history_offset_n: -60.0, ..SlowStart::SETTLED }));
        let gaps: Vec<f64> = cold.iter().zip(&settled).map(|(c, s)| c - s).collect();
        let widest = gaps.iter().copied().fold(0.0, f64::max);
        assert!(widest > 0.05 && gaps.iter().all(|g| *g > -0.01), "more thrust at first: {widest}");
        assert!(gaps[5999] < 0.05 * widest, "it fades: {} after {widest}", gaps[5999]);
        // A plant without the state ignores its start.
        let plain = Plant::new(p, Effects::none());
        let odd = SlowStart { bias_n: 5.0, history_offset_n: -40.0, ..SlowStart::SETTLED };
        assert_eq!(from(&plain, SlowStart::SETTLED, 1), from(&plain, odd, 1));
        // An engine started from another's state and slow states carries on as it does.
        let plant = Plant::new(
            p,
            with(&[
                "sensor_drift:gain=0.05,time_constant_s=25",
                "discrepancy:gain_history_per_n=-0.0005,history_time_constant_s=30",
                "gain_drift:per_minute=0.01",
            ]),
        );
        let mut first = plant.at_equilibrium(30.0);
        for _ in 0..2000 {
            first.step(90.0).unwrap();
        }
        let slow = first.slow_states();
        assert!(slow.bias_n > 1.0 && slow.history_offset_n < -10.0, "on their way: {slow:?}");
        let mut second = plant.engine_from(first.state(), slow, 90.0, first.time_s());
        assert!((second.measured_n() - first.measured_n()).abs() < 1e-12);
        for k in 0..1000 {
            let (a, b) = (
                first.step(if k < 500 { 90.0 } else { 50.0 }).unwrap(),
                second.step(if k < 500 { 90.0 } else { 50.0 }).unwrap(),
            );
            assert!((a.measured_n - b.measured_n).abs() < 1e-9, "row {k}: {} vs {}", a.measured_n, b.measured_n);
        }
    }

    #[test]
    fn the_stand_is_an_exact_damped_oscillator() {
        // A unit step of the frame force: x(t) = 1 − e^(−ζωt)·(cos ω_d t + ζ/√(1 − ζ²)·sin ω_d t).
        let (f_hz, zeta, h) = (4.0, 0.05, 0.001);
        let stand = Stand::new(f_hz, zeta, h);
        let omega = 2.0 * std::f64::consts::PI * f_hz;
        let wd = omega * (1.0 - zeta * zeta).sqrt();
        let (mut x, mut xd) = (0.0, 0.0);
        (x, xd) = stand.advance(x, xd, 0.0, 1.0);
        // The first substep ramps the force up; from then on it is held at 1.
        let shift = h / 2.0;
        for k in 1..2000 {
            (x, xd) = stand.advance(x, xd, 1.0, 1.0);
            let t = (k + 1) as f64 * h - shift;
            let exact =
                1.0 - (-zeta * omega * t).exp() * ((wd * t).cos() + zeta / (1.0 - zeta * zeta).sqrt() * (wd * t).sin());
            assert!((x - exact).abs() < 0.01, "t = {t}: {x} vs {exact}");
        }
        // Overdamped and critically damped stands settle without overshoot.
        for zeta in [1.0, 3.0] {
            let stand = Stand::new(2.0, zeta, 0.01);
            let (mut x, mut xd) = (0.0, 0.0);
            for _ in 0..1000 {
                (x, xd) = stand.advance(x, xd, 1.0, 1.0);
                assert!(x <= 1.0 + 1e-12 && x.is_finite());
            }
            assert!((x - 1.0).abs() < 1e-6 && xd.abs() < 1e-6);
        }
    }

    #[test]
    fn the_stand_rings_after_a_step_and_settles_on_the_thrust() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let nominal = run(&Plant::new(p, Effects::none()), &u);
        let ringing = run(&Plant::new(p, with(&["stand_resonance:frequency_hz=4,damping_ratio=0.05"])), &u);
        let r: Vec<f64> = ringing.iter().zip(&nominal).map(|(a, b)| a - b).collect();
        assert!(r[101..300].iter().any(|x| x.abs() > 0.2), "it rings");
        assert!(r[780..800].iter().all(|x| x.abs() < 0.01), "and settles on the thrust");
    }

    #[test]
    fn a_discrepancy_dead_band_is_the_engine_on_a_clamped_throttle() {
        let p = Preset::P100Diesel.params();
        let u: Vec<f64> = step_input().iter().map(|u| u - 15.0).collect();
        let band = run(&Plant::new(p, with(&["discrepancy:map_below=1,knot_below_pct=45"])), &u);
        let clamped: Vec<f64> = u.iter().map(|u| u.max(45.0)).collect();
        let truth = run(&Plant::new(p, Effects::none()), &clamped);
        for (k, (a, b)) in band.iter().zip(&truth).enumerate() {
            assert!((a - b).abs() < 1e-6, "row {k}: {a} vs {b}");
        }
        // Heat soak: the gain sags with thrust history, so sustained thrust falls.
        let u: Vec<f64> = (0..12_000).map(|k| if k < 1000 { 30.0 } else { 90.0 }).collect();
        let soak =
            run(&Plant::new(p, with(&["discrepancy:gain_history_per_n=-0.0005,history_time_constant_s=30"])), &u);
        assert!(soak[11_999] < soak[1500] - 1.0, "{} after {}", soak[11_999], soak[1500]);
        let plant = Plant::new(p, with(&["discrepancy:gain_history_per_n=-0.0005,history_time_constant_s=30"]));
        let rest = plant.rest_thrust_n(90.0);
        let mut engine = plant.at_equilibrium(90.0);
        for _ in 0..500 {
            engine.step(90.0).unwrap();
        }
        assert!((engine.measured_n() - rest).abs() < 1e-6, "at rest: {} vs {rest}", engine.measured_n());
    }

    #[test]
    fn a_fuel_soak_follows_the_throttle_not_the_thrust() {
        let p = Preset::P100Diesel.params();
        let fuel = "discrepancy:gain_throttle_history_per_pct=-0.0005,throttle_history_time_constant_s=15";
        // The history starts settled at v(30 %): the engine holds its rest with that loss of
        // gain, below the model without it. The gain sags further while the throttle is held
        // high, so the thrust falls there.
        let u: Vec<f64> = (0..12_000).map(|k| if k < 1000 { 30.0 } else { 90.0 }).collect();
        let plant = Plant::new(p, with(&[fuel]));
        let (soak, nominal) = (run(&plant, &u), run(&Plant::new(p, Effects::none()), &u));
        let rest_30 = plant.rest_thrust_n(30.0);
        assert!((soak[990] - rest_30).abs() < 1e-6, "settled at the start: {} vs {rest_30}", soak[990]);
        assert!(soak[990] < nominal[990] - 0.1, "the settled loss: {} vs {}", soak[990], nominal[990]);
        assert!(soak[11_999] < soak[1500] - 1.0, "{} after {}", soak[11_999], soak[1500]);
        // Settled again, the history is v(90 %): the engine's gain g(T, Ṫ) times
        // 1 − 0.0005·v(90 %), at rest.
        let mut q = p.to_array();
        for b in &mut q[6..9] {
            *b *= 1.0 - 0.0005 * p.v(90.0); // B_U, B_T, B_D
        }
        let rest = Params::from_array(q).stable_equilibrium(90.0).unwrap();
        assert!((soak[11_999] - rest).abs() < 0.02, "{} vs {rest}", soak[11_999]);
    }

    fn turbojet_run(effects: &[&str], u: &[f64]) -> Vec<f64> {
        run(&Plant::with_turbojet(TurbojetParams::p100(), with(effects)), u)
    }

    #[test]
    fn a_turbojet_plant_without_effects_is_the_turbojet_bit_for_bit() {
        let u = step_input();
        let sim = turbojet_run(&[], &u);
        let mut engine = Turbojet::at_rest(TurbojetParams::p100(), u[0]);
        assert_eq!(sim[0], engine.sample().thrust_n);
        for (k, &uk) in u.iter().enumerate().take(u.len() - 1) {
            assert_eq!(engine.step(uk).thrust_n.to_bits(), sim[k + 1].to_bits(), "row {k}");
        }
        let plant = Plant::with_turbojet(TurbojetParams::p100(), Effects::none());
        assert_eq!(plant.rest_thrust_n(100.0), 100.0);
        let mut e = plant.at_equilibrium(60.0);
        let s = e.step(60.0).unwrap();
        assert!((s.state.thrust_n - plant.rest_thrust_n(60.0)).abs() < 1e-9, "at rest: {:?}", s.state);
        let spool = e.turbojet().expect("a turbojet plant reports its spool");
        assert!((spool.rpm - TurbojetParams::p100().governed_speed(60.0) * 154_000.0).abs() < 1.0);
        assert!(Plant::new(Preset::P100Diesel.params(), Effects::none()).at_equilibrium(60.0).turbojet().is_none());
    }

    #[test]
    fn the_catalogue_applies_to_a_turbojet_plant() {
        let u = step_input();
        let nominal = turbojet_run(&[], &u);
        let delayed = turbojet_run(&["input_delay:delay_s=0.08"], &u);
        for k in 0..u.len() - 8 {
            assert!((delayed[k + 8] - nominal[k]).abs() < 1e-9, "row {k}: {} vs {}", delayed[k + 8], nominal[k]);
        }
        // The lag acts on the throttle the turbojet's governor reads, as on the polynomial
        // plant's: the plant is the bare turbojet fed, tick by tick, the lagged command.
        let lagged = turbojet_run(&["actuator_lag:time_constant_s=0.3"], &u);
        let mut engine = Turbojet::at_rest(TurbojetParams::p100(), u[0]);
        let (alpha, mut followed) = (1.0 - (-0.001f64 / 0.3).exp(), u[0]);
        for (k, &uk) in u.iter().enumerate().take(u.len() - 1) {
            for _ in 0..SUBSTEPS {
                followed += (uk - followed) * alpha;
                engine.substep(followed, STEP_S / SUBSTEPS as f64);
            }
            assert!((engine.sample().thrust_n - lagged[k + 1]).abs() < 1e-9, "row {k}");
        }
        // A full step's rise is paced by the fuel schedule, not by the throttle, so a lag
        // shorter than the spool's acceleration barely shows there (0.03 N at 0.3 s): it
        // shows on the way down and inside the governor's range, and settles on the same
        // thrust. (The polynomial plant's lag check, 5 N at 0.3 s into the rise, does not
        // transfer: that engine has no schedule.)
        assert!(lagged[820] > nominal[820] + 5.0, "falling: {} vs {}", lagged[820], nominal[820]);
        assert!((lagged[799] - nominal[799]).abs() < 0.05 && (lagged[1599] - nominal[1599]).abs() < 0.05);
        let small: Vec<f64> = (0..600).map(|k| if k < 100 { 60.0 } else { 66.0 }).collect();
        let (nominal_small, lagged_small) =
            (turbojet_run(&[], &small), turbojet_run(&["actuator_lag:time_constant_s=0.3"], &small));
        let rise = |y: &[f64]| (y[130] - y[99]) / (y[599] - y[99]);
        // The spool settles a 6 % step within 0.3 s, so the lagged engine follows the lag's
        // own step response, 1 − e⁻¹ of the way at one time constant.
        let (fast, slow) = (rise(&nominal_small), rise(&lagged_small));
        assert!(fast > 0.95 && (slow - (1.0 - (-1.0f64).exp())).abs() < 0.1, "a small step lags: {fast} vs {slow}");
        assert!((nominal_small[599] - lagged_small[599]).abs() < 0.05);
        // Bearing friction: the stand's frame stays within the play of the thrust and moves
        // only when the thrust pushes it, so it trails a rise by the band and a fall from
        // above. The governor overshoots a full step by a few tenths of a newton: the frame
        // stays where the overshoot's peak pushed it.
        let friction = turbojet_run(&["bearing_friction:force_n=2"], &u);
        for (k, (f, n)) in friction.iter().zip(&nominal).enumerate() {
            assert!((f - n).abs() <= 2.0 + 1e-9, "row {k}: {f} outside the play of {n}");
        }
        assert!((friction[150] - nominal[150] + 2.0).abs() < 1e-9, "rising: trails by the band");
        assert!((friction[820] - nominal[820] - 2.0).abs() < 1e-9, "falling: trails from above");
        let peak = nominal[100..800].iter().copied().fold(f64::MIN, f64::max);
        assert!(peak > nominal[799] && friction[700] >= peak - 2.0 - 1e-9, "held by the overshoot's peak {peak}");
        // A gain drift sags the combustion efficiency. The governor holds the spool's speed,
        // so the thrust stays where it was (its integral follows a drift this slow), and the
        // lost efficiency shows as more fuel and a hotter exhaust for the same speed, as on a
        // wearing engine: after a minute at 5 %/min, fuel up by 1/0.95 and the exhaust by
        // egt_overfuel_c·(1/0.95 − 1) ≈ 26 °C.
        let params = TurbojetParams::p100();
        let sagging = Plant::with_turbojet(params, with(&["gain_drift:per_minute=0.05"]));
        let mut engine = sagging.at_equilibrium(60.0);
        let start = engine.turbojet().expect("a turbojet");
        for _ in 0..6000 {
            engine.step(60.0).unwrap();
        }
        let after = engine.turbojet().expect("a turbojet");
        let hotter = params.egt_overfuel_c * (1.0 / 0.95 - 1.0);
        assert!((after.thrust_n - start.thrust_n).abs() < 0.05, "{start:?} → {after:?}");
        assert!((after.fuel / start.fuel - 1.0 / 0.95).abs() < 0.005, "{start:?} → {after:?}");
        assert!((after.egt_c - start.egt_c - hotter).abs() < 2.0, "{start:?} → {after:?}");
        let warm = turbojet_run(&["sensor_drift:gain=0.05,time_constant_s=5"], &vec![90.0; 6000]);
        assert!((warm[5999] - 1.05 * TurbojetParams::p100().rest_thrust_n(90.0)).abs() < 0.05);
        let plant = Plant::with_turbojet(TurbojetParams::p100(), with(&["discrepancy:map_below=1,knot_below_pct=45"]));
        assert!(plant.turbojet_conflict().is_some_and(|(_, m)| m.contains("turbojet")));
    }

    #[test]
    fn a_reanchored_turbojet_settles_from_the_new_thrust() {
        let plant = Plant::with_turbojet(TurbojetParams::p100(), Effects::none());
        let mut e = plant.at_equilibrium(50.0);
        e.set_state(State { thrust_n: 60.0, thrust_rate_n_per_s: 0.0 });
        let first = e.step(50.0).unwrap().state.thrust_n;
        assert!((first - 60.0).abs() < 3.0, "starts near the new thrust: {first}");
        for _ in 0..1000 {
            e.step(50.0).unwrap();
        }
        assert!((e.state().thrust_n - plant.rest_thrust_n(50.0)).abs() < 0.01);
    }

    /// A run on kept drives reads what a full run reads, bit for bit: drives kept by a plant
    /// that differs in everything the drive does not depend on (the other parameters, a gain
    /// drift, the sensor side, the discrepancy's other terms), over the whole run and a
    /// prefix; and a plant whose drive differs (another rate limit, `B_UU`, throttles) runs
    /// its own path instead of reading the kept one.
    #[test]
    fn a_run_on_kept_drives_is_the_full_run_bit_for_bit() {
        let p = Preset::P100Diesel.params();
        let path = [
            "input_delay:delay_s=0.037",
            "rate_limit:up_pct_per_s=60,down_pct_per_s=90",
            "actuator_lag:time_constant_s=0.15",
        ];
        let hinges =
            "discrepancy:map_below=0.5,knot_below_pct=45,gain_history_per_n=-0.0004,history_time_constant_s=20";
        let keeper = Plant::new(p, with(&[&path[..], &[hinges]].concat()));
        let mut other = p.to_array();
        other[0] *= 1.02;
        other[6] *= 0.98;
        let reader = Plant::new(
            Params::from_array(other),
            with(
                &[
                    &path[..],
                    &[
                        "discrepancy:map_below=0.5,knot_below_pct=45,gain_history_per_n=-0.0002,history_time_constant_s=40",
                        "gain_drift:per_minute=0.01",
                        "stand_resonance:frequency_hz=3,damping_ratio=0.05",
                    ],
                ]
                .concat(),
            ),
        );
        for substeps in [1, 2, SUBSTEPS] {
            assert!(keeper.drive_key(substeps).is_some() && keeper.drive_key(substeps) == reader.drive_key(substeps));
        }
        let u = step_input();
        let initial = State { thrust_n: keeper.rest_thrust_n(u[0]), thrust_rate_n_per_s: 0.0 };
        let slow = SlowStart { bias_n: 0.0, history_offset_n: -2.0, ..SlowStart::SETTLED };
        for substeps in [1, SUBSTEPS] {
            let (mut track, mut out, mut expected) = (DriveTrack::default(), Vec::new(), Vec::new());
            assert!(keeper
                .free_run_keeping(substeps, 1.0, initial, slow, &u, &mut out, None, Some(&mut track))
                .is_none());
            assert!(keeper.free_run_from(substeps, 1.0, initial, slow, &u, &mut expected).is_none());
            assert_eq!(out, expected, "the keeping run itself");
            for len in [u.len(), 700] {
                assert!(reader.free_run_from(substeps, 1.0, initial, slow, &u[..len], &mut expected).is_none());
                let (mut got, mut thrust_n) = (Vec::new(), Vec::new());
                let kept = track.drives.clone();
                reader.free_run_keeping(
                    substeps,
                    1.0,
                    initial,
                    slow,
                    &u[..len],
                    &mut got,
                    Some(&mut thrust_n),
                    Some(&mut track),
                );
                assert_eq!(got, expected, "{substeps} substeps, {len} samples");
                assert_eq!(track.drives.len(), kept.len(), "read, not run again");
                assert_eq!(thrust_n.len(), (len - 1) * if substeps == 1 { 1 } else { SUBSTEPS });
            }
            // Another drive: the kept one is not read.
            let faster = Plant::new(p, with(&[path[0], "rate_limit:up_pct_per_s=61,down_pct_per_s=90", path[2]]));
            let mut curved = p.to_array();
            curved[9] += 1e-4;
            let curved = Plant::new(Params::from_array(curved), with(&path));
            let moved: Vec<f64> = u.iter().map(|x| x + 1.0).collect();
            for (plant, u) in [(&faster, &u), (&curved, &u), (&keeper, &moved)] {
                let mut fresh = track.clone();
                assert!(plant.free_run_from(substeps, 1.0, initial, slow, u, &mut expected).is_none());
                assert!(plant
                    .free_run_keeping(substeps, 1.0, initial, slow, u, &mut out, None, Some(&mut fresh))
                    .is_none());
                assert_eq!(out, expected, "{substeps} substeps");
                assert!(fresh.holds(plant.drive_key(substeps).unwrap(), &u[..u.len() - 1], (u.len() - 1) * substeps));
            }
        }
        // Without a throttle path there is nothing to keep.
        assert_eq!(Plant::new(p, with(&["gain_drift:per_minute=0.01"])).drive_key(1), None);
    }

    /// A sensor side run on a kept engine path reads what a full run of that plant reads,
    /// bit for bit: with an engine side that shapes the throttle and has a thrust history,
    /// every sensor-side effect changed, over the whole run and a prefix of it.
    #[test]
    fn the_sensor_side_replayed_on_a_kept_path_is_the_full_run_bit_for_bit() {
        let p = Preset::P100Diesel.params();
        let engine =
            ["actuator_lag:time_constant_s=0.2", "discrepancy:gain_history_per_n=-0.0005,history_time_constant_s=30"];
        let recorded = Plant::new(p, with(&engine));
        let sensor = [
            "bearing_friction:force_n=1.5",
            "stand_resonance:frequency_hz=3,damping_ratio=0.05",
            "sensor_drift:gain=0.03,time_constant_s=40",
        ];
        let replayed = Plant::new(p, with(&[&engine[..], &sensor[..]].concat()));
        assert_eq!(recorded.engine_side(), replayed.engine_side());
        let u = step_input();
        let initial = State { thrust_n: recorded.rest_thrust_n(u[0]), thrust_rate_n_per_s: 0.0 };
        let slow = SlowStart { bias_n: 0.4, history_offset_n: -3.0, ..SlowStart::SETTLED };
        let (mut out, mut path, mut expected, mut got) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        assert!(recorded.free_run_recorded(1, 2.0, initial, slow, &u, &mut out, &mut path).is_none());
        for len in [u.len(), 700] {
            assert!(replayed.free_run_from(1, 2.0, initial, slow, &u[..len], &mut expected).is_none());
            replayed.replay_sensor(1, initial, slow, &path, len, None, &mut got);
            assert_eq!(got, expected, "{len} samples");
        }
    }

    /// Plants stepped in lockstep give the readings (and divergences) of each run alone, bit
    /// for bit: on kept drives and on their own paths, at 1 and 10 substeps, for an odd
    /// count, every effect, a plant that diverges beside others and a turbojet.
    #[test]
    fn runs_in_lockstep_are_runs_alone_bit_for_bit() {
        let p = Preset::P100Diesel.params();
        let u = step_input();
        let path = ["rate_limit:up_pct_per_s=60,down_pct_per_s=90", "actuator_lag:time_constant_s=0.15"];
        let params = |i: usize, factor: f64| {
            let mut a = p.to_array();
            a[i] *= factor;
            Params::from_array(a)
        };
        let over_path = |extra: &[&str]| with(&[&path[..], extra].concat());
        // One throttle path and map: the others differ in what acts after the drive.
        let alike = [
            Plant::new(p, over_path(&[])),
            Plant::new(params(0, 1.02), over_path(&["gain_drift:per_minute=0.01"])),
            Plant::new(
                params(6, 0.98),
                over_path(&[
                    "discrepancy:gain_history_per_n=-0.0004,history_time_constant_s=20",
                    "stand_resonance:frequency_hz=3,damping_ratio=0.05",
                ]),
            ),
            Plant::new(p, over_path(&["sensor_drift:gain=0.05,time_constant_s=25", "bearing_friction:force_n=2"])),
            Plant::new(p, over_path(&["accel_schedule:up_n_per_s=60,down_n_per_s=80,exponent=1.5,offset_n=5"])),
            // Unstable: it diverges within the run, beside plants that do not.
            Plant::new(params(0, -1.0), over_path(&[])),
        ];
        // Each on its own path (or none).
        let apart = [
            Plant::new(p, with(&["rate_limit:up_pct_per_s=40,down_pct_per_s=80"])),
            Plant::new(p, with(&["input_delay:delay_s=0.037", "gain_drift:per_minute=-0.02"])),
            Plant::new(
                params(9, 1.5),
                with(&[
                    "actuator_lag:time_constant_s=0.3",
                    "discrepancy:map_below=0.5,knot_below_pct=45,gain_history_per_n=-0.0004,history_time_constant_s=20",
                ]),
            ),
            Plant::new(
                p,
                with(&["discrepancy:gain_throttle_history_per_pct=-0.001,throttle_history_time_constant_s=15"]),
            ),
            Plant::new(p, with(&["stand_resonance:frequency_hz=3,damping_ratio=0.05"])),
            Plant::with_turbojet(TurbojetParams::p100(), with(&[path[0]])),
        ];
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let rest_n = Plant::new(p, Effects::none()).rest_thrust_n(u[0]);
        for substeps in [1, SUBSTEPS] {
            // Five: four in lockstep and one alone; three: a pair and one; the unstable plant
            // in a pair and alone; a turbojet among them: each alone.
            let counts = [(&alike[..], true), (&alike[..3], true), (&alike[1..], true), (&alike[3..], true)];
            for (plants, kept) in
                counts.into_iter().chain([(&apart[..4], false), (&apart[1..4], false), (&apart[..], false)])
            {
                let starts: Vec<(State, SlowStart)> = (0..plants.len())
                    .map(|i| {
                        let state = State { thrust_n: rest_n + i as f64, thrust_rate_n_per_s: 0.0 };
                        (state, SlowStart { bias_n: 0.3, history_offset_n: -2.0, ..SlowStart::SETTLED })
                    })
                    .collect();
                let mut track = DriveTrack::default();
                if kept {
                    let (state, slow) = starts[0];
                    plants[0].free_run_keeping(substeps, 1.0, state, slow, &u, &mut Vec::new(), None, Some(&mut track));
                }
                let refs: Vec<&Plant> = plants.iter().collect();
                let (mut outs, mut diverged_s) = (vec![Vec::new(); plants.len()], vec![None; plants.len()]);
                let lockstep = |drives: &DriveTrack, outs: &mut [Vec<f64>], diverged_s: &mut [Option<f64>]| {
                    Plant::free_runs_in_lockstep(&refs, substeps, 1.0, &starts, &u, Some(drives), outs, diverged_s)
                };
                lockstep(&track, &mut outs, &mut diverged_s);
                for (i, plant) in plants.iter().enumerate() {
                    let mut alone = Vec::new();
                    let (state, slow) = starts[i];
                    let diverged = plant.free_run_from(substeps, 1.0, state, slow, &u, &mut alone);
                    assert_eq!(bits(&outs[i]), bits(&alone), "plant {i}, {substeps} substeps");
                    assert_eq!(diverged_s[i], diverged, "plant {i}, {substeps} substeps");
                    assert_eq!(
                        diverged.is_some(),
                        std::ptr::eq(plant, &alike[5]),
                        "plant {i} diverges, only the unstable"
                    );
                }
                if kept {
                    // The kept drives are what the plants read: other drives, other readings.
                    let mut other = track.clone();
                    other.drives.iter_mut().for_each(|d| d.v *= 1.01);
                    lockstep(&other, &mut outs, &mut diverged_s);
                    let mut alone = Vec::new();
                    plants[1].free_run_from(substeps, 1.0, starts[1].0, starts[1].1, &u, &mut alone);
                    assert_ne!(bits(&outs[1]), bits(&alone), "{substeps} substeps");
                }
            }
        }
    }

    #[test]
    fn rk4_in_lanes_is_rk4_bit_for_bit() {
        let accel = |l: usize, t: f64, d: f64| -0.7 * t - (0.3 + l as f64) * d * d.abs() + 11.0 / (1.0 + t * t);
        let (mut t, mut d) = ([1.0, -3.5, 40.0], [0.25, 7.0, -120.0]);
        for _ in 0..1000 {
            let alone: Vec<(f64, f64)> = (0..3).map(|l| rk4_step(t[l], d[l], 0.01, |t, d| accel(l, t, d))).collect();
            (t, d) = rk4_step_lanes(t, d, 0.01, accel);
            for l in 0..3 {
                assert_eq!((t[l].to_bits(), d[l].to_bits()), (alone[l].0.to_bits(), alone[l].1.to_bits()), "lane {l}");
            }
        }
    }
}
