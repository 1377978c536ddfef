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

use crate::Recording;

/// Name of the recorder's metadata record about the run.
pub const RUN: &str = "jetbench";
/// Name of the metadata record a replayed recording gets (what replay found).
pub const REPLAY: &str = "replay";
/// The whole bench config of the run (TOML).
pub const KEY_CONFIG: &str = "config";
/// The estimator's resolved model parameters (a model file's TOML), which parse back bit for bit.
pub const KEY_MODEL_TOML: &str = "model_toml";
/// What the timestamps mean.
pub const KEY_CLOCK: &str = "clock";
/// `CLOCK_MONOTONIC` when the recorder started, ns.
pub const KEY_MONOTONIC_NS_AT_START: &str = "monotonic_ns_at_start";
/// `CLOCK_REALTIME` (ns since the Unix epoch) at the same moment.
pub const KEY_REALTIME_NS_AT_START: &str = "realtime_ns_at_start";

/// The entries of the [`RUN`] record, typed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RunMetadata {
    pub config_toml: String,
    /// Absent in recordings of older runs.
    pub model_toml: Option<String>,
    pub clock: String,
    pub monotonic_ns_at_start: Option<u64>,
    pub realtime_ns_at_start: Option<u64>,
}

impl RunMetadata {
    /// The run's record as the recorder writes it: `(RUN, entries)`.
    pub fn record(&self) -> (String, BTreeMap<String, String>) {
        let mut entries = BTreeMap::new();
        entries.insert(KEY_CONFIG.to_string(), self.config_toml.clone());
        if let Some(model) = &self.model_toml {
            entries.insert(KEY_MODEL_TOML.to_string(), model.clone());
        }
        if !self.clock.is_empty() {
            entries.insert(KEY_CLOCK.to_string(), self.clock.clone());
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
            monotonic_ns_at_start: ns(KEY_MONOTONIC_NS_AT_START),
            realtime_ns_at_start: ns(KEY_REALTIME_NS_AT_START),
        })
    }
}
