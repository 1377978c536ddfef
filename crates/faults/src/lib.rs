//! Faults at the bench, measured: the experiments behind `jetbench faults`
//! (`scripts/faults.sh`, which writes `docs/faults/REPORT.md`) and `jetbench
//! soak` (`scripts/soak.sh`). Every experiment runs the real `jetbench`
//! binary and its real service processes, sends real signals and reads the
//! real recordings; the end-to-end tests (`tests/faults.rs`) run each once and
//! assert the bounds.
//!
//! - [`kill`]: SIGKILL of each service and of the launcher, then the safe
//!   state measured in the recording, the orphans counted, a restart tried;
//! - [`recorder`]: a recorder killed mid-run (what is lost, `jetbench
//!   recover`, every offline command on the truncated file) and a recorder
//!   whose disk fills ([`recorder::disk_full`]);
//! - [`inject`]: bad sensor data in the live loop (`--inject`);
//! - [`set`]: a running set, a second set in the same namespace, and who may
//!   read its files;
//! - [`limits`]: a healthy engine with every `[limits]` entry on: trips
//!   counted, the margin each limit kept, the pauses in the telemetry;
//! - [`soak`]: the set for minutes under load, its memory over time;
//! - [`campaign`]: the campaign runner, every fault at random moments;
//! - [`report`]: its report.
//!
//! ```no_run
//! use jetbench_faults::kill::{kill_trial, Victim};
//! use jetbench_faults::Bench;
//!
//! # fn main() -> Result<(), jetbench_faults::FaultsError> {
//! let bench = Bench::new("target/release/jetbench".into(), "faults", std::env::temp_dir().join("faults"))?;
//! let trial = kill_trial(&bench, Victim::Control, 2.5)?;
//! println!("{}: safe after {:?} ms", trial.victim, trial.time_to_safe_ms);
//! # Ok(())
//! # }
//! ```
#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

pub mod campaign;
pub mod inject;
pub mod kill;
pub mod limits;
pub mod recorder;
pub mod report;
pub mod set;
pub mod soak;

/// Why an experiment could not be run (a fault it measures is a result, not an error).
#[derive(Debug, thiserror::Error)]
pub enum FaultsError {
    /// A process could not be started.
    #[error("cannot run {what}: {source}")]
    Start {
        /// The process, e.g. `jetbench up`.
        what: String,
        /// Why the operating system refused.
        source: std::io::Error,
    },
    /// A process ran past its time and was killed.
    #[error("{what} did not end within {limit:?} (a hang); it was killed{processes}")]
    Hang {
        /// The process, e.g. `jetbench up (healthy engine)`.
        what: String,
        /// The time it had.
        limit: Duration,
        /// What each process of the set was doing then, thread by thread
        /// (empty, or lines each starting with a line break).
        processes: String,
    },
    /// A step of an experiment failed (a set that never became ready, a tool missing).
    #[error("{what}: {message}")]
    Failed {
        /// The step.
        what: String,
        /// What went wrong, as its tool said it.
        message: String,
    },
    /// A recording could not be read.
    #[error(transparent)]
    Record(#[from] jetbench_record::RecordError),
    /// A scratch file or folder could not be written or read.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

/// Where and how experiments run `jetbench`: the binary (its services next to
/// it), a bus namespace of their own for each set, a scratch folder, and the
/// Python with the reference MCAP reader (if any).
#[derive(Debug)]
pub struct Bench {
    /// The `jetbench` binary the experiments run.
    pub exe: PathBuf,
    namespace: String,
    scratch: PathBuf,
    /// `python` with `mcap` installed (scripts/pyenv.sh), to read recovered files independently.
    pub python: Option<PathBuf>,
}

/// Sets started by this process, over every [`Bench`]: each gets a namespace
/// of its own, so a set that would not stop (its lock still held) never
/// refuses the next experiment's set.
static SETS: AtomicU32 = AtomicU32::new(0);

impl Bench {
    /// `exe` is the `jetbench` binary; namespaces are `<namespace><pid>x<n>`.
    pub fn new(exe: PathBuf, namespace: &str, scratch: PathBuf) -> Result<Self, FaultsError> {
        std::fs::create_dir_all(&scratch).map_err(|source| FaultsError::Io { path: scratch.clone(), source })?;
        let namespace = format!("{namespace}{}", std::process::id());
        Ok(Bench { exe, namespace, scratch, python: None })
    }

    /// A bus namespace no set of this process has used.
    pub fn fresh_namespace(&self) -> String {
        format!("{}x{}", self.namespace, SETS.fetch_add(1, Ordering::Relaxed) + 1)
    }

    /// `jetbench` in bus namespace `namespace`, finding its services next to it.
    pub fn command(&self, namespace: &str) -> Command {
        let mut command = Command::new(&self.exe);
        command.env("JETBENCH_BUS", namespace);
        if let Some(dir) = self.exe.parent() {
            command.env("JETBENCH_BIN_DIR", dir);
        }
        command
    }

    /// A fresh path in the scratch folder (an old file of that name removed).
    pub fn scratch(&self, name: &str) -> PathBuf {
        let path = self.scratch.join(name);
        let _ = std::fs::remove_file(&path);
        path
    }

    /// The folder the experiments' files go to (configs, recordings, logs).
    pub fn scratch_dir(&self) -> &Path {
        &self.scratch
    }
}

/// Percentiles of a list: p50 and max (NaN when empty).
pub fn p50_max(values: &[f64]) -> (f64, f64) {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[v.len() - 1])
}
