//! Replay: a recording's thrust samples through the live estimator, offline.
//!
//! [`replay`] feeds the recorded `bench/thrust` samples through the same
//! [`Estimation`] step the estimation service runs, as fast as the machine
//! allows, on recorded time (it never reads a clock and never sleeps).
//!
//! ```
//! use jetbench_stack::config::BenchConfig;
//! use jetbench_stack::replay::{replay, EstimatorSource, InputRule};
//! use jetbench_stack::synthetic::synthetic_recording;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // Two seconds of the simulated closed loop, laid out as the recorder writes it.
//! let recording = synthetic_recording(&BenchConfig::default_sim()?, 200)?;
//! let outcome = replay(&recording, EstimatorSource::Recorded, InputRule::Auto)?;
//! assert_eq!(outcome.report.replayed, 200);
//! assert_eq!(outcome.report.identical, 200, "the recorded estimates are reproduced bit for bit");
//! assert!(outcome.report.is_identical());
//! # Ok(())
//! # }
//! ```
//!
//! # Determinism contract
//! Replaying a live recording reproduces its recorded `bench/state` bit for
//! bit: every `f64` field compared by its bits, plus `stamp_ns`, `source_seq`
//! and `flags`. `seq` and `publish_ns` belong to the live publisher and are not
//! compared. That holds because the estimator is a pure function of its
//! configuration, the thrust samples it processed and the throttle each
//! prediction used (its measurement gate included: which measurements it
//! rejects as spikes or a stuck sensor depends on nothing else), and a
//! recording holds all three:
//! - the configuration: the recorder's `jetbench` metadata record holds the
//!   bench config (`config`) and the resolved model (`model_toml`: parameters,
//!   which parse back bit for bit, and effects, whose input delay the filter
//!   predicts through), so a model file deleted since does not matter;
//! - which thrust samples: exactly those with a recorded state whose
//!   `source_seq` is their `seq`; the others (the estimator started late, or its
//!   queue overflowed) are skipped and counted;
//! - which throttle: the live estimator predicts with the last `bench/actuation`
//!   it happened to see, which depends on process timing, so every state records
//!   it in `input_throttle_pct` (and sets `INPUT_ASSUMED` when it had none).
//!
//! # Input rules
//! - [`InputRule::RecordedState`]: each prediction uses `input_throttle_pct` of
//!   the recorded state with `source_seq == thrust.seq`; when that state has
//!   `INPUT_ASSUMED`, no throttle is set (as live, before any actuation sample).
//! - [`InputRule::Actuation`] (recordings without `bench/state`): for each
//!   thrust sample, the last `bench/actuation` sample (in recorded order) whose
//!   `publish_ns <= thrust.stamp_ns`, i.e. the newest throttle that had been
//!   applied when the sensor frame arrived; none yet means the idle throttle,
//!   flagged `INPUT_ASSUMED`. Every thrust sample is processed. This is what the
//!   live estimator sees when nothing runs late; a race it lost is not rebuilt.
//! - [`InputRule::Auto`]: the recorded states when there are any, else actuation.

use std::collections::BTreeMap;
use std::path::Path;

use jetbench_estim::{EstimError, ObserverConfig};
use jetbench_model::{ModelError, ModelFile, Params};
use jetbench_msgs::{channels, state_flags, Actuation, Sample, StateEstimate, Thrust, CDR_HEADER};
use jetbench_record::meta::{RunMetadata, KEY_CONFIG, KEY_MODEL_TOML, REPLAY, RUN};
use jetbench_record::{McapWriter, RecordError, RecordedMessage, Recording};

use crate::config::BenchConfig;
use crate::estimation::EstimationStep;

/// Why a recording cannot be replayed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// No `jetbench` metadata with the bench config: an older recorder, or a
    /// file cut off before its metadata.
    #[error(
        "the recording has no `{RUN}` metadata with the run's bench config, so the estimator's model \
         is unknown; pass the bench config the run used (jetbench replay --config FILE)"
    )]
    NoMetadata,
    /// The recorded configuration does not parse.
    #[error(
        "the recording's `{RUN}` metadata `{key}` does not parse: {message}; \
         pass the bench config the run used (jetbench replay --config FILE)"
    )]
    BadMetadata {
        /// The metadata key.
        key: &'static str,
        /// Why it does not parse.
        message: String,
    },
    /// The recording predates `model_toml` and its `[model] model` file is gone.
    #[error(
        "the recording holds no model parameters (`{KEY_MODEL_TOML}`), and its [model] model = {spec:?} \
         cannot be resolved now ({source}); pass a bench config with that model (jetbench replay --config FILE)"
    )]
    ModelUnavailable {
        /// The recorded `[model] model`.
        spec: String,
        /// Why it cannot be resolved now.
        source: ModelError,
    },
    /// Nothing to feed the estimator.
    #[error("the recording has no /bench/thrust samples to replay ({malformed} malformed){}",
        if *truncated { "; the file is truncated" } else { "" })]
    NoThrust {
        /// Thrust messages that did not decode.
        malformed: usize,
        /// The file ends in the middle of a record.
        truncated: bool,
    },
    /// [`InputRule::RecordedState`] was asked for, but there is no state.
    #[error(
        "the recorded-state input rule needs /bench/state samples, and the recording has none; use the actuation rule"
    )]
    NoStates,
    /// The estimator's configuration is unusable (every step would fail).
    #[error("the estimator cannot run with this configuration: {0}")]
    Estimator(EstimError),
}

/// The estimator's model and noise settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatorSetup {
    /// The model the observer predicts with.
    pub params: Params,
    /// The observer's noise and gate settings.
    pub observer: ObserverConfig,
}

impl EstimatorSetup {
    /// The estimator of a bench config, as the estimation service builds it.
    pub fn from_config(config: &BenchConfig) -> Result<Self, ModelError> {
        let (params, observer) = config.estimator()?;
        Ok(EstimatorSetup { params, observer })
    }

    /// The estimator recorded with a run: `[estimator]` from the recorded
    /// config, the model from `model_toml` when present, else the config's
    /// `[model] model` resolved now (older recordings).
    pub fn from_recording(recording: &Recording) -> Result<(Self, EstimatorOrigin), ReplayError> {
        let config = recorded_config(recording)?;
        let meta = &recording.metadata[RUN];
        // A config recorded before the disturbance state has no key for it and gets
        // the default, 0: the filter those runs had. The input delay is the recorded
        // model's: recorders before the estimator modelled it stored the parameters
        // alone, and older ones no model, so their filters had none.
        if let Some(model) = meta.get(KEY_MODEL_TOML) {
            let file = ModelFile::from_toml_str(model)
                .map_err(|e| ReplayError::BadMetadata { key: KEY_MODEL_TOML, message: e.to_string() })?;
            let observer = config.estimator.observer_config(file.effects.input_delay_s());
            return Ok((EstimatorSetup { params: file.model, observer }, EstimatorOrigin::RecordedModel));
        }
        let observer = config.estimator.observer_config(0.0);
        let spec = config.model.model.clone();
        match config.model_params() {
            Ok(params) => Ok((EstimatorSetup { params, observer }, EstimatorOrigin::RecordedSpec(spec))),
            Err(source) => Err(ReplayError::ModelUnavailable { spec, source }),
        }
    }
}

/// The bench config a recording was made with (its `jetbench` metadata), parsed
/// without [`BenchConfig::validate`]: that resolves the model files, which may be
/// gone since, and the plant, which an offline reader does not need.
pub fn recorded_config(recording: &Recording) -> Result<BenchConfig, ReplayError> {
    let meta = recording.metadata.get(RUN).ok_or(ReplayError::NoMetadata)?;
    let text = meta.get(KEY_CONFIG).filter(|t| !t.trim().is_empty()).ok_or(ReplayError::NoMetadata)?;
    toml::from_str(text)
        .map_err(|e| ReplayError::BadMetadata { key: KEY_CONFIG, message: e.to_string().trim_end().into() })
}

/// The resolved estimator model of `config` (parameters and effects: the filter
/// predicts through its input delay) as model-file TOML, which
/// [`ModelFile::from_toml_str`] parses back bit for bit: what the recorder
/// stores under [`KEY_MODEL_TOML`].
pub fn model_toml(config: &BenchConfig) -> Result<String, ModelError> {
    Ok(jetbench_model::resolve_model(&config.model.model)?.to_toml_string())
}

/// What the recorder says about a run of `config` ([`jetbench_record::meta`]):
/// the config and the estimator's resolved model; the recorder adds the clocks.
pub fn run_metadata(config: &BenchConfig) -> Result<RunMetadata, ModelError> {
    Ok(RunMetadata {
        config_toml: toml::to_string(config).unwrap_or_default(),
        model_toml: Some(model_toml(config)?),
        ..RunMetadata::default()
    })
}

/// Where [`replay`] takes the estimator from.
#[derive(Clone, Debug, PartialEq)]
pub enum EstimatorSource {
    /// The recording's own (see [`EstimatorSetup::from_recording`]).
    Recorded,
    /// Given by the caller (`jetbench replay --config`): a bit-exact replay is
    /// then not expected.
    Given(EstimatorSetup),
}

/// Where the estimator of a replay came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum EstimatorOrigin {
    /// The model parameters recorded with the run (`model_toml`).
    RecordedModel,
    /// The recorded config's `[model] model`, resolved at replay time.
    RecordedSpec(String),
    /// Given by the caller.
    Given,
}

impl EstimatorOrigin {
    /// True when the replay should reproduce the recording bit for bit.
    pub fn exact_expected(&self) -> bool {
        !matches!(self, EstimatorOrigin::Given)
    }
}

impl std::fmt::Display for EstimatorOrigin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EstimatorOrigin::RecordedModel => {
                write!(f, "the model parameters recorded with the run ({KEY_MODEL_TOML})")
            }
            EstimatorOrigin::RecordedSpec(spec) => write!(f, "the recorded config's [model] model = {spec:?}"),
            EstimatorOrigin::Given => write!(f, "a given bench config (not the recording's)"),
        }
    }
}

/// Where each prediction's throttle comes from (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputRule {
    /// [`InputRule::RecordedState`] when the recording has states, else [`InputRule::Actuation`].
    Auto,
    /// `input_throttle_pct` of the recorded state with `source_seq == thrust.seq`.
    RecordedState,
    /// The last actuation with `publish_ns <= thrust.stamp_ns`.
    Actuation,
}

impl std::fmt::Display for InputRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            InputRule::Auto => "auto: recorded states if any, else actuation",
            InputRule::RecordedState => {
                "recorded-state: input_throttle_pct of the /bench/state whose source_seq is the thrust seq"
            }
            InputRule::Actuation => "actuation: the last /bench/actuation with publish_ns <= the thrust stamp_ns",
        })
    }
}

/// Messages that did not decode as their channel's type, per channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Malformed {
    /// On `bench/thrust`.
    pub thrust: usize,
    /// On `bench/state`.
    pub state: usize,
    /// On `bench/actuation`.
    pub actuation: usize,
}

impl Malformed {
    /// On every channel.
    pub fn total(&self) -> usize {
        self.thrust + self.state + self.actuation
    }
}

/// The first replayed estimate that differs from the recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FirstDifference {
    /// `seq` of the thrust sample.
    pub source_seq: u64,
    /// First differing field, or `"rejected"` when the estimator refused the
    /// sample the live one accepted.
    pub field: &'static str,
}

/// What a replay did and how it compares with the recording.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayReport {
    /// Where the estimator's model came from.
    pub estimator: EstimatorOrigin,
    /// The rule used ([`InputRule::Auto`] resolved).
    pub inputs: InputRule,
    /// Thrust samples in the recording.
    pub thrust_samples: usize,
    /// Thrust samples fed to the estimator (including rejected ones).
    pub replayed: usize,
    /// Thrust samples the live estimator never processed (no state with their `seq`).
    pub skipped: usize,
    /// Thrust samples the estimator refused (not finite), as the live one does.
    pub rejected: usize,
    /// Recorded states whose thrust sample is not in the recording (the
    /// recorder lost it): the estimates after it cannot match.
    pub states_without_thrust: usize,
    /// Messages that did not decode, per channel.
    pub malformed: Malformed,
    /// Replayed estimates that had a recorded state to compare with.
    pub compared: usize,
    /// Of those, identical bit for bit (all but `seq` and `publish_ns`).
    pub identical: usize,
    /// The first replayed estimate that differs, if one does.
    pub first_difference: Option<FirstDifference>,
    /// Largest |replayed - recorded| thrust, N (0 when identical).
    pub max_diff_thrust_n: f64,
    /// Largest |replayed - recorded| thrust rate, N/s.
    pub max_diff_thrust_rate_n_per_s: f64,
    /// The recording was cut off; what was there was replayed.
    pub truncated: bool,
}

impl ReplayReport {
    /// True when every compared estimate is identical (or none was compared):
    /// the determinism contract holds.
    pub fn is_identical(&self) -> bool {
        self.compared == self.identical
    }

    /// The entries of the [`REPLAY`] record of a replayed recording.
    pub fn metadata(&self, source: &Path) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        let mut put = |k: &str, v: String| {
            m.insert(k.to_string(), v);
        };
        put("source", source.display().to_string());
        put("estimator", self.estimator.to_string());
        put("inputs", self.inputs.to_string());
        put("thrust_samples", self.thrust_samples.to_string());
        put("replayed", self.replayed.to_string());
        put("skipped", self.skipped.to_string());
        put("rejected", self.rejected.to_string());
        put("states_without_thrust", self.states_without_thrust.to_string());
        put("malformed", self.malformed.total().to_string());
        put("compared", self.compared.to_string());
        put("identical", self.identical.to_string());
        put("truncated", self.truncated.to_string());
        put("tool", concat!("jetbench ", env!("CARGO_PKG_VERSION")).to_string());
        m
    }
}

/// One replayed estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReplayedEstimate {
    /// Index in [`Recording::messages`] of the thrust sample it was computed from.
    pub thrust_message: usize,
    /// The estimate. `seq` and `publish_ns` are those of the recorded state with
    /// the same `source_seq` (so references and commands still point at it);
    /// without one, `seq` counts the replayed estimates and `publish_ns` is 0.
    pub estimate: StateEstimate,
}

/// The result of [`replay`].
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayOutcome {
    /// In recorded order of their thrust samples.
    pub estimates: Vec<ReplayedEstimate>,
    /// How the replay compares with the recording.
    pub report: ReplayReport,
}

/// Replays `recording`'s thrust samples through [`Estimation`] and compares
/// the estimates with its recorded `bench/state` (see the module docs).
///
/// Allocates once up front (compact indices of the samples and the output);
/// the per-sample loop only pushes into the preallocated output.
pub fn replay(recording: &Recording, source: EstimatorSource, inputs: InputRule) -> Result<ReplayOutcome, ReplayError> {
    replay_with_alternatives(recording, source, inputs, |_| None).map(|(outcome, _)| outcome)
}

/// [`replay`], and for each thrust sample for which `instead` gives another reading
/// (N), the estimate the filter would have made from that reading in the state it was
/// in: the counterfactual of one measurement (a spike against the clean reading). The
/// alternatives never enter the replay; each is stamped and numbered like the
/// estimate it stands beside.
pub fn replay_with_alternatives(
    recording: &Recording,
    source: EstimatorSource,
    inputs: InputRule,
    instead: impl Fn(&Thrust) -> Option<f64>,
) -> Result<(ReplayOutcome, Vec<StateEstimate>), ReplayError> {
    let (setup, origin) = match source {
        EstimatorSource::Recorded => EstimatorSetup::from_recording(recording)?,
        EstimatorSource::Given(setup) => (setup, EstimatorOrigin::Given),
    };
    let messages = &recording.messages;
    let index = SampleIndex::new(messages);
    if index.thrust.is_empty() {
        return Err(ReplayError::NoThrust { malformed: index.malformed.thrust, truncated: recording.truncated });
    }
    let inputs = match inputs {
        InputRule::Auto if index.states.is_empty() => InputRule::Actuation,
        InputRule::Auto => InputRule::RecordedState,
        InputRule::RecordedState if index.states.is_empty() => return Err(ReplayError::NoStates),
        rule => rule,
    };
    let mut estimation = EstimationStep::new(setup.params, setup.observer);
    let mut report = ReplayReport {
        estimator: origin,
        inputs,
        thrust_samples: index.thrust.len(),
        replayed: 0,
        skipped: 0,
        rejected: 0,
        states_without_thrust: 0,
        malformed: index.malformed,
        compared: 0,
        identical: 0,
        first_difference: None,
        max_diff_thrust_n: 0.0,
        max_diff_thrust_rate_n_per_s: 0.0,
        truncated: recording.truncated,
    };
    let mut estimates = Vec::with_capacity(index.thrust.len());
    let mut states = StateLookup { index: &index.states, next: 0 };
    let mut actuation = ActuationCursor { samples: &index.actuation, next: 0 };
    let mut matched_states = 0;
    let mut alternatives = Vec::new();

    for &thrust_message in &index.thrust {
        // Indexed only when it decodes, so this skips nothing.
        let Some(thrust) = messages.get(thrust_message).and_then(|m| Thrust::from_cdr(&m.data)) else { continue };
        let recorded =
            states.find(thrust.seq).and_then(|i| messages.get(i)).and_then(|m| StateEstimate::from_cdr(&m.data));
        matched_states += usize::from(recorded.is_some());
        match (inputs, &recorded) {
            (InputRule::RecordedState, None) => {
                report.skipped += 1;
                continue;
            }
            (InputRule::RecordedState, Some(s)) => {
                if s.flags & state_flags::INPUT_ASSUMED == 0 {
                    estimation.set_applied(s.input_throttle_pct);
                }
            }
            _ => {
                if let Some(applied_pct) = actuation.applied_at(thrust.stamp_ns) {
                    estimation.set_applied(applied_pct);
                }
            }
        }
        report.replayed += 1;
        if let Some(thrust_n) = instead(&thrust) {
            if let Ok(mut alternative) = estimation.clone().step(&Thrust { thrust_n, ..thrust }) {
                (alternative.seq, alternative.publish_ns) =
                    recorded.map_or((estimates.len() as u64, 0), |s| (s.seq, s.publish_ns));
                alternatives.push(alternative);
            }
        }
        let mut estimate = match estimation.step(&thrust) {
            Ok(e) => e,
            Err(e @ (EstimError::InvalidConfig { .. } | EstimError::InvalidParams { .. })) => {
                return Err(ReplayError::Estimator(e))
            }
            Err(EstimError::NonFiniteInput { .. }) => {
                report.rejected += 1;
                if recorded.is_some() {
                    report.compared += 1;
                    report
                        .first_difference
                        .get_or_insert(FirstDifference { source_seq: thrust.seq, field: "rejected" });
                }
                continue;
            }
        };
        match &recorded {
            Some(s) => {
                estimate.seq = s.seq;
                estimate.publish_ns = s.publish_ns;
                report.compared += 1;
                match first_differing_field(&estimate, s) {
                    None => report.identical += 1,
                    Some(field) => {
                        report.first_difference.get_or_insert(FirstDifference { source_seq: thrust.seq, field });
                        report.max_diff_thrust_n =
                            report.max_diff_thrust_n.max(abs_diff(estimate.thrust_n, s.thrust_n));
                        report.max_diff_thrust_rate_n_per_s = report
                            .max_diff_thrust_rate_n_per_s
                            .max(abs_diff(estimate.thrust_rate_n_per_s, s.thrust_rate_n_per_s));
                    }
                }
            }
            None => estimate.seq = estimates.len() as u64,
        }
        estimates.push(ReplayedEstimate { thrust_message, estimate });
    }
    report.states_without_thrust = index.states.len().saturating_sub(matched_states);
    Ok((ReplayOutcome { estimates, report }, alternatives))
}

/// |a - b|, with a NaN on one side only as an infinite difference.
fn abs_diff(a: f64, b: f64) -> f64 {
    match (a.is_nan(), b.is_nan()) {
        (false, false) => (a - b).abs(),
        (true, true) => 0.0,
        _ => f64::INFINITY,
    }
}

/// The first field (other than `seq` and `publish_ns`) whose bits differ.
fn first_differing_field(replayed: &StateEstimate, recorded: &StateEstimate) -> Option<&'static str> {
    let strip = |s: &StateEstimate| StateEstimate { seq: 0, publish_ns: 0, ..*s };
    let (a, b) = (strip(replayed), strip(recorded));
    if a.as_bytes() == b.as_bytes() {
        return None;
    }
    let fields = StateEstimate::FIELDS;
    fields.iter().enumerate().find_map(|(i, f)| {
        let end = fields.get(i + 1).map_or(size_of::<StateEstimate>(), |next| next.offset);
        (a.as_bytes()[f.offset..end] != b.as_bytes()[f.offset..end]).then_some(f.name)
    })
}

/// Where the samples replay needs are, found in one pass. Compact (a few
/// bytes per sample, the samples stay in the messages): at 30 000 cycles
/// fresh memory, not arithmetic, is the largest cost of a replay.
struct SampleIndex {
    /// Message indices of the well-formed thrust samples, in recorded order.
    thrust: Vec<usize>,
    /// (`source_seq`, message index) of the well-formed states, sorted by
    /// `source_seq`; equal keys keep their recorded order.
    states: Vec<(u64, usize)>,
    /// (`publish_ns`, `applied_pct`) of the actuation samples, in recorded order.
    actuation: Vec<(u64, f64)>,
    malformed: Malformed,
}

impl SampleIndex {
    fn new(messages: &[RecordedMessage]) -> Self {
        // The recorded topics (checked against the channels in the tests);
        // one `match` is one comparison per message.
        const THRUST: &str = "/bench/thrust";
        const STATE: &str = "/bench/state";
        const ACTUATION: &str = "/bench/actuation";
        let mut d = SampleIndex {
            thrust: Vec::new(),
            states: Vec::new(),
            actuation: Vec::new(),
            malformed: Malformed::default(),
        };
        for (i, m) in messages.iter().enumerate() {
            match m.topic.as_str() {
                THRUST => match Thrust::from_cdr(&m.data) {
                    Some(_) => d.thrust.push(i),
                    None => d.malformed.thrust += 1,
                },
                STATE => match StateEstimate::from_cdr(&m.data) {
                    Some(s) => d.states.push((s.source_seq, i)),
                    None => d.malformed.state += 1,
                },
                ACTUATION => match Actuation::from_cdr(&m.data) {
                    Some(a) => d.actuation.push((a.publish_ns, a.applied_pct)),
                    None => d.malformed.actuation += 1,
                },
                _ => {}
            }
        }
        // Usually sorted already, which the stable sort detects in one pass.
        d.states.sort_by_key(|&(seq, _)| seq);
        d
    }
}

/// Finds states by `source_seq`: O(1) while thrust samples come in `seq`
/// order (the usual case), a binary search otherwise. When a `source_seq`
/// occurs twice (sensing restarted mid-run) the first recorded state is used.
struct StateLookup<'a> {
    index: &'a [(u64, usize)],
    next: usize,
}

impl StateLookup<'_> {
    /// The message index of the state computed from thrust sample `seq`.
    fn find(&mut self, seq: u64) -> Option<usize> {
        let at = match self.index.get(self.next) {
            Some(&(s, _)) if s == seq => self.next,
            _ => self.index.partition_point(|&(s, _)| s < seq),
        };
        let &(_, message) = self.index.get(at).filter(|(s, _)| *s == seq)?;
        self.next = at + 1;
        Some(message)
    }
}

/// The last actuation with `publish_ns <= t`, for nondecreasing `t`.
struct ActuationCursor<'a> {
    samples: &'a [(u64, f64)],
    next: usize,
}

impl ActuationCursor<'_> {
    /// The newest throttle published at or before `t_ns` that was not
    /// returned before, as the live estimator's `latest()` read gives it.
    fn applied_at(&mut self, t_ns: u64) -> Option<f64> {
        let start = self.next;
        while self.samples.get(self.next).is_some_and(|&(publish_ns, _)| publish_ns <= t_ns) {
            self.next += 1;
        }
        if self.next > start {
            self.samples.get(self.next - 1).map(|&(_, applied_pct)| applied_pct)
        } else {
            None
        }
    }
}

/// What [`write_replayed`] wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WriteReport {
    /// Messages written, replayed estimates included.
    pub written: u64,
    /// Original messages that could not be copied: not a CDR sample, or on a
    /// topic that is not a jetbench channel.
    pub not_copied: usize,
}

/// Writes a new recording at `path`: every message of `recording` except
/// `bench/state`, which is replaced by the replayed estimates (each logged
/// at its thrust sample's log time, right after it), the original metadata
/// records (an old `replay` record is replaced) and a `replay` record with
/// `replay_metadata` (see [`ReplayReport::metadata`]).
pub fn write_replayed(
    recording: &Recording,
    outcome: &ReplayOutcome,
    path: &Path,
    replay_metadata: BTreeMap<String, String>,
) -> Result<WriteReport, RecordError> {
    let mut writer = McapWriter::create(path)?;
    for (name, entries) in recording.metadata.iter().filter(|(name, _)| *name != REPLAY) {
        writer.write_metadata(name, entries.clone())?;
    }
    writer.write_metadata(REPLAY, replay_metadata)?;
    let state_topic = channels::STATE.topic();
    let mut not_copied = 0;
    let mut replayed = outcome.estimates.iter().peekable();
    for (i, m) in recording.messages.iter().enumerate() {
        if m.topic != state_topic {
            let channel = m.topic.strip_prefix('/');
            let body = m.data.strip_prefix(&CDR_HEADER[..]);
            match (channel, body) {
                (Some(channel), Some(body)) => {
                    // Every sample starts with its publisher's seq.
                    let seq = body.get(..8).and_then(|b| b.try_into().ok()).map_or(0, u64::from_le_bytes);
                    match writer.write_raw(channel, seq, m.log_time_ns, m.publish_time_ns, body) {
                        Ok(()) => {}
                        Err(RecordError::UnknownChannel(_) | RecordError::SampleTooLarge { .. }) => not_copied += 1,
                        Err(e) => return Err(e),
                    }
                }
                _ => not_copied += 1,
            }
        }
        while let Some(r) = replayed.next_if(|r| r.thrust_message == i) {
            writer.write_sample(channels::STATE, m.log_time_ns, &r.estimate)?;
        }
    }
    let written = writer.finish()?;
    Ok(WriteReport { written, not_copied })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensing::SensingStep;
    use crate::sim_bench::{SimBenchStep, SimForceSensor};
    use crate::synthetic::synthetic_recording;
    use jetbench_model::THROTTLE_MIN_PCT;

    fn config() -> BenchConfig {
        BenchConfig::default_sim().expect("built-in config")
    }

    fn recorded_states(recording: &Recording) -> Vec<StateEstimate> {
        recording.samples(channels::STATE)
    }

    /// A live-like recording: an open-loop throttle schedule, actuation that
    /// sometimes reaches the estimator only after the thrust sample was
    /// stamped (the live race), and thrust sample 37 that the estimator
    /// never saw (no state for it).
    fn raced_recording(cycles: u64) -> Recording {
        let config = config();
        let params = config.model_params().unwrap();
        let mut sim = SimBenchStep::new(
            &jetbench_model::Plant::new(params, jetbench_model::Effects::none()),
            SimForceSensor::new(7.0, [0.0; 6], 11).unwrap(),
            25.0,
        );
        let mut sensing = SensingStep::new(&config.sensor).unwrap();
        let mut estimation = EstimationStep::new(params, config.estimator.observer_config(0.0));
        let mut messages = Vec::new();
        let mut frame = None;
        let mut state_seq = 0;
        let mut pending: Option<Actuation> = None;
        for k in 0..cycles {
            let t = 1_000_000_000 + k * 10_000_000;
            let (reading, _) = sim.step(t, frame).unwrap();
            let mut thrust = sensing.step(&reading, t).unwrap();
            (thrust.seq, thrust.publish_ns) = (k, t + 1_000);
            messages.push(RecordedMessage::of_sample(channels::THRUST, t + 20_000, &thrust));
            // The late actuation of the previous cycle, published after this
            // thrust's stamp but seen by the estimator all the same.
            if let Some(a) = pending.take() {
                messages.push(RecordedMessage::of_sample(channels::ACTUATION, a.publish_ns + 10_000, &a));
                estimation.set_applied(a.applied_pct);
            }
            if k != 37 {
                let mut s = estimation.step(&thrust).unwrap();
                (s.seq, s.publish_ns) = (state_seq, t + 50_000);
                state_seq += 1;
                messages.push(RecordedMessage::of_sample(channels::STATE, t + 60_000, &s));
            }
            if k >= 3 {
                let throttle_pct = 25.0 + ((k / 20) % 4) as f64 * 20.0 + (k % 3) as f64;
                let a = Actuation {
                    seq: k - 3,
                    stamp_ns: t,
                    applied_pct: throttle_pct,
                    commanded_pct: throttle_pct,
                    ..Actuation::default()
                };
                frame = Some(throttle_pct);
                if k % 5 == 0 {
                    pending = Some(Actuation { publish_ns: t + 10_000_000 + 5_000, ..a });
                } else {
                    let a = Actuation { publish_ns: t + 600_000, ..a };
                    messages.push(RecordedMessage::of_sample(channels::ACTUATION, t + 620_000, &a));
                    estimation.set_applied(a.applied_pct);
                }
            }
        }
        Recording { messages, truncated: false, metadata: [run_metadata(&config).unwrap().record()].into() }
    }

    #[test]
    fn the_index_finds_the_recorded_topics() {
        let recording = synthetic_recording(&config(), 3).unwrap();
        let d = SampleIndex::new(&recording.messages);
        assert_eq!((d.thrust.len(), d.states.len(), d.actuation.len()), (3, 3, 3));
        let topics: Vec<String> = recording.messages[..5].iter().map(|m| m.topic.clone()).collect();
        assert_eq!(topics[0], channels::THRUST.topic());
        assert_eq!(topics[1], channels::STATE.topic());
        assert_eq!(topics[4], channels::ACTUATION.topic());
    }

    #[test]
    fn raced_inputs_and_a_skipped_sample_replay_bit_for_bit() {
        let recording = raced_recording(300);
        let outcome = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap();
        let r = &outcome.report;
        assert_eq!(r.inputs, InputRule::RecordedState);
        assert_eq!(r.estimator, EstimatorOrigin::RecordedModel);
        assert_eq!((r.thrust_samples, r.replayed, r.skipped, r.rejected), (300, 299, 1, 0));
        assert_eq!((r.compared, r.identical), (299, 299), "first difference: {:?}", r.first_difference);
        assert!(r.is_identical());
        assert_eq!((r.max_diff_thrust_n, r.max_diff_thrust_rate_n_per_s), (0.0, 0.0));
        let states = recorded_states(&recording);
        // Actuation starts after cycle 3: the first four predictions assumed idle.
        assert!(states[..4].iter().all(|s| s.flags & state_flags::INPUT_ASSUMED != 0));
        assert!(states[4..].iter().all(|s| s.flags & state_flags::INPUT_ASSUMED == 0));
        // Every field, seq and publish_ns included (they are copied from the match).
        let replayed: Vec<StateEstimate> = outcome.estimates.iter().map(|e| e.estimate).collect();
        assert_eq!(replayed.len(), states.len());
        for (a, b) in replayed.iter().zip(&states) {
            assert_eq!(a.as_bytes(), b.as_bytes());
        }
    }

    #[test]
    fn the_actuation_rule_cannot_rebuild_a_lost_race() {
        // The same recording through the time rule: the late actuations were
        // published after the thrust stamp, so the rule uses the older
        // throttle there, as documented, and the replay differs.
        let recording = raced_recording(300);
        let outcome = replay(&recording, EstimatorSource::Recorded, InputRule::Actuation).unwrap();
        let r = &outcome.report;
        assert_eq!((r.replayed, r.skipped, r.compared), (300, 0, 299));
        assert!(!r.is_identical());
        assert!(r.max_diff_thrust_n > 0.0 && r.max_diff_thrust_rate_n_per_s > 0.0, "{r:?}");
    }

    #[test]
    fn the_closed_loop_replays_bit_for_bit() {
        let recording = synthetic_recording(&config(), 1500).unwrap();
        let outcome = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap();
        assert_eq!(outcome.report.compared, 1500);
        assert!(outcome.report.is_identical(), "{:?}", outcome.report.first_difference);
        assert_ne!(recorded_states(&recording)[0].flags & state_flags::INPUT_ASSUMED, 0);
    }

    #[test]
    fn a_tampered_state_is_reported_with_its_field_and_size() {
        let mut recording = synthetic_recording(&config(), 400).unwrap();
        let target = recording.messages.iter().position(|m| m.topic == "/bench/state").unwrap();
        let target = target + 5 * 250; // five messages per cycle: state 250
        let mut s = StateEstimate::from_cdr(&recording.messages[target].data).unwrap();
        assert_eq!(s.source_seq, 250);
        s.thrust_n += 1e-9;
        recording.messages[target] =
            RecordedMessage::of_sample(channels::STATE, recording.messages[target].log_time_ns, &s);
        let r = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap().report;
        assert_eq!((r.compared, r.identical), (400, 399));
        assert!(!r.is_identical());
        assert_eq!(r.first_difference, Some(FirstDifference { source_seq: 250, field: "thrust_n" }));
        assert!((r.max_diff_thrust_n - 1e-9).abs() < 1e-12, "{}", r.max_diff_thrust_n);
        assert_eq!(r.max_diff_thrust_rate_n_per_s, 0.0);

        // A flipped flag alone is a difference too.
        let mut recording = synthetic_recording(&config(), 50).unwrap();
        let at = recording.messages.iter().rposition(|m| m.topic == "/bench/state").unwrap();
        let mut s = StateEstimate::from_cdr(&recording.messages[at].data).unwrap();
        s.flags |= state_flags::MODEL_FALLBACK;
        recording.messages[at] = RecordedMessage::of_sample(channels::STATE, 0, &s);
        let r = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap().report;
        assert_eq!(r.first_difference.map(|d| d.field), Some("flags"));
    }

    #[test]
    fn without_states_the_actuation_rule_rebuilds_the_inputs() {
        let mut recording = synthetic_recording(&config(), 800).unwrap();
        let original = recorded_states(&recording);
        recording.messages.retain(|m| m.topic != "/bench/state");
        let outcome = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap();
        let r = &outcome.report;
        assert_eq!(r.inputs, InputRule::Actuation);
        assert_eq!((r.replayed, r.compared, r.skipped), (800, 0, 0));
        assert!(r.is_identical(), "nothing to compare is not a difference");
        // The synthetic loop's actuation always lands before the next frame,
        // so the time rule rebuilds exactly the inputs the estimator used.
        assert_eq!(outcome.estimates[0].estimate.input_throttle_pct, THROTTLE_MIN_PCT);
        for (e, s) in outcome.estimates.iter().zip(&original) {
            let strip = |s: &StateEstimate| StateEstimate { seq: 0, publish_ns: 0, ..*s };
            assert_eq!(strip(&e.estimate).as_bytes(), strip(s).as_bytes(), "source_seq {}", s.source_seq);
        }
        let err = replay(&recording, EstimatorSource::Recorded, InputRule::RecordedState).unwrap_err();
        assert!(matches!(err, ReplayError::NoStates), "{err}");
    }

    #[test]
    fn missing_or_unresolvable_metadata_asks_for_a_config() {
        let mut recording = synthetic_recording(&config(), 20).unwrap();
        let with_meta = recording.metadata.clone();
        recording.metadata.clear();
        let err = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap_err();
        assert!(matches!(err, ReplayError::NoMetadata));
        assert!(err.to_string().contains("--config FILE"), "{err}");

        // An older recording: no model_toml, and the model file is gone.
        let mut meta = with_meta[RUN].clone();
        meta.remove(KEY_MODEL_TOML);
        let mut old: BenchConfig = toml::from_str(&meta[KEY_CONFIG]).unwrap();
        old.model.model = "/gone/model.toml".into();
        meta.insert(KEY_CONFIG.into(), toml::to_string(&old).unwrap());
        recording.metadata.insert(RUN.into(), meta.clone());
        let err = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap_err();
        assert!(matches!(err, ReplayError::ModelUnavailable { .. }), "{err}");
        assert!(err.to_string().contains("/gone/model.toml") && err.to_string().contains("--config"), "{err}");

        // With model_toml the missing file does not matter.
        meta.insert(KEY_MODEL_TOML.into(), model_toml(&config()).unwrap());
        recording.metadata.insert(RUN.into(), meta);
        let r = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap().report;
        assert!(r.is_identical() && r.compared == 20);

        // A given estimator needs no metadata.
        recording.metadata.clear();
        let given = EstimatorSetup::from_config(&config()).unwrap();
        let r = replay(&recording, EstimatorSource::Given(given), InputRule::Auto).unwrap().report;
        assert_eq!(r.estimator, EstimatorOrigin::Given);
        assert!(!r.estimator.exact_expected());
        assert!(r.is_identical(), "the same config as the run reproduces it");
    }

    #[test]
    fn the_recorded_config_and_model_parse_back_exactly() {
        let mut config = config();
        config.estimator.accel_noise_n_per_s2 = 0.1 + 0.2; // not a short decimal
        let entries = run_metadata(&config).unwrap().record().1;
        let back: BenchConfig = toml::from_str(&entries[KEY_CONFIG]).unwrap();
        assert_eq!(back, config);
        let recording = Recording { metadata: [(RUN.to_string(), entries)].into(), ..Recording::default() };
        let (setup, origin) = EstimatorSetup::from_recording(&recording).unwrap();
        assert_eq!(origin, EstimatorOrigin::RecordedModel);
        assert_eq!(setup, EstimatorSetup::from_config(&config).unwrap());
    }

    #[test]
    fn a_model_with_an_input_delay_travels_with_the_recording_and_replays_bit_for_bit() {
        let dir = std::env::temp_dir().join(format!("jetbench-replay-delay-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let model = dir.join("delayed.toml");
        let delayed = jetbench_model::ModelFile {
            model: jetbench_model::Preset::P100Diesel.params(),
            effects: jetbench_model::Effects::new(["input_delay:delay_s=0.115".parse().unwrap()]).unwrap(),
        };
        delayed.save(&model).unwrap();
        let mut config = config();
        (config.plant.model, config.model.model) = (model.display().to_string(), model.display().to_string());
        let recording = synthetic_recording(&config, 400).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();

        let (setup, origin) = EstimatorSetup::from_recording(&recording).unwrap();
        assert_eq!((origin, setup.observer.input_delay_s), (EstimatorOrigin::RecordedModel, 0.115));
        let r = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap().report;
        assert!(r.is_identical() && r.compared == 400, "{r:?}");
        // The delay is used: the same estimator without it gives other estimates.
        let without = EstimatorSetup { observer: ObserverConfig { input_delay_s: 0.0, ..setup.observer }, ..setup };
        let r = replay(&recording, EstimatorSource::Given(without), InputRule::Auto).unwrap().report;
        assert!(r.identical < 400, "{r:?}");
    }

    #[test]
    fn malformed_and_missing_samples_are_counted_not_fatal() {
        let mut recording = synthetic_recording(&config(), 100).unwrap();
        let mut bad = recording.messages[0].clone();
        bad.data.truncate(20);
        recording.messages.insert(1, bad.clone());
        bad.topic = "/bench/state".into();
        recording.messages.insert(1, bad);
        // The recorder lost thrust sample 60: its state cannot be replayed.
        let lost = recording
            .messages
            .iter()
            .position(|m| m.topic == "/bench/thrust" && Thrust::from_cdr(&m.data).is_some_and(|t| t.seq == 60))
            .unwrap();
        recording.messages.remove(lost);
        recording.truncated = true;
        let r = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap().report;
        assert_eq!(r.malformed, Malformed { thrust: 1, state: 1, actuation: 0 });
        assert_eq!((r.thrust_samples, r.replayed, r.states_without_thrust), (99, 99, 1));
        assert!(r.truncated);
        assert!(!r.is_identical(), "the estimates after a lost sample cannot match");
        assert_eq!(r.first_difference.map(|d| d.source_seq), Some(61));

        recording.messages.retain(|m| m.topic != "/bench/thrust" || m.data.len() < 30);
        let err = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap_err();
        assert!(matches!(err, ReplayError::NoThrust { malformed: 1, truncated: true }), "{err}");
        assert!(err.to_string().contains("truncated"), "{err}");
    }

    #[test]
    fn an_unusable_estimator_is_an_error() {
        let recording = synthetic_recording(&config(), 10).unwrap();
        let mut setup = EstimatorSetup::from_config(&config()).unwrap();
        setup.observer.measurement_var_n2 = -1.0;
        let err = replay(&recording, EstimatorSource::Given(setup), InputRule::Auto).unwrap_err();
        assert!(matches!(err, ReplayError::Estimator(EstimError::InvalidConfig { .. })), "{err}");
    }

    #[test]
    fn the_replayed_file_holds_the_replayed_states_and_everything_else() {
        let mut recording = synthetic_recording(&config(), 300).unwrap();
        // A message no jetbench channel carries is reported, not fatal.
        recording.messages.push(RecordedMessage {
            topic: "/other".into(),
            data: CDR_HEADER.to_vec(),
            ..recording.messages[0].clone()
        });
        let outcome = replay(&recording, EstimatorSource::Recorded, InputRule::Auto).unwrap();
        let dir = std::env::temp_dir().join(format!("jetbench-replay-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("replayed.mcap");
        let meta = outcome.report.metadata(Path::new("run.mcap"));
        let written = write_replayed(&recording, &outcome, &path, meta).unwrap();
        assert_eq!(written, WriteReport { written: 1500, not_copied: 1 });
        let back = Recording::open(&path).unwrap();
        assert!(!back.truncated);
        assert_eq!(back.samples(channels::STATE), recorded_states(&recording));
        assert_eq!(back.samples(channels::THRUST), recording.samples(channels::THRUST));
        assert_eq!(back.samples(channels::ACTUATION), recording.samples(channels::ACTUATION));
        assert_eq!(back.metadata[RUN], recording.metadata[RUN]);
        assert_eq!(back.metadata[REPLAY]["identical"], "300");
        assert_eq!(back.metadata[REPLAY]["source"], "run.mcap");
        // Each state right after its thrust sample, at its log time.
        let thrust_at = back.messages.iter().position(|m| m.topic == "/bench/thrust").unwrap();
        assert_eq!(back.messages[thrust_at + 1].topic, "/bench/state");
        assert_eq!(back.messages[thrust_at + 1].log_time_ns, back.messages[thrust_at].log_time_ns);
        // A replayed recording replays identically again.
        let again = replay(&back, EstimatorSource::Recorded, InputRule::Auto).unwrap().report;
        assert!(again.is_identical() && again.compared == 300);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
