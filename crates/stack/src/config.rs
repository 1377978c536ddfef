//! The bench configuration (TOML), shared by every service of a run.

use std::path::{Path, PathBuf};

use jetbench_control::{Controller, FblGains, Law, LawSettings, MpcSettings, Profile, ShaperSettings, SmcGains};
use jetbench_io::can::source::{CanInterface, InterfaceError};
use jetbench_io::ecu::emulator::EcuFaults;
use jetbench_model::{Params, Plant};
use jetbench_msgs::ServiceId;
use serde::{Deserialize, Serialize};

/// The configuration `jetbench up --sim` uses when no file is given.
pub const DEFAULT_SIM_CONFIG: &str = include_str!("../../../config/sim.toml");

/// Why a configuration is unusable.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file cannot be read.
    #[error("cannot read the bench config {path}: {source}")]
    Read {
        /// The file given.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// Not TOML, or a key that does not exist (the message names it).
    #[error("bench config {origin}: {message}")]
    Parse {
        /// Where the text came from (a path, or what built it).
        origin: String,
        /// The TOML parser's message, naming the line and key.
        message: String,
    },
    /// A value out of range, or settings that contradict each other.
    #[error("bench config {origin}: {message}")]
    Invalid {
        /// Where the text came from (a path, or what built it).
        origin: String,
        /// Which section and key, what is wrong, and what is allowed.
        message: String,
    },
}

/// Why the control law could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum ControlSetupError {
    /// The model file the controller plans with is unusable.
    #[error("controller model: {0}")]
    Model(#[from] jetbench_model::ModelError),
    /// The open-loop throttle profile could not be read.
    #[error("throttle profile: {0}")]
    Profile(#[from] jetbench_record::series::DataError),
    /// The law refused its settings.
    #[error("controller: {0}")]
    Law(#[from] jetbench_control::ControlError),
}

/// The bench configuration (`config/bench.example.toml`): one section per
/// concern, each checked by what it configures when the file loads.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    /// `[bench]`: simulated or real devices.
    pub bench: BenchSection,
    /// `[plant]`: the simulated engine (used only with `devices = "sim"`).
    pub plant: PlantSection,
    /// `[model]`: the model the estimator and the controller use.
    pub model: ModelSection,
    /// `[sensor]`: the force/torque sensor's link and calibration.
    #[serde(default)]
    pub sensor: SensorSection,
    /// `[estimator]`: the observer's noise settings.
    #[serde(default)]
    pub estimator: EstimatorSection,
    /// `[control]`: which law runs and every law's tunables.
    #[serde(default)]
    pub control: ControlSection,
    /// `[actuation]`: the throttle board and its watchdog.
    #[serde(default)]
    pub actuation: ActuationSection,
    /// `[ecu]`: the engine ECU's telemetry port.
    #[serde(default)]
    pub ecu: EcuSection,
    /// `[reference]`: the thrust profile a run tracks.
    #[serde(default)]
    pub reference: Profile,
    /// `[recorder]`: queue size and what a write error does.
    #[serde(default)]
    pub recorder: RecorderSection,
    /// `[rt]`: real-time priorities, CPUs and memory locking.
    #[serde(default)]
    pub rt: RtSection,
    /// `[engine]`: how the engine starts, what it tracks, how a run ends.
    #[serde(default)]
    pub engine: EngineSection,
    /// The operating envelope, checked and typed by [`BenchConfig::limits`]
    /// (kept as written so that a derived config carries it unchanged).
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub limits: toml::Table,
    /// Who may operate the bench from the control room; `None`: view only (crates/bridge).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operator: Option<jetbench_control::operator::OperatorSettings>,
}

/// `[bench]`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BenchSection {
    /// The simulated devices or the real bench.
    pub devices: Devices,
    /// No longer a setting: the bench runs at the model's period
    /// ([`jetbench_model::PERIOD_NS`]). Read only so that the configs recorded with
    /// older runs still load for replay; a config given to a run that has it is
    /// refused with a message saying so.
    #[serde(default, skip_serializing)]
    pub rate_hz: Option<f64>,
    /// A group that may use the running set too (watch it with `jetbench echo`
    /// and the like): its files become `0660` instead of its user's only `0600`,
    /// and the set must run with that group (`sg NAME -c "jetbench up ..."`).
    /// See `jetbench_bus::access`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
}

/// `[bench] devices`: what the services talk to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Devices {
    /// Simulated engine and devices: sim-bench emulates the sensor, the
    /// throttle board and the ECU, which the services reach through the same
    /// drivers as at the bench.
    Sim,
    /// The real bench: the sensor on `[sensor] can_interface`, the throttle
    /// board on `[actuation] board_port`, the ECU on `[ecu] port`.
    Bench,
}

/// `[plant]`: the simulated engine and its sensor (used only with `devices = "sim"`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlantSection {
    /// Preset name or model file of the simulated engine.
    pub model: String,
    /// Variance of the simulated force sensor's noise, N².
    #[serde(default = "default_noise")]
    pub noise_var_n2: f64,
    /// Seed of the sensor noise (the same seed gives the same noise).
    #[serde(default)]
    pub seed: u64,
    /// The throttle the engine rests at when the run begins, %.
    #[serde(default = "default_idle")]
    pub initial_throttle_pct: f64,
    /// The simulated sensor's reading at zero load `[Fx, Fy, Fz, Tx, Ty, Tz]`,
    /// N and N·m: the offset `jetbench tare` finds and `[sensor] tare` removes.
    #[serde(default)]
    pub sensor_zero: [f64; 6],
    /// Faults injected into the simulated sensor's path, `KIND:KEY=VALUE,...`
    /// each (`jetbench up --inject`; see [`crate::inject`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inject: Vec<String>,
}

impl PlantSection {
    /// The injected faults ([`crate::inject`]); none unless asked for.
    pub fn faults(&self) -> Result<crate::inject::FaultPlan, crate::inject::InjectError> {
        crate::inject::FaultPlan::parse(&self.inject)
    }

    /// The emulated ECU's faults (`--inject ecu:overtemp_at_s=20,...`); none unless asked for.
    pub fn ecu_faults(&self) -> Result<EcuFaults, jetbench_io::ecu::emulator::EcuFaultError> {
        let mut faults = EcuFaults::default();
        for spec in self.inject.iter().filter(|s| EcuFaults::is_ecu_spec(s)) {
            faults.merge(spec.parse()?);
        }
        Ok(faults)
    }

    /// The simulated force sensor of this plant: its noise, its zero offset, its seed.
    pub fn sensor(&self) -> Result<crate::sim_bench::SimForceSensor, crate::sim_bench::SimError> {
        crate::sim_bench::SimForceSensor::new(self.noise_var_n2, self.sensor_zero, self.seed)
    }
}

fn default_noise() -> f64 {
    7.0
}

fn default_idle() -> f64 {
    jetbench_model::THROTTLE_MIN_PCT
}

/// `[model]`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSection {
    /// Preset name or model file used by the estimator and the controller.
    pub model: String,
}

/// A force axis of the sensor's calibrated frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// Fx, the usual thrust axis.
    #[default]
    X,
    /// Fy.
    Y,
    /// Fz.
    Z,
}

impl Axis {
    /// Its index in a `[Fx, Fy, Fz, Tx, Ty, Tz]` reading.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// The force/torque sensor: where its CAN frames travel, and its calibration.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSection {
    /// Calibrated force axis that carries the thrust.
    #[serde(default)]
    pub thrust_axis: Axis,
    /// Tare offsets `[Fx, Fy, Fz, Tx, Ty, Tz]` subtracted after calibration,
    /// N and N·m (`jetbench tare` measures them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tare: Option<[f64; 6]>,
    /// Older configs: force-only tare `[Fx, Fy, Fz]`, N (torque tare 0). Use `tare`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tare_n: Option<[f64; 3]>,
    /// 6×6 calibration matrix, rows as in the sensor's calibration sheet:
    /// `calibrated = calibration · [Fx, Fy, Fz, Tx, Ty, Tz] − tare`.
    #[serde(default = "identity6")]
    pub calibration: [[f64; 6]; 6],
    /// `can0` (SocketCAN at the bench) or `user:NAME` (userspace bus). Unset:
    /// `user:simcan0` with `devices = "sim"`, `can0` otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub can_interface: Option<String>,
    /// Base identifier: forces on base+1, torques on base+2.
    #[serde(default = "default_can_base_id")]
    pub can_base_id: u16,
}

fn identity6() -> [[f64; 6]; 6] {
    std::array::from_fn(|r| std::array::from_fn(|c| if r == c { 1.0 } else { 0.0 }))
}

/// The userspace CAN bus of the simulated bench.
pub const SIM_CAN_INTERFACE: &str = "user:simcan0";

fn default_can_base_id() -> u16 {
    jetbench_io::can::DEFAULT_BASE_ID
}

impl Default for SensorSection {
    fn default() -> Self {
        SensorSection {
            thrust_axis: Axis::default(),
            tare: None,
            tare_n: None,
            calibration: identity6(),
            can_interface: None,
            can_base_id: default_can_base_id(),
        }
    }
}

impl SensorSection {
    /// The six tare offsets (`tare`, else `tare_n` with zero torque tare).
    pub fn tare_offsets(&self) -> [f64; 6] {
        match (self.tare, self.tare_n) {
            (Some(t), _) => t,
            (None, Some([x, y, z])) => [x, y, z, 0.0, 0.0, 0.0],
            (None, None) => [0.0; 6],
        }
    }

    /// Calibration matrix and tare.
    pub fn calibration(&self) -> Result<jetbench_io::calib::Calibration, jetbench_io::calib::CalibrationError> {
        jetbench_io::calib::Calibration::new(&self.calibration, self.tare_offsets())
    }

    /// The configured interface, else the default for `devices`; a userspace
    /// bus in this process's bus namespace.
    pub fn interface(&self, devices: Devices) -> Result<CanInterface, InterfaceError> {
        let interface: CanInterface = match (&self.can_interface, devices) {
            (Some(name), _) => name.parse()?,
            (None, Devices::Sim) => SIM_CAN_INTERFACE.parse()?,
            (None, Devices::Bench) => "can0".parse()?,
        };
        Ok(interface.in_namespace(&bus_namespace()))
    }

    /// The frame codec for the sensor's CAN identifiers (`can_base_id`).
    pub fn codec(&self) -> Result<jetbench_io::can::Codec, jetbench_io::can::CodecError> {
        jetbench_io::can::Codec::new(self.can_base_id)
    }

    fn validate(&self, devices: Devices) -> Result<(), String> {
        if self.tare.is_some() && self.tare_n.is_some() {
            return Err("[sensor] has both tare and tare_n: keep only tare = [Fx, Fy, Fz, Tx, Ty, Tz]".into());
        }
        self.calibration().map_err(|e| format!("[sensor] {e}"))?;
        self.interface(devices).map_err(|e| format!("[sensor] can_interface: {e}"))?;
        self.codec().map_err(|e| format!("[sensor] can_base_id: {e}"))?;
        Ok(())
    }
}

/// `[estimator]`: the observer's settings (checked by [`jetbench_estim`]).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct EstimatorSection {
    /// Variance of the thrust measurement's noise, N².
    pub measurement_var_n2: f64,
    /// Process noise: the thrust's unmodelled acceleration, N/s² (> 0).
    pub accel_noise_n_per_s2: f64,
    /// Drift of the disturbance state over one second, N/s² (0: no disturbance state).
    pub disturbance_drift_n_per_s2: f64,
    /// A measurement whose normalised innovation squared exceeds this is rejected
    /// (chi-square, one degree of freedom; 25 = five standard deviations).
    pub gate_chi2: f64,
    /// Identical readings in a row that mark the sensor stuck; 0 turns the test
    /// off (a noise-free simulated sensor repeats itself at rest).
    pub stuck_after_samples: u32,
}

impl Default for EstimatorSection {
    fn default() -> Self {
        let d = jetbench_estim::ObserverConfig::default();
        EstimatorSection {
            measurement_var_n2: d.measurement_var_n2,
            accel_noise_n_per_s2: d.accel_noise_n_per_s2,
            disturbance_drift_n_per_s2: d.disturbance_drift_n_per_s2,
            gate_chi2: d.gate.chi2_threshold,
            stuck_after_samples: d.gate.stuck_after_samples,
        }
    }
}

impl EstimatorSection {
    /// Checked by the estimator crate ([`jetbench_estim::ObserverConfig::validate`]); the
    /// error names the key as this section spells it.
    fn validate(&self) -> Result<(), String> {
        self.observer_config(0.0).validate().map_err(|e| match e {
            jetbench_estim::EstimError::InvalidConfig { name, value, requirement } => {
                let key = if name == "chi2_threshold" { "gate_chi2" } else { name };
                format!("[estimator] {key} = {value} is invalid: it must be finite and {requirement}")
            }
            other => format!("[estimator] {other}"),
        })
    }

    /// The observer of these settings on a model whose input delay is `input_delay_s`
    /// (the model's, not a setting: [`BenchConfig::estimator`] takes it from `[model]`).
    pub fn observer_config(&self, input_delay_s: f64) -> jetbench_estim::ObserverConfig {
        let d = jetbench_estim::ObserverConfig::default();
        jetbench_estim::ObserverConfig {
            measurement_var_n2: self.measurement_var_n2,
            accel_noise_n_per_s2: self.accel_noise_n_per_s2,
            disturbance_drift_n_per_s2: self.disturbance_drift_n_per_s2,
            input_delay_s,
            gate: jetbench_estim::GateConfig {
                chi2_threshold: self.gate_chi2,
                stuck_after_samples: self.stuck_after_samples,
                ..d.gate
            },
            ..d
        }
    }
}

/// `[control]`: which law runs, and every law's tunables in its own sub-table
/// (`[control.fbl]`, `[control.smc]`, `[control.mpc]`, `[control.shaping]`), so a gain
/// changes without recompiling and the unused laws' settings are still checked.
#[derive(Clone, Debug, PartialEq, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControlSection {
    /// The law that runs.
    pub controller: Controller,
    /// `[control.fbl]`: feedback linearisation's gains.
    pub fbl: FblGains,
    /// `[control.smc]`: sliding mode's gains.
    pub smc: SmcGains,
    /// `[control.mpc]`: the predictive controller's horizon and weights.
    pub mpc: MpcSettings,
    /// `[control.shaping]`: the reference shaper in front of every law.
    pub shaping: ShaperSettings,
    /// CSV `time_s,throttle_pct` at 100 Hz (e.g. from `jetbench excite`), for `open-loop`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub throttle_profile: Option<String>,
}

impl ControlSection {
    /// The tunables of every law.
    pub fn law_settings(&self) -> LawSettings {
        LawSettings { fbl: self.fbl, smc: self.smc, mpc: self.mpc, shaping: self.shaping }
    }
}

/// `[actuation]`: the throttle board and the actuation watchdog.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ActuationSection {
    /// Command idle after this many 10 ms cycles without a control sample.
    pub idle_after_missed_cycles: u32,
    /// Serial port of the throttle board, e.g. `/dev/ttyUSB0`. Unset with
    /// `devices = "sim"`: the pty link sim-bench publishes ([`sim_port_link`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub board_port: Option<String>,
    /// Baud rate of the throttle board (8N1).
    pub board_baud: u32,
}

impl Default for ActuationSection {
    fn default() -> Self {
        ActuationSection { idle_after_missed_cycles: 3, board_port: None, board_baud: 115_200 }
    }
}

/// The engine's lifecycle in a run (`[engine]`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct EngineSection {
    /// How the engine gets to run: `wait` (someone starts it, from the ECU's
    /// panel or `jetbench start`), `auto` (`jetbench up` starts it through the
    /// ECU), or `running` (the simulated bench only: the emulated engine is
    /// running when the run begins).
    pub start: EngineStart,
    /// What the controller tracks once the engine runs: `idle` (until an
    /// operator runs a profile: `jetbench run --profile NAME`) or `profile`
    /// (`[reference]`; `jetbench up --profile NAME` sets this).
    pub reference: EngineReference,
    /// At the end of a run, bring the engine down through the ECU and record
    /// its cool-down until it is off.
    pub cool_down_at_end: bool,
    /// The longest `jetbench up` waits for the engine to run, s.
    pub start_timeout_s: f64,
    /// The longest `jetbench up` records a cool-down, s.
    pub cool_down_timeout_s: f64,
    /// A stop idles this long before the ECU shuts the engine down, s.
    pub stop_idle_s: f64,
}

impl Default for EngineSection {
    fn default() -> Self {
        EngineSection {
            start: EngineStart::Wait,
            reference: EngineReference::Idle,
            cool_down_at_end: true,
            start_timeout_s: 120.0,
            cool_down_timeout_s: 120.0,
            stop_idle_s: 3.0,
        }
    }
}

/// `[engine] start`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum EngineStart {
    /// Someone starts the engine (the ECU's panel, or `jetbench start`).
    Wait,
    /// `jetbench up` starts it through the ECU.
    Auto,
    /// The emulated engine is already running (simulated bench only).
    Running,
}

/// `[engine] reference`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum EngineReference {
    /// Idle until an operator runs a profile.
    Idle,
    /// Track `[reference]` from the moment the engine runs.
    Profile,
}

/// The engine ECU's telemetry port, polled by the actuation service.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct EcuSection {
    /// Serial port of the ECU, e.g. `/dev/ttyUSB1`. Unset with `devices = "sim"`:
    /// the pty link sim-bench publishes ([`sim_port_link`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub port: Option<String>,
    /// Baud rate (8N1).
    pub baud: u32,
    /// Polls per second; one poll and its reply take about 52 ms at 9600 baud.
    /// On a real line ([`EcuSection::port`] set) the rate must fit the baud rate
    /// ([`jetbench_io::serial::EcuLineBudget`]): at 9600 baud, at most 13 Hz.
    pub poll_hz: f64,
}

impl Default for EcuSection {
    fn default() -> Self {
        EcuSection { port: None, baud: 9600, poll_hz: 10.0 }
    }
}

impl EcuSection {
    /// On a real serial line: refuses a poll rate whose replies do not fit the
    /// baud rate (polls answered after their window would be recorded stale),
    /// naming the fastest rate that fits. A pseudo-terminal has no baud rate,
    /// so the simulated bench's link is not checked.
    pub fn check_line(&self) -> Result<(), String> {
        use jetbench_io::serial::EcuLineBudget;
        let budget = EcuLineBudget::new(self.baud, self.poll_hz);
        if budget.fits() {
            return Ok(());
        }
        // The fastest rate in 10..50, in steps of 0.5 Hz, that fits.
        let fastest =
            (20..=100).rev().map(|half| f64::from(half) / 2.0).find(|&hz| EcuLineBudget::new(self.baud, hz).fits());
        let why = if budget.rx_share >= 1.0 {
            format!("the replies need {:.0} % of the line and fall behind", budget.rx_share * 100.0)
        } else {
            format!(
                "the poll after each battery read is answered after {:.0} ms, past its {:.0} ms window (the line {:.0} % busy)",
                budget.reply_after_fuel_s * 1e3,
                budget.answer_window_s * 1e3,
                budget.rx_share * 100.0
            )
        };
        let advice = match fastest {
            Some(hz) => format!("poll at {hz} Hz or less, or raise the ECU's baud rate"),
            None => "raise the ECU's baud rate".into(),
        };
        Err(format!(
            "[ecu] poll_hz = {} does not fit a {}-baud line: {why}, so readings would be recorded stale; {advice} \
             (docs/bench/RUN.md, \"How fast to poll the ECU\")",
            self.poll_hz, self.baud
        ))
    }
}

/// File name of the throttle board's link in the sim port folder.
pub const SIM_BOARD_LINK: &str = "throttle-board";
/// File name of the ECU's link in the sim port folder.
pub const SIM_ECU_LINK: &str = "ecu";

/// Where sim-bench publishes the pty of an emulated serial device (`name`
/// is [`SIM_BOARD_LINK`] or [`SIM_ECU_LINK`]): a symlink to the pty slave in
/// `$TMPDIR/jetbench-sim-<bus namespace>/`, so every process of one run finds
/// the same path without being told, and parallel runs in other namespaces
/// do not meet.
pub fn sim_port_link(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("jetbench-sim-{}", bus_namespace())).join(name)
}

/// This process's bus namespace ([`jetbench_bus::NAMESPACE_ENV`]), `default`
/// when unset (an invalid one is refused when the bus opens).
pub fn bus_namespace() -> String {
    jetbench_bus::namespace_name().unwrap_or_else(|_| "default".into())
}

/// `[recorder]`.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecorderSection {
    /// Samples the queue between the recorder and its writer thread holds: it
    /// absorbs a disk stall of `queue` divided by the samples recorded per second.
    pub queue: usize,
    /// What a run does when the recording cannot be written (a full disk).
    pub on_error: OnRecordError,
}

impl Default for RecorderSection {
    fn default() -> Self {
        RecorderSection { queue: 16_384, on_error: OnRecordError::Stop }
    }
}

/// `[recorder] on_error`: what a run does when its recording fails.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum OnRecordError {
    /// The recorder stops with the error and the launcher stops the run safely
    /// (engine to idle, board disarmed): no run goes unrecorded.
    #[default]
    Stop,
    /// The recorder says so, flags its heartbeat and the run goes on unrecorded.
    Continue,
}

/// Real-time settings of the service processes (`[rt]`).
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RtSection {
    /// Apply the settings on every start; `jetbench up --rt` and `jetbench latency --rt`
    /// apply them for one run.
    pub enabled: bool,
    /// Lock every page of each service in memory (`mlockall`).
    pub lock_memory: bool,
    /// SCHED_FIFO priority of each service, 1–99 (the viewer and the bridge run at
    /// the normal scheduler unless given one: they are off the control path).
    pub priority: PerService<u8>,
    /// SCHED_FIFO priority of actuation's ECU polling thread: below the
    /// control path, so a 9600-baud telemetry poll never delays a command.
    pub ecu_priority: u8,
    /// CPUs each service may run on; an empty list leaves it to the scheduler.
    pub cpus: PerService<Vec<usize>>,
}

impl Default for RtSection {
    fn default() -> Self {
        RtSection {
            enabled: false,
            lock_memory: true,
            // Along the control path, each stage above the one that feeds it:
            // a stage that publishes is preempted at once by the stage it woke,
            // so a cycle runs through to the throttle board before any stage's
            // bookkeeping (heartbeat, next read). See docs/latency/README.md, "Preparing a bench PC".
            priority: PerService {
                sim_bench: 90,
                actuation: 80,
                control: 70,
                estimation: 60,
                sensing: 50,
                recorder: 40,
                viewer: None,
                bridge: None,
            },
            ecu_priority: 45,
            // The control chain on one core, so each hand-over wakes a process on the
            // core it runs on; the simulated devices and every reader of the bus
            // (recorder, viewer, bridge: their threads, sockets and network work)
            // on the other.
            cpus: PerService {
                sim_bench: vec![0],
                sensing: vec![1],
                estimation: vec![1],
                control: vec![1],
                actuation: vec![1],
                recorder: vec![0],
                viewer: Some(vec![0]),
                bridge: Some(vec![0]),
            },
        }
    }
}

/// One value per service, keyed by the service's name; the services off the
/// control path (viewer, bridge) may go without one.
#[derive(Clone, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PerService<T> {
    /// `sim-bench`, the simulated devices.
    #[serde(rename = "sim-bench")]
    pub sim_bench: T,
    /// `sensing`.
    pub sensing: T,
    /// `estimation`.
    pub estimation: T,
    /// `control`.
    pub control: T,
    /// `actuation`.
    pub actuation: T,
    /// `recorder`.
    pub recorder: T,
    /// `viewer`, the Foxglove server (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub viewer: Option<T>,
    /// `bridge`, the control room's gateway (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bridge: Option<T>,
}

impl<T> PerService<T> {
    /// The value for `id`; `None` for an optional service without one.
    pub fn get(&self, id: ServiceId) -> Option<&T> {
        match id {
            ServiceId::SimBench => Some(&self.sim_bench),
            ServiceId::Sensing => Some(&self.sensing),
            ServiceId::Estimation => Some(&self.estimation),
            ServiceId::Control => Some(&self.control),
            ServiceId::Actuation => Some(&self.actuation),
            ServiceId::Recorder => Some(&self.recorder),
            ServiceId::Viewer => self.viewer.as_ref(),
            ServiceId::Bridge => self.bridge.as_ref(),
        }
    }
}

impl RtSection {
    /// What service `id` asks of the kernel; `None` when real-time settings are
    /// off (neither `enabled` nor `force`).
    /// A service with neither a priority nor CPUs (the viewer, the bridge, unless
    /// configured) asks for nothing.
    pub fn request(&self, id: ServiceId, force: bool) -> Option<crate::runtime::rt::RtRequest> {
        let (priority, cpus) = (self.priority.get(id).copied(), self.cpus.get(id).cloned().unwrap_or_default());
        (self.enabled || force)
            .then_some(())
            .filter(|()| priority.is_some() || !cpus.is_empty())
            .map(|()| crate::runtime::rt::RtRequest { priority, cpus, lock_memory: self.lock_memory })
    }

    fn validate(&self) -> Result<(), String> {
        for id in ServiceId::ALL {
            if let Some(&priority) = self.priority.get(id).filter(|p| !(1..=99).contains(*p)) {
                return Err(format!("[rt] priority.{} = {priority} must be within 1..99", id.name()));
            }
            if let Some(cpu) = self.cpus.get(id).into_iter().flatten().find(|&&c| c >= 1024) {
                return Err(format!("[rt] cpus.{} names CPU {cpu}: CPUs are numbered from 0", id.name()));
            }
        }
        if !(1..=99).contains(&self.ecu_priority) {
            return Err(format!("[rt] ecu_priority = {} must be within 1..99", self.ecu_priority));
        }
        Ok(())
    }
}

impl BenchConfig {
    /// The built-in simulated-bench configuration.
    pub fn default_sim() -> Result<Self, ConfigError> {
        Self::from_toml_str(DEFAULT_SIM_CONFIG, "(built-in sim.toml)", None)
    }

    /// Reads and checks a configuration file. Relative model paths are
    /// resolved against the file's folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.into(), source })?;
        Self::from_toml_str(&text, &path.display().to_string(), path.parent())
    }

    /// Loads `path` if given, else the built-in simulated bench.
    pub fn load_or_default(path: Option<&Path>) -> Result<Self, ConfigError> {
        match path {
            Some(p) => Self::load(p),
            None => Self::default_sim(),
        }
    }

    /// Parses and checks a configuration; relative paths in it are taken from
    /// `base_dir` (the config file's folder). `origin` names the text in errors.
    pub fn from_toml_str(text: &str, origin: &str, base_dir: Option<&Path>) -> Result<Self, ConfigError> {
        let mut config: BenchConfig =
            toml::from_str(text).map_err(|e| ConfigError::Parse { origin: origin.into(), message: e.to_string() })?;
        if let Some(dir) = base_dir {
            for spec in [&mut config.plant.model, &mut config.model.model] {
                if !jetbench_model::names_a_plant(spec) && Path::new(spec.as_str()).is_relative() {
                    *spec = dir.join(spec.as_str()).display().to_string();
                }
            }
            if let Some(operator) = config.operator.as_mut() {
                operator.resolve(dir);
            }
            if let Some(profile) = config.control.throttle_profile.as_mut() {
                if Path::new(profile.as_str()).is_relative() {
                    *profile = dir.join(profile.as_str()).display().to_string();
                }
            }
        }
        config.validate(origin)?;
        Ok(config)
    }

    fn validate(&self, origin: &str) -> Result<(), ConfigError> {
        let invalid = |message: String| ConfigError::Invalid { origin: origin.into(), message };
        if let Some(operator) = &self.operator {
            operator.check().map_err(|e| invalid(e.to_string()))?;
        }
        if let Some(rate_hz) = self.bench.rate_hz {
            return Err(invalid(format!(
                "[bench] rate_hz = {rate_hz} is no longer a setting: the bench runs at 100 Hz, the model's and the \
                 estimator's 10 ms step; delete the line"
            )));
        }
        if !(self.plant.noise_var_n2.is_finite() && self.plant.noise_var_n2 >= 0.0) {
            return Err(invalid(format!("[plant] noise_var_n2 = {} must be >= 0", self.plant.noise_var_n2)));
        }
        self.plant.faults().map_err(|e| invalid(format!("[plant] inject: {e}")))?;
        self.plant.ecu_faults().map_err(|e| invalid(format!("[plant] inject: {e}")))?;
        if !self.plant.inject.is_empty() && self.bench.devices != Devices::Sim {
            return Err(invalid("[plant] inject needs the simulated bench (devices = \"sim\")".into()));
        }
        if !(0.0..=120.0).contains(&self.plant.initial_throttle_pct) {
            return Err(invalid(format!(
                "[plant] initial_throttle_pct = {} is outside 0..120",
                self.plant.initial_throttle_pct
            )));
        }
        // Each section's settings are checked by the crate they configure.
        self.estimator.validate().map_err(invalid)?;
        self.control.law_settings().validate().map_err(|e| invalid(e.to_string()))?;
        if self.bench.devices == Devices::Bench && (self.actuation.board_port.is_none() || self.ecu.port.is_none()) {
            return Err(invalid(
                "devices = \"bench\" needs [actuation] board_port and [ecu] port (e.g. \"/dev/ttyUSB0\", \"/dev/ttyUSB1\")"
                    .into(),
            ));
        }
        if self.actuation.board_baud == 0 || self.ecu.baud == 0 {
            return Err(invalid("[actuation] board_baud and [ecu] baud must be positive".into()));
        }
        if !(self.ecu.poll_hz.is_finite() && (10.0..=50.0).contains(&self.ecu.poll_hz)) {
            return Err(invalid(format!("[ecu] poll_hz = {} must be within 10..50", self.ecu.poll_hz)));
        }
        if self.ecu.port.is_some() {
            self.ecu.check_line().map_err(invalid)?;
        }
        self.sensor.validate(self.bench.devices).map_err(invalid)?;
        let engine = &self.engine;
        if engine.start == EngineStart::Running && self.bench.devices != Devices::Sim {
            return Err(invalid(
                "[engine] start = \"running\" is for the simulated bench; at the bench use \"wait\" or \"auto\"".into(),
            ));
        }
        for (key, v) in [
            ("start_timeout_s", engine.start_timeout_s),
            ("cool_down_timeout_s", engine.cool_down_timeout_s),
            ("stop_idle_s", engine.stop_idle_s),
        ] {
            if !(v.is_finite() && (0.0..=3600.0).contains(&v)) {
                return Err(invalid(format!("[engine] {key} = {v} must be within 0..3600 s")));
            }
        }
        let limits = self.limits().map_err(|e| invalid(e.to_string()))?;
        if self.bench.devices == Devices::Bench && limits.is_empty() {
            return Err(invalid(
                "devices = \"bench\" needs [limits] (e.g. preset = \"p100\" or \"p220\"; see docs/bench/RUN.md)".into(),
            ));
        }
        self.rt.validate().map_err(invalid)?;
        if self.actuation.idle_after_missed_cycles == 0 {
            return Err(invalid("[actuation] idle_after_missed_cycles must be at least 1".into()));
        }
        if self.recorder.queue < 16 {
            return Err(invalid("[recorder] queue must be at least 16".into()));
        }
        self.reference.validate().map_err(|e| invalid(format!("[reference] {e}")))?;
        match (self.control.controller, &self.control.throttle_profile) {
            (Controller::OpenLoop, None) => return Err(invalid(
                "[control] controller = \"open-loop\" needs throttle_profile = \"FILE.csv\" (see `jetbench excite`)"
                    .into(),
            )),
            (Controller::OpenLoop, Some(_)) => {
                self.throttle_profile().map_err(|e| invalid(format!("[control] throttle_profile: {e}")))?;
            }
            (_, _) => {}
        }
        self.plant().map_err(|e| invalid(format!("[plant] model: {e}")))?;
        let model =
            jetbench_model::resolve_model(&self.model.model).map_err(|e| invalid(format!("[model] model: {e}")))?;
        if model.effects.get(jetbench_model::EffectKind::AccelSchedule).is_some() {
            return Err(invalid(format!(
                "[model] model {} is paced by an acceleration schedule (accel_schedule): its ten parameters are \
                 fitted to run faster than the engine wherever the schedule holds it back, and FBL and SMC cancel \
                 them alone (on the turbojet, FBL ran 100 times the error of an unpaced model, the MPC 9 times); \
                 identify without --schedule for the bench (a paced model is for simulate, sim-record and diagnose, \
                 and as a [plant])",
                self.model.model
            )));
        }
        if !model.effects.is_empty() && self.control.controller != Controller::Mpc {
            // Not an error: the same file can serve as [plant] and as [model].
            tracing::warn!(
                "{origin}: [model] model {} has effects ({}); the estimator and the {} controller use only its \
                 ten parameters (the mpc controller uses the effects too)",
                self.model.model,
                model.effects,
                self.control.controller
            );
        }
        Ok(())
    }

    /// The operating envelope of `[limits]`, checked: every key known (a typo
    /// names the key it resembles), every value in range.
    pub fn limits(&self) -> Result<crate::limits::Limits, crate::limits::LimitsError> {
        crate::limits::Limits::from_table(&self.limits)
    }

    /// The open-loop throttle profile, one value per 10 ms (empty when none is set).
    pub fn throttle_profile(&self) -> Result<Vec<f64>, jetbench_record::series::DataError> {
        match &self.control.throttle_profile {
            Some(path) => Ok(jetbench_record::series::Series::load(Path::new(path), false)?.u_pct),
            None => Ok(Vec::new()),
        }
    }

    /// The simulated engine with its effects, as the sim-bench runs it: a model preset or
    /// file, or a turbojet (`turbojet-p100`, `turbojet-p220`, or a plant file with a
    /// `[turbojet]` table; see [`jetbench_model::resolve_plant`]).
    pub fn plant(&self) -> Result<Plant, jetbench_model::ModelError> {
        jetbench_model::resolve_plant(&self.plant.model)
    }

    /// The throttle board's serial port: the configured one, else (simulated bench) sim-bench's pty link.
    pub fn board_port(&self) -> PathBuf {
        self.actuation.board_port.as_ref().map_or_else(|| sim_port_link(SIM_BOARD_LINK), PathBuf::from)
    }

    /// The ECU's serial port: the configured one, else (simulated bench) sim-bench's pty link.
    pub fn ecu_port(&self) -> PathBuf {
        self.ecu.port.as_ref().map_or_else(|| sim_port_link(SIM_ECU_LINK), PathBuf::from)
    }

    /// Parameters the estimator and controller use.
    pub fn model_params(&self) -> Result<Params, jetbench_model::ModelError> {
        jetbench_model::resolve_params(&self.model.model)
    }

    /// The estimator: the parameters of `[model] model`, the `[estimator]` settings, and
    /// the model's input delay, which the filter predicts through.
    pub fn estimator(&self) -> Result<(Params, jetbench_estim::ObserverConfig), jetbench_model::ModelError> {
        let model = jetbench_model::resolve_model(&self.model.model)?;
        Ok((model.model, self.estimator.observer_config(model.effects.input_delay_s())))
    }

    /// The control law `[control]` chooses, on the controller's model.
    pub fn control_law(&self) -> Result<crate::control::ControlLaw, ControlSetupError> {
        Ok(match self.control.controller {
            Controller::OpenLoop => crate::control::ControlLaw::OpenLoop {
                throttle_pct: self.throttle_profile()?,
                model: self.model_params()?,
            },
            kind => crate::control::ControlLaw::Closed(Box::new(Law::new(
                kind,
                &self.control_plant()?,
                &self.control.law_settings(),
            )?)),
        })
    }

    /// The controller's model: the parameters and any effects of `[model] model` (the
    /// MPC predicts with the effects; FBL and SMC use the parameters).
    pub fn control_plant(&self) -> Result<Plant, jetbench_model::ModelError> {
        jetbench_model::resolve_model(&self.model.model).map(|file| file.plant())
    }
}

/// What the command line may change in a bench config (`jetbench up`): each a
/// key of the config, given as it would be written there.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// `[control] controller`.
    pub controller: Option<Controller>,
    /// `[model] model`: a preset name, or a model file (made absolute by the caller).
    pub model: Option<String>,
    /// `[plant] model`, as `model`.
    pub plant: Option<String>,
    /// `[reference]`: a built-in profile by name, scaled to the model's thrust range.
    pub profile: Option<String>,
    /// `[control] throttle_profile` (an absolute path), with `controller = open_loop`.
    pub open_loop: Option<PathBuf>,
    /// Appended to `[plant] inject`.
    pub inject: Vec<String>,
}

impl Overrides {
    /// True when nothing is overridden (the config file is used as it is).
    pub fn is_empty(&self) -> bool {
        self.controller.is_none()
            && self.model.is_none()
            && self.plant.is_none()
            && self.profile.is_none()
            && self.open_loop.is_none()
            && self.inject.is_empty()
    }
}

impl BenchConfig {
    /// This config with `overrides` applied, checked as the services will read it
    /// (models and profiles loaded). Errors name the key they concern.
    pub fn with_overrides(&self, overrides: &Overrides) -> Result<BenchConfig, ConfigError> {
        let origin = "the command-line options".to_string();
        let invalid = |message: String| ConfigError::Invalid { origin: origin.clone(), message };
        let mut config = self.clone();
        if let Some(kind) = overrides.controller {
            config.control.controller = kind;
        }
        if let Some(model) = &overrides.model {
            config.model.model = model.clone();
        }
        if let Some(plant) = &overrides.plant {
            config.plant.model = plant.clone();
        }
        if let Some(name) = &overrides.profile {
            let params =
                config.model_params().map_err(|e| invalid(format!("[reference] scales to [model] model: {e}")))?;
            let range = params
                .stable_equilibrium(jetbench_model::THROTTLE_MIN_PCT)
                .zip(params.stable_equilibrium(jetbench_model::THROTTLE_MAX_PCT));
            let (idle_n, max_n) = range.ok_or_else(|| {
                invalid(format!(
                    "[reference] {name}: model {} has no stable thrust at 25 % or 100 % throttle to scale to",
                    config.model.model
                ))
            })?;
            config.reference = Profile::builtin(name, idle_n, max_n).ok_or_else(|| {
                invalid(format!("[reference] {name}: the model's thrust range {idle_n:.1}..{max_n:.1} N is empty"))
            })?;
            // A profile chosen on the command line is the explicit choice the
            // bench waits for: it runs once the engine does.
            config.engine.reference = EngineReference::Profile;
        }
        config.plant.inject.extend(overrides.inject.iter().cloned());
        if let Some(profile) = &overrides.open_loop {
            config.control.controller = Controller::OpenLoop;
            config.control.throttle_profile = Some(profile.display().to_string());
            config.engine.reference = EngineReference::Profile;
        }
        let text = toml::to_string(&config).map_err(|e| invalid(format!("cannot be written as TOML: {e}")))?;
        BenchConfig::from_toml_str(&text, &origin, None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_config_is_valid() {
        let c = BenchConfig::default_sim().unwrap();
        assert_eq!(c.bench.devices, Devices::Sim);
        assert_eq!(c.actuation.idle_after_missed_cycles, 3);
    }

    #[test]
    fn sensor_section_keeps_old_tare_and_checks_the_can_keys() {
        let c = BenchConfig::default_sim().unwrap();
        assert_eq!(c.sensor.interface(Devices::Sim).unwrap().to_string(), "user:simcan0");
        let unset = SensorSection::default();
        assert_eq!(unset.interface(Devices::Sim).unwrap().to_string(), "user:simcan0");
        assert_eq!(c.sensor.codec().unwrap().force_id(), 0x101);
        assert_eq!(c.sensor.calibration().unwrap(), jetbench_io::calib::Calibration::identity());
        // An older config: force-only tare_n, no CAN keys.
        let old = DEFAULT_SIM_CONFIG.replace("tare = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]", "tare_n = [1.0, 2.0, 3.0]");
        let c = BenchConfig::from_toml_str(&old, "old.toml", None).unwrap();
        assert_eq!(c.sensor.tare_offsets(), [1.0, 2.0, 3.0, 0.0, 0.0, 0.0]);
        let both = DEFAULT_SIM_CONFIG.replace("tare = [", "tare_n = [0.0, 0.0, 0.0]\ntare = [");
        let e = BenchConfig::from_toml_str(&both, "t.toml", None).unwrap_err().to_string();
        assert!(e.contains("both tare and tare_n"), "{e}");
        for (from, to, says) in [
            ("can_interface = \"user:simcan0\"", "can_interface = \"can 0\"", "can_interface"),
            ("can_base_id = 0x100", "can_base_id = 0x7fe", "can_base_id"),
            ("[0.0, 0.0, 0.0, 0.0, 0.0, 1.0],", "[0.0, 0.0, 0.0, 0.0, 0.0, nan],", "[5][5]"),
        ] {
            let e = BenchConfig::from_toml_str(&DEFAULT_SIM_CONFIG.replace(from, to), "t.toml", None)
                .unwrap_err()
                .to_string();
            assert!(e.contains(says), "{e}");
        }
        // The config round-trips through TOML (the open-loop launcher writes it).
        let text = toml::to_string(&c).unwrap();
        assert_eq!(BenchConfig::from_toml_str(&text, "rt.toml", None).unwrap(), c);
    }

    #[test]
    fn the_example_bench_config_names_its_serial_ports() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/bench.example.toml");
        let c = BenchConfig::load(&path).unwrap();
        assert_eq!(c.bench.devices, Devices::Bench);
        assert_eq!((c.board_port(), c.actuation.board_baud), (PathBuf::from("/dev/ttyUSB0"), 115_200));
        assert_eq!((c.ecu_port(), c.ecu.baud, c.ecu.poll_hz), (PathBuf::from("/dev/ttyUSB1"), 9600, 10.0));
        // Real-time at the bench, with the built-in priorities and cores.
        assert_eq!(c.rt, RtSection { enabled: true, ..RtSection::default() });
        // 15 Hz does not fit 9600 baud on a real line: refused, with the rate that does.
        let text = std::fs::read_to_string(&path).unwrap().replace("poll_hz = 10.0", "poll_hz = 15.0");
        let e = BenchConfig::from_toml_str(&text, "t.toml", None).unwrap_err().to_string();
        assert!(e.contains("poll_hz = 15") && e.contains("9600-baud") && e.contains("poll at 13 Hz or less"), "{e}");
        // A faster line takes it.
        let fast = text.replace("baud = 9600", "baud = 57600");
        assert_eq!(BenchConfig::from_toml_str(&fast, "t.toml", None).unwrap().ecu.poll_hz, 15.0);
        let text = std::fs::read_to_string(&path).unwrap().replace("port = \"/dev/ttyUSB1\"", "");
        let e = BenchConfig::from_toml_str(&text, "t.toml", None).unwrap_err().to_string();
        assert!(e.contains("[ecu] port"), "{e}");
    }

    #[test]
    fn sim_serial_ports_are_links_in_the_bus_namespace_folder() {
        let c = BenchConfig::default_sim().unwrap();
        let board = c.board_port();
        assert_eq!(board.file_name().and_then(|n| n.to_str()), Some(SIM_BOARD_LINK));
        assert_eq!(board.parent(), c.ecu_port().parent());
        let text = DEFAULT_SIM_CONFIG.replace("poll_hz = 15.0", "poll_hz = 5.0");
        let e = BenchConfig::from_toml_str(&text, "t.toml", None).unwrap_err().to_string();
        assert!(e.contains("poll_hz"), "{e}");
    }

    #[test]
    fn a_bad_gain_or_observer_setting_is_named_by_its_section_and_key() {
        let bad: [(&[&str], toml::Value, &str); 6] = [
            (&["control", "fbl", "kp"], (-1.0).into(), "[control.fbl] controller setting kp = -1"),
            (&["control", "smc", "beta"], (-5.0).into(), "[control.smc] controller setting beta = -5"),
            (&["control", "shaping", "authority"], 1.5.into(), "[control.shaping] controller setting authority = 1.5"),
            (&["control", "mpc", "moves"], 0.into(), "[control.mpc] controller setting moves = 0"),
            (&["estimator", "gate_chi2"], 0.0.into(), "[estimator] gate_chi2 = 0"),
            (&["estimator", "accel_noise_n_per_s2"], 0.0.into(), "[estimator] accel_noise_n_per_s2 = 0"),
        ];
        for (path, value, expected) in bad {
            let mut doc: toml::Table = toml::from_str(DEFAULT_SIM_CONFIG).expect("sim.toml parses");
            let (key, tables) = path.split_last().expect("a key");
            let mut table = &mut doc;
            for name in tables {
                table = table.get_mut(*name).and_then(toml::Value::as_table_mut).expect("the section exists");
            }
            table.insert((*key).into(), value);
            let text = toml::to_string(&doc).expect("serialises");
            let e = match BenchConfig::from_toml_str(&text, "t.toml", None) {
                Ok(_) => panic!("{path:?} was accepted"),
                Err(e) => e.to_string(),
            };
            assert!(e.contains(expected), "{path:?}: {e}");
        }
    }

    #[test]
    fn typo_key_is_an_error_naming_it() {
        let text = DEFAULT_SIM_CONFIG.replace("noise_var_n2", "noise_varn2");
        let e = BenchConfig::from_toml_str(&text, "t.toml", None).unwrap_err().to_string();
        assert!(e.contains("noise_varn2"), "{e}");
    }

    #[test]
    fn an_old_rate_key_is_explained() {
        for rate in ["100.0", "200.0"] {
            let text = DEFAULT_SIM_CONFIG.replace("devices = \"sim\"", &format!("devices = \"sim\"\nrate_hz = {rate}"));
            let e = BenchConfig::from_toml_str(&text, "t.toml", None).unwrap_err().to_string();
            assert!(e.contains("rate_hz") && e.contains("no longer a setting") && e.contains("delete"), "{e}");
        }
    }

    #[test]
    fn unknown_preset_is_an_error() {
        let text = DEFAULT_SIM_CONFIG.replace("model = \"p100-diesel\"\n# Force", "model = \"p999\"\n# Force");
        assert!(BenchConfig::from_toml_str(&text, "t.toml", None).is_err());
    }

    #[test]
    fn effects_reach_the_plant_and_are_no_error_in_the_model() {
        let dir = std::env::temp_dir().join(format!("jetbench-config-effects-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut file = jetbench_model::ModelFile::new(jetbench_model::Preset::P100Diesel.params());
        file.effects = jetbench_model::Effects::new(["input_delay:delay_s=0.1".parse().unwrap()]).unwrap();
        file.save(&dir.join("delayed.toml")).unwrap();
        let text = DEFAULT_SIM_CONFIG.replace("model = \"p100-diesel\"", "model = \"delayed.toml\"");
        let c = BenchConfig::from_toml_str(&text, "t.toml", Some(&dir)).unwrap();
        assert_eq!(c.plant().unwrap(), file.plant());
        assert_eq!(c.model_params().unwrap(), file.model);
        // A paced model may be the plant, never the model the bench runs on.
        file.effects =
            jetbench_model::Effects::new(["accel_schedule:up_n_per_s=300,down_n_per_s=300,exponent=1.5,offset_n=3"
                .parse()
                .unwrap()])
            .unwrap();
        file.save(&dir.join("paced.toml")).unwrap();
        let (preset, paced) = ("model = \"p100-diesel\"", "model = \"paced.toml\"");
        let as_plant = DEFAULT_SIM_CONFIG.replacen(preset, paced, 1);
        let c = BenchConfig::from_toml_str(&as_plant, "t.toml", Some(&dir)).unwrap();
        assert_eq!(c.plant().unwrap(), file.plant());
        let at = DEFAULT_SIM_CONFIG.find("[model]").expect("a [model] table");
        let as_model = format!("{}{}", &DEFAULT_SIM_CONFIG[..at], DEFAULT_SIM_CONFIG[at..].replacen(preset, paced, 1));
        let err = BenchConfig::from_toml_str(&as_model, "t.toml", Some(&dir)).unwrap_err().to_string();
        assert!(err.contains("accel_schedule") && err.contains("--schedule"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn overrides_change_their_keys_and_nothing_else() {
        let base = BenchConfig::default_sim().unwrap();
        assert!(Overrides::default().is_empty());
        assert_eq!(base.with_overrides(&Overrides::default()).unwrap(), base);
        let overrides = Overrides {
            controller: Some(Controller::Smc),
            model: Some("p100-diesel".into()),
            plant: Some("p100-diesel".into()),
            profile: Some("ramps".into()),
            inject: vec!["spikes:rate_per_s=1,size_n=20".into()],
            ..Overrides::default()
        };
        assert!(!overrides.is_empty());
        let changed = base.with_overrides(&overrides).unwrap();
        assert_eq!(changed.control.controller, Controller::Smc);
        assert_eq!((changed.model.model.as_str(), changed.plant.model.as_str()), ("p100-diesel", "p100-diesel"));
        assert_ne!(changed.reference, base.reference, "the ramps profile replaces the config's");
        assert_eq!(changed.plant.inject.last().map(String::as_str), Some("spikes:rate_per_s=1,size_n=20"));
        let restored = BenchConfig {
            control: base.control.clone(),
            model: base.model.clone(),
            plant: base.plant.clone(),
            reference: base.reference.clone(),
            ..changed
        };
        assert_eq!(restored, base, "nothing but the overridden keys changed");
    }

    #[test]
    fn a_bad_override_is_an_error_naming_its_key() {
        let base = BenchConfig::default_sim().unwrap();
        let bad_model = Overrides { model: Some("no-such-model.toml".into()), ..Overrides::default() };
        assert!(base.with_overrides(&bad_model).is_err());
        let bad_inject = Overrides { inject: vec!["spikes:rate_per_s=-1".into()], ..Overrides::default() };
        let e = base.with_overrides(&bad_inject).unwrap_err().to_string();
        assert!(e.contains("command-line options"), "{e}");
    }
}
