//! The simulated bench: engine, force sensor, throttle board and ECU in real time.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use jetbench_bus::{Publisher, Wake};
use jetbench_io::can::source::CanForceSink;
use jetbench_io::emulate::{EcuModel, PtyBoard, PtyEcu};
use jetbench_io::ForceSink;
use jetbench_msgs::{channels, ServiceId, SimTruth};

use super::SimBenchStep;
use crate::config::{sim_port_link, Devices};
use crate::inject::FaultySensor;
use crate::runtime::clock::{monotonic_ns, PERIOD, STALL};
use crate::runtime::{Context, Schedule, Service, ServiceError, Setup};

/// File that, while it exists, unplugs sim-bench's force sensor (it stops
/// sending frames): `touch` it to test the silent-sensor path, remove it and
/// the frames come back. In the run's sim folder (`config::sim_port_link`).
pub const SENSOR_UNPLUGGED_FILE: &str = "sensor-unplugged";

/// Sim-bench: the engine ([`SimBenchStep`]) stepped on its own clock, its
/// force sensor sending real CAN frames, the throttle board and the ECU each
/// on its own pty pair, published where actuation opens them.
pub struct SimBenchService {
    sim: SimBenchStep,
    /// Injected faults between the sensor and its frames (`--inject`).
    faults: FaultySensor,
    /// Frames injected with each fault, by [`jetbench_msgs::sim_faults`] bit.
    injected: [u64; 4],
    sensor: CanForceSink,
    unplugged: Unplugged,
    board: PtyBoard,
    ecu_model: EcuModel,
    ecu: PtyEcu,
    truth: Publisher<SimTruth>,
    next: Instant,
}

impl Service for SimBenchService {
    const ID: ServiceId = ServiceId::SimBench;
    type Inputs = ();

    fn new(setup: &Setup<'_>) -> Result<(Self, ()), ServiceError> {
        let config = setup.config;
        if config.bench.devices != Devices::Sim {
            return Err(ServiceError::Setup("sim-bench runs only with [bench] devices = \"sim\"".into()));
        }
        let sim = SimBenchStep::new(&config.plant()?, config.plant.sensor()?, config.plant.initial_throttle_pct);
        let plan = config.plant.faults().map_err(|e| ServiceError::Setup(e.to_string()))?;
        if !plan.is_empty() {
            tracing::warn!("injecting sensor faults: {plan}");
        }
        // The force sensor: real CAN frames on the configured interface (the
        // userspace bus here, vcan or can0 where the kernel has CAN).
        let interface =
            config.sensor.interface(config.bench.devices).map_err(|e| ServiceError::Setup(e.to_string()))?;
        let codec = config.sensor.codec().map_err(|e| ServiceError::Setup(e.to_string()))?;
        tracing::info!("force sensor sends CAN frames (base {:#x}) on {interface}", codec.base_id());
        let sensor = CanForceSink::open(&interface, codec)?;
        // The throttle board and the ECU, each on its own pty pair, published
        // where actuation opens them (see `config::sim_port_link`).
        let board = PtyBoard::spawn(&config.board_port(), monotonic_ns)?;
        let ecu_model = EcuModel::settled(0.0, config.plant.initial_throttle_pct);
        let ecu = PtyEcu::spawn(&config.ecu_port(), ecu_model.reading())?;
        tracing::info!("throttle board on {}, ECU on {}", board.link().display(), ecu.link().display());
        let bench = SimBenchService {
            sim,
            faults: FaultySensor::new(plan),
            injected: [0; 4],
            sensor,
            unplugged: Unplugged::new(sim_port_link(SENSOR_UNPLUGGED_FILE)),
            board,
            ecu_model,
            ecu,
            truth: setup.bus.publisher(channels::SIM_TRUTH)?,
            next: Instant::now(),
        };
        Ok((bench, ()))
    }

    fn schedule(&self) -> Schedule {
        Schedule::SelfPaced
    }

    fn start(&mut self, _ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        self.next = Instant::now() + PERIOD;
        Ok(())
    }

    fn process(&mut self, _wake: Wake, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        if !ctx.bus().sleep_until(self.next) {
            return Ok(());
        }
        self.tick(ctx)
    }

    /// Runs the bench down (see [`SimBench::run_down`]) and reports what its devices saw.
    fn stop(&mut self, _inputs: &(), ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        let run_down = self.run_down(ctx);
        let fw = self.board.firmware();
        let c = fw.counters();
        let status = fw.status(monotonic_ns());
        tracing::info!(
            "throttle board emulator: {} valid frames, {} commands applied, {} watchdog trips, {} at the end; \
             rejected: crc={} truncated={} bad_length={} unknown_type={} out_of_range={} garbage_bytes={}; \
             ECU emulator answered {} polls",
            c.frames,
            self.board.applied_count(),
            status.watchdog_trips,
            if fw.is_armed() { "armed" } else { "disarmed" },
            c.crc_errors,
            c.truncated,
            c.bad_length,
            c.unknown_type,
            c.out_of_range,
            c.garbage_bytes,
            self.ecu.polls()
        );
        if !self.faults.plan().is_empty() {
            let [spikes, stuck, nan, silent] = self.injected;
            tracing::info!(
                "injected sensor faults: {spikes} spikes, {stuck} stuck frames, {nan} NaN frames, {silent} silent frames"
            );
        }
        run_down
    }
}

/// The longest a stopping sim-bench runs on for its board to idle: the board's
/// own watchdog (100 ms) and a few cycles.
const RUN_DOWN: Duration = Duration::from_millis(300);

impl SimBenchService {
    /// One 10 ms step of the bench, at its scheduled time.
    fn tick(&mut self, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        let start_ns = ctx.woke();
        // A sensor keeps its own clock: after a scheduling hiccup the missed
        // ticks are caught up, so the frame rate holds. Only a real stall
        // (the machine frozen for longer than STALL) restarts the schedule.
        let now = Instant::now();
        let late = now > self.next + PERIOD;
        self.next = if now > self.next + STALL { now + PERIOD } else { self.next + PERIOD };
        // Idle while the board idles (disarmed, or its watchdog tripped).
        let throttle_pct = self.board.output_pct(start_ns).unwrap_or(jetbench_model::THROTTLE_MIN_PCT);
        let (reading, mut truth) = self.sim.step_driven(start_ns, throttle_pct).map_err(|e| {
            tracing::error!("the simulated engine failed: {e}");
            e
        })?;
        let injected = self.faults.apply(reading);
        (truth.faults, truth.injected_n) = (injected.faults, injected.injected_n);
        for (bit, count) in self.injected.iter_mut().enumerate() {
            *count += (injected.faults >> bit) & 1;
        }
        self.ecu_model.step(truth.thrust_n, truth.engine_throttle_pct, jetbench_model::STEP_S);
        self.ecu.set_reading(self.ecu_model.reading());
        if let (true, Some(reading)) = (self.unplugged.check(), injected.reading) {
            self.sensor.emit(&reading, start_ns)?;
        }
        ctx.publish(&mut self.truth, truth, |_, _| {})?;
        ctx.cycle(late)?;
        Ok(())
    }

    /// A bench outlives the processes that drive it: when sim-bench is asked to
    /// stop, its engine, board and sensor run on until the board drives idle
    /// (actuation disarmed it, or its own watchdog tripped; at most
    /// [`RUN_DOWN`]), so that `sim/truth` shows the engine brought to idle
    /// whatever stopped the set, a launcher killed with every service at once too.
    fn run_down(&mut self, ctx: &mut Context<'_>) -> Result<(), ServiceError> {
        let deadline = Instant::now() + RUN_DOWN;
        while self.board.output_pct(monotonic_ns()).is_some() && Instant::now() < deadline {
            std::thread::sleep(self.next.saturating_duration_since(Instant::now()));
            self.tick(ctx)?;
        }
        // One more step, so the idle engine is on record.
        self.tick(ctx)
    }
}

/// The unplug marker file: watched every cycle, each change logged once.
struct Unplugged {
    file: PathBuf,
    unplugged: bool,
}

impl Unplugged {
    fn new(file: PathBuf) -> Self {
        // A marker left by an earlier run must not start this one unplugged.
        let _ = std::fs::remove_file(&file);
        Unplugged { file, unplugged: false }
    }

    /// True while the sensor is plugged in.
    fn check(&mut self) -> bool {
        let unplugged = self.file.exists();
        if unplugged != self.unplugged {
            self.unplugged = unplugged;
            if unplugged {
                tracing::warn!("force sensor unplugged ({} exists): no frames", self.file.display());
            } else {
                tracing::info!("force sensor plugged back in");
            }
        }
        !unplugged
    }
}
