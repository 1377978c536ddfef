//! One `jetbench latency` run: does the 100 Hz loop hold under load?
//!
//! Under one background load and one set of real-time settings it measures
//! three things:
//! 1. the service set on the simulated bench over iceoryx2 (real processes,
//!    the real bus, recorded), cycle by cycle from the samples' own stamps
//!    ([`crate::pipeline`]);
//! 2. the same service set with every sample copied through Unix domain
//!    sockets instead (`jetbench up --transport uds`): the copying baseline,
//!    measured the same way;
//! 3. the machine's floor: a bare eventfd ping chained through as many
//!    processes as the control path has, at the same priorities and CPUs
//!    ([`crate::chain`]).
//!
//! A virtual machine's speed drifts with its host's load, so measurements
//! taken one after the other would mix the transport with the time of day:
//! the duration is split into rounds, each measuring all three in turn (in
//! alternating order), and the rounds' histograms are merged. The report
//! states the pipeline's figures as ratios to the floor and to the baseline.

use std::collections::BTreeMap;
use std::fmt;
use std::os::fd::AsFd;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use jetbench_bus::Transport;
use jetbench_record::Recording;
use jetbench_stack::config::{BenchConfig, ConfigError, Devices};
use jetbench_stack::runtime::rt::RtOutcome;
use jetbench_stack::runtime::supervise::describe_exit;
use serde::Serialize;

use crate::chain::{run_chain, stage_rt_requests, ChainError, ChainOptions, ChainRun, HOPS as FLOOR_HOPS};
use crate::control_room::{CommandReport, Commanding, ControlRoom, ControlRoomReport, RoomPki};
use crate::load::{Load, LoadError, LoadKind};
use crate::pipeline::{analyse_pipeline, LatencyHistogram, Percentiles, PipelineAnalysis, HOPS};
use crate::steal::{steal_ms_per_cpu, StealSampler, StealTimeline};

/// What one run measures.
#[derive(Clone, Debug)]
pub struct CampaignOptions {
    /// Seconds to measure each of the three, spread over the rounds.
    pub duration_s: f64,
    /// Rounds the duration is split into; each measures all three in turn.
    pub rounds: u32,
    /// Seconds at the start of each service-set run left out (start-up).
    pub warmup_s: f64,
    /// Background load on every core while measuring.
    pub load: LoadKind,
    /// The config's `[rt]` settings for the services and the floor chain.
    pub rt: bool,
    /// Bench config of the simulated bench (`None`: the built-in one).
    pub config: Option<PathBuf>,
    /// Keep the service sets' recordings here (`<transport>-<round>.mcap`).
    pub keep: Option<PathBuf>,
    /// The `jetbench` binary: it runs the service sets (`up`), the floor's
    /// stages (`latency-stage`) and the built-in load (`latency-load`).
    pub exe: PathBuf,
    /// Also measure the service set over iceoryx2 with the control room
    /// attached: the viewer and the bridge running, with Foxglove clients that
    /// read, never read and disconnect, a Zenoh subscriber, and an operator's
    /// client commanding the bench over TLS every 100 ms, through an
    /// `[operator]` section and certificates the run makes ([`crate::control_room`]).
    pub control_room: bool,
}

/// Why a run could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum CampaignError {
    /// Options that leave nothing to measure.
    #[error("{0}")]
    Options(String),
    /// The bench config does not load.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The background load did not start.
    #[error(transparent)]
    Load(#[from] LoadError),
    /// A file or folder of the run.
    #[error("cannot {what} {path}: {source}")]
    Io {
        /// What was being done, e.g. `create`.
        what: &'static str,
        /// The file or folder.
        path: PathBuf,
        /// The system's reason.
        source: std::io::Error,
    },
    /// `jetbench up` did not start.
    #[error("cannot start `jetbench up` from {exe}: {source}")]
    Launch {
        /// The `jetbench` binary.
        exe: PathBuf,
        /// The system's reason.
        source: std::io::Error,
    },
    /// A service set exited with an error or was killed.
    #[error("the service set over {transport} failed ({how}); its log is above{}",
        log.as_ref().map(|l| format!(" and in {}", l.display())).unwrap_or_default())]
    Pipeline {
        /// The set's transport.
        transport: Transport,
        /// How it ended (exit code or signal).
        how: String,
        /// Its kept log, with `--keep`.
        log: Option<PathBuf>,
    },
    /// A service set's recording does not read back.
    #[error("cannot read back the {transport} run's recording {path}: {source}")]
    Recording {
        /// The set's transport.
        transport: Transport,
        /// The recording.
        path: PathBuf,
        /// Why it does not read.
        source: jetbench_record::RecordError,
    },
    /// A service set ran but not one cycle went from the sensor to the board.
    #[error("the {transport} run's recording {} has no complete cycle", path.display())]
    NoCycle {
        /// The set's transport.
        transport: Transport,
        /// The recording.
        path: PathBuf,
    },
    /// The control room's certificates or config could not be made.
    #[error("cannot set up the control room's operator: {0}")]
    ControlRoom(String),
    /// The floor chain failed.
    #[error(transparent)]
    Chain(#[from] ChainError),
    /// The thread running the floor chain panicked (a bug: reported, not hidden).
    #[error("the floor chain's thread panicked")]
    ChainPanicked,
}

/// How a run shows its progress: one phase of known length after another.
pub trait Progress {
    /// A phase of `seconds` begins.
    fn start(&mut self, what: &str, seconds: f64);
    /// `elapsed_s` of the current phase have passed.
    fn advance(&mut self, elapsed_s: f64);
    /// The current phase is over.
    fn finish(&mut self);
    /// True when progress is drawn live on a terminal: the service sets'
    /// output then goes to a log file beside each recording, not to stderr.
    fn is_live(&self) -> bool;
    /// Something the user should know (the load, a refused setting).
    fn note(&mut self, line: &str);
}

/// One of the three measurements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Measurement {
    Pipeline(Transport),
    /// The iceoryx2 set with the viewer, the bridge and their clients, and
    /// with or without the operator who `commands` (the difference is what
    /// the commands cost; the set without any of it is what watching costs).
    ControlRoom {
        commands: bool,
    },
    Floor,
}

impl Measurement {
    /// Round `r` measures in this order; odd rounds reverse it, so drift
    /// over the run favours none of them.
    fn order(round: u32, control_room: bool) -> Vec<Measurement> {
        let mut order = vec![Measurement::Pipeline(Transport::Iceoryx2)];
        if control_room {
            order.extend([Measurement::ControlRoom { commands: false }, Measurement::ControlRoom { commands: true }]);
        }
        order.extend([Measurement::Pipeline(Transport::UnixSockets), Measurement::Floor]);
        if !round.is_multiple_of(2) {
            order.reverse();
        }
        order
    }

    fn describe(self) -> &'static str {
        match self {
            Measurement::Pipeline(Transport::Iceoryx2) => "service set over iceoryx2",
            Measurement::Pipeline(Transport::UnixSockets) => "service set over Unix sockets",
            Measurement::ControlRoom { commands: false } => "iceoryx2 set, control room watching",
            Measurement::ControlRoom { commands: true } => "iceoryx2 set, control room watching and commanding",
            Measurement::Floor => "floor: eventfd ping chain",
        }
    }
}

/// The floor chain's results, over every round.
#[derive(Default)]
pub struct FloorResult {
    /// First stage woken → last stage done, per cycle.
    pub e2e: LatencyHistogram,
    /// Per hop of the chain (one per process hand-over of the control path).
    pub hops: [LatencyHistogram; FLOOR_HOPS],
    /// Cycles the chain dropped (a stage still busy with the previous one).
    pub lost: u64,
    /// Real-time settings the kernel refused the chain's stages (each once).
    pub refused: Vec<String>,
}

impl FloorResult {
    fn add(&mut self, run: &ChainRun) {
        for cycle in &run.cycles {
            self.e2e.record(cycle.e2e_ns());
            for (h, ns) in self.hops.iter_mut().zip(cycle.hop_ns()) {
                h.record(ns);
            }
        }
        self.lost += run.lost;
        for r in run.stages.iter().flat_map(|s| &s.rt.refused) {
            add_once(&mut self.refused, r);
        }
    }
}

fn add_once(list: &mut Vec<String>, item: &str) {
    if !list.iter().any(|r| r == item) {
        list.push(item.to_string());
    }
}

/// What the copying baseline measured, beside its end-to-end latency.
#[derive(Serialize)]
pub struct BaselineReport {
    /// Sensor cycles judged ([`PipelineAnalysis::cycles`]).
    pub cycles: u64,
    /// Of those, cycles whose command reached the board.
    pub completed: u64,
    /// [`PipelineAnalysis::deadline_misses`].
    pub deadline_misses: u64,
    /// [`PipelineAnalysis::lost`].
    pub lost: u64,
    /// Per hop of the control path ([`HOPS`]), µs.
    pub hops_us: BTreeMap<&'static str, Percentiles>,
    /// |time between sensor cycles − 10 ms|, µs.
    pub period_jitter_us: Percentiles,
}

/// Everything one run measured, as `--json` prints it; [`fmt::Display`] is the text report.
#[derive(Serialize)]
pub struct Report {
    /// Seconds measured of each of the three ([`CampaignOptions::duration_s`]).
    pub duration_s: f64,
    /// Rounds the duration was split into.
    pub rounds: u32,
    /// The background load ([`LoadKind::name`]).
    pub load: String,
    /// True when the config's `[rt]` settings were asked for (`--rt`).
    pub rt_requested: bool,
    /// Real-time settings the kernel refused (each once); empty when all held.
    pub rt_refused: Vec<String>,
    /// iceoryx2 set: sensor cycles judged, after each run's warm-up.
    pub cycles: u64,
    /// Of those, cycles whose command reached the board.
    pub completed: u64,
    /// Deadline misses: `late_e2e + late_periods + superseded`.
    pub deadline_misses: u64,
    /// Cycles whose command was written more than one 10 ms period after the sensor frame.
    pub late_e2e: u64,
    /// Sensor cycles more than 20 ms after the previous one.
    pub late_periods: u64,
    /// Cycles whose command a newer one replaced before actuation wrote it.
    pub superseded: u64,
    /// Samples lost anywhere: `frames_lost`, the `seq_gaps` and `unfinished`.
    pub lost: u64,
    /// Sensor frames lost before sensing (jumps of the sensor's frame counter).
    pub frames_lost: u64,
    /// Cycles a stage produced nothing for (the run's last 0.5 s excepted).
    pub unfinished: u64,
    /// `seq` gaps per recorded channel: samples lost between publisher and recorder.
    pub seq_gaps: BTreeMap<String, u64>,
    /// Deadline misses each service counted itself.
    pub service_deadline_misses: BTreeMap<String, u64>,
    /// Sensor frame received → command frame written, µs.
    pub e2e_us: Percentiles,
    /// Per hop of the control path ([`HOPS`]), µs.
    pub hops_us: BTreeMap<&'static str, Percentiles>,
    /// |time between sensor cycles − 10 ms|, µs.
    pub period_jitter_us: Percentiles,
    /// The floor chain, first stage woken → last stage done, µs: what the machine
    /// gives any chain of processes, none of our code in it.
    pub floor_us: Percentiles,
    /// The floor chain per hop, µs.
    pub floor_hops_us: Vec<Percentiles>,
    /// Cycles the floor chain dropped.
    pub floor_lost: u64,
    /// The same service set over Unix domain sockets: its end-to-end latency.
    pub uds_us: Percentiles,
    /// The Unix-socket set's counts, hops and jitter.
    pub uds: BaselineReport,
    /// CPU time the hypervisor took per CPU while measuring, ms
    /// (empty where the kernel does not report steal).
    pub steal_ms: Vec<f64>,
    /// Deadline misses of the iceoryx2 runs that came within 40 ms before to
    /// 20 ms after the hypervisor took a CPU (a bench PC has no hypervisor).
    pub misses_during_steal: u64,
    /// The iceoryx2 set against the floor and the baseline.
    pub ratios: Ratios,
    /// The iceoryx2 set with the control room attached (`--control-room`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub control_room: Option<ControlRoomCost>,
}

/// The iceoryx2 set's end-to-end latency as ratios: to the machine's floor (how much
/// our code and the bus add to what any chain of processes costs; it does not move
/// with the VM's speed the way absolute figures do) and to the copying baseline.
#[derive(Serialize)]
pub struct Ratios {
    /// Pipeline p99 / floor p99.
    pub e2e_p99_over_floor_p99: f64,
    /// Pipeline p50 / floor p50.
    pub e2e_p50_over_floor_p50: f64,
    /// iceoryx2 p50 / Unix sockets p50, the same service set.
    pub e2e_p50_over_uds_p50: f64,
    /// iceoryx2 p99 / Unix sockets p99, the same service set.
    pub e2e_p99_over_uds_p99: f64,
}

/// A whole run: the report and the distributions behind it.
pub struct Campaign {
    /// The figures, as printed.
    pub report: Report,
    /// The iceoryx2 set, every round merged.
    pub iceoryx2: PipelineAnalysis,
    /// The Unix-socket set, every round merged.
    pub uds: PipelineAnalysis,
    /// The floor chain, every round merged.
    pub floor: FloorResult,
    /// The iceoryx2 set with the control room attached (`--control-room`).
    pub control_room: Option<PipelineAnalysis>,
}

/// Where the control room of one run connects: a Foxglove port, a Zenoh
/// endpoint and the operators' TLS endpoint on this machine, free when
/// reserved, and the bench config whose `[operator]` section listens there.
struct Room {
    foxglove: std::net::SocketAddr,
    zenoh: String,
    commanding: Commanding,
    config: PathBuf,
}

impl Room {
    /// Reserves the ports and writes `config` (the run's bench config with an
    /// `[operator]` section trusting `pki`'s operator) to `path`.
    fn new(config: &BenchConfig, pki: &RoomPki, path: &Path) -> Result<Room, CampaignError> {
        let io = |what: &'static str, path: &Path| {
            let path = path.to_path_buf();
            move |source| CampaignError::Io { what, path, source }
        };
        let free = || std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr());
        let (foxglove, zenoh, tls) = (
            free().map_err(io("reserve a port on", Path::new("127.0.0.1")))?,
            free().map_err(io("reserve a port on", Path::new("127.0.0.1")))?,
            free().map_err(io("reserve a port on", Path::new("127.0.0.1")))?,
        );
        let tls = format!("tls/{tls}");
        let mut config = config.clone();
        config.operator = Some(pki.settings(&tls));
        let text = toml::to_string(&config).map_err(|e| CampaignError::ControlRoom(format!("config: {e}")))?;
        std::fs::write(path, text).map_err(io("write", path))?;
        let endpoint = tls.parse().map_err(|e| CampaignError::ControlRoom(format!("{e}")))?;
        Ok(Room {
            foxglove,
            zenoh: format!("tcp/{zenoh}"),
            commanding: Commanding { endpoint, pki: pki.clone() },
            config: path.to_path_buf(),
        })
    }

    /// The arguments of `jetbench up` that start the viewer and the bridge there.
    fn up_args(&self) -> Vec<String> {
        vec!["--foxglove".into(), self.foxglove.to_string(), "--zenoh".into(), self.zenoh.clone()]
    }

    /// The clients, connecting as soon as the services are up, on `cpus`;
    /// the operator among them when `commands`.
    fn attach(&self, cpus: Vec<usize>, commands: bool) -> ControlRoom {
        let endpoint = self.zenoh.parse().expect("a tcp/HOST:PORT endpoint made here");
        ControlRoom::attach(
            self.foxglove,
            endpoint,
            jetbench_bus::namespace_name().unwrap_or_else(|_| "default".into()),
            cpus,
            commands.then(|| self.commanding.clone()),
        )
    }
}

/// Counts, in a control-room run's recording, the operator's commands on
/// `bench/operator`, the control service's acceptances of them and any
/// `DEADMAN` event.
fn count_recorded_commands(recording: &Recording, report: &mut CommandReport) {
    use jetbench_msgs::{channels, event_kinds, identity_text};
    let ours = |identity: &[u8; jetbench_msgs::IDENTITY_LEN]| identity_text(identity) == crate::control_room::OPERATOR;
    report.recorded = recording.samples(channels::OPERATOR).iter().filter(|c| ours(&c.identity)).count() as u64;
    let events = recording.samples(channels::EVENTS);
    report.recorded_accepted =
        events.iter().filter(|e| e.kind == event_kinds::COMMAND_ACCEPTED && ours(&e.identity)).count() as u64;
    report.deadman_events = events.iter().filter(|e| e.kind == event_kinds::DEADMAN).count() as u64;
}

/// What the control room cost the loop: the iceoryx2 set with the control
/// room attached and commanding, against the same set with the control room
/// only watching (what the commands cost) and without it (what the whole
/// control room costs), from the same rounds.
#[derive(Serialize)]
pub struct ControlRoomCost {
    /// End-to-end latency with the control room attached and commanding, µs.
    pub e2e_us: Percentiles,
    /// End-to-end latency with the control room attached, watching only, µs.
    pub watching_e2e_us: Percentiles,
    /// Deadline misses with the control room watching only.
    pub watching_deadline_misses: u64,
    /// Of those, the ones within 40 ms after or 20 ms before the hypervisor stole a CPU.
    pub watching_misses_during_steal: u64,
    /// p99 commanding / p99 watching: what the operator's commands cost.
    pub commands_e2e_p99_ratio: f64,
    /// p50 commanding / p50 watching.
    pub commands_e2e_p50_ratio: f64,
    /// Sensor cycles judged with it attached.
    pub cycles: u64,
    /// Deadline misses with it attached.
    pub deadline_misses: u64,
    /// Of those, the ones within 40 ms after or 20 ms before the hypervisor stole a CPU.
    pub misses_during_steal: u64,
    /// Deadline misses of the same set without it, in the same rounds.
    pub deadline_misses_without: u64,
    /// End-to-end p99 of the same set without it, µs (the report's `e2e_us.p99`).
    pub e2e_p99_us_without: f64,
    /// Samples lost with it attached.
    pub lost: u64,
    /// Deadline misses each service counted itself, with it attached.
    pub service_deadline_misses: BTreeMap<String, u64>,
    /// Deadline misses per 1000 cycles with the control room, and without it.
    pub misses_per_1000: f64,
    /// Deadline misses per 1000 cycles without it.
    pub misses_per_1000_without: f64,
    /// p99 with / p99 without.
    pub e2e_p99_ratio: f64,
    /// p50 with / p50 without.
    pub e2e_p50_ratio: f64,
    /// What the clients did, one per round.
    pub clients: Vec<ControlRoomReport>,
}

/// The deadline misses of `pipeline` within 40 ms after or 20 ms before the
/// hypervisor stole a CPU (a stolen CPU stalls every process on it).
fn misses_during_steal(steal: &StealTimeline, pipeline: &PipelineAnalysis) -> u64 {
    let stolen = |t: u64| steal.stolen_ms(t.saturating_sub(40_000_000), t + 20_000_000) > 0.0;
    pipeline.miss_stamps_ns.iter().filter(|&&t| stolen(t)).count() as u64
}

impl ControlRoomCost {
    fn of(
        watched: &PipelineAnalysis,
        watching: &PipelineAnalysis,
        plain: &PipelineAnalysis,
        clients: &[ControlRoomReport],
        steal: &StealTimeline,
    ) -> Self {
        let (with, without) = (watched.e2e.percentiles(), plain.e2e.percentiles());
        let looking = watching.e2e.percentiles();
        let per_1000 = |p: &PipelineAnalysis| 1000.0 * p.deadline_misses() as f64 / p.cycles.max(1) as f64;
        ControlRoomCost {
            e2e_us: with,
            watching_e2e_us: looking,
            watching_deadline_misses: watching.deadline_misses(),
            watching_misses_during_steal: misses_during_steal(steal, watching),
            commands_e2e_p99_ratio: ratio(with.p99, looking.p99),
            commands_e2e_p50_ratio: ratio(with.p50, looking.p50),
            cycles: watched.cycles,
            deadline_misses: watched.deadline_misses(),
            misses_during_steal: misses_during_steal(steal, watched),
            deadline_misses_without: plain.deadline_misses(),
            e2e_p99_us_without: without.p99,
            lost: watched.lost(),
            service_deadline_misses: watched.service_deadline_misses.clone(),
            misses_per_1000: per_1000(watched),
            misses_per_1000_without: per_1000(plain),
            e2e_p99_ratio: ratio(with.p99, without.p99),
            e2e_p50_ratio: ratio(with.p50, without.p50),
            clients: clients.to_vec(),
        }
    }
}

impl Campaign {
    /// The three end-to-end distributions, named as a plot labels them.
    pub fn distributions(&self) -> [(&'static str, &LatencyHistogram); 3] {
        [
            ("service set over iceoryx2", &self.iceoryx2.e2e),
            ("service set over Unix sockets", &self.uds.e2e),
            ("floor: eventfd ping chain", &self.floor.e2e),
        ]
    }
}

impl CampaignOptions {
    fn check(&self) -> Result<(), CampaignError> {
        let bad = |m: String| Err(CampaignError::Options(m));
        if !(self.duration_s.is_finite() && self.duration_s >= 1.0) {
            return bad(format!("--duration {} must be at least 1 second", self.duration_s));
        }
        if !(self.warmup_s.is_finite() && self.warmup_s >= 0.0) {
            return bad(format!("--warmup {} must be a number of seconds >= 0", self.warmup_s));
        }
        if self.rounds == 0 || self.duration_s / f64::from(self.rounds) < 1.0 {
            return bad(format!(
                "--rounds {} must be at least 1 and leave each round 1 s of --duration {}",
                self.rounds, self.duration_s
            ));
        }
        Ok(())
    }
}

/// Measures the three in rounds under the load; blocks for about three times
/// the duration plus start-ups.
pub fn run_campaign(options: &CampaignOptions, progress: &mut dyn Progress) -> Result<Campaign, CampaignError> {
    options.check()?;
    let config = BenchConfig::load_or_default(options.config.as_deref())?;
    if config.bench.devices != Devices::Sim {
        return Err(CampaignError::Options(
            "`jetbench latency` runs the simulated bench: the config must have [bench] devices = \"sim\"".into(),
        ));
    }
    let (work, temporary) = match &options.keep {
        Some(dir) => (dir.clone(), false),
        None => (std::env::temp_dir().join(format!("jetbench-latency-{}", std::process::id())), true),
    };
    std::fs::create_dir_all(&work).map_err(|source| CampaignError::Io {
        what: "create",
        path: work.clone(),
        source,
    })?;

    let mut rt_refused = if options.rt { probe_rt(&config) } else { Vec::new() };
    for refusal in &rt_refused {
        progress.note(&format!("warning: {refusal}; measuring without it"));
    }
    let mut load = Load::start(options.load, &options.exe)?;
    progress.note(&format!("load: {}", load.description));
    // Let the load reach every core before measuring.
    std::thread::sleep(Duration::from_secs(1));

    let segment_s = options.duration_s / f64::from(options.rounds);
    let steal_before = steal_ms_per_cpu();
    let steal_sampler = StealSampler::start();
    let (mut iceoryx2, mut uds, mut floor) =
        (PipelineAnalysis::default(), PipelineAnalysis::default(), FloorResult::default());
    let mut watched = options.control_room.then(|| (PipelineAnalysis::default(), Vec::new()));
    let mut watching = PipelineAnalysis::default();
    // The control room's operator: certificates made for this run, and the
    // run's config with an `[operator]` section that trusts them.
    let pki = if options.control_room {
        Some(RoomPki::make(&work.join("control-room-pki")).map_err(CampaignError::ControlRoom)?)
    } else {
        None
    };
    for round in 0..options.rounds {
        for measurement in Measurement::order(round, options.control_room) {
            let what = format!("round {}/{}: {}", round + 1, options.rounds, measurement.describe());
            let (transport, name) = match measurement {
                Measurement::Floor => {
                    floor.add(&run_floor(options, &config, segment_s, &what, progress)?);
                    continue;
                }
                Measurement::Pipeline(transport) => (transport, transport.name()),
                Measurement::ControlRoom { commands: false } => (Transport::Iceoryx2, "control-room-watching"),
                Measurement::ControlRoom { commands: true } => (Transport::Iceoryx2, "control-room"),
            };
            let path = work.join(format!("{name}-{}.mcap", round + 1));
            let clients = match (measurement, &pki) {
                (Measurement::ControlRoom { commands }, Some(pki)) => {
                    let room = Room::new(&config, pki, &work.join(format!("{name}-{}.toml", round + 1)))?;
                    let args = room.up_args();
                    // Under --rt, the clients (another computer) where the viewer runs.
                    let cpus = if options.rt { config.rt.cpus.viewer.clone().unwrap_or_default() } else { Vec::new() };
                    let attached = room.attach(cpus, commands);
                    let ran =
                        run_pipeline(options, &path, transport, segment_s, &what, &args, Some(&room.config), progress);
                    let clients = attached.finish();
                    ran?;
                    Some(clients)
                }
                _ => {
                    run_pipeline(
                        options,
                        &path,
                        transport,
                        segment_s,
                        &what,
                        &[],
                        options.config.as_deref(),
                        progress,
                    )?;
                    None
                }
            };
            let recording = Recording::open(&path).map_err(|source| CampaignError::Recording {
                transport,
                path: path.clone(),
                source,
            })?;
            let analysis = analyse_pipeline(&recording, options.warmup_s);
            if analysis.completed == 0 {
                return Err(CampaignError::NoCycle { transport, path });
            }
            match (measurement, watched.as_mut(), clients) {
                (Measurement::ControlRoom { commands: false }, ..) => watching.merge(&analysis),
                (Measurement::ControlRoom { commands: true }, Some((total, reports)), Some(mut clients)) => {
                    total.merge(&analysis);
                    count_recorded_commands(&recording, &mut clients.commands);
                    reports.push(clients);
                }
                (Measurement::Pipeline(Transport::Iceoryx2), ..) => iceoryx2.merge(&analysis),
                _ => uds.merge(&analysis),
            }
            if options.keep.is_none() {
                let _ = std::fs::remove_file(&path);
            }
        }
    }
    let steal_ms: Vec<f64> = match (steal_before, steal_ms_per_cpu()) {
        (Some(a), Some(b)) if a.len() == b.len() => b.iter().zip(&a).map(|(b, a)| (b - a).max(0.0)).collect(),
        _ => Vec::new(),
    };
    let steal = steal_sampler.map(StealSampler::finish).unwrap_or_default();
    let misses_during_steal = misses_during_steal(&steal, &iceoryx2);
    if !load.running() {
        progress.note(&format!("warning: the load `{}` ended before the measurements did", load.description));
    }
    let load_description = load.description.clone();
    drop(load);
    if temporary {
        let _ = std::fs::remove_dir_all(&work);
    }
    for r in &floor.refused {
        add_once(&mut rt_refused, r);
    }
    let mut report =
        build_report(options, load_description, rt_refused, &iceoryx2, &uds, &floor, steal_ms, misses_during_steal);
    report.control_room = watched
        .as_ref()
        .map(|(pipeline, clients)| ControlRoomCost::of(pipeline, &watching, &iceoryx2, clients, &steal));
    Ok(Campaign { report, iceoryx2, uds, floor, control_room: watched.map(|(pipeline, _)| pipeline) })
}

/// Waits for `finished` while a phase of `seconds` shows its progress.
fn follow<T>(progress: &mut dyn Progress, what: &str, seconds: f64, mut finished: impl FnMut() -> Option<T>) -> T {
    progress.start(what, seconds);
    let started = Instant::now();
    let result = loop {
        if let Some(result) = finished() {
            break result;
        }
        progress.advance(started.elapsed().as_secs_f64());
        std::thread::sleep(Duration::from_millis(100));
    };
    progress.finish();
    result
}

/// Runs the floor chain for `seconds` at the services' real-time settings.
fn run_floor(
    options: &CampaignOptions,
    config: &BenchConfig,
    seconds: f64,
    what: &str,
    progress: &mut dyn Progress,
) -> Result<ChainRun, CampaignError> {
    let mut chain = ChainOptions::new(&options.exe);
    chain.duration = Duration::from_secs_f64(seconds);
    chain.rt = stage_rt_requests(&config.rt, options.rt);
    let handle = std::thread::spawn(move || run_chain(&chain));
    follow(progress, what, seconds, || handle.is_finished().then_some(()));
    Ok(handle.join().map_err(|_| CampaignError::ChainPanicked)??)
}

/// What the kernel would refuse of each service's `[rt]` request.
fn probe_rt(config: &BenchConfig) -> Vec<String> {
    let mut refused: Vec<String> = Vec::new();
    for id in jetbench_msgs::ServiceId::ALL {
        let Some(request) = config.rt.request(id, true) else { continue };
        let outcome: RtOutcome = jetbench_stack::runtime::rt::probe(&request);
        for r in &outcome.refused {
            add_once(&mut refused, r);
        }
    }
    refused
}

/// Runs `jetbench up --sim` over `transport` for warm-up + `seconds`, recording every
/// channel, with the bench config `config` (`None`: the built-in one).
#[allow(clippy::too_many_arguments)]
fn run_pipeline(
    options: &CampaignOptions,
    recording: &Path,
    transport: Transport,
    seconds: f64,
    what: &str,
    extra: &[String],
    config: Option<&Path>,
    progress: &mut dyn Progress,
) -> Result<(), CampaignError> {
    let seconds = options.warmup_s + seconds;
    let mut command = Command::new(&options.exe);
    command
        .args(["up", "--sim", "--quiet", "--transport", transport.name(), "--duration", &seconds.to_string()])
        .arg("--record")
        .arg(recording)
        .args(extra);
    if let Some(config) = config {
        command.arg("--config").arg(config);
    }
    if options.rt {
        command.arg("--rt");
    }
    // Under a live progress bar the launcher's output goes to a log beside the
    // recording; otherwise to stderr, so that stdout keeps only the results.
    let log = progress.is_live().then(|| recording.with_extension("log"));
    let io_error = |what, path: &Path| {
        let path = path.to_path_buf();
        move |source| CampaignError::Io { what, path, source }
    };
    let (out, err) = match &log {
        None => {
            let stderr =
                std::io::stderr().as_fd().try_clone_to_owned().map_err(io_error("pass on", Path::new("stderr")))?;
            (Stdio::from(stderr), Stdio::inherit())
        }
        Some(log) => {
            let file = std::fs::File::create(log).map_err(io_error("create", log))?;
            (Stdio::from(file.try_clone().map_err(io_error("reopen", log))?), Stdio::from(file))
        }
    };
    let mut child = command
        .stdin(Stdio::null())
        .stdout(out)
        .stderr(err)
        .spawn()
        .map_err(|source| CampaignError::Launch { exe: options.exe.clone(), source })?;
    let status = follow(progress, what, seconds, || child.try_wait().ok().flatten());
    if !status.success() {
        if let Some(text) = log.as_ref().and_then(|l| std::fs::read_to_string(l).ok()) {
            let lines: Vec<&str> = text.lines().collect();
            progress.note(&lines[lines.len().saturating_sub(30)..].join("\n"));
        }
        return Err(CampaignError::Pipeline { transport, how: describe_exit(status), log });
    }
    if let Some(log) = log {
        let _ = std::fs::remove_file(log);
    }
    Ok(())
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else {
        f64::NAN
    }
}

fn hops_of(pipeline: &PipelineAnalysis) -> BTreeMap<&'static str, Percentiles> {
    HOPS.iter().copied().zip(pipeline.hops.iter().map(LatencyHistogram::percentiles)).collect()
}

#[allow(clippy::too_many_arguments)]
fn build_report(
    options: &CampaignOptions,
    load: String,
    rt_refused: Vec<String>,
    pipeline: &PipelineAnalysis,
    uds: &PipelineAnalysis,
    floor: &FloorResult,
    steal_ms: Vec<f64>,
    misses_during_steal: u64,
) -> Report {
    let (e2e, uds_e2e, floor_e2e) = (pipeline.e2e.percentiles(), uds.e2e.percentiles(), floor.e2e.percentiles());
    Report {
        duration_s: options.duration_s,
        rounds: options.rounds,
        load,
        rt_requested: options.rt,
        rt_refused,
        cycles: pipeline.cycles,
        completed: pipeline.completed,
        deadline_misses: pipeline.deadline_misses(),
        late_e2e: pipeline.late_e2e,
        late_periods: pipeline.late_periods,
        superseded: pipeline.superseded,
        lost: pipeline.lost(),
        frames_lost: pipeline.frames_lost,
        unfinished: pipeline.unfinished,
        seq_gaps: pipeline.seq_gaps.clone(),
        service_deadline_misses: pipeline.service_deadline_misses.clone(),
        e2e_us: e2e,
        hops_us: hops_of(pipeline),
        period_jitter_us: pipeline.period_jitter.percentiles(),
        floor_us: floor_e2e,
        floor_hops_us: floor.hops.iter().map(LatencyHistogram::percentiles).collect(),
        floor_lost: floor.lost,
        uds_us: uds_e2e,
        uds: BaselineReport {
            cycles: uds.cycles,
            completed: uds.completed,
            deadline_misses: uds.deadline_misses(),
            lost: uds.lost(),
            hops_us: hops_of(uds),
            period_jitter_us: uds.period_jitter.percentiles(),
        },
        steal_ms,
        misses_during_steal,
        ratios: Ratios {
            e2e_p99_over_floor_p99: ratio(e2e.p99, floor_e2e.p99),
            e2e_p50_over_floor_p50: ratio(e2e.p50, floor_e2e.p50),
            e2e_p50_over_uds_p50: ratio(e2e.p50, uds_e2e.p50),
            e2e_p99_over_uds_p99: ratio(e2e.p99, uds_e2e.p99),
        },
        control_room: None,
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let r = self;
        let rt = if !r.rt_requested {
            "off".to_string()
        } else if r.rt_refused.is_empty() {
            "on".to_string()
        } else {
            format!("asked for, partly refused ({})", r.rt_refused.join("; "))
        };
        writeln!(
            f,
            "jetbench latency: {:.0} s per measurement in {} rounds, load {}, real-time settings {rt}",
            r.duration_s, r.rounds, r.load
        )?;
        writeln!(f)?;
        writeln!(f, "latency, µs                                   p50      p90      p99    p99.9       max")?;
        writeln!(f, "service set over iceoryx2, frame → board {}", r.e2e_us.row())?;
        for (name, p) in &r.hops_us {
            writeln!(f, "  hop {name:<37}{}", p.row())?;
        }
        writeln!(f, "  sensing period jitter                  {}", r.period_jitter_us.row())?;
        if let Some(room) = &r.control_room {
            writeln!(f, "same set, control room watching         {}", room.watching_e2e_us.row())?;
            writeln!(f, "same set, control room commanding       {}", room.e2e_us.row())?;
        }
        writeln!(f, "same service set over Unix sockets      {}", r.uds_us.row())?;
        for (name, p) in &r.uds.hops_us {
            writeln!(f, "  hop {name:<37}{}", p.row())?;
        }
        writeln!(f, "floor: eventfd ping, {FLOOR_HOPS} hops               {}", r.floor_us.row())?;
        writeln!(f)?;
        writeln!(
            f,
            "iceoryx2: cycles {} (completed {}), deadline misses {} (late cycles {}, late sensor periods {}, \
             commands superseded {}), lost {} (sensor frames {}, bus/recorder gaps {}, unfinished cycles {})",
            r.cycles,
            r.completed,
            r.deadline_misses,
            r.late_e2e,
            r.late_periods,
            r.superseded,
            r.lost,
            r.frames_lost,
            r.seq_gaps.values().sum::<u64>(),
            r.unfinished
        )?;
        writeln!(
            f,
            "Unix sockets: cycles {} (completed {}), deadline misses {}, lost {}; floor chain lost {}",
            r.uds.cycles, r.uds.completed, r.uds.deadline_misses, r.uds.lost, r.floor_lost
        )?;
        if r.steal_ms.iter().any(|&ms| ms > 0.0) {
            let per_cpu: Vec<String> =
                r.steal_ms.iter().enumerate().map(|(i, ms)| format!("cpu{i} {ms:.0} ms")).collect();
            writeln!(
                f,
                "hypervisor steal while measuring: {} (a stolen CPU stalls even SCHED_FIFO); \
                 of the iceoryx2 deadline misses, {} came while the hypervisor took a CPU",
                per_cpu.join(", "),
                r.misses_during_steal
            )?;
        }
        if let Some(room) = &r.control_room {
            let errors: Vec<&String> = room.clients.iter().flat_map(|c| &c.errors).collect();
            writeln!(
                f,
                "control room attached (viewer, bridge; Foxglove clients that read, never read and disconnect; a \
                 Zenoh subscriber; an operator commanding every 100 ms over TLS): cycles {}, lost {}; the clients \
                 read {} Foxglove messages and {} Zenoh samples ({} lost){}",
                room.cycles,
                room.lost,
                room.clients.iter().map(|c| c.foxglove_read).sum::<u64>(),
                room.clients.iter().map(|c| c.zenoh_received).sum::<u64>(),
                room.clients.iter().map(|c| c.zenoh_gaps).sum::<u64>(),
                if errors.is_empty() { String::new() } else { format!("; client errors: {errors:?}") },
            )?;
            let commands: Vec<&CommandReport> = room.clients.iter().map(|c| &c.commands).collect();
            let sum = |f: fn(&CommandReport) -> u64| commands.iter().map(|c| f(c)).sum::<u64>();
            let worst = |f: fn(&CommandReport) -> f64| commands.iter().map(|c| f(c)).fold(0.0, f64::max);
            writeln!(
                f,
                "  the operator's commands: control taken in {} of {} rounds; {} heartbeats sent, {} accepted, {} \
                 refused, {} unanswered while the set ran ({} more as it went down), {} sent late; answered in \
                 p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms (worst round); recorded on bench/operator {}, accepted \
                 events {}, DEADMAN events {}{}",
                commands.iter().filter(|c| c.took_control).count(),
                commands.len(),
                sum(|c| c.sent),
                sum(|c| c.accepted),
                sum(|c| c.refused),
                sum(|c| c.unanswered),
                sum(|c| c.unanswered_at_end),
                sum(|c| c.late_sends),
                worst(|c| c.answer_ms_p50),
                worst(|c| c.answer_ms_p99),
                worst(|c| c.answer_ms_max),
                sum(|c| c.recorded),
                sum(|c| c.recorded_accepted),
                sum(|c| c.deadman_events),
                commands
                    .iter()
                    .find_map(|c| c.first_problem.as_ref())
                    .map(|p| format!("; first problem: {p}"))
                    .unwrap_or_default(),
            )?;
            writeln!(
                f,
                "  what the commands cost the loop: e2e p99 {:.1} µs commanding, {:.1} µs only watching (x{:.2}; \
                 p50 x{:.2}); deadline misses {} commanding ({} while the hypervisor stole a CPU), {} only \
                 watching ({} while it stole)",
                room.e2e_us.p99,
                room.watching_e2e_us.p99,
                room.commands_e2e_p99_ratio,
                room.commands_e2e_p50_ratio,
                room.deadline_misses,
                room.misses_during_steal,
                room.watching_deadline_misses,
                room.watching_misses_during_steal,
            )?;
            writeln!(
                f,
                "  what the whole control room cost the loop: e2e p99 {:.1} µs with it, {:.1} µs without (x{:.2}; \
                 p50 x{:.2}); deadline misses {} with it, {} without ({:.2} and {:.2} per 1000 cycles)",
                room.e2e_us.p99,
                room.e2e_p99_us_without,
                room.e2e_p99_ratio,
                room.e2e_p50_ratio,
                room.deadline_misses,
                room.deadline_misses_without,
                room.misses_per_1000,
                room.misses_per_1000_without,
            )?;
        }
        writeln!(
            f,
            "ratios: iceoryx2 to the floor p99 {:.2} (p50 {:.2}); iceoryx2 to Unix sockets p50 {:.2}, p99 {:.2}",
            r.ratios.e2e_p99_over_floor_p99,
            r.ratios.e2e_p50_over_floor_p50,
            r.ratios.e2e_p50_over_uds_p50,
            r.ratios.e2e_p99_over_uds_p99,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounds_alternate_the_order_of_the_three() {
        assert_eq!(Measurement::order(0, false)[0], Measurement::Pipeline(Transport::Iceoryx2));
        assert_eq!(Measurement::order(1, false)[0], Measurement::Floor);
        assert_eq!(Measurement::order(1, false)[2], Measurement::Pipeline(Transport::Iceoryx2));
        // The control room right after the plain iceoryx2 set (before it in odd
        // rounds), watching, then commanding.
        let (watching, commanding) =
            (Measurement::ControlRoom { commands: false }, Measurement::ControlRoom { commands: true });
        assert_eq!(Measurement::order(0, true)[1..3], [watching, commanding]);
        assert_eq!(Measurement::order(1, true)[2..4], [commanding, watching]);
    }

    #[test]
    fn options_that_leave_no_time_are_refused() {
        let options = CampaignOptions {
            duration_s: 3.0,
            rounds: 4,
            warmup_s: 2.0,
            load: LoadKind::None,
            rt: false,
            config: None,
            keep: None,
            exe: PathBuf::from("/nonexistent"),
            control_room: false,
        };
        assert!(matches!(options.check(), Err(CampaignError::Options(m)) if m.contains("--rounds 4")));
        assert!(CampaignOptions { rounds: 2, ..options.clone() }.check().is_ok());
        assert!(CampaignOptions { warmup_s: f64::NAN, rounds: 1, ..options }.check().is_err());
    }
}
