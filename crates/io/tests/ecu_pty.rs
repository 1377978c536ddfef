//! The ECU poller against the emulated ECU over a real pseudo-terminal pair:
//! poll rate, garbage lines, an ECU that goes silent and comes back.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use jetbench_io::ecu::EcuReading;
use jetbench_io::emulate::{EcuModel, PtyEcu};
use jetbench_io::serial::EcuPoller;
use jetbench_msgs::{ecu_flags, EcuTelemetry};

fn clock() -> u64 {
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_nanos() as u64
}

fn link(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("jetbench-io-test-{}", std::process::id())).join(name)
}

/// Collects the poller's samples until `until` holds for the samples so far.
fn collect(poller: &EcuPoller, what: &str, until: impl Fn(&[EcuTelemetry]) -> bool) -> Vec<EcuTelemetry> {
    let started = Instant::now();
    let mut samples = Vec::new();
    while !until(&samples) {
        assert!(started.elapsed() < Duration::from_secs(30), "watchdog: {what} never happened");
        samples.extend(poller.try_iter());
        std::thread::sleep(Duration::from_millis(5));
    }
    samples
}

#[test]
fn ecu_telemetry_arrives_at_the_poll_rate_and_survives_noise_and_silence() {
    let reading = EcuReading { rpm: 61_250.0, egt_c: 612.5, pump_v: 3.05, state: 10, throttle_pct: 42.0 };
    let ecu = PtyEcu::spawn(&link("ecu"), reading).expect("emulated ECU on a pty");
    let poller = EcuPoller::spawn(ecu.link(), 9600, 20.0, clock).expect("poller thread");

    // 40 fresh samples at 20 Hz, each the reading the ECU holds.
    let first = collect(&poller, "40 samples", |s| s.iter().filter(|t| t.flags == 0).count() >= 40);
    let fresh: Vec<&EcuTelemetry> = first.iter().filter(|t| t.flags == 0).collect();
    assert!(fresh
        .iter()
        .all(|t| (t.rpm, t.egt_c, t.pump_v, t.state, t.throttle_pct) == (61_250.0, 612.5, 3.05, 10, 42.0)));
    let span_s = (fresh[fresh.len() - 1].stamp_ns - fresh[0].stamp_ns) as f64 * 1e-9;
    let rate_hz = (fresh.len() - 1) as f64 / span_s;
    println!("{} fresh samples at {rate_hz:.1} Hz", fresh.len());
    assert!((rate_hz - 20.0).abs() < 2.0, "polled at {rate_hz:.1} Hz, configured 20");

    // Garbage lines between replies are counted and skipped.
    for junk in [&b"1,HS,OK,12,x\r"[..], b"\x00\xff\xa5garbage\r", b"1,HS,OK,1,2,3,4,500\r", b"1,HS,OK,1,2\r"] {
        ecu.inject_to_pc(junk).unwrap();
        collect(&poller, "a sample after noise", |s| !s.is_empty());
    }
    let counters = poller.shared().counters;
    println!("{counters:?}");
    assert!(counters.garbled >= 1 && counters.out_of_range >= 1 && counters.truncated >= 2, "{counters:?}");

    // Silent: flagged stale at once, silent from the third unanswered poll.
    ecu.set_silent(true);
    let quiet = collect(&poller, "silence", |s| s.iter().any(|t| t.flags & ecu_flags::SILENT != 0));
    let first_stale = quiet.iter().position(|t| t.flags & ecu_flags::STALE != 0).unwrap();
    let first_silent = quiet.iter().position(|t| t.flags & ecu_flags::SILENT != 0).unwrap();
    assert_eq!(first_silent - first_stale, 2, "silent on the third unanswered poll");
    assert!(quiet[first_stale..].iter().all(|t| t.rpm == 61_250.0), "stale samples hold the last values");

    // Back: reopened, fresh values.
    ecu.set_reading(EcuModel::settled(40.0, 60.0).reading());
    ecu.set_silent(false);
    let back = collect(&poller, "recovery", |s| s.iter().any(|t| t.flags == 0));
    let t = back.iter().find(|t| t.flags == 0).unwrap();
    assert_eq!(t.rpm, (35_000.0 + 8_000.0 * 40f64.sqrt()).round());
    assert!(poller.shared().opens >= 2, "the port was reopened");
}

#[test]
fn a_reply_that_comes_after_its_window_is_dropped_not_taken_for_the_next_poll() {
    // Polls every 2 s: the window closes 1.8 s after each poll, leaving 200 ms in
    // which a late reply can land before the next poll (a wide margin for a busy
    // machine to inject it there).
    let reading = EcuReading { rpm: 61_250.0, egt_c: 612.5, pump_v: 3.05, state: 10, throttle_pct: 42.0 };
    let ecu = PtyEcu::spawn(&link("ecu-late"), reading).expect("emulated ECU on a pty");
    let poller = EcuPoller::spawn(ecu.link(), 9600, 0.5, clock).expect("poller thread");
    collect(&poller, "a fresh sample", |s| s.iter().any(|t| t.flags == 0));
    // The ECU misses a poll; its reply comes once the window has closed.
    ecu.set_silent(true);
    collect(&poller, "a stale sample", |s| s.iter().any(|t| t.flags & ecu_flags::STALE != 0));
    let late = EcuReading { rpm: 99_000.0, egt_c: 777.0, pump_v: 9.99, state: 10, throttle_pct: 99.0 };
    ecu.inject_to_pc(jetbench_io::ecu::encode_reply(&late).as_bytes()).unwrap();
    ecu.set_silent(false);
    // The next poll's reading is the ECU's, not the late reply.
    let next = collect(&poller, "the next fresh sample", |s| s.iter().any(|t| t.flags == 0));
    let t = next.iter().find(|t| t.flags == 0).unwrap();
    assert_eq!((t.rpm, t.egt_c), (61_250.0, 612.5), "the late reply was taken for a fresh reading: {t:?}");
    assert_eq!(poller.shared().late_replies, 1, "{:?}", poller.shared());
}
