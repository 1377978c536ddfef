//! Sim-bench's algorithm: the simulated engine (the plant with its effects),
//! its throttle board and its force sensor, stepped 10 ms at a time. Plain code
//! that never touches the bus; [`super::SimBenchService`] runs it in real time,
//! [`crate::synthetic`] faster than real time.

use jetbench_io::board::{self, Frame, Throttle};
use jetbench_io::emulate::BoardFirmware;
use jetbench_io::ForceReading;
use jetbench_model::{ModelError, Plant, PlantEngine, PlantSample, State, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use jetbench_msgs::SimTruth;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// The throttle board of runs stepped in code (synthetic recordings, the tests): the
/// board's own firmware ([`BoardFirmware`], the code the live simulated bench runs
/// behind its pseudo-terminal), fed the frames actuation's driver would send. It is
/// armed by the first command, outputs the throttle to the board's 0.01 % resolution,
/// and idles by its own watchdog when frames stop.
#[derive(Debug, Clone, Default)]
pub struct SimBoard {
    firmware: BoardFirmware,
    seq: u16,
    frame: Vec<u8>,
    replies: Vec<u8>,
}

impl SimBoard {
    /// Powered up, disarmed.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sends a throttle command at `now_ns`, arming the board first if it is not; a
    /// throttle outside 0..=100 % or not finite is no valid frame, as on the wire.
    pub fn receive(&mut self, throttle_pct: f64, now_ns: u64) {
        let Some(throttle) = Throttle::from_pct(throttle_pct.clamp(0.0, THROTTLE_MAX_PCT)) else {
            return;
        };
        if !self.firmware.is_armed() {
            self.send(Frame::Arm { seq: self.seq }, now_ns);
        }
        self.send(Frame::SetThrottle { seq: self.seq, throttle }, now_ns);
    }

    fn send(&mut self, frame: Frame, now_ns: u64) {
        self.seq = self.seq.wrapping_add(1);
        self.frame.clear();
        board::encode_into(&frame, &mut self.frame);
        self.firmware.receive(&self.frame, now_ns, &mut self.replies, |_, _| {});
        self.replies.clear();
    }

    /// The throttle the board drives at `now_ns` (its watchdog run first); the engine
    /// ECU treats no signal, or anything below idle, as idle.
    pub fn output_pct(&mut self, now_ns: u64) -> f64 {
        self.firmware.tick(now_ns, &mut self.replies);
        self.replies.clear();
        self.firmware.output(now_ns).map_or(THROTTLE_MIN_PCT, |t| t.pct().max(THROTTLE_MIN_PCT))
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
pub struct SimBenchStep {
    engine: PlantEngine,
    board: SimBoard,
    sensor: SimForceSensor,
}

impl SimBenchStep {
    /// `plant` starts at rest at `initial_throttle_pct` (effects settled there),
    /// measured by `sensor`.
    pub fn new(plant: &Plant, sensor: SimForceSensor, initial_throttle_pct: f64) -> Self {
        SimBenchStep { engine: plant.at_equilibrium(initial_throttle_pct), board: SimBoard::new(), sensor }
    }

    /// What the engine's spool and exhaust do now, when the plant is a turbojet (the
    /// ten-parameter model has neither: the ECU derives them from the thrust).
    pub fn turbojet(&self) -> Option<jetbench_model::turbojet::TurbojetSample> {
        self.engine.turbojet()
    }

    /// One 10 ms step at `now_ns`: apply the newest throttle frame (if any),
    /// advance the engine, and sample the sensor (its reading, effects included).
    pub fn step(&mut self, now_ns: u64, throttle_frame: Option<f64>) -> Result<(ForceReading, SimTruth), ModelError> {
        if let Some(t) = throttle_frame {
            self.board.receive(t, now_ns);
        }
        let throttle_pct = self.board.output_pct(now_ns);
        self.step_driven(now_ns, throttle_pct)
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
    /// A sensor noise variance that is negative or not finite, N².
    #[error("sensor noise variance {0} N^2 must be finite and >= 0")]
    Noise(f64),
}

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_model::{Effects, Preset};

    #[test]
    fn board_idles_after_its_watchdog() {
        let mut b = SimBoard::new();
        assert_eq!(b.output_pct(0), THROTTLE_MIN_PCT, "disarmed at power-up");
        b.receive(80.0, 0);
        assert_eq!(b.output_pct(100_000_000), 80.0);
        assert_eq!(b.output_pct(100_000_001), THROTTLE_MIN_PCT);
        b.receive(f64::NAN, 150_000_000);
        assert_eq!(b.output_pct(150_000_000), THROTTLE_MIN_PCT, "a NaN frame is not a valid frame");
        b.receive(12.3456, 200_000_000);
        assert_eq!(b.output_pct(200_000_000), THROTTLE_MIN_PCT, "below idle drives idle");
        b.receive(73.4567, 210_000_000);
        assert_eq!(b.output_pct(210_000_000), 73.46, "the board's resolution is 0.01 %");
        b.receive(130.0, 220_000_000);
        assert_eq!(b.output_pct(220_000_000), THROTTLE_MAX_PCT, "clamped to the engine's range");
    }
    /// The time the true thrust takes to rise 5 N after a throttle step from idle
    /// to 80 % commanded at 1 s, as the board applies it.
    fn rise_time_s(plant: &Plant) -> (f64, f64) {
        let mut sim = SimBenchStep::new(plant, SimForceSensor::new(0.0, [0.0; 6], 1).unwrap(), 25.0);
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
