//! Bad sensor data in the live loop (`jetbench up --sim --inject ...`),
//! judged from the recording: `sim/truth` marks every injected frame, and a
//! frame is followed through the loop by its number (`sim/truth` seq k is the
//! sensor frame k that `bench/thrust` counts in `frame_seq`; a state names its
//! thrust sample in `source_seq`, a command its state).

use std::collections::HashMap;

use jetbench_control::recorded::{recording_metrics, ThrustSource};
use jetbench_control::MetricsOptions;
use jetbench_msgs::{
    channels, command_flags, sim_faults, state_flags, visit_channels, Channel, ChannelVisitor, Sample,
};
use jetbench_record::Recording;
use jetbench_stack::control::ControlStep;
use jetbench_stack::replay::{recorded_config, replay_with_alternatives, EstimatorSource, InputRule};

use crate::set::run_to_end;
use crate::{p50_max, Bench, FaultsError};

/// What bad data did to a live run.
#[derive(Clone, Debug, Default)]
pub struct BadData {
    /// Length of the run, s.
    pub duration_s: f64,
    /// `--inject` specifications of the run.
    pub inject: Vec<String>,
    /// Frames with a spike (and no other fault) that reached the estimator.
    pub spikes: usize,
    /// Those of them whose state was flagged rejected.
    pub spikes_rejected: usize,
    /// Spikes on a frame with another fault (stuck, NaN, silent): not judged.
    pub spikes_in_other_faults: usize,
    /// States flagged rejected without a spike in their frame.
    pub other_rejections: usize,
    /// Tracking MAE (true thrust against the reference), N.
    pub mae_n: f64,
    /// Tracking MAE of the same run without faults, N.
    pub baseline_mae_n: f64,
    /// What each spike did to the throttle, % (p50, max): the recorded command at the
    /// spike against the command the same controller, with the same history, computes
    /// from the estimate the clean reading would have given ([`spike_effects`]); or why
    /// the recording cannot say.
    pub spike_effect: SpikeEffect,
    /// |throttle step| of the command computed at a spike, % (p50, max).
    pub step_at_spike_pct: (f64, f64),
    /// |throttle step| at every other cycle, % (p50, max): the loop's own movement.
    pub step_elsewhere_pct: (f64, f64),
    /// The limits that tripped (`bench/events`), in order.
    pub trips: Vec<&'static str>,
    /// From the first stuck frame to the first state flagged stuck, s.
    pub stuck_flagged_after_s: Option<f64>,
    /// NaN frames injected.
    pub nan_frames: usize,
    /// NaN frames that reached `bench/thrust` (should be none).
    pub nan_published: usize,
    /// Recorded samples holding NaN or an infinity, on any channel.
    pub non_finite_samples: usize,
    /// Frames the sensor left out (silence injected).
    pub silent_frames: usize,
    /// Actuation idled while the sensor was silent (its fail-safe).
    pub idled_in_silence: bool,
    /// Every bound this run broke, in words (empty: all held).
    pub problems: Vec<String>,
}

/// What the spikes of a run did to the commanded throttle ([`spike_effects`]).
#[derive(Clone, Debug, PartialEq)]
pub enum SpikeEffect {
    /// Measured over the spikes of the run.
    Measured {
        /// The median effect, %.
        p50_pct: f64,
        /// The largest effect, %.
        max_pct: f64,
    },
    /// Why the recording cannot say (no spike, or a loop it does not reproduce).
    Unknown(String),
}

impl Default for SpikeEffect {
    fn default() -> Self {
        SpikeEffect::Unknown("not measured".into())
    }
}

impl std::fmt::Display for SpikeEffect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SpikeEffect::Measured { p50_pct, max_pct } => write!(f, "{p50_pct:.2} / {max_pct:.2}"),
            SpikeEffect::Unknown(why) => write!(f, "unknown: {why}"),
        }
    }
}

/// Runs `jetbench up --sim --inject SPEC...` for `duration_s` (and, with
/// `baseline`, the same run without faults, for the MAE) and judges the recording.
pub fn bad_data(bench: &Bench, inject: &[&str], duration_s: u32, baseline: bool) -> Result<BadData, FaultsError> {
    let run = |inject: &[&str]| -> Result<Recording, FaultsError> {
        let namespace = bench.fresh_namespace();
        let record = bench.scratch(&format!("inject-{namespace}.mcap"));
        let mut command = bench.command(&namespace);
        command.args(["up", "--sim", "--quiet", "--duration", &duration_s.to_string(), "--record"]).arg(&record);
        for spec in inject {
            command.args(["--inject", spec]);
        }
        let (status, said) = run_to_end(&mut command, "jetbench up --inject")?;
        // A limit that trips on an injected sensor fault (a stuck reading
        // disagreeing with the RPM) is the stack doing its job: the run is
        // judged, and its trips are listed.
        if !status.success() && !said.contains("limits tripped during the run") {
            return Err(FaultsError::Failed { what: format!("jetbench up --inject {inject:?}"), message: said });
        }
        Ok(Recording::open(&record)?)
    };
    let faulty = run(inject)?;
    let mut out = judge(&faulty);
    out.duration_s = f64::from(duration_s);
    out.inject = inject.iter().map(|s| s.to_string()).collect();
    out.baseline_mae_n = if baseline { mae(&run(&[])?) } else { f64::NAN };
    if baseline && out.mae_n > 1.10 * out.baseline_mae_n {
        out.problems
            .push(format!("MAE {:.3} N, more than 10 % above {:.3} N without spikes", out.mae_n, out.baseline_mae_n));
    }
    Ok(out)
}

fn mae(recording: &Recording) -> f64 {
    let options = MetricsOptions { skip_s: 1.0, ..MetricsOptions::default() };
    recording_metrics(recording, Some(ThrustSource::Truth), &options)
        .ok()
        .and_then(|m| m.runs.first().map(|r| r.metrics.mae_n))
        .unwrap_or(f64::NAN)
}

/// Judges one recording of a run with injected faults.
pub fn judge(recording: &Recording) -> BadData {
    let truth = recording.samples(channels::SIM_TRUTH);
    let thrust = recording.samples(channels::THRUST);
    let states = recording.samples(channels::STATE);
    let commands = recording.samples(channels::COMMAND);
    let actuation = recording.samples(channels::ACTUATION);
    let thrust_of_frame: HashMap<u64, u64> = thrust.iter().map(|t| (t.frame_seq, t.seq)).collect();
    let state_of_thrust: HashMap<u64, usize> = states.iter().enumerate().map(|(i, s)| (s.source_seq, i)).collect();
    let frame_of_thrust: HashMap<u64, u64> = thrust.iter().map(|t| (t.seq, t.frame_seq)).collect();
    let state_at = |frame: u64| thrust_of_frame.get(&frame).and_then(|t| state_of_thrust.get(t)).map(|&i| &states[i]);
    let mut out = BadData { mae_n: mae(recording), ..BadData::default() };
    out.trips = recording
        .samples(channels::EVENTS)
        .iter()
        .filter(|e| e.kind == jetbench_msgs::event_kinds::TRIP)
        .map(|e| jetbench_stack::limits::LimitKind::from_code(e.code).map_or("unknown limit", |k| k.key()))
        .collect();

    // A spike on a stuck, NaN or silent frame is another fault's frame: a
    // silent one never arrives, and one on a stuck sensor breaks its repeats.
    let spiked = truth.iter().filter(|t| t.faults & sim_faults::SPIKE != 0);
    let spike_frames: Vec<u64> =
        spiked.clone().filter(|t| t.faults == sim_faults::SPIKE && state_at(t.seq).is_some()).map(|t| t.seq).collect();
    out.spikes_in_other_faults = spiked.filter(|t| t.faults != sim_faults::SPIKE).count();
    out.spikes = spike_frames.len();
    out.spikes_rejected = spike_frames
        .iter()
        .filter(|&&k| state_at(k).is_some_and(|s| s.flags & state_flags::MEASUREMENT_REJECTED != 0))
        .count();
    let spike_states: std::collections::HashSet<u64> =
        spike_frames.iter().filter_map(|&k| state_at(k)).map(|s| s.seq).collect();
    out.other_rejections = states
        .iter()
        .filter(|s| s.flags & state_flags::MEASUREMENT_REJECTED != 0 && !spike_states.contains(&s.seq))
        .count();
    let (mut at_spike, mut elsewhere) = (Vec::new(), Vec::new());
    for w in commands.windows(2) {
        let step = (w[1].throttle_pct - w[0].throttle_pct).abs();
        if spike_states.contains(&w[1].source_seq) {
            at_spike.push(step)
        } else {
            elsewhere.push(step)
        }
    }
    out.step_at_spike_pct = p50_max(&at_spike);
    let spike_sizes: HashMap<u64, f64> = truth
        .iter()
        .filter(|t| t.faults == sim_faults::SPIKE && spike_frames.binary_search(&t.seq).is_ok())
        .map(|t| (t.seq, t.injected_n))
        .collect();
    out.spike_effect = match spike_effects(recording, &spike_sizes) {
        Ok(effects) if effects.is_empty() => SpikeEffect::Unknown("no spike reached the controller".into()),
        Ok(effects) => {
            let (p50_pct, max_pct) = p50_max(&effects);
            SpikeEffect::Measured { p50_pct, max_pct }
        }
        Err(why) => SpikeEffect::Unknown(why),
    };
    out.step_elsewhere_pct = p50_max(&elsewhere);

    let first_stuck = truth.iter().find(|t| t.faults & sim_faults::STUCK != 0).map(|t| t.seq);
    let flagged = states
        .iter()
        .find(|s| s.flags & state_flags::SENSOR_STUCK != 0)
        .and_then(|s| frame_of_thrust.get(&s.source_seq).copied());
    if let (Some(from), Some(flagged)) = (first_stuck, flagged) {
        out.stuck_flagged_after_s = Some(flagged.saturating_sub(from) as f64 * jetbench_model::STEP_S);
    }
    let nan_frames: Vec<u64> = truth.iter().filter(|t| t.faults & sim_faults::NAN != 0).map(|t| t.seq).collect();
    out.nan_frames = nan_frames.len();
    out.nan_published = nan_frames.iter().filter(|k| thrust_of_frame.contains_key(k)).count();
    out.non_finite_samples = non_finite_samples(recording);

    let silent: Vec<&jetbench_msgs::SimTruth> = truth.iter().filter(|t| t.faults & sim_faults::SILENCE != 0).collect();
    out.silent_frames = silent.len();
    if let (Some(first), Some(last)) = (silent.first(), silent.last()) {
        out.idled_in_silence = actuation.iter().any(|a| {
            a.publish_ns > first.stamp_ns
                && a.publish_ns <= last.stamp_ns
                && a.flags & jetbench_msgs::actuation_flags::IDLE_FALLBACK != 0
        });
    }
    judge_bounds(&mut out, first_stuck.is_some());
    out
}

/// How much each spike moved the commanded throttle, %, in the order of the
/// spikes: `spike_sizes` maps a sensor frame to what was added to its thrust
/// reading (`sim/truth`'s `injected_n`).
///
/// The estimator is replayed on the recording (it must reproduce the recorded
/// estimates bit for bit, else nothing is claimed), and at each spike it is also
/// given the clean reading: the spiked reading less the spike (on the simulated
/// bench's identity calibration). The controller is replayed too, from the
/// recording's config on the estimates it was given (the commands name them); at
/// a spike it must reproduce the recorded command bit for bit, and the effect is
/// the distance from that command to the one computed from the clean estimate.
pub fn spike_effects(recording: &Recording, spike_sizes: &HashMap<u64, f64>) -> Result<Vec<f64>, String> {
    let (outcome, clean) =
        replay_with_alternatives(recording, EstimatorSource::Recorded, InputRule::RecordedState, |t| {
            spike_sizes.get(&t.frame_seq).map(|size| t.thrust_n - size)
        })
        .map_err(|e| format!("the estimator cannot be replayed: {e}"))?;
    if !outcome.report.is_identical() {
        return Err(format!(
            "the replayed estimates differ from the recorded ones ({:?})",
            outcome.report.first_difference
        ));
    }
    if clean.len() != spike_sizes.len() {
        return Err(format!("{} spikes, {} of them replayed", spike_sizes.len(), clean.len()));
    }
    let config = recorded_config(recording).map_err(|e| e.to_string())?;
    let states: HashMap<u64, jetbench_msgs::StateEstimate> =
        recording.samples(channels::STATE).into_iter().map(|s| (s.seq, s)).collect();
    let commands = recording.samples(channels::COMMAND);
    // The estimates the controller computed its commands from, in its order. A
    // command computed from an estimate carries its stamp; the idle sent in a
    // cycle with no estimate names none (its stamp is the time it was sent).
    let seen: Vec<(&jetbench_msgs::StateEstimate, &jetbench_msgs::Command)> = commands
        .iter()
        .filter_map(|c| states.get(&c.source_seq).filter(|s| s.stamp_ns == c.stamp_ns).map(|s| (s, c)))
        .collect();
    let mut effects = Vec::with_capacity(clean.len());
    for alternative in &clean {
        // An estimate the controller never computed from (its queue overflowed) had no effect.
        let Some(at) = seen.iter().position(|(s, _)| s.seq == alternative.seq) else { continue };
        // Nor had one whose command was held whatever the law asked (idle, a hold, an
        // estimate still settling): the law's output did not reach the engine.
        if seen[at].1.flags & command_flags::GATED != 0 {
            continue;
        }
        // A controller with the same history; `Law` holds solver state that is not
        // cloned, so each spike replays the run up to it (FBL: microseconds a cycle).
        let replayed = |last: &jetbench_msgs::StateEstimate| -> Result<f64, String> {
            let law = config.control_law().map_err(|e| format!("the recorded controller: {e}"))?;
            // From the last time the live law was started afresh (the engine
            // reached run, a trip was cleared): the recording flags that command.
            let from = seen[..=at].iter().rposition(|(_, c)| c.flags & command_flags::LAW_RESET != 0).unwrap_or(0);
            let mut control = ControlStep::with_law(law, config.reference.clone());
            for (s, _) in &seen[from..at] {
                control.step(s).map_err(|e| e.to_string())?;
            }
            Ok(control.step(last).map_err(|e| e.to_string())?.1.throttle_pct)
        };
        let (state, command) = seen[at];
        let recomputed = replayed(state)?;
        if recomputed.to_bits() != command.throttle_pct.to_bits() {
            return Err(format!(
                "the controller does not reproduce its recorded command at state {} ({recomputed} % against {} %)",
                state.seq, command.throttle_pct
            ));
        }
        effects.push((command.throttle_pct - replayed(alternative)?).abs());
    }
    Ok(effects)
}

/// The median effect of the spikes on the throttle a run may show, %.
pub const SPIKE_EFFECT_P50_PCT: f64 = 0.5;
/// The largest effect of one spike on the throttle a run may show, %.
pub const SPIKE_EFFECT_MAX_PCT: f64 = 2.0;

fn judge_bounds(out: &mut BadData, stuck_injected: bool) {
    if out.spikes_rejected != out.spikes {
        out.problems.push(format!("{} of {} spikes rejected", out.spikes_rejected, out.spikes));
    }
    // A rejected spike costs the estimate one measurement update. On the simulated
    // bench that moves FBL's throttle by 0.1-0.3 % at the median, and by 0.85-0.99 %
    // at most (a spike on the first climb, the figure set by the cycle the law
    // started at). At the same spikes, an honest reading 1 N or 3 N off the clean
    // one (the sensor's noise is 2.6 N), taken in place of rejecting the spike,
    // lands up to 1.2 % or 2.1 % from the command sent: the noise of one reading
    // moves the throttle that much. The bounds keep about twice what was measured
    // under load; a leak as small as one reading's noise is below them, a 30 N
    // spike leaking whole (ten times the noise, at every spike) is what the median
    // bound is for.
    match &out.spike_effect {
        SpikeEffect::Measured { p50_pct, max_pct }
            if *p50_pct >= SPIKE_EFFECT_P50_PCT || *max_pct >= SPIKE_EFFECT_MAX_PCT =>
        {
            out.problems.push(format!("a spike moved the throttle by {max_pct:.2} % (median {p50_pct:.2} %)"))
        }
        SpikeEffect::Unknown(why) if out.spikes > 0 => {
            out.problems.push(format!("what a spike did to the throttle is unknown: {why}"))
        }
        _ => {}
    }
    // After a stuck sensor or a silence, the first fresh reading may rightly
    // fail the gate; with spikes alone, nothing but a spike may.
    let spikes_only = !stuck_injected && out.silent_frames == 0 && out.nan_frames == 0;
    if spikes_only && out.other_rejections > 0 {
        out.problems.push(format!("{} honest measurements rejected", out.other_rejections));
    }
    if stuck_injected && !out.stuck_flagged_after_s.is_some_and(|s| s < 1.0) {
        out.problems.push(format!("stuck sensor flagged after {:?} s", out.stuck_flagged_after_s));
    }
    if out.nan_published > 0 || out.non_finite_samples > 0 {
        out.problems.push(format!(
            "NaN reached the bus: {} NaN frames published, {} non-finite samples recorded",
            out.nan_published, out.non_finite_samples
        ));
    }
    if out.silent_frames > 0 && !out.idled_in_silence {
        out.problems.push("actuation did not idle while the sensor was silent".into());
    }
}

/// Samples of any channel with a NaN or infinite field.
fn non_finite_samples(recording: &Recording) -> usize {
    struct Count<'a>(&'a Recording, usize);
    impl ChannelVisitor for Count<'_> {
        fn visit<T: Sample>(&mut self, channel: Channel<T>) {
            self.1 += self.0.samples(channel).iter().filter(|s| s.non_finite_field().is_some()).count();
        }
    }
    let mut count = Count(recording, 0);
    visit_channels(&mut count);
    count.1
}
