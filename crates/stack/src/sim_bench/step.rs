//! Sim-bench's algorithm: the simulated engine (the plant with its effects),
//! its throttle board and its force sensor, stepped 10 ms at a time. Plain code
//! that never touches the bus; [`super::SimBenchService`] runs it in real time,
//! [`crate::synthetic`] faster than real time.

use jetbench_io::ForceReading;
use jetbench_model::{ModelError, Plant, PlantEngine, PlantSample, State, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use jetbench_msgs::SimTruth;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

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
pub struct SimBenchStep {
    engine: PlantEngine,
    board: BoardEmulator,
    sensor: SimForceSensor,
}

impl SimBenchStep {
    /// `plant` starts at rest at `initial_throttle_pct` (effects settled there),
    /// measured by `sensor`.
    pub fn new(plant: &Plant, sensor: SimForceSensor, initial_throttle_pct: f64) -> Self {
        SimBenchStep { engine: plant.at_equilibrium(initial_throttle_pct), board: BoardEmulator::new(), sensor }
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
    use jetbench_model::{Effects, Preset};

    #[test]
    fn board_idles_after_its_watchdog() {
        let mut b = BoardEmulator::new();
        b.receive(80.0, 0);
        assert_eq!(b.output_pct(100_000_000), 80.0);
        assert_eq!(b.output_pct(100_000_001), THROTTLE_MIN_PCT);
        b.receive(f64::NAN, 150_000_000);
        assert_eq!(b.output_pct(150_000_000), THROTTLE_MIN_PCT, "a NaN frame is not a valid frame");
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
