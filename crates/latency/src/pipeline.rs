//! Latency of the control path, from the stamps every sample carries.
//!
//! A cycle starts when sensing receives the sensor frame (`Thrust::stamp_ns`)
//! and ends when actuation hands the command frame to the throttle board
//! (`Actuation::written_ns`). In between, every sample records when it was
//! published and which input it was computed from (`source_seq`,
//! `command_seq`), so a recording alone gives each hop of each cycle:
//!
//! | hop | from | to |
//! |---|---|---|
//! | sensing | frame received | `bench/thrust` published |
//! | estimation | thrust published | `bench/state` published |
//! | control | state published | `bench/command` published |
//! | actuation | command published | frame written to the board |
//!
//! Each hop includes the wake-up of its process and its work. Percentiles
//! come from HDR histograms (3 significant digits, 1 ns to 60 s).

use std::collections::{BTreeMap, HashMap};

use hdrhistogram::Histogram;
use jetbench_msgs::{actuation_flags, channels, Sample, ServiceId};
use jetbench_record::{seq_gaps, Recording};
use serde::Serialize;

use jetbench_stack::runtime::clock::PERIOD_NS;

/// The hops of the control path, in order.
pub const HOPS: [&str; 4] = ["sensing", "estimation", "control", "actuation"];

/// Percentiles of one latency distribution, µs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Percentiles {
    /// Median, µs.
    pub p50: f64,
    /// 90th percentile, µs.
    pub p90: f64,
    /// 99th percentile, µs: the figure a 100 Hz loop's margin is judged by.
    pub p99: f64,
    /// 99.9th percentile, µs.
    pub p999: f64,
    /// Longest, µs.
    pub max: f64,
    /// Mean, µs.
    pub mean: f64,
    /// Values in the distribution.
    pub count: u64,
}

impl Percentiles {
    /// One row of a text table: `p50 p90 p99 p99.9 max`, µs.
    pub fn row(&self) -> String {
        format!("{:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>9.1}", self.p50, self.p90, self.p99, self.p999, self.max)
    }
}

/// A latency distribution in ns.
#[derive(Clone, Debug)]
pub struct LatencyHistogram {
    histogram: Histogram<u64>,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self::new()
    }
}

impl LatencyHistogram {
    /// Longest latency recorded exactly; longer ones are recorded as this (and
    /// would be reported as a deadline miss long before).
    pub const MAX_NS: u64 = 60_000_000_000;

    /// An empty distribution.
    pub fn new() -> Self {
        // The bounds are constants that hdrhistogram accepts.
        let histogram = Histogram::new_with_bounds(1, Self::MAX_NS, 3).expect("valid histogram bounds");
        LatencyHistogram { histogram }
    }

    /// Adds one latency, ns (beyond [`LatencyHistogram::MAX_NS`]: recorded as that).
    pub fn record(&mut self, ns: u64) {
        self.histogram.saturating_record(ns.clamp(1, Self::MAX_NS));
    }

    /// Adds every value of `other` (another round of the same measurement).
    pub fn add(&mut self, other: &LatencyHistogram) {
        // Both have the same bounds, so adding cannot fail.
        let _ = self.histogram.add(&other.histogram);
    }

    /// Latencies recorded.
    pub fn len(&self) -> u64 {
        self.histogram.len()
    }

    /// True before the first latency.
    pub fn is_empty(&self) -> bool {
        self.histogram.is_empty()
    }

    /// p50, p90, p99, p99.9 and max in µs; zeros when empty.
    pub fn percentiles(&self) -> Percentiles {
        if self.histogram.is_empty() {
            return Percentiles::default();
        }
        let us = |ns: u64| ns as f64 / 1e3;
        Percentiles {
            p50: us(self.histogram.value_at_quantile(0.5)),
            p90: us(self.histogram.value_at_quantile(0.9)),
            p99: us(self.histogram.value_at_quantile(0.99)),
            p999: us(self.histogram.value_at_quantile(0.999)),
            max: us(self.histogram.max()),
            mean: self.histogram.mean() / 1e3,
            count: self.histogram.len(),
        }
    }

    /// Counts in `bins` equal bins over `[0, upper_us)`, as (bin centre µs, count);
    /// values beyond go to the last bin.
    pub fn bins(&self, upper_us: f64, bins: usize) -> Vec<(f64, u64)> {
        let bins = bins.max(1);
        let width_us = upper_us / bins as f64;
        let mut counts = vec![0u64; bins];
        for v in self.histogram.iter_recorded() {
            let us = self.histogram.median_equivalent(v.value_iterated_to()) as f64 / 1e3;
            let i = ((us / width_us) as usize).min(bins - 1);
            counts[i] += v.count_at_value();
        }
        counts.into_iter().enumerate().map(|(i, c)| ((i as f64 + 0.5) * width_us, c)).collect()
    }
}

/// The control path of a recorded run, cycle by cycle.
#[derive(Debug, Default)]
pub struct PipelineAnalysis {
    /// Sensor cycles judged (after the warm-up).
    pub cycles: u64,
    /// Of those, cycles whose command reached the board.
    pub completed: u64,
    /// Sensor frame received → command frame written.
    pub e2e: LatencyHistogram,
    /// Per hop, in [`HOPS`] order.
    pub hops: [LatencyHistogram; 4],
    /// |time between sensor cycles − 10 ms|.
    pub period_jitter: LatencyHistogram,
    /// Cycles whose command was written more than one period after the sensor frame.
    pub late_e2e: u64,
    /// Sensor cycles that came more than one period behind the 100 Hz schedule
    /// (more than 20 ms after the previous one).
    pub late_periods: u64,
    /// Cycles whose command never reached the board because actuation, late,
    /// found a newer one waiting and wrote that instead (it always applies the
    /// newest). No sample was lost, but the cycle missed its deadline.
    pub superseded: u64,
    /// Cycles that stopped short of a command: a stage produced nothing for
    /// them (the run's last 0.5 s excepted).
    pub unfinished: u64,
    /// Sensor frames lost before sensing (jumps of the sensor's frame counter).
    pub frames_lost: u64,
    /// `seq` gaps per recorded channel: samples lost between publisher and recorder.
    pub seq_gaps: BTreeMap<String, u64>,
    /// When each deadline miss happened: the sensor frame stamp of the late,
    /// superseded or late-period cycle, ns.
    pub miss_stamps_ns: Vec<u64>,
    /// Deadline misses each service counted itself over the judged cycles.
    pub service_deadline_misses: BTreeMap<String, u64>,
}

impl PipelineAnalysis {
    /// Adds another run of the same pipeline (a later round of one measurement).
    pub fn merge(&mut self, other: &PipelineAnalysis) {
        self.cycles += other.cycles;
        self.completed += other.completed;
        self.e2e.add(&other.e2e);
        for (mine, theirs) in self.hops.iter_mut().zip(&other.hops) {
            mine.add(theirs);
        }
        self.period_jitter.add(&other.period_jitter);
        self.late_e2e += other.late_e2e;
        self.late_periods += other.late_periods;
        self.superseded += other.superseded;
        self.unfinished += other.unfinished;
        self.miss_stamps_ns.extend_from_slice(&other.miss_stamps_ns);
        self.frames_lost += other.frames_lost;
        for (channel, gaps) in &other.seq_gaps {
            *self.seq_gaps.entry(channel.clone()).or_default() += gaps;
        }
        for (service, misses) in &other.service_deadline_misses {
            *self.service_deadline_misses.entry(service.clone()).or_default() += misses;
        }
    }

    /// Deadline misses: late cycles, late sensor periods, and cycles whose
    /// command was superseded before it could be written.
    pub fn deadline_misses(&self) -> u64 {
        self.late_e2e + self.late_periods + self.superseded
    }

    /// Samples lost anywhere: sensor frames, bus or recorder gaps, cycles a
    /// stage produced nothing for.
    pub fn lost(&self) -> u64 {
        self.frames_lost + self.seq_gaps.values().sum::<u64>() + self.unfinished
    }
}

/// Rebuilds every cycle of a recorded run and measures it. Cycles in the
/// first `warmup_s` seconds are left out (processes still faulting in pages
/// and the controller starting).
pub fn analyse_pipeline(recording: &Recording, warmup_s: f64) -> PipelineAnalysis {
    let thrust = recording.samples(channels::THRUST);
    let states = recording.samples(channels::STATE);
    let commands = recording.samples(channels::COMMAND);
    let actuation = recording.samples(channels::ACTUATION);
    let mut analysis = PipelineAnalysis::default();

    let state_by_source: HashMap<u64, u64> = states.iter().map(|s| (s.source_seq, s.publish_ns)).collect();
    let state_seq_by_source: HashMap<u64, u64> = states.iter().map(|s| (s.source_seq, s.seq)).collect();
    // A command belongs to the estimate it names *and* whose stamp it carries: the idle
    // control sends in a cycle with no estimate names none (`source_seq` 0) and carries the
    // time it was sent, and must not pass for the answer to estimate 0.
    let command_by_cycle: HashMap<(u64, u64), (u64, u64)> =
        commands.iter().map(|c| ((c.source_seq, c.stamp_ns), (c.seq, c.publish_ns))).collect();
    // The first write of each command (a stale cycle re-sends the last one).
    let mut written_by_command: HashMap<u64, u64> = HashMap::new();
    for a in &actuation {
        if a.written_ns != 0 && a.flags & actuation_flags::STALE == 0 {
            written_by_command.entry(a.command_seq).or_insert(a.written_ns);
        }
    }
    let newest_written = written_by_command.keys().copied().max();

    let Some(first) = thrust.first() else { return analysis };
    let last_stamp = thrust.last().map_or(0, |t| t.stamp_ns);
    let start_ns = first.stamp_ns + (warmup_s.max(0.0) * 1e9) as u64;
    let tail_ns = last_stamp.saturating_sub(500_000_000);
    let mut previous: Option<&jetbench_msgs::Thrust> = None;
    for t in &thrust {
        if let Some(p) = previous {
            if t.frame_seq > p.frame_seq + 1 {
                analysis.frames_lost += t.frame_seq - p.frame_seq - 1;
            }
        }
        let judged = t.stamp_ns >= start_ns;
        if judged {
            if let Some(p) = previous {
                let period = t.stamp_ns.saturating_sub(p.stamp_ns);
                analysis.period_jitter.record(period.abs_diff(PERIOD_NS));
                if period > 2 * PERIOD_NS {
                    analysis.late_periods += 1;
                    analysis.miss_stamps_ns.push(t.stamp_ns);
                }
            }
        }
        previous = Some(t);
        if !judged {
            continue;
        }
        analysis.cycles += 1;
        let command = state_by_source
            .get(&t.seq)
            .zip(state_seq_by_source.get(&t.seq))
            .and_then(|(&state_ns, &state_seq)| command_by_cycle.get(&(state_seq, t.stamp_ns)).map(|&c| (state_ns, c)));
        let Some((state_ns, (command_seq, command_ns))) = command else {
            if t.stamp_ns < tail_ns {
                analysis.unfinished += 1;
            }
            continue;
        };
        let Some(&written_ns) = written_by_command.get(&command_seq) else {
            if newest_written.is_some_and(|newest| newest > command_seq) {
                analysis.superseded += 1;
                analysis.miss_stamps_ns.push(t.stamp_ns);
            } else if t.stamp_ns < tail_ns {
                analysis.unfinished += 1;
            }
            continue;
        };
        let stamps = [t.stamp_ns, t.publish_ns, state_ns, command_ns, written_ns];
        analysis.completed += 1;
        let e2e = stamps[4].saturating_sub(stamps[0]);
        analysis.e2e.record(e2e);
        if e2e > PERIOD_NS {
            analysis.late_e2e += 1;
            analysis.miss_stamps_ns.push(t.stamp_ns);
        }
        for (hop, pair) in analysis.hops.iter_mut().zip(stamps.windows(2)) {
            hop.record(pair[1].saturating_sub(pair[0]));
        }
    }

    struct Gaps<'a>(&'a Recording, &'a mut BTreeMap<String, u64>);
    impl jetbench_msgs::ChannelVisitor for Gaps<'_> {
        fn visit<T: Sample>(&mut self, channel: jetbench_msgs::Channel<T>) {
            // Health carries one publisher per service on one channel: gaps per service below.
            if channel.name != channels::HEALTH.name {
                self.1.insert(channel.name.to_string(), seq_gaps(&self.0.samples(channel)));
            }
        }
    }
    jetbench_msgs::visit_channels(&mut Gaps(recording, &mut analysis.seq_gaps));
    // Each service's own count over the judged cycles: its heartbeat counter at
    // the last sensor frame less the count before the first judged one (the
    // start-up, and the stop, when sim-bench goes first and every input falls
    // silent, are not the run's).
    let mut before: BTreeMap<u32, u64> = BTreeMap::new();
    let mut at_end: BTreeMap<u32, u64> = BTreeMap::new();
    for h in recording.samples(channels::HEALTH) {
        if h.stamp_ns < start_ns {
            before.insert(h.service_id, h.deadline_misses);
        } else if h.stamp_ns <= last_stamp {
            at_end.insert(h.service_id, h.deadline_misses);
        }
    }
    for (id, misses) in at_end {
        let name = ServiceId::from_u32(id).map_or("unknown", ServiceId::name);
        let since = misses.saturating_sub(before.get(&id).copied().unwrap_or(0));
        analysis.service_deadline_misses.insert(name.to_string(), since);
    }
    analysis
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_a_known_distribution() {
        let mut h = LatencyHistogram::new();
        for us in 1..=1000u64 {
            h.record(us * 1000);
        }
        let p = h.percentiles();
        assert_eq!(p.count, 1000);
        assert!((p.p50 - 500.0).abs() < 1.0, "{p:?}");
        assert!((p.p99 - 990.0).abs() < 1.0, "{p:?}");
        assert!((p.max - 1000.0).abs() < 1.0, "{p:?}");
        let bins = h.bins(1000.0, 10);
        assert_eq!(bins.len(), 10);
        assert_eq!(bins.iter().map(|b| b.1).sum::<u64>(), 1000);
        assert!(bins.iter().all(|b| (99..=101).contains(&b.1)), "{bins:?}");
    }

    #[test]
    fn rounds_merge_into_one_distribution() {
        let (mut a, mut b) = (PipelineAnalysis::default(), PipelineAnalysis::default());
        for us in 1..=500u64 {
            a.e2e.record(us * 1000);
            b.e2e.record((us + 500) * 1000);
        }
        (a.cycles, a.completed, a.late_e2e) = (500, 500, 1);
        (b.cycles, b.completed, b.frames_lost) = (510, 500, 2);
        a.seq_gaps.insert("bench/state".into(), 1);
        b.seq_gaps.insert("bench/state".into(), 2);
        b.service_deadline_misses.insert("control".into(), 3);
        a.merge(&b);
        assert_eq!((a.cycles, a.completed, a.deadline_misses(), a.lost()), (1010, 1000, 1, 5));
        let p = a.e2e.percentiles();
        assert_eq!(p.count, 1000);
        assert!((p.p50 - 500.0).abs() < 1.0 && (p.max - 1000.0).abs() < 1.0, "{p:?}");
        assert_eq!(a.service_deadline_misses["control"], 3);
    }

    /// Every cycle pairs the command computed from its estimate: an idle sent in a cycle with
    /// no estimate names none (`source_seq` 0) and carries the time it was sent, and is not
    /// taken for the answer to estimate 0, which the run's first sensor frame started.
    #[test]
    fn an_idle_sent_without_an_estimate_is_no_cycles_command() {
        use jetbench_msgs::{Actuation, Command, StateEstimate, Thrust};
        use jetbench_record::RecordedMessage;
        let mut recording = Recording::default();
        let ms = 1_000_000u64;
        let mut push = |m: RecordedMessage| recording.messages.push(m);
        for k in 0..200u64 {
            let stamp_ns = 1_000 * ms + k * 10 * ms;
            let thrust = Thrust { seq: k, stamp_ns, publish_ns: stamp_ns + ms / 10, frame_seq: k, ..Thrust::default() };
            push(RecordedMessage::of_sample(channels::THRUST, thrust.publish_ns, &thrust));
            let state =
                StateEstimate { seq: k, stamp_ns, publish_ns: stamp_ns + ms / 5, source_seq: k, ..Default::default() };
            push(RecordedMessage::of_sample(channels::STATE, state.publish_ns, &state));
            // Command seq 2k answers estimate k; at 1.5 s control also sends idle (seq 2k + 1).
            let command =
                Command { seq: 2 * k, stamp_ns, publish_ns: stamp_ns + ms / 2, source_seq: k, ..Default::default() };
            push(RecordedMessage::of_sample(channels::COMMAND, command.publish_ns, &command));
            let written =
                Actuation { seq: 2 * k, stamp_ns, written_ns: stamp_ns + ms, command_seq: 2 * k, ..Default::default() };
            push(RecordedMessage::of_sample(channels::ACTUATION, written.written_ns, &written));
            if k == 50 {
                let sent_ns = stamp_ns + 3 * ms;
                let idle = Command {
                    seq: 2 * k + 1,
                    stamp_ns: sent_ns,
                    publish_ns: sent_ns,
                    source_seq: 0,
                    ..Default::default()
                };
                push(RecordedMessage::of_sample(channels::COMMAND, idle.publish_ns, &idle));
                let applied = Actuation {
                    seq: 2 * k + 1,
                    stamp_ns: sent_ns,
                    written_ns: sent_ns + ms,
                    command_seq: 2 * k + 1,
                    ..Default::default()
                };
                push(RecordedMessage::of_sample(channels::ACTUATION, applied.written_ns, &applied));
            }
        }
        let analysis = analyse_pipeline(&recording, 0.0);
        assert_eq!((analysis.cycles, analysis.completed), (200, 200), "{analysis:?}");
        assert_eq!(analysis.deadline_misses(), 0, "{analysis:?}");
        let e2e = analysis.e2e.percentiles();
        assert!((e2e.max - 1_000.0).abs() < 5.0, "every cycle written 1 ms after its frame: {e2e:?}");
    }

    #[test]
    fn an_empty_histogram_reports_zeros() {
        assert_eq!(LatencyHistogram::new().percentiles(), Percentiles::default());
    }
}
