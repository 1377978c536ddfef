//! The runtime adapter of every service: wires a step struct to the bus.
//!
//! Each `run_*` function opens the bus, creates its ports, prints `ready`
//! on stdout (the launcher waits for it), and loops until SIGINT/SIGTERM.
//! Consumers sleep on their input's doorbell with a deadline; only sim-bench keeps time.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use jetbench_bus::{AnySubscriber, Bus, BusError, Flow, LoopExit, Publisher, Trigger, Wake};
use jetbench_io::can::source::{CanForceSink, CanForceSource};
use jetbench_io::can::RejectCounts;
use jetbench_io::emulate::{EcuModel, PtyBoard, PtyEcu};
use jetbench_io::serial::{EcuPoller, ThrottleBoard, SILENT_AFTER};
use jetbench_io::{DeviceError, ForceSink, ForceSource, ThrottleOutput};
use jetbench_msgs::{channels, command_flags, visit_channels, Channel, ChannelVisitor, Sample, ServiceId};
use jetbench_record::{spawn_writer, RawRecord, RecordError};

use crate::clock::{monotonic_ns, realtime_ns, PERIOD_NS};
use crate::config::{BenchConfig, ConfigError, Devices};
use crate::health::HealthReporter;
use crate::step::{Actuator, Control, ControlLaw, Estimation, Sensing, SimBench, SimError};

/// How long a consumer waits for its input before counting a missed cycle:
/// one and a half periods, so ordinary jitter is not a miss.
pub const INPUT_DEADLINE: Duration = Duration::from_millis(15);

/// How far behind its schedule sim-bench may fall before it stops catching up.
const STALL: Duration = Duration::from_millis(100);

/// Actuation's deadline: a missed cycle is counted every period after the
/// last command, plus a small margin for jitter.
pub const COMMAND_DEADLINE: Duration = Duration::from_millis(11);

/// Why a service stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Device(#[from] DeviceError),
    #[error(transparent)]
    Model(#[from] jetbench_model::ModelError),
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error("throttle profile: {0}")]
    Profile(#[from] jetbench_record::series::DataError),
    #[error(transparent)]
    ControlSetup(#[from] crate::config::ControlSetupError),
    #[error("{0}")]
    Other(String),
}

/// Tells the launcher this service's ports exist.
pub fn announce_ready() {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "ready");
    let _ = out.flush();
}

/// Logs the first few occurrences of a recurring error, then every 1000th.
fn log_rejection(count: u64, what: &str, error: &dyn std::fmt::Display) {
    if count <= 5 || count.is_multiple_of(1000) {
        tracing::warn!("{what} rejected ({count} so far): {error}");
    }
}

/// Publishes with `publish_ns` stamped right before the sample leaves.
fn publish_now<T: Sample>(publisher: &mut Publisher<T>, mut sample: T, set: fn(&mut T, u64)) -> Result<u64, BusError> {
    set(&mut sample, monotonic_ns());
    publisher.publish(sample)
}

/// The simulated bench: engine, sensor and throttle board in real time.
pub fn run_sim_bench(config: &BenchConfig) -> Result<(), ServiceError> {
    if config.bench.devices != Devices::Sim {
        return Err(ServiceError::Other("sim-bench runs only with [bench] devices = \"sim\"".into()));
    }
    let mut sim = SimBench::new(
        &config.plant()?,
        config.plant.noise_var_n2,
        config.plant.seed,
        config.plant.initial_throttle_pct,
    )?;
    let bus = Bus::open("sim-bench")?;
    // The force sensor: real CAN frames on the configured interface (the
    // userspace bus here, vcan or can0 where the kernel has CAN).
    let mut sensor = SimSensor::open(config)?;
    // The throttle board and the ECU, each on its own pty pair, published
    // where actuation opens them (see `config::sim_port_link`).
    let board = PtyBoard::spawn(&config.board_port(), monotonic_ns)?;
    let mut ecu_model = EcuModel::settled(0.0, config.plant.initial_throttle_pct);
    let ecu = PtyEcu::spawn(&config.ecu_port(), ecu_model.reading())?;
    tracing::info!("throttle board on {}, ECU on {}", board.link().display(), ecu.link().display());
    let mut truth_pub = bus.publisher(channels::SIM_TRUTH)?;
    let mut health = HealthReporter::new(&bus, ServiceId::SimBench)?;
    announce_ready();

    let period = Duration::from_nanos(PERIOD_NS);
    let mut next = Instant::now() + period;
    while bus.sleep_until(next) {
        let start_ns = monotonic_ns();
        // A sensor keeps its own clock: after a scheduling hiccup the missed
        // ticks are caught up, so the frame rate holds. Only a real stall
        // (the machine frozen for longer than STALL) restarts the schedule.
        let now = Instant::now();
        let late = now > next + period;
        next = if now > next + STALL { now + period } else { next + period };
        // Idle while the board idles (disarmed, or its watchdog tripped).
        let throttle_pct = board.output_pct(start_ns).unwrap_or(jetbench_model::THROTTLE_MIN_PCT);
        let (reading, truth) = sim.step_driven(start_ns, throttle_pct).map_err(|e| {
            tracing::error!("the simulated engine failed: {e}");
            e
        })?;
        ecu_model.step(truth.thrust_n, truth.engine_throttle_pct, PERIOD_NS as f64 * 1e-9);
        ecu.set_reading(ecu_model.reading());
        sensor.emit(&reading, start_ns)?;
        truth_pub.publish(truth)?;
        health.cycle(start_ns, monotonic_ns(), late)?;
    }
    let fw = board.firmware();
    let c = fw.counters();
    tracing::info!(
        "throttle board emulator: {} valid frames, {} commands applied; rejected: crc={} truncated={} bad_length={} \
         unknown_type={} out_of_range={} garbage_bytes={}; ECU emulator answered {} polls",
        c.frames,
        board.applied_count(),
        c.crc_errors,
        c.truncated,
        c.bad_length,
        c.unknown_type,
        c.out_of_range,
        c.garbage_bytes,
        ecu.polls()
    );
    Ok(())
}

/// File that, while it exists, unplugs sim-bench's force sensor (it stops
/// sending frames): `touch` it to test the silent-sensor path, remove it and
/// the frames come back. In the run's sim folder (`config::sim_port_link`).
pub const SENSOR_UNPLUGGED_FILE: &str = "sensor-unplugged";

/// Sim-bench's force sensor: adds the sensor's zero offset and sends the
/// reading as the two CAN frames, unless unplugged.
struct SimSensor {
    sink: CanForceSink,
    zero: [f64; 6],
    unplugged_file: std::path::PathBuf,
    unplugged: bool,
}

impl SimSensor {
    fn open(config: &BenchConfig) -> Result<Self, ServiceError> {
        let interface =
            config.sensor.interface(config.bench.devices).map_err(|e| ServiceError::Other(e.to_string()))?;
        let codec = config.sensor.codec().map_err(|e| ServiceError::Other(e.to_string()))?;
        let unplugged_file = crate::config::sim_port_link(SENSOR_UNPLUGGED_FILE);
        // A marker left by an earlier run must not start this one unplugged.
        let _ = std::fs::remove_file(&unplugged_file);
        tracing::info!("force sensor sends CAN frames (base {:#x}) on {interface}", codec.base_id());
        Ok(SimSensor {
            sink: CanForceSink::open(&interface, codec)?,
            zero: config.plant.sensor_zero,
            unplugged_file,
            unplugged: false,
        })
    }

    fn emit(&mut self, reading: &jetbench_io::ForceReading, now_ns: u64) -> Result<(), ServiceError> {
        let unplugged = self.unplugged_file.exists();
        if unplugged != self.unplugged {
            self.unplugged = unplugged;
            if unplugged {
                tracing::warn!("force sensor unplugged ({} exists): no frames", self.unplugged_file.display());
            } else {
                tracing::info!("force sensor plugged back in");
            }
        }
        if unplugged {
            return Ok(());
        }
        let mut r = *reading;
        for i in 0..3 {
            r.force_n[i] += self.zero[i];
            r.torque_nm[i] += self.zero[3 + i];
        }
        self.sink.emit(&r, now_ns)?;
        Ok(())
    }
}

/// Sensing: force/torque CAN frames in, `bench/thrust` out; clocked by the
/// sensor. A sensor silent for one input deadline (15 ms) is reported in
/// `bench/health` (input overdue) every deadline until it is back; the first
/// sample after it carries `SENSOR_RESUMED`. The link reopens by itself.
pub fn run_sensing(config: &BenchConfig) -> Result<(), ServiceError> {
    let bus = Bus::open("sensing")?;
    let interface = config.sensor.interface(config.bench.devices).map_err(|e| ServiceError::Other(e.to_string()))?;
    let codec = config.sensor.codec().map_err(|e| ServiceError::Other(e.to_string()))?;
    let mut source = CanForceSource::open(&interface, codec)?;
    tracing::info!("reading {}", source.describe());
    let mut step = Sensing::new(&config.sensor).map_err(|e| ServiceError::Other(format!("[sensor] {e}")))?;
    let mut thrust_pub = bus.publisher(channels::THRUST)?;
    let mut health = HealthReporter::new(&bus, ServiceId::Sensing)?;
    announce_ready();

    let mut seen = RejectCounts::default();
    let mut rejected = 0;
    while !bus.stop_requested() {
        let reading = source.read(INPUT_DEADLINE)?;
        let start_ns = monotonic_ns();
        match reading {
            Some(reading) => {
                if let Some(since) = step.silent_since_ns() {
                    let silent_ms = start_ns.saturating_sub(since) as f64 * 1e-6;
                    tracing::info!("force sensor back after {:.0} ms", silent_ms + INPUT_DEADLINE.as_secs_f64() * 1e3);
                }
                match step.step(&reading, start_ns) {
                    Ok(thrust) => {
                        publish_now(&mut thrust_pub, thrust, |t, ns| t.publish_ns = ns)?;
                    }
                    Err(e) => {
                        rejected += 1;
                        health.error();
                        log_rejection(rejected, "force reading", &e);
                    }
                }
                let counts = *source.counts();
                for _ in seen.frames_rejected()..counts.frames_rejected() {
                    health.error();
                }
                if counts != seen {
                    log_rejection(counts.frames_rejected() + counts.sequence_jump, "CAN frames", &counts);
                    seen = counts;
                }
                health.set_input_gaps(counts.lost_pairs);
                health.cycle(start_ns, monotonic_ns(), false)?;
            }
            // The sensor went quiet: say so every deadline.
            None => {
                if step.silent(start_ns) {
                    tracing::warn!("force sensor silent: no reading for {} ms", INPUT_DEADLINE.as_millis());
                }
                if step.silent_since_ns().is_some() {
                    health.cycle(start_ns, monotonic_ns(), true)?;
                }
            }
        }
    }
    let (frames, pairs) = source.frames_and_pairs();
    tracing::info!("force sensor: {frames} frames in, {pairs} readings; rejected: {}", source.counts());
    Ok(())
}

/// Runs a consumer loop and turns its first error into the result.
fn consume<F>(bus: &Bus, inputs: &[(&dyn Trigger, Option<Duration>)], mut on_wake: F) -> Result<(), ServiceError>
where
    F: FnMut(Wake) -> Result<(), ServiceError>,
{
    let mut failure = None;
    let exit = bus.run(inputs, None, |wake| match on_wake(wake) {
        Ok(()) => Flow::Continue,
        Err(e) => {
            failure = Some(e);
            Flow::Stop
        }
    })?;
    match (failure, exit) {
        (Some(e), _) => Err(e),
        (None, LoopExit::Stopped | LoopExit::Terminated) => Ok(()),
    }
}

/// Estimation: `bench/thrust` (and the newest `bench/actuation`, read with it) in, `bench/state` out.
pub fn run_estimation(config: &BenchConfig) -> Result<(), ServiceError> {
    let bus = Bus::open("estimation")?;
    let thrust_sub = bus.subscriber(channels::THRUST, 16)?;
    // Read with each thrust sample, never woken by: an actuation sample
    // arrives mid-cycle and has nothing to start.
    let actuation_sub = bus.polled_subscriber(channels::ACTUATION, 16)?;
    let mut state_pub = bus.publisher(channels::STATE)?;
    let mut health = HealthReporter::new(&bus, ServiceId::Estimation)?;
    let mut step = Estimation::new(config.model_params()?, config.estimator.observer_config());
    announce_ready();

    let mut started = false;
    let mut rejected = 0;
    consume(&bus, &[(&thrust_sub, Some(INPUT_DEADLINE))], |wake| {
        let start_ns = monotonic_ns();
        match wake {
            Wake::Input(0) => {
                if let Some(a) = actuation_sub.latest()? {
                    step.set_applied(a.applied_pct);
                }
                while let Some(thrust) = thrust_sub.try_recv()? {
                    started = true;
                    match step.step(&thrust) {
                        Ok(state) => {
                            publish_now(&mut state_pub, state, |s, ns| s.publish_ns = ns)?;
                        }
                        Err(e) => {
                            rejected += 1;
                            health.error();
                            log_rejection(rejected, "thrust sample", &e);
                        }
                    }
                    health.set_input_gaps(thrust_sub.gaps());
                    health.cycle(start_ns, monotonic_ns(), false)?;
                }
            }
            Wake::Missed(_) if started => health.cycle(start_ns, monotonic_ns(), true)?,
            _ => {}
        }
        Ok(())
    })
}

/// Control: `bench/state` in, `bench/reference` and `bench/command` out.
pub fn run_control(config: &BenchConfig) -> Result<(), ServiceError> {
    let bus = Bus::open("control")?;
    let state_sub = bus.subscriber(channels::STATE, 16)?;
    let mut reference_pub = bus.publisher(channels::REFERENCE)?;
    let mut command_pub = bus.publisher(channels::COMMAND)?;
    let mut health = HealthReporter::new(&bus, ServiceId::Control)?;
    let law = config.control_law()?;
    match &law {
        ControlLaw::Closed(law) => tracing::info!("controller {} on model {}", law.kind(), config.model.model),
        ControlLaw::OpenLoop { throttle_pct, .. } => tracing::info!(
            "playing a {:.1} s throttle profile open loop",
            throttle_pct.len() as f64 * jetbench_model::STEP_S
        ),
    }
    let mut step = Control::with_law(law, config.reference.clone());
    announce_ready();

    let mut started = false;
    let mut rejected = 0;
    consume(&bus, &[(&state_sub, Some(INPUT_DEADLINE))], |wake| {
        let start_ns = monotonic_ns();
        match wake {
            Wake::Input(_) => {
                while let Some(state) = state_sub.try_recv()? {
                    started = true;
                    match step.step(&state) {
                        Ok((reference, command)) => {
                            if command.flags & command_flags::FALLBACK != 0 {
                                health.error();
                                log_rejection(step.fallbacks(), "MPC solve", &"fell back to FBL for this cycle");
                            }
                            // The command first: it wakes actuation, the reference only the recorder.
                            publish_now(&mut command_pub, command, |c, ns| c.publish_ns = ns)?;
                            publish_now(&mut reference_pub, reference, |r, ns| r.publish_ns = ns)?;
                        }
                        Err(e) => {
                            rejected += 1;
                            health.error();
                            log_rejection(rejected, "state estimate", &e);
                        }
                    }
                    health.set_input_gaps(state_sub.gaps());
                    health.cycle(start_ns, monotonic_ns(), false)?;
                }
            }
            Wake::Missed(_) if started => health.cycle(start_ns, monotonic_ns(), true)?,
            _ => {}
        }
        Ok(())
    })
}

/// Actuation: `bench/command` in; throttle board, `bench/actuation` and
/// `bench/ecu` out. Without fresh commands it holds, then idles after the
/// configured cycles. The board and the ECU are serial devices opened by
/// path (sim-bench's ptys with `devices = "sim"`); the ECU is polled on its
/// own thread and its samples are published here without waiting.
pub fn run_actuation(config: &BenchConfig) -> Result<(), ServiceError> {
    let bus = Bus::open("actuation")?;
    let command_sub = bus.subscriber(channels::COMMAND, 16)?;
    let mut board = ThrottleBoard::new(config.board_port(), config.actuation.board_baud, monotonic_ns);
    tracing::info!("driving the {}", board.describe());
    let ecu = EcuPoller::spawn(config.ecu_port(), config.ecu.baud, config.ecu.poll_hz, monotonic_ns)?;
    tracing::info!("polling the {} at {} Hz", ecu.describe(), config.ecu.poll_hz);
    if config.rt.enabled {
        // It inherited actuation's priority, the highest of the control path.
        let priority = config.rt.ecu_priority;
        match ecu.pthread().map(|t| crate::rt::set_thread_fifo(t, priority)) {
            Some(Ok(())) => tracing::info!("ECU poller at SCHED_FIFO {priority}"),
            Some(Err(e)) => tracing::warn!("cannot set the ECU poller to SCHED_FIFO {priority}: {e}"),
            None => {}
        }
    }
    let mut actuation_pub = bus.publisher(channels::ACTUATION)?;
    let mut ecu_pub = bus.publisher(channels::ECU)?;
    let mut health = HealthReporter::new(&bus, ServiceId::Actuation)?;
    let mut step = Actuator::new(config.actuation.idle_after_missed_cycles);
    announce_ready();

    let mut was_idle = false;
    let mut started = false;
    let mut links = LinkLog::default();
    let result = consume(&bus, &[(&command_sub, Some(COMMAND_DEADLINE))], |wake| {
        let start_ns = monotonic_ns();
        // Before the first command the board is kept at idle; that is the
        // expected start, not a missed deadline.
        let (output, late) = match wake {
            Wake::Input(_) => match command_sub.latest()? {
                Some(command) => {
                    started = true;
                    (step.on_command(&command), false)
                }
                None => return Ok(()),
            },
            Wake::Missed(_) => (step.on_missed(), started),
            Wake::Tick => return Ok(()),
        };
        if let Err(e) = board.write(output.applied_pct) {
            health.error();
            log_rejection(health.counters().errors, "throttle write", &e);
        }
        let mut output = step.with_board(output, board.acknowledged(), board.unacked_writes(), board.silent_writes());
        output.written_ns = board.written_ns().unwrap_or(0);
        publish_now(&mut actuation_pub, output, |a, ns| a.publish_ns = ns)?;
        let board_silent = board.silent_writes() >= SILENT_AFTER;
        if links.board(board_silent, &board) {
            health.error();
        }
        for telemetry in ecu.try_iter() {
            if links.ecu(telemetry.flags, &ecu) {
                health.error();
            }
            publish_now(&mut ecu_pub, telemetry, |t, ns| t.publish_ns = ns)?;
        }
        let idle = step.is_idle_fallback();
        if idle != was_idle {
            if !started {
                tracing::info!("no controller yet: throttle held at idle");
            } else if idle {
                tracing::warn!("no command for {} cycles: throttle to idle", output.missed_cycles);
            } else {
                tracing::info!("commands are back: leaving idle");
            }
            was_idle = idle;
        }
        health.set_fallback(idle || board_silent);
        health.set_input_gaps(command_sub.gaps());
        health.cycle(start_ns, monotonic_ns(), late)?;
        Ok(())
    });
    // Disarm, whatever ended the loop.
    board.stop();
    let c = board.counters();
    tracing::info!(
        "throttle board: {} acknowledged frames, {} rejected from the board ({} CRC, {} truncated), {} late acks, \
         opened {} times; ECU: {:?}",
        c.frames,
        c.rejected(),
        c.crc_errors,
        c.truncated,
        board.late_acks(),
        board.opens(),
        ecu.shared().counters
    );
    result
}

/// Logs each serial device going silent and coming back, once per change.
#[derive(Default)]
struct LinkLog {
    board_seen: bool,
    board_silent: bool,
    ecu_seen: bool,
    ecu_silent: bool,
}

impl LinkLog {
    /// Returns true when the board has just gone silent after answering.
    fn board(&mut self, silent: bool, board: &ThrottleBoard) -> bool {
        let changed = silent != self.board_silent;
        self.board_silent = silent;
        match (changed, silent, self.board_seen) {
            (true, true, true) => {
                let why = board.link_error().unwrap_or("no acknowledgement");
                tracing::warn!("{} is silent ({why}); reopening it", board.describe());
                true
            }
            (_, false, false) if board.acknowledged().is_some() => {
                self.board_seen = true;
                tracing::info!("{} answers", board.describe());
                false
            }
            (true, false, true) => {
                tracing::info!("{} answers again (port opened {} times)", board.describe(), board.opens());
                false
            }
            _ => false,
        }
    }

    /// One ECU sample's flags; returns true when the ECU has just gone silent after answering.
    fn ecu(&mut self, flags: u32, ecu: &EcuPoller) -> bool {
        let fresh = flags & jetbench_msgs::ecu_flags::STALE == 0;
        let silent = flags & jetbench_msgs::ecu_flags::SILENT != 0;
        let mut went_silent = false;
        if fresh && !self.ecu_seen {
            self.ecu_seen = true;
            tracing::info!("{} answers", ecu.describe());
        } else if fresh && self.ecu_silent {
            tracing::info!("{} answers again", ecu.describe());
        } else if silent && !self.ecu_silent && self.ecu_seen {
            let why = ecu.shared().link_error.unwrap_or_else(|| "no valid reply".into());
            tracing::warn!("{} is silent ({why}); reopening it", ecu.describe());
            went_silent = true;
        }
        if fresh || silent {
            self.ecu_silent = silent;
        }
        went_silent
    }
}

/// Per-channel counts the recorder reports at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ChannelReport {
    pub channel: &'static str,
    pub received: u64,
    pub gaps: u64,
}

/// What the recorder did, printed at exit.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecorderReport {
    pub channels: Vec<ChannelReport>,
    pub written: u64,
    pub dropped_full: u64,
}

impl RecorderReport {
    pub fn total_gaps(&self) -> u64 {
        self.channels.iter().map(|c| c.gaps).sum()
    }
}

impl std::fmt::Display for RecorderReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "recorder: {} messages written, {} dropped for a full queue", self.written, self.dropped_full)?;
        for c in self.channels.iter().filter(|c| c.received > 0 || c.gaps > 0) {
            let gaps = if c.gaps == 0 { "no gaps".to_string() } else { format!("{} lost (seq gaps)", c.gaps) };
            writeln!(f, "  /{:<16} {:>7} messages, {gaps}", c.channel, c.received)?;
        }
        Ok(())
    }
}

/// The recorder: every channel into one MCAP file. Subscribers hand samples
/// to a writer thread through a bounded queue and never wait on the disk.
pub fn run_recorder(config: &BenchConfig, path: &Path) -> Result<RecorderReport, ServiceError> {
    let bus = Bus::open("recorder")?;
    struct Subscribe<'a> {
        bus: &'a Bus,
        subs: Vec<Box<dyn AnySubscriber>>,
        error: Option<BusError>,
    }
    impl ChannelVisitor for Subscribe<'_> {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            // The deepest queue the channel allows: the recorder must never drop.
            // Polled on the recorder's own clock: publishing costs the control path no
            // wake-up of the recorder. The deepest queue holds 5 s at 100 Hz.
            match self.bus.polled_subscriber(channel, jetbench_bus::limits::MAX_BUFFER) {
                Ok(s) => self.subs.push(Box::new(s)),
                Err(e) => self.error = self.error.take().or(Some(e)),
            }
        }
    }
    let mut subscribe = Subscribe { bus: &bus, subs: Vec::new(), error: None };
    visit_channels(&mut subscribe);
    if let Some(e) = subscribe.error {
        return Err(e.into());
    }
    let subs = subscribe.subs;
    let mut run_info = vec![
        (
            "clock".to_string(),
            "CLOCK_MONOTONIC; log_time is the recorder's receive time, publish_time the sample's stamp_ns".to_string(),
        ),
        ("monotonic_ns_at_start".to_string(), monotonic_ns().to_string()),
        ("realtime_ns_at_start".to_string(), realtime_ns().to_string()),
    ];
    // The config and the estimator's resolved model parameters, so that
    // `jetbench replay` reproduces the run even when its model file is gone.
    run_info.extend(crate::replay::estimator_metadata(config)?);
    let mut writer = spawn_writer(
        path,
        config.recorder.queue,
        vec![(crate::replay::METADATA_NAME.into(), run_info.into_iter().collect())],
    )?;
    let mut health = HealthReporter::new(&bus, ServiceId::Recorder)?;
    tracing::info!("recording {} channels to {}", subs.len(), path.display());
    announce_ready();

    let drain = |sub: &dyn AnySubscriber, writer: &mut jetbench_record::WriterHandle| -> Result<(), ServiceError> {
        let log_time_ns = monotonic_ns();
        let mut failure = None;
        sub.drain_raw(&mut |seq, stamp_ns, bytes| {
            if failure.is_some() {
                return;
            }
            match RawRecord::new(sub.channel_name(), seq, log_time_ns, stamp_ns, bytes) {
                Some(record) => {
                    if let Err(e) = writer.send(record) {
                        failure = Some(e);
                    }
                }
                None => {
                    failure = Some(RecordError::SampleTooLarge {
                        channel: sub.channel_name().into(),
                        size: bytes.len(),
                        max: jetbench_record::MAX_SAMPLE_BYTES,
                    })
                }
            }
        })?;
        failure.map_or(Ok(()), |e| Err(e.into()))
    };

    let mut failure = None;
    bus.run(&[], Some(Duration::from_nanos(PERIOD_NS)), |wake| {
        if wake != Wake::Tick {
            return Flow::Continue;
        }
        let start_ns = monotonic_ns();
        for sub in &subs {
            if let Err(e) = drain(sub.as_ref(), &mut writer) {
                failure = Some(e);
                return Flow::Stop;
            }
        }
        health.set_input_gaps(subs.iter().map(|s| s.gaps()).sum());
        if let Err(e) = health.cycle(start_ns, monotonic_ns(), false) {
            failure = Some(e.into());
            return Flow::Stop;
        }
        Flow::Continue
    })?;
    // Take what arrived while stopping, then close the file.
    for sub in &subs {
        drain(sub.as_ref(), &mut writer)?;
    }
    let dropped_full = writer.dropped_full;
    let stats = writer.finish()?;
    if let Some(e) = failure {
        return Err(e);
    }
    Ok(RecorderReport {
        channels: subs
            .iter()
            .map(|s| ChannelReport { channel: s.channel_name(), received: s.received(), gaps: s.gaps() })
            .collect(),
        written: stats.written,
        dropped_full,
    })
}
