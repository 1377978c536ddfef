//! The recorder's metadata contract: what a jetbench recording says about its run.
//!
//! Every recording the recorder writes holds one MCAP metadata record named
//! [`RUN`] (`jetbench`) with the keys below; a replayed recording adds one
//! named [`REPLAY`]. Replay reproduces a run from [`KEY_CONFIG`] and
//! [`KEY_MODEL_TOML`] even when the model file it used is gone; the clock keys
//! relate the samples' `CLOCK_MONOTONIC` stamps to the wall clock.
//!
//! ```
//! use jetbench_record::meta::{self, RunMetadata};
//! use jetbench_record::Recording;
//!
//! let run = RunMetadata { config_toml: "[bench]\ndevices = \"sim\"\n".into(), ..RunMetadata::default() };
//! let recording = Recording { metadata: [run.record()].into(), ..Recording::default() };
//! assert_eq!(RunMetadata::of(&recording).map(|r| r.config_toml), Some(run.config_toml));
//! assert_eq!(recording.metadata[meta::RUN][meta::KEY_CONFIG], "[bench]\ndevices = \"sim\"\n");
//! ```

use std::collections::BTreeMap;

use crate::clock::{ClockOrigin, LogClock};
use crate::Recording;

/// Name of the recorder's metadata record about the run.
pub const RUN: &str = "jetbench";
/// Name of the metadata record a replayed recording gets (what replay found).
pub const REPLAY: &str = "replay";
/// The whole bench config of the run (TOML).
pub const KEY_CONFIG: &str = "config";
/// The estimator's resolved model parameters (a model file's TOML), which parse back bit for bit.
pub const KEY_MODEL_TOML: &str = "model_toml";
/// What the timestamps mean, in words.
pub const KEY_CLOCK: &str = "clock";
/// The clock of `log_time`: `CLOCK_REALTIME` (wall clock, ns since the Unix epoch)
/// or `CLOCK_MONOTONIC`; absent in recordings made before wall-clock log times,
/// whose `log_time` is monotonic ([`crate::clock`] tells them apart).
pub const KEY_LOG_TIME_CLOCK: &str = "log_time_clock";
/// `CLOCK_MONOTONIC` when the recorder started, ns.
pub const KEY_MONOTONIC_NS_AT_START: &str = "monotonic_ns_at_start";
/// `CLOCK_REALTIME` (ns since the Unix epoch) at the same moment.
pub const KEY_REALTIME_NS_AT_START: &str = "realtime_ns_at_start";

/// The entries of the [`RUN`] record, typed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RunMetadata {
    /// The bench configuration the run used, as TOML.
    pub config_toml: String,
    /// Absent in recordings of older runs.
    pub model_toml: Option<String>,
    /// How the samples' stamps were taken (the clock's name).
    pub clock: String,
    /// [`KEY_LOG_TIME_CLOCK`]; empty in older recordings.
    pub log_time_clock: String,
    /// `CLOCK_MONOTONIC` when the recording started, ns; absent in older recordings.
    pub monotonic_ns_at_start: Option<u64>,
    /// `CLOCK_REALTIME` at the same moment, ns since the Unix epoch.
    pub realtime_ns_at_start: Option<u64>,
}

impl RunMetadata {
    /// A run recorded with `log_time` on the wall clock at receive (what the
    /// recorder writes), which started at `origin`.
    pub fn wall_clock(origin: ClockOrigin) -> RunMetadata {
        RunMetadata {
            clock: "log_time is CLOCK_REALTIME at receive (ns since the Unix epoch); publish_time is the sample's \
                    stamp_ns (CLOCK_MONOTONIC)"
                .into(),
            log_time_clock: LogClock::Realtime.name().into(),
            monotonic_ns_at_start: Some(origin.monotonic_ns),
            realtime_ns_at_start: Some(origin.realtime_ns),
            ..RunMetadata::default()
        }
    }

    /// The run's record as the recorder writes it: `(RUN, entries)`.
    pub fn record(&self) -> (String, BTreeMap<String, String>) {
        let mut entries = BTreeMap::new();
        entries.insert(KEY_CONFIG.to_string(), self.config_toml.clone());
        if let Some(model) = &self.model_toml {
            entries.insert(KEY_MODEL_TOML.to_string(), model.clone());
        }
        for (key, value) in [(KEY_CLOCK, &self.clock), (KEY_LOG_TIME_CLOCK, &self.log_time_clock)] {
            if !value.is_empty() {
                entries.insert(key.to_string(), value.clone());
            }
        }
        for (key, value) in [
            (KEY_MONOTONIC_NS_AT_START, self.monotonic_ns_at_start),
            (KEY_REALTIME_NS_AT_START, self.realtime_ns_at_start),
        ] {
            if let Some(ns) = value {
                entries.insert(key.to_string(), ns.to_string());
            }
        }
        (RUN.to_string(), entries)
    }

    /// The run's record of `recording`, if it has one.
    pub fn of(recording: &Recording) -> Option<RunMetadata> {
        let entries = recording.metadata.get(RUN)?;
        let text = |key: &str| entries.get(key).cloned();
        let ns = |key: &str| entries.get(key).and_then(|v| v.parse().ok());
        Some(RunMetadata {
            config_toml: text(KEY_CONFIG).unwrap_or_default(),
            model_toml: text(KEY_MODEL_TOML),
            clock: text(KEY_CLOCK).unwrap_or_default(),
            log_time_clock: text(KEY_LOG_TIME_CLOCK).unwrap_or_default(),
            monotonic_ns_at_start: ns(KEY_MONOTONIC_NS_AT_START),
            realtime_ns_at_start: ns(KEY_REALTIME_NS_AT_START),
        })
    }
}
