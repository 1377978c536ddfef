//! Each `[limits]` entry trips, end to end: `jetbench up --sim` with the P100
//! preset, the cause injected into the simulated bench (its force sensor, or
//! the emulated ECU behind its pseudo-terminal), and the trip judged from the
//! recording: the trip within the limit's hold plus 100 ms of the cause as the
//! recording shows it, the throttle held at idle from then on, the reason in
//! `bench/events`, and the launcher's exit naming the limit.
//!
//! Four runs cover the eight limits: limits whose responses do not mask each
//! other share a run (the `idle` ones of the sensor and the ECU's silence;
//! the EGT rise and the EGT, which the same surge exceeds one after the other).

mod common;

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use common::{repo_root, run, scratch};
use jetbench_msgs::{channels, command_flags, end_reasons, event_kinds, Command, EcuTelemetry, Event};
use jetbench_record::Recording;
use jetbench_stack::limits::{LimitKind, Limits, Response, ThrustLag, EGT_RATE_WINDOW_NS};

const SUITE: &str = "limits";

/// One set at a time: two cores.
static SETS: Mutex<()> = Mutex::new(());

const IDLE: f64 = jetbench_model::THROTTLE_MIN_PCT;

/// What the monitor may take beyond a limit's hold: a cycle or two, the ECU's
/// poll, a loaded machine.
const MARGIN_S: f64 = 0.1;

fn preset() -> Limits {
    Limits::preset("p100").expect("the p100 preset")
}

/// config/sim.toml with the engine running from the start, the reference
/// profile, and `[limits]` the P100 preset with every limit on.
fn config(name: &str) -> PathBuf {
    let text = std::fs::read_to_string(repo_root().join("config/sim.toml")).expect("config/sim.toml");
    let base = text.split("\n[engine]").next().expect("sim.toml has [engine] last");
    let path = scratch(SUITE, &format!("{name}.toml"));
    let engine = "start = \"running\"\nreference = \"profile\"\ncool_down_at_end = false";
    std::fs::write(&path, format!("{base}\n[engine]\n{engine}\n\n[limits]\npreset = \"p100\"\n"))
        .expect("write config");
    path
}

/// What one run left: the launcher's exit and words, and its recording.
struct Run {
    name: &'static str,
    code: i32,
    log: String,
    err: String,
    ecu: Vec<EcuTelemetry>,
    commands: Vec<Command>,
    events: Vec<Event>,
    states: Vec<jetbench_msgs::StateEstimate>,
    thrust: Vec<jetbench_msgs::Thrust>,
}

fn s(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

/// `jetbench up --sim` for `duration_s` with `inject`, in its own namespace.
fn up(name: &'static str, duration_s: u32, inject: &[&str]) -> Run {
    let cfg = config(name);
    let record = scratch(SUITE, &format!("{name}.mcap"));
    let mut command = common::jetbench(SUITE);
    command.env(jetbench_bus::NAMESPACE_ENV, format!("lim{name}{}", std::process::id()));
    command.args(["up", "--sim", "--quiet", "--config"]).arg(&cfg).arg("--record").arg(&record);
    command.args(["--duration", &duration_s.to_string()]);
    for spec in inject {
        command.args(["--inject", spec]);
    }
    let (status, out, err) = run(&mut command, Duration::from_secs(u64::from(duration_s) + 90), name);
    let log = format!("{out}\n{err}");
    let recording = read(&record, &log);
    Run {
        name,
        code: status.code().unwrap_or(-1),
        log,
        err,
        ecu: recording.samples(channels::ECU),
        commands: recording.samples(channels::COMMAND),
        events: recording.samples(channels::EVENTS),
        states: recording.samples(channels::STATE),
        thrust: recording.samples(channels::THRUST),
    }
}

fn read(record: &Path, log: &str) -> Recording {
    let recording = Recording::open(record).unwrap_or_else(|e| panic!("a readable recording: {e}\n{log}"));
    assert!(!recording.truncated, "the recording was closed\n{log}");
    recording
}

impl Run {
    fn fresh_ecu(&self) -> impl Iterator<Item = &EcuTelemetry> {
        self.ecu.iter().filter(|t| t.flags == 0)
    }

    /// The trip of `kind` in `bench/events` (exactly one: trips latch).
    fn trip(&self, kind: LimitKind) -> &Event {
        let trips: Vec<&Event> =
            self.events.iter().filter(|e| e.kind == event_kinds::TRIP && e.code == kind.code()).collect();
        assert_eq!(trips.len(), 1, "{}: one {} trip in bench/events\n{:?}\n{}", self.name, kind.key(), trips, self.log);
        trips[0]
    }

    /// Judges the trip of `kind` against its cause at `cause_ns` (as the
    /// recording shows it) and `bound_s` (the hold, or for a silence its
    /// limit and hold): the event in time, the throttle gated to idle in
    /// time and never above idle after; returns the delay from the cause.
    fn judge(&self, kind: LimitKind, cause_ns: u64, bound_s: f64) -> f64 {
        let trip = self.trip(kind);
        let limit = preset().get(kind).expect("the preset sets every limit");
        assert_eq!(trip.limit, limit.limit, "{}: the event carries the limit", kind.key());
        assert_eq!(trip.previous, i32::from(limit.response == Response::Shutdown), "the response in the event");
        let delay_s = s(trip.stamp_ns) - s(cause_ns);
        // The gated idle command that answers the trip: the first at or after it.
        let idle = self.commands.iter().find(|c| {
            c.stamp_ns >= trip.stamp_ns && c.flags & command_flags::GATED != 0 && c.throttle_pct <= IDLE + 1e-9
        });
        let idle = idle.unwrap_or_else(|| panic!("{}: no gated idle command after the {} trip", self.name, kind.key()));
        let idle_s = s(idle.stamp_ns) - s(cause_ns);
        let above =
            self.commands.iter().filter(|c| c.stamp_ns >= idle.stamp_ns && c.throttle_pct > IDLE + 1e-9).count();
        println!(
            "{}: {} tripped {:.3} s after its cause (bound {bound_s:.1} s + {MARGIN_S} s), idle commanded after {:.3} s; \
             value {:.1} against {:.1} {}",
            self.name,
            kind.key(),
            delay_s,
            idle_s,
            trip.value,
            trip.limit,
            kind.unit()
        );
        assert!(delay_s >= 0.0, "{}: the trip came before its cause ({delay_s:.3} s)", kind.key());
        assert!(delay_s <= bound_s + MARGIN_S, "{}: tripped {delay_s:.3} s after the cause", kind.key());
        assert!(idle_s <= bound_s + MARGIN_S, "{}: idle {idle_s:.3} s after the cause", kind.key());
        assert_eq!(above, 0, "{}: throttle above idle after the {} trip", self.name, kind.key());
        delay_s
    }

    /// No limit tripped before `ns` (a healthy engine before the cause).
    fn no_trip_before(&self, ns: u64) {
        let early: Vec<&Event> =
            self.events.iter().filter(|e| e.kind == event_kinds::TRIP && e.stamp_ns < ns).collect();
        assert!(early.is_empty(), "{}: trips before the cause: {early:?}", self.name);
    }

    /// The throttle was above idle before `ns`: the trip had something to take away.
    fn throttle_above_idle_before(&self, ns: u64) {
        let above = self.commands.iter().filter(|c| c.stamp_ns < ns && c.throttle_pct > IDLE + 1.0).count();
        assert!(above > 50, "{}: the profile ran before the cause ({above} commands above idle)", self.name);
    }

    /// The launcher exits non-zero naming `words`.
    fn exit_names(&self, words: &str) {
        assert_ne!(self.code, 0, "{}: a trip must end the launcher with an error\n{}", self.name, self.log);
        assert!(self.err.contains(words), "{}: the launcher names {words:?}\n{}", self.name, self.log);
    }

    /// A shutdown trip ended the test: `TEST_ENDED` names the limit.
    fn ended_by(&self, kind: LimitKind) {
        let ended = self.events.iter().find(|e| e.kind == event_kinds::TEST_ENDED).expect("a TEST_ENDED event");
        assert_eq!((ended.code, ended.previous), (end_reasons::TRIP, kind.code()), "{ended:?}");
    }
}

/// The first fresh ECU reading (at or after `from_ns`) where `cause` holds.
fn first_ecu(run: &Run, from_ns: u64, cause: impl Fn(&EcuTelemetry) -> bool) -> u64 {
    run.fresh_ecu()
        .find(|t| t.stamp_ns >= from_ns && cause(t))
        .unwrap_or_else(|| panic!("{}: the cause never shows in the ECU's telemetry\n{}", run.name, run.log))
        .stamp_ns
}

/// When the run's engine started (its first fresh ECU reading).
fn t0(run: &Run) -> u64 {
    run.fresh_ecu().next().expect("ECU telemetry").stamp_ns
}

#[test]
fn the_sensor_and_silence_limits_trip_on_their_causes() {
    let _one = SETS.lock().unwrap_or_else(|e| e.into_inner());
    let limits = preset();
    // A mount that shifts the reading by 120 N from 4 s (over the stand's
    // rating, and far from what the RPM says), the sensor silent for a second
    // at 8 s, the ECU silent from 11 s.
    let run = up("sensor", 14, &["offset:at_s=4,for_s=30,size_n=120", "silence:at_s=8,for_s=1", "ecu:silent_at_s=11"]);
    run.exit_names("limits tripped during the run");
    for kind in [LimitKind::MaxThrust, LimitKind::ThrustRpmBand, LimitKind::SensorSilent, LimitKind::EcuSilent] {
        assert!(run.err.contains(kind.key()), "the launcher names {}\n{}", kind.key(), run.log);
    }
    let start = t0(&run);

    // Max thrust: the estimate the monitor watches, above the rating.
    let max = limits.get(LimitKind::MaxThrust).unwrap();
    let over = run.states.iter().find(|e| e.thrust_n > max.limit).expect("the estimate passes the rating");
    run.no_trip_before(over.stamp_ns);
    run.throttle_above_idle_before(over.stamp_ns);
    run.judge(LimitKind::MaxThrust, over.stamp_ns, max.hold_s);

    // Thrust against RPM: the estimate (through the map's lag) against the
    // thrust the newest ECU reading stands for.
    let band = limits.get(LimitKind::ThrustRpmBand).unwrap();
    let map = limits.rpm_map.unwrap();
    let mut ecu = run.fresh_ecu().peekable();
    let mut newest: Option<&EcuTelemetry> = None;
    let mut apart = None;
    let mut lag = ThrustLag::new(map.lag_s);
    for e in &run.states {
        let lagged = lag.step(e.stamp_ns, e.thrust_n);
        while let Some(t) = ecu.next_if(|t| t.stamp_ns <= e.stamp_ns) {
            newest = Some(t);
        }
        if let Some(t) = newest {
            if (lagged - map.thrust_n(t.rpm)).abs() > band.limit {
                apart = Some(e.stamp_ns);
                break;
            }
        }
    }
    let apart = apart.expect("thrust and RPM disagree");
    assert!(s(apart) - s(start) > 3.5, "thrust and RPM agreed until the offset: apart at {:.2} s", s(apart) - s(start));
    run.judge(LimitKind::ThrustRpmBand, apart, band.hold_s);

    // The sensor's silence: from its last frame before the gap.
    let silent = limits.get(LimitKind::SensorSilent).unwrap();
    let gap =
        run.thrust.windows(2).find(|w| w[1].stamp_ns - w[0].stamp_ns > 300_000_000).expect("a gap in bench/thrust");
    println!("sensor: silent {:.3} s", s(gap[1].stamp_ns) - s(gap[0].stamp_ns));
    run.judge(LimitKind::SensorSilent, gap[0].stamp_ns, silent.limit + silent.hold_s);

    // The ECU's silence: from its last fresh reading.
    let ecu_silent = limits.get(LimitKind::EcuSilent).unwrap();
    let last = run.fresh_ecu().last().expect("ECU telemetry").stamp_ns;
    assert!(s(last) - s(start) > 10.0, "the ECU answered until its silence");
    run.judge(LimitKind::EcuSilent, last, ecu_silent.limit + ecu_silent.hold_s);
}

#[test]
fn a_surge_trips_the_egt_rise_then_the_egt_and_shuts_the_engine_down() {
    let _one = SETS.lock().unwrap_or_else(|e| e.into_inner());
    let limits = preset();
    let run = up("surge", 15, &["ecu:surge_at_s=5"]);
    run.exit_names("limit max_egt_c tripped");
    run.ended_by(LimitKind::MaxEgt);
    // The rise rate as the monitor measures it: the slope from the newest
    // reading at least a window old.
    let rise = limits.get(LimitKind::MaxEgtRise).unwrap();
    let fresh: Vec<&EcuTelemetry> = run.fresh_ecu().collect();
    let mut rising = None;
    for (i, t) in fresh.iter().enumerate() {
        let Some(from) = fresh[..i].iter().rev().find(|f| f.stamp_ns + EGT_RATE_WINDOW_NS <= t.stamp_ns) else {
            continue;
        };
        let rate = (t.egt_c - from.egt_c) / (s(t.stamp_ns) - s(from.stamp_ns));
        if rate > rise.limit {
            rising = Some(t.stamp_ns);
            break;
        }
    }
    let rising = rising.expect("the EGT rises faster than the limit");
    run.no_trip_before(rising);
    run.throttle_above_idle_before(rising);
    run.judge(LimitKind::MaxEgtRise, rising, rise.hold_s);
    let max = limits.get(LimitKind::MaxEgt).unwrap();
    let hot = first_ecu(&run, rising, |t| t.egt_c > max.limit);
    run.judge(LimitKind::MaxEgt, hot, max.hold_s);
    // The stack acted before the ECU's own over-temperature (800 °C for 1 s).
    assert!(!run.events.iter().any(|e| e.kind == event_kinds::SHUTDOWN), "the ECU did not have to shut down itself");
}

/// A cause the emulated ECU shows on request (`inject`): `kind` trips on the
/// first fresh reading `past` its limit, within its hold, the throttle goes to
/// idle, and as a `shutdown` limit it shuts the engine down through the ECU
/// and ends the test, the launcher naming the limit.
fn trips_and_shuts_down(name: &'static str, inject: &str, kind: LimitKind, past: impl Fn(&EcuTelemetry, f64) -> bool) {
    let _one = SETS.lock().unwrap_or_else(|e| e.into_inner());
    let limit = preset().get(kind).expect("the preset sets every limit");
    assert_eq!(limit.response, Response::Shutdown, "{} is a shutdown limit in the preset", kind.key());
    let run = up(name, 14, &[inject]);
    run.exit_names(&format!("limit {} tripped", kind.key()));
    run.ended_by(kind);
    let cause = first_ecu(&run, 0, |t| past(t, limit.limit));
    run.no_trip_before(cause);
    run.throttle_above_idle_before(cause);
    run.judge(kind, cause, limit.hold_s);
}

#[test]
fn an_overspeed_trips_max_rpm_and_shuts_the_engine_down() {
    trips_and_shuts_down("overspeed", "ecu:overrpm_at_s=5", LimitKind::MaxRpm, |t, limit| t.rpm > limit);
}

#[test]
fn a_flame_out_trips_min_rpm_and_shuts_the_engine_down() {
    trips_and_shuts_down("flameout", "ecu:flameout_at_s=5", LimitKind::MinRpm, |t, limit| t.rpm < limit);
}
