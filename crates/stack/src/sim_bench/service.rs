//! The simulated bench: engine, force sensor, throttle board and ECU in real time.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use jetbench_bus::{Publisher, Wake};
use jetbench_io::can::source::CanForceSink;
use jetbench_io::ecu::emulator::{EcuEmulator, EcuParams};
use jetbench_io::ecu::state::EcuState;
use jetbench_io::emulate::{PtyBoard, PtyEcu};
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

/// File that, while it exists, silences sim-bench's ECU (it answers no poll,
/// like an ECU that lost power or its cable), in the run's sim folder.
pub const ECU_UNPLUGGED_FILE: &str = "ecu-unplugged";

/// Frames sent with each kind of injected sensor fault, reported at exit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct InjectedCounts {
    spikes: u64,
    stuck: u64,
    nan: u64,
    silent: u64,
    offset: u64,
}

impl InjectedCounts {
    /// Counts one frame by its [`jetbench_msgs::sim_faults`] flags.
    fn count(&mut self, faults: u64) {
        use jetbench_msgs::sim_faults as f;
        let add = |count: &mut u64, flag: u64| *count += u64::from(faults & flag != 0);
        add(&mut self.spikes, f::SPIKE);
        add(&mut self.stuck, f::STUCK);
        add(&mut self.nan, f::NAN);
        add(&mut self.silent, f::SILENCE);
        add(&mut self.offset, f::OFFSET);
    }
}

/// Sim-bench: the engine ([`SimBenchStep`]) stepped on its own clock, its
/// force sensor sending real CAN frames, the throttle board and the ECU each
/// on its own pty pair, published where actuation opens them.
pub struct SimBenchService {
    sim: SimBenchStep,
    /// Injected faults between the sensor and its frames (`--inject`).
    faults: FaultySensor,
    /// Frames sent with each injected fault.
    injected: InjectedCounts,
    sensor: CanForceSink,
    unplugged: Unplugged,
    ecu_unplugged: Unplugged,
    board: PtyBoard,
    /// The emulated ECU ([`EcuEmulator`]) on its pty, clocked by the bench's clock.
    ecu: PtyEcu,
    /// The ECU state last logged.
    ecu_state: EcuState,
    /// The ECU's clock starts here (monotonic ns): its faults' times count from it.
    ecu_t0_ns: u64,
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
        let (ecu, ecu_t0_ns) = Self::spawn_ecu(config)?;
        tracing::info!("throttle board on {}, ECU on {}", board.link().display(), ecu.link().display());
        let bench = SimBenchService {
            sim,
            faults: FaultySensor::new(plan),
            injected: InjectedCounts::default(),
            sensor,
            unplugged: Unplugged::new(sim_port_link(SENSOR_UNPLUGGED_FILE), "force sensor"),
            ecu_unplugged: Unplugged::new(sim_port_link(ECU_UNPLUGGED_FILE), "ECU"),
            board,
            ecu_state: ecu.with_emulator(|e| e.state()).unwrap_or(EcuState::Off),
            ecu_t0_ns,
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
            let InjectedCounts { spikes, stuck, nan, silent, offset } = self.injected;
            tracing::info!(
                "injected sensor faults: {spikes} spikes, {stuck} stuck frames, {nan} NaN frames, {silent} silent frames, \
                 {offset} offset frames"
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
        let board_pct = self.board.output_pct(start_ns).unwrap_or(jetbench_model::THROTTLE_MIN_PCT);
        // The ECU gets the board's signal (no signal reads as idle) and the
        // engine follows it only while the ECU runs it; otherwise it idles.
        let now_s = start_ns.saturating_sub(self.ecu_t0_ns) as f64 * 1e-9;
        let running = self.ecu.with_emulator(|e| {
            let _ = e.throttle(board_pct, now_s);
            e.state().is_running()
        });
        let throttle_pct = if running == Some(true) { board_pct } else { jetbench_model::THROTTLE_MIN_PCT };
        let (reading, mut truth) = self.sim.step_driven(start_ns, throttle_pct).map_err(|e| {
            tracing::error!("the simulated engine failed: {e}");
            e
        })?;
        let injected = self.faults.apply(reading);
        (truth.faults, truth.injected_n) = (injected.faults, injected.injected_n);
        self.injected.count(injected.faults);
        // Unplugged by its marker file, or silenced by `--inject ecu:silent_at_s=...`.
        let injected_silence = self.ecu.with_emulator(|e| e.faults().silent(now_s)).unwrap_or(false);
        self.ecu.set_silent(!self.ecu_unplugged.check() || injected_silence);
        match self.sim.turbojet() {
            // A turbojet plant has its own spool and exhaust: the ECU reports them.
            Some(engine) => {
                let now_s = monotonic_ns().saturating_sub(self.ecu_t0_ns) as f64 * 1e-9;
                self.ecu.with_emulator(|e| e.step_with_engine(now_s, truth.thrust_n, Some((engine.rpm, engine.egt_c))));
            }
            None => self.ecu.step(truth.thrust_n),
        }
        self.log_ecu_state();
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

/// Shaft speed of the emulated engine at the plant's full thrust, rev/min (a
/// P100's is about 115 000; the emulated ECU's over-RPM is 5 % above 125 000).
pub const FULL_RPM: f64 = 115_000.0;
/// Exhaust temperature of the emulated engine at the plant's full thrust, °C
/// (the emulated ECU's over-temperature is 800 °C).
pub const FULL_EGT_C: f64 = 750.0;

impl SimBenchService {
    /// The emulated ECU on its pty: sized for the plant (full thrust at
    /// [`FULL_RPM`] and [`FULL_EGT_C`], below the ECU's own limits), its
    /// faults from `--inject ecu:...`, running from the start or off
    /// (`[engine] start`), clocked in seconds since now.
    fn spawn_ecu(config: &crate::config::BenchConfig) -> Result<(PtyEcu, u64), ServiceError> {
        let faults = config.plant.ecu_faults().map_err(|e| ServiceError::Setup(e.to_string()))?;
        if !faults.is_empty() {
            tracing::warn!("injecting ECU faults: {faults:?}");
        }
        let plant = config.plant()?;
        let full_n = plant.rest_thrust_n(jetbench_model::THROTTLE_MAX_PCT);
        let full_n = if full_n.is_finite() { full_n.max(1.0) } else { 100.0 };
        let mut params = EcuParams::default();
        params.rpm_per_sqrt_n = (FULL_RPM - params.idle_rpm) / full_n.sqrt();
        params.egt_per_n = (FULL_EGT_C - params.idle_egt_c) / full_n;
        if let Some(turbojet) = &plant.turbojet {
            // The ECU of that engine: its idle and full speed, its idle exhaust; the
            // start sequence ends at its idle speed.
            for phase in params.phases.iter_mut().filter(|p| p.rpm == params.idle_rpm) {
                phase.rpm = turbojet.rpm_idle;
            }
            (params.idle_rpm, params.max_rpm) = (turbojet.rpm_idle, turbojet.rpm_max);
            params.idle_egt_c = turbojet.egt_idle_c;
        }
        let t0 = monotonic_ns();
        let clock = move || monotonic_ns().saturating_sub(t0) as f64 * 1e-9;
        let emulator = if config.engine.start == crate::config::EngineStart::Running {
            EcuEmulator::running(params, faults, 0.0)
        } else {
            EcuEmulator::new(params, faults, 0.0)
        };
        tracing::info!("emulated ECU {} at power-up", emulator.state());
        Ok((PtyEcu::emulated(&config.ecu_port(), emulator, clock)?, t0))
    }

    /// Logs each state the emulated ECU enters, with the reason when it stops.
    fn log_ecu_state(&mut self) {
        let Some((state, off)) = self.ecu.with_emulator(|e| (e.state(), e.off_condition())) else { return };
        if state != self.ecu_state {
            if state.is_stopping() {
                tracing::info!("emulated ECU: {} -> {state} ({off})", self.ecu_state);
            } else {
                tracing::info!("emulated ECU: {} -> {state}", self.ecu_state);
            }
            self.ecu_state = state;
        }
    }
}

/// The unplug marker file: watched every cycle, each change logged once.
struct Unplugged {
    file: PathBuf,
    what: &'static str,
    unplugged: bool,
}

impl Unplugged {
    fn new(file: PathBuf, what: &'static str) -> Self {
        // A marker left by an earlier run must not start this one unplugged.
        let _ = std::fs::remove_file(&file);
        Unplugged { file, what, unplugged: false }
    }

    /// True while the sensor is plugged in.
    fn check(&mut self) -> bool {
        let unplugged = self.file.exists();
        if unplugged != self.unplugged {
            self.unplugged = unplugged;
            if unplugged {
                tracing::warn!("{} unplugged ({} exists): silent", self.what, self.file.display());
            } else {
                tracing::info!("{} plugged back in", self.what);
            }
        }
        !unplugged
    }
}
