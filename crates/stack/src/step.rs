//! The step logic of every service: plain structs that never touch IPC.
//!
//! The same code runs live (wired to the bus by [`crate::service`]), in
//! replay and in tests. Time comes in as arguments, never from a clock.

use jetbench_control::{Controller, Law, Profile};
use jetbench_estim::{EstimError, ObserverConfig, ThrustObserver, Verdict};
use jetbench_io::{Acknowledgement, ForceReading};
use jetbench_model::{
    ModelError, Params, Plant, PlantEngine, PlantSample, State, STEP_S, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT,
};
use jetbench_msgs::{
    actuation_flags, command_flags, sensor_status, state_flags, thrust_flags, Actuation, Command, Reference, SimTruth,
    StateEstimate, Thrust,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::clock::PERIOD_NS;
use crate::config::SensorSection;
use crate::inject::FaultPlan;
use jetbench_io::calib::{Calibration, CalibrationError};

/// Why sensing rejected a reading.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SensingError {
    #[error("force reading is not finite: {0:?}")]
    NonFinite([f64; 3]),
}

/// Sensing: calibrates a force/torque reading into a thrust sample, and
/// keeps track of the sensor's frame counter and of silences.
#[derive(Debug, Clone)]
pub struct Sensing {
    axis: usize,
    calibration: Calibration,
    last: Option<(u32, u64)>,
    frame_seq: u64,
    silent_since_ns: Option<u64>,
    /// Injected driver faults (the simulated bench only): readings made NaN.
    faults: FaultPlan,
}

impl Sensing {
    /// With the section's calibration matrix, tare and thrust axis.
    pub fn new(sensor: &SensorSection) -> Result<Self, CalibrationError> {
        Ok(Sensing {
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
    /// [`Sensing::silent`] sets `SENSOR_RESUMED`.
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

/// Estimation: the EKF observer of `[T, Ṫ]` on thrust samples.
#[derive(Debug, Clone)]
pub struct Estimation {
    observer: ThrustObserver,
    applied_pct: Option<f64>,
}

impl Estimation {
    pub fn new(params: Params, config: ObserverConfig) -> Self {
        Estimation { observer: ThrustObserver::new(params, config), applied_pct: None }
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
    OpenLoop { throttle_pct: Vec<f64>, model: Params },
}

/// Control: the reference profile and the control law.
#[derive(Debug)]
pub struct Control {
    law: ControlLaw,
    profile: Profile,
    start_ns: Option<u64>,
    fallbacks: u64,
}

impl Control {
    pub fn new(law: Law, profile: Profile) -> Self {
        Control::with_law(ControlLaw::Closed(Box::new(law)), profile)
    }

    pub fn with_law(law: ControlLaw, profile: Profile) -> Self {
        Control { law, profile, start_ns: None, fallbacks: 0 }
    }

    /// True once an open-loop profile has been played to its end.
    pub fn finished(&self, profile_time_s: f64) -> bool {
        match &self.law {
            ControlLaw::OpenLoop { throttle_pct, .. } => profile_time_s / STEP_S >= throttle_pct.len() as f64 - 0.5,
            ControlLaw::Closed(_) => false,
        }
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
                let command = jetbench_control::Command {
                    throttle_pct: applied,
                    unclamped_pct: u,
                    virtual_input: model.v(applied),
                    saturated: applied != u,
                };
                (r, command, Controller::OpenLoop.code(), false, 0.0)
            }
        };
        let mut flags = 0;
        if c.saturated {
            flags |= if c.unclamped_pct < THROTTLE_MIN_PCT || c.unclamped_pct.is_nan() {
                command_flags::SATURATED_LOW
            } else {
                command_flags::SATURATED_HIGH
            };
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

/// Actuation: applies commands, and idles when they stop coming.
#[derive(Debug, Clone)]
pub struct Actuator {
    idle_after_missed: u32,
    missed: u32,
    last: Option<Command>,
}

impl Actuator {
    pub fn new(idle_after_missed: u32) -> Self {
        Actuator { idle_after_missed: idle_after_missed.max(1), missed: 0, last: None }
    }

    /// A fresh command: apply it (clamped to the engine range).
    pub fn on_command(&mut self, command: &Command) -> Actuation {
        self.missed = 0;
        self.last = Some(*command);
        let applied_pct = if command.throttle_pct.is_finite() {
            command.throttle_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT)
        } else {
            THROTTLE_MIN_PCT
        };
        self.output(applied_pct, 0)
    }

    /// A cycle without a fresh command, at `now_ns`: hold the last one, and
    /// after `idle_after_missed` such cycles command idle. Before any command
    /// the sample is stamped `now_ns` (a recording dates it by its stamp).
    pub fn on_missed(&mut self, now_ns: u64) -> Actuation {
        self.missed = self.missed.saturating_add(1);
        let mut out = match self.last {
            Some(c) if self.missed < self.idle_after_missed => {
                self.output(c.throttle_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT), actuation_flags::STALE)
            }
            _ => self.output(THROTTLE_MIN_PCT, actuation_flags::STALE | actuation_flags::IDLE_FALLBACK),
        };
        if self.last.is_none() {
            out.stamp_ns = now_ns;
        }
        out
    }

    /// Completes this cycle's sample with what the board acknowledged:
    /// `applied_pct` and `round_trip_ns` from the newest acknowledgement, and
    /// flags when the board has not acknowledged this cycle's command in time
    /// (`UNACKED`: the newest acknowledged value stands) or has said nothing
    /// for [`SILENT_AFTER`](jetbench_io::serial::SILENT_AFTER) cycles
    /// (`BOARD_SILENT`: the board idles by its own watchdog, so idle is reported).
    /// `ack = None` with zero counts (a device without acknowledgements)
    /// leaves the sample as it is.
    pub fn with_board(
        &self,
        mut out: Actuation,
        ack: Option<Acknowledgement>,
        unacked_writes: u32,
        silent_writes: u32,
    ) -> Actuation {
        if let Some(a) = ack {
            out.applied_pct = a.applied_pct;
            out.round_trip_ns = a.round_trip_ns;
            if a.idle_fallback {
                out.flags |= actuation_flags::BOARD_IDLE;
            }
        }
        if unacked_writes > 0 {
            out.flags |= actuation_flags::UNACKED;
        }
        if silent_writes >= jetbench_io::serial::SILENT_AFTER {
            out.flags |= actuation_flags::BOARD_SILENT;
            out.applied_pct = THROTTLE_MIN_PCT;
        }
        out
    }

    /// The sample of a stopped actuator: idle, whatever the last command was.
    pub fn on_stop(&self) -> Actuation {
        self.output(THROTTLE_MIN_PCT, actuation_flags::IDLE_FALLBACK)
    }

    /// True while idling for lack of commands.
    pub fn is_idle_fallback(&self) -> bool {
        self.missed >= self.idle_after_missed || (self.missed > 0 && self.last.is_none())
    }

    fn output(&self, applied_pct: f64, flags: u32) -> Actuation {
        let (stamp_ns, command_seq, commanded_pct) =
            self.last.map_or((0, 0, f64::NAN), |c| (c.stamp_ns, c.seq, c.throttle_pct));
        Actuation {
            seq: 0,
            stamp_ns,
            publish_ns: 0,
            written_ns: 0,
            command_seq,
            applied_pct,
            // No command yet: report idle rather than a NaN a reader must special-case.
            commanded_pct: if commanded_pct.is_nan() { THROTTLE_MIN_PCT } else { commanded_pct },
            round_trip_ns: 0,
            missed_cycles: self.missed,
            flags,
        }
    }
}

/// The simulated throttle board: applies valid frames, idles by itself when
/// none arrive for [`BoardEmulator::WATCHDOG_NS`].
#[derive(Debug, Clone)]
pub struct BoardEmulator {
    throttle_pct: f64,
    last_frame_ns: Option<u64>,
}

impl BoardEmulator {
    /// The board's own watchdog, as on the real board.
    pub const WATCHDOG_NS: u64 = jetbench_io::board::WATCHDOG_NS;

    pub fn new() -> Self {
        BoardEmulator { throttle_pct: THROTTLE_MIN_PCT, last_frame_ns: None }
    }

    /// Applies a frame received at `now_ns`.
    pub fn receive(&mut self, throttle_pct: f64, now_ns: u64) {
        if throttle_pct.is_finite() {
            self.throttle_pct = throttle_pct.clamp(0.0, THROTTLE_MAX_PCT);
            self.last_frame_ns = Some(now_ns);
        }
    }

    /// The throttle the board outputs at `now_ns`; the engine ECU treats
    /// anything below idle as idle.
    pub fn output_pct(&self, now_ns: u64) -> f64 {
        match self.last_frame_ns {
            Some(t) if now_ns.saturating_sub(t) <= Self::WATCHDOG_NS => self.throttle_pct.max(THROTTLE_MIN_PCT),
            _ => THROTTLE_MIN_PCT,
        }
    }
}

impl Default for BoardEmulator {
    fn default() -> Self {
        Self::new()
    }
}

/// The simulated force/torque sensor: the thrust on the x axis with Gaussian
/// noise, noise on the other axes, the sensor's offset at zero load, and its
/// frame counter. The one sensor of the simulated bench, of `jetbench tare`'s
/// sensor at rest, and of the synthetic recordings.
#[derive(Debug, Clone)]
pub struct SimForceSensor {
    rng: ChaCha8Rng,
    noise: Normal<f64>,
    cross_noise: Normal<f64>,
    /// Reading at zero load `[Fx, Fy, Fz, Tx, Ty, Tz]`, N and N·m.
    zero: [f64; 6],
    counter: u32,
}

/// Noise on the force axes that do not carry thrust, N (std-dev); the torques
/// get a hundredth of it in N·m.
const CROSS_AXIS_NOISE_N: f64 = 0.3;

impl SimForceSensor {
    /// Noise of variance `noise_var_n2` (N²) on the thrust axis, from `seed`;
    /// `zero` is the reading at zero load. Fails if the variance is negative or
    /// not finite.
    pub fn new(noise_var_n2: f64, zero: [f64; 6], seed: u64) -> Result<Self, SimError> {
        let bad_noise = |_| SimError::Noise(noise_var_n2);
        Ok(SimForceSensor {
            rng: ChaCha8Rng::seed_from_u64(seed),
            noise: Normal::new(0.0, noise_var_n2.sqrt()).map_err(bad_noise)?,
            cross_noise: Normal::new(0.0, CROSS_AXIS_NOISE_N).map_err(bad_noise)?,
            zero,
            counter: 0,
        })
    }

    /// One reading with `thrust_n` on the thrust axis; the frame counter advances.
    pub fn read(&mut self, thrust_n: f64) -> ForceReading {
        self.counter = self.counter.wrapping_add(1) & 0xff;
        let mut reading = ForceReading {
            force_n: [
                thrust_n + self.noise.sample(&mut self.rng),
                self.cross_noise.sample(&mut self.rng),
                self.cross_noise.sample(&mut self.rng),
            ],
            torque_nm: [
                0.01 * self.cross_noise.sample(&mut self.rng),
                0.01 * self.cross_noise.sample(&mut self.rng),
                0.01 * self.cross_noise.sample(&mut self.rng),
            ],
            counter: self.counter,
            status: 0,
        };
        for i in 0..3 {
            reading.force_n[i] += self.zero[i];
            reading.torque_nm[i] += self.zero[3 + i];
        }
        reading
    }
}

/// The simulated engine (with the plant's effects), throttle board and force sensor.
#[derive(Debug, Clone)]
pub struct SimBench {
    engine: PlantEngine,
    board: BoardEmulator,
    sensor: SimForceSensor,
}

impl SimBench {
    /// `plant` starts at rest at `initial_throttle_pct` (effects settled there),
    /// measured by `sensor`.
    pub fn new(plant: &Plant, sensor: SimForceSensor, initial_throttle_pct: f64) -> Self {
        SimBench { engine: plant.at_equilibrium(initial_throttle_pct), board: BoardEmulator::new(), sensor }
    }

    /// One 10 ms step at `now_ns`: apply the newest throttle frame (if any),
    /// advance the engine, and sample the sensor (its reading, effects included).
    pub fn step(&mut self, now_ns: u64, throttle_frame: Option<f64>) -> Result<(ForceReading, SimTruth), ModelError> {
        if let Some(t) = throttle_frame {
            self.board.receive(t, now_ns);
        }
        self.step_driven(now_ns, self.board.output_pct(now_ns))
    }

    /// One 10 ms step with the engine driven at `throttle_pct` by a board
    /// emulated elsewhere (sim-bench's pty board, which keeps its own
    /// watchdog); below idle counts as idle, as in the engine's ECU.
    pub fn step_driven(&mut self, now_ns: u64, throttle_pct: f64) -> Result<(ForceReading, SimTruth), ModelError> {
        let throttle_pct = if throttle_pct.is_finite() { throttle_pct.max(THROTTLE_MIN_PCT) } else { THROTTLE_MIN_PCT };
        let PlantSample { state: State { thrust_n, thrust_rate_n_per_s }, measured_n, engine_throttle_pct } =
            self.engine.step(throttle_pct)?;
        let reading = self.sensor.read(measured_n);
        let truth = SimTruth {
            seq: 0,
            stamp_ns: now_ns,
            thrust_n,
            thrust_rate_n_per_s,
            engine_throttle_pct,
            measured_thrust_n: measured_n,
            injected_n: 0.0,
            faults: 0,
        };
        Ok((reading, truth))
    }
}

/// Why the simulated bench cannot start.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error("sensor noise variance {0} N^2 must be finite and >= 0")]
    Noise(f64),
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_control::LawSettings;
    use jetbench_model::{Effects, Preset};

    fn command(seq: u64, throttle_pct: f64) -> Command {
        Command { seq, stamp_ns: seq * 10_000_000, throttle_pct, ..Command::default() }
    }

    #[test]
    fn actuator_idles_on_the_third_missed_cycle() {
        let mut a = Actuator::new(3);
        let before_any = a.on_missed(7_000);
        assert_eq!((before_any.stamp_ns, before_any.command_seq), (7_000, 0), "stamped now, not at boot");
        let mut a = Actuator::new(3);
        let applied = a.on_command(&command(5, 70.0));
        assert_eq!(applied.applied_pct, 70.0);
        assert_eq!(applied.flags, 0);
        let m1 = a.on_missed(1);
        let m2 = a.on_missed(2);
        let m3 = a.on_missed(3);
        assert_eq!((m1.applied_pct, m2.applied_pct), (70.0, 70.0));
        assert_eq!(m1.flags & actuation_flags::IDLE_FALLBACK, 0);
        assert_eq!(m3.applied_pct, THROTTLE_MIN_PCT);
        assert_ne!(m3.flags & actuation_flags::IDLE_FALLBACK, 0);
        assert_eq!(m3.missed_cycles, 3);
        assert_eq!(m3.command_seq, 5);
        assert!(a.is_idle_fallback());
        // A fresh command ends the fallback.
        assert_eq!(a.on_command(&command(6, 40.0)).flags, 0);
        assert!(!a.is_idle_fallback());
    }

    #[test]
    fn actuation_reports_the_acknowledged_command_and_a_silent_board() {
        let a = Actuator::new(3);
        let out = Actuation { applied_pct: 42.345, ..Actuation::default() };
        let ack =
            Acknowledgement { seq: 9, applied_pct: 42.35, round_trip_ns: 180_000, armed: true, idle_fallback: false };
        let acked = a.with_board(out, Some(ack), 0, 0);
        assert_eq!((acked.applied_pct, acked.round_trip_ns, acked.flags), (42.35, 180_000, 0));
        let late = a.with_board(out, Some(ack), 5, 0);
        assert_eq!((late.applied_pct, late.flags), (42.35, actuation_flags::UNACKED), "slow but alive");
        let silent = a.with_board(out, Some(ack), 3, 3);
        assert_eq!(silent.applied_pct, THROTTLE_MIN_PCT);
        assert_eq!(silent.flags, actuation_flags::UNACKED | actuation_flags::BOARD_SILENT);
        let never = a.with_board(out, None, 1, 1);
        assert_eq!((never.applied_pct, never.flags), (42.345, actuation_flags::UNACKED));
        assert_eq!(a.with_board(out, None, 0, 0), out, "a device without acknowledgements");
    }

    #[test]
    fn actuator_clamps_and_rejects_nan() {
        let mut a = Actuator::new(3);
        assert_eq!(a.on_command(&command(1, 140.0)).applied_pct, THROTTLE_MAX_PCT);
        assert_eq!(a.on_command(&command(2, f64::NAN)).applied_pct, THROTTLE_MIN_PCT);
    }

    #[test]
    fn board_idles_after_its_watchdog() {
        let mut b = BoardEmulator::new();
        b.receive(80.0, 0);
        assert_eq!(b.output_pct(100_000_000), 80.0);
        assert_eq!(b.output_pct(100_000_001), THROTTLE_MIN_PCT);
        b.receive(f64::NAN, 150_000_000);
        assert_eq!(b.output_pct(150_000_000), THROTTLE_MIN_PCT, "a NaN frame is not a valid frame");
    }

    #[test]
    fn sensing_flags_frame_gaps_and_rejects_nan() {
        let mut s = Sensing::new(&SensorSection::default()).unwrap();
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
        let mut s = Sensing::new(&section).unwrap();
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

    /// The whole loop on the model, with the same step code the services run:
    /// sim-bench -> sensing -> estimation -> control -> actuation -> sim-bench.
    #[test]
    fn closed_loop_tracks_the_reference_with_every_law() {
        for kind in Controller::LAWS {
            closed_loop_tracks_the_reference(kind);
        }
    }

    fn closed_loop_tracks_the_reference(kind: Controller) {
        let params = Preset::P100Diesel.params();
        let plant = Plant::new(params, Effects::none());
        let config = crate::config::BenchConfig::default_sim().unwrap();
        let mut sim = SimBench::new(&plant, SimForceSensor::new(7.0, [0.0; 6], 3).unwrap(), 25.0);
        let mut sensing = Sensing::new(&config.sensor).unwrap();
        let mut estimation = Estimation::new(params, config.estimator.observer_config(0.0));
        let law = Law::new(kind, &plant, &LawSettings::default()).unwrap();
        let mut control = Control::new(law, config.reference.clone());
        let mut actuator = Actuator::new(3);
        let mut throttle = None;
        let mut errors = Vec::new();
        let steps = 3000; // 30 s
        for k in 0..steps {
            let now_ns = k * 10_000_000;
            let (reading, truth) = sim.step(now_ns, throttle).unwrap();
            let thrust = sensing.step(&reading, now_ns).unwrap();
            let state = estimation.step(&thrust).unwrap();
            let (reference, command) = control.step(&state).unwrap();
            let applied = actuator.on_command(&command);
            estimation.set_applied(applied.applied_pct);
            throttle = Some(applied.applied_pct);
            if k >= steps / 2 {
                errors.push((truth.thrust_n - reference.thrust_n).abs());
            }
        }
        errors.sort_by(f64::total_cmp);
        let median = errors[errors.len() / 2];
        let (lo, hi) = config.reference.span_n();
        assert!(median < 0.05 * (hi - lo), "{kind}: median error {median:.2} N over span {:.1} N", hi - lo);
        assert_eq!(control.fallbacks(), 0, "{kind}");
    }

    /// The time the true thrust takes to rise 5 N after a throttle step from idle
    /// to 80 % commanded at 1 s, as the board applies it.
    fn rise_time_s(plant: &Plant) -> (f64, f64) {
        let mut sim = SimBench::new(plant, SimForceSensor::new(0.0, [0.0; 6], 1).unwrap(), 25.0);
        let (_, rest) = sim.step(0, Some(25.0)).unwrap();
        let (mut rise_s, mut followed_s) = (f64::NAN, f64::NAN);
        for k in 1..300u64 {
            let now_ns = k * 10_000_000;
            let (reading, truth) = sim.step(now_ns, Some(if k >= 100 { 80.0 } else { 25.0 })).unwrap();
            assert_eq!(reading.force_n[0], truth.measured_thrust_n, "noise-free bench: the sensor reads the plant");
            if followed_s.is_nan() && truth.engine_throttle_pct > 50.0 {
                followed_s = now_ns as f64 * 1e-9;
            }
            if rise_s.is_nan() && truth.thrust_n > rest.thrust_n + 5.0 {
                rise_s = now_ns as f64 * 1e-9;
            }
        }
        (rise_s, followed_s)
    }

    #[test]
    fn an_input_delay_makes_the_bench_answer_later() {
        let params = Preset::P100Diesel.params();
        let (rise_s, followed_s) = rise_time_s(&Plant::new(params, Effects::none()));
        let delay = Effects::new(["input_delay:delay_s=0.2".parse().unwrap()]).unwrap();
        let (delayed_rise_s, delayed_followed_s) = rise_time_s(&Plant::new(params, delay));
        assert!((followed_s - 1.0).abs() < 1e-9, "without delay the engine follows at once: {followed_s}");
        assert!((delayed_followed_s - followed_s - 0.2).abs() < 0.015, "{delayed_followed_s} vs {followed_s}");
        assert!((delayed_rise_s - rise_s - 0.2).abs() < 0.015, "{delayed_rise_s} vs {rise_s}");
    }
}
