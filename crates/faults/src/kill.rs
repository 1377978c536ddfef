//! SIGKILL of a process of a running set, and what followed: the safe state,
//! measured in the recording on the samples' own monotonic stamps; whether the
//! launcher named the dead; orphans; the recording; a restart right after.
//!
//! The safe state of each death:
//! - sensing, estimation, control (upstream of actuation): actuation commands
//!   idle after its missed cycles (3) and the board acknowledges it
//!   (`IDLE_FALLBACK`, acknowledged at 25 %, on that sample or, when the
//!   board answered after the cycle's wait, a later one within the board's
//!   own 100 ms watchdog); the time is to the acknowledgement;
//! - sim-bench: the sensor and the board die with it; actuation idles for
//!   lack of commands (no board is left to acknowledge);
//! - actuation: the board's own 100 ms watchdog idles the engine (`sim/truth`
//!   at idle throttle; the emulator's watchdog trips in sim-bench's log);
//! - the recorder: the launcher names it and stops the set safely (the board
//!   disarmed, in sim-bench's log), from the kill to the launcher's exit;
//! - the launcher: every service gets SIGTERM from the kernel, actuation
//!   disarms the board (its last sample `DISARMED`), and no process survives.

use std::fmt;
use std::time::{Duration, Instant};

use jetbench_io::board::WATCHDOG_NS;
use jetbench_msgs::{actuation_flags, channels};
use jetbench_record::{seq_gaps, Recording};

use crate::set::{kill_now, run_to_end, wait_gone, RunningSet};
use crate::{Bench, FaultsError};

/// The idle throttle, %.
const IDLE_PCT: f64 = jetbench_model::THROTTLE_MIN_PCT;
/// Cycles without a command after which actuation idles (`[actuation] idle_after_missed_cycles`).
pub const IDLE_AFTER_CYCLES: u32 = 3;
/// The bound on the board watchdog's idle, ms: the watchdog and two engine steps.
pub const WATCHDOG_BOUND_MS: f64 = (WATCHDOG_NS as f64 + 2.0 * jetbench_model::STEP_S * 1e9) * 1e-6;

/// A process of the set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Victim {
    /// The sensing service (the force sensor's reader).
    Sensing,
    /// The estimation service (the thrust observer).
    Estimation,
    /// The control service (the loop's controller).
    Control,
    /// The actuation service (the throttle board and the ECU's poller).
    Actuation,
    /// The simulated bench (the engine, the sensor, the board and the ECU behind their ports).
    SimBench,
    /// The recorder (the MCAP file).
    Recorder,
    /// The launcher, `jetbench up` itself.
    Launcher,
}

impl Victim {
    /// Every process the campaign kills, in the report's order.
    pub const ALL: [Victim; 7] = [
        Victim::Sensing,
        Victim::Estimation,
        Victim::Control,
        Victim::Actuation,
        Victim::SimBench,
        Victim::Recorder,
        Victim::Launcher,
    ];

    /// The service's name, `launcher` for `jetbench up` itself.
    pub fn name(self) -> &'static str {
        match self {
            Victim::Sensing => "sensing",
            Victim::Estimation => "estimation",
            Victim::Control => "control",
            Victim::Actuation => "actuation",
            Victim::SimBench => "sim-bench",
            Victim::Recorder => "recorder",
            Victim::Launcher => "launcher",
        }
    }

    /// What the safe state is, in words (the report's column).
    pub fn safe_state(self) -> &'static str {
        match self {
            Victim::Sensing | Victim::Estimation | Victim::Control => {
                "actuation at idle after its missed cycles, acknowledged by the board (time: to the acknowledgement)"
            }
            Victim::SimBench => "actuation at idle for lack of commands (the board died with sim-bench)",
            Victim::Actuation => "the board's own 100 ms watchdog idles the engine (sim/truth)",
            Victim::Recorder => "the launcher stops the set: engine to idle, board disarmed",
            Victim::Launcher => "every service stops on its own: board disarmed, no orphan",
        }
    }
}

impl fmt::Display for Victim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Victim {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Victim::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| format!("unknown process `{s}`; one of {}", Victim::ALL.map(Victim::name).join(", ")))
    }
}

/// One kill and what followed.
#[derive(Clone, Debug)]
pub struct KillTrial {
    /// The process killed (SIGKILL).
    pub victim: Victim,
    /// When it was killed, s after the set was ready.
    pub at_s: f64,
    /// The throttle the board had applied when it was killed, %.
    pub throttle_at_kill_pct: Option<f64>,
    /// From the kill to the safe state, ms.
    pub time_to_safe_ms: Option<f64>,
    /// Actuation's missed cycles at its first idle sample (upstream deaths).
    pub idle_cycle: Option<u32>,
    /// The launcher's message names the dead service (or the launcher died).
    pub named: bool,
    /// Processes of the set still running 10 s after the launcher ended.
    pub orphans: Vec<u32>,
    /// The run's recording opened and read to its end.
    pub readable: bool,
    /// The recording was left unfinished (no summary): `jetbench recover` rewrites it.
    pub truncated: bool,
    /// `seq` gaps in the recording (samples lost between the services and the recorder).
    pub seq_gaps: u64,
    /// A new `jetbench up` right after ran cleanly and recorded from its first sample.
    pub restart_clean: bool,
    /// Every bound this trial broke, in words (empty: all held).
    pub problems: Vec<String>,
}

impl KillTrial {
    /// Every bound held.
    pub fn ok(&self) -> bool {
        self.problems.is_empty()
    }
}

/// Runs a set recording, kills `victim` with SIGKILL `at_s` seconds after it
/// is ready, and measures what follows.
pub fn kill_trial(bench: &Bench, victim: Victim, at_s: f64) -> Result<KillTrial, FaultsError> {
    let namespace = bench.fresh_namespace();
    let record = bench.scratch(&format!("kill-{namespace}.mcap"));
    let record_arg = record.display().to_string();
    let mut set = RunningSet::start(bench, &namespace, &["--duration", "120", "--record", &record_arg])?;
    std::thread::sleep(Duration::from_secs_f64(at_s));
    let services: Vec<u32> = set.service_pids().into_iter().map(|(_, pid)| pid).collect();
    let pid = match victim {
        Victim::Launcher => set.launcher_pid(),
        _ => set.pid(victim.name()).ok_or_else(|| FaultsError::Failed {
            what: "jetbench up".into(),
            message: format!("did not print the pid of {victim}:\n{}", set.log()),
        })?,
    };
    let kill_mono_ns = jetbench_record::clock::monotonic_ns();
    kill_now(pid);
    let killed = Instant::now();
    let (status, exited) = set.wait_exit(Duration::from_secs(60))?;
    let orphans = wait_gone(&services, Duration::from_secs(10));
    for &pid in &orphans {
        kill_now(pid); // not to leave them running; they are reported
    }
    let log = set.log();
    let mut trial = KillTrial {
        victim,
        at_s,
        throttle_at_kill_pct: None,
        time_to_safe_ms: None,
        idle_cycle: None,
        named: victim == Victim::Launcher
            || log.contains(&format!("service `{}` was killed by signal 9", victim.name())),
        orphans,
        readable: false,
        truncated: false,
        seq_gaps: 0,
        restart_clean: false,
        problems: Vec::new(),
    };
    match Recording::open(&record) {
        Ok(recording) => {
            trial.readable = true;
            trial.truncated = recording.truncated;
            trial.seq_gaps = gaps(&recording);
            trial.throttle_at_kill_pct = recording
                .samples(channels::ACTUATION)
                .iter()
                .rev()
                .find(|a| a.publish_ns < kill_mono_ns)
                .map(|a| a.applied_pct);
            safe_state(&mut trial, &recording, kill_mono_ns, &log);
        }
        Err(e) => trial.problems.push(format!("the recording does not open: {e}")),
    }
    if victim == Victim::Recorder {
        trial.time_to_safe_ms = Some((exited - killed).as_secs_f64() * 1e3);
        if !log.contains("disarmed at the end") {
            trial.problems.push("sim-bench did not report its board disarmed".into());
        }
    }
    if victim != Victim::Launcher && status.success() {
        trial.problems.push("jetbench up exited 0 after a service died".into());
    }
    if !trial.named {
        trial.problems.push(format!("the launcher did not name {victim}:\n{log}"));
    }
    if !trial.orphans.is_empty() {
        trial.problems.push(format!("{} process(es) outlived the set: {:?}", trial.orphans.len(), trial.orphans));
    }
    if trial.seq_gaps > 0 {
        trial.problems.push(format!("{} samples lost on the way to the recorder", trial.seq_gaps));
    }
    trial.restart_clean = restart_is_clean(bench, &namespace)?;
    if !trial.restart_clean {
        trial.problems.push("a new jetbench up right after did not run cleanly".into());
    }
    Ok(trial)
}

/// `seq` gaps of the control path's channels and `sim/truth`.
fn gaps(recording: &Recording) -> u64 {
    seq_gaps(&recording.samples(channels::THRUST))
        + seq_gaps(&recording.samples(channels::STATE))
        + seq_gaps(&recording.samples(channels::COMMAND))
        + seq_gaps(&recording.samples(channels::ACTUATION))
        + seq_gaps(&recording.samples(channels::SIM_TRUTH))
}

/// Finds the safe state in the recording (see the module docs).
fn safe_state(trial: &mut KillTrial, recording: &Recording, kill_ns: u64, log: &str) {
    let after_ms = |ns: u64| ns.saturating_sub(kill_ns) as f64 * 1e-6;
    let actuation = recording.samples(channels::ACTUATION);
    let later = actuation.iter().filter(|a| a.publish_ns >= kill_ns);
    match trial.victim {
        Victim::Sensing | Victim::Estimation | Victim::Control | Victim::SimBench => {
            let Some(idle) = later.clone().find(|a| a.flags & actuation_flags::IDLE_FALLBACK != 0) else {
                trial.problems.push("actuation never went to idle in the recording".into());
                return;
            };
            trial.time_to_safe_ms = Some(after_ms(idle.publish_ns));
            trial.idle_cycle = Some(idle.missed_cycles);
            if idle.missed_cycles > IDLE_AFTER_CYCLES {
                trial
                    .problems
                    .push(format!("idle after {} missed cycles, not {IDLE_AFTER_CYCLES}", idle.missed_cycles));
            }
            // The engine is safe once the board has applied idle: on the idle
            // command's own sample, or, when the board answered after the
            // cycle's 4 ms wait, on a later one (a late acknowledgement), but
            // before the board's own watchdog would have idled it anyway.
            let acknowledged = actuation
                .iter()
                .filter(|a| a.publish_ns >= idle.publish_ns)
                .take_while(|a| a.publish_ns - idle.publish_ns <= WATCHDOG_NS)
                .find(|a| {
                    a.flags & (actuation_flags::UNACKED | actuation_flags::BOARD_SILENT) == 0
                        && a.applied_pct == IDLE_PCT
                });
            match acknowledged {
                // The board died with sim-bench: nothing can acknowledge.
                _ if trial.victim == Victim::SimBench => {}
                Some(ack) => trial.time_to_safe_ms = Some(after_ms(ack.publish_ns)),
                None => trial.problems.push(format!(
                    "the board did not acknowledge the idle command within {} ms: {idle:?}",
                    WATCHDOG_NS / 1_000_000
                )),
            }
        }
        Victim::Actuation => {
            let truth = recording.samples(channels::SIM_TRUTH);
            match truth.iter().find(|t| t.stamp_ns >= kill_ns && t.engine_throttle_pct <= IDLE_PCT) {
                Some(t) => trial.time_to_safe_ms = Some(after_ms(t.stamp_ns)),
                None => trial.problems.push("sim/truth never shows the engine at idle".into()),
            }
            if trial.time_to_safe_ms.is_some_and(|ms| ms > WATCHDOG_BOUND_MS) {
                trial.problems.push(format!("idle only {:.0} ms after the kill", trial.time_to_safe_ms.unwrap_or(0.0)));
            }
            let trips = log.split(" watchdog trips").next().and_then(|s| s.rsplit(' ').next()?.parse::<u32>().ok());
            if trips.is_none_or(|n| n == 0) {
                trial.problems.push("the board emulator counted no watchdog trip".into());
            }
        }
        Victim::Launcher => match later.clone().find(|a| a.flags & actuation_flags::DISARMED != 0) {
            Some(last) => trial.time_to_safe_ms = Some(after_ms(last.publish_ns)),
            None => trial.problems.push(format!(
                "no acknowledged disarm in the recording; actuation's last sample: {:?}; its log: {:?}",
                actuation.last(),
                log.lines().filter(|l| l.contains("actuation")).rev().take(4).collect::<Vec<_>>()
            )),
        },
        Victim::Recorder => {
            if !recording.truncated {
                trial.problems.push("the killed recorder's file is not flagged truncated".into());
            }
        }
    }
    if trial.victim != Victim::Recorder && recording.truncated {
        trial.problems.push("the recording was not closed".into());
    }
}

/// A new set in the same namespace runs 2 s and records from its first sample, gap-free.
fn restart_is_clean(bench: &Bench, namespace: &str) -> Result<bool, FaultsError> {
    let record = bench.scratch(&format!("restart-{namespace}.mcap"));
    let (status, _) = run_to_end(
        bench.command(namespace).args(["up", "--sim", "--quiet", "--duration", "2", "--record"]).arg(&record),
        "restart",
    )?;
    let thrust = Recording::open(&record).map(|r| r.samples(channels::THRUST)).unwrap_or_default();
    Ok(status.success() && thrust.len() >= 100 && thrust[0].seq == 0 && seq_gaps(&thrust) == 0)
}
