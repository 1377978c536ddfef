//! The force sensor in the running service set: `jetbench up --sim` reads it
//! as CAN frames over the userspace bus; unplugging the simulated sensor
//! mid-run is reported within 3 cycles and flagged, and the sensor resumes
//! without restarting anything. `jetbench tare` finds the simulated sensor's
//! zero offset at rest.
//!
//! Real processes; hangs are caught by a watchdog; no runtime is asserted.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use jetbench_msgs::{channels, health_flags, thrust_flags, ServiceId};
use jetbench_record::{seq_gaps, Recording};

mod common;

const SUITE: &str = "cansensor";

fn jetbench() -> Command {
    common::jetbench(SUITE)
}

/// The sim folder of this suite's bus namespace (where sim-bench looks for the unplug marker).
fn unplug_marker() -> PathBuf {
    std::env::temp_dir().join(format!("jetbench-sim-{SUITE}{}", std::process::id())).join("sensor-unplugged")
}

/// One test at a time: each has the machine's cores to itself.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn an_unplugged_sensor_is_reported_and_resumes_without_a_restart() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let out = common::scratch(SUITE, "unplug.mcap");
    let (mut child, stdout, stderr) = common::spawn_up(jetbench(), 8, &out);
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Ok(line) = stdout.recv_timeout(Duration::from_secs(1)) {
            if line.starts_with("all ") && line.contains("services ready") {
                break;
            }
        }
        assert!(Instant::now() < deadline, "the service set never became ready");
    }
    std::thread::sleep(Duration::from_secs(2));
    let marker = unplug_marker();
    std::fs::create_dir_all(marker.parent().expect("a folder")).expect("the sim folder");
    std::fs::write(&marker, b"").expect("unplug the simulated sensor");
    std::thread::sleep(Duration::from_millis(600));
    std::fs::remove_file(&marker).expect("plug it back in");
    let status = common::wait_with_watchdog(&mut child, Duration::from_secs(90), "jetbench up");
    let log: Vec<String> = stdout.try_iter().chain(stderr.try_iter()).collect();
    let log = log.join("\n");
    assert!(status.success(), "the set must survive a silent sensor: {status}\n{log}");
    assert!(log.contains("force sensor silent"), "sensing reports the silence\n{log}");
    assert!(log.contains("force sensor back after"), "sensing reports the return\n{log}");

    let recording = Recording::open(&out).expect("read the recording");
    let thrust = recording.samples(channels::THRUST);
    assert_eq!(seq_gaps(&thrust), 0);
    // The unplugged stretch is the longest gap; scheduling on a busy machine
    // may add short ones, but nothing else near it.
    let i = (1..thrust.len()).max_by_key(|&i| thrust[i].stamp_ns - thrust[i - 1].stamp_ns).expect("samples");
    let others_ms = (1..thrust.len())
        .filter(|&j| j != i)
        .map(|j| (thrust[j].stamp_ns - thrust[j - 1].stamp_ns) as f64 * 1e-6)
        .fold(0.0, f64::max);
    assert!(others_ms < 200.0, "another silence of {others_ms:.0} ms");
    let (before, after) = (&thrust[i - 1], &thrust[i]);
    let silence_ms = (after.stamp_ns - before.stamp_ns) as f64 * 1e-6;
    let lost = after.frame_seq - before.frame_seq - 1;
    println!("silence {silence_ms:.0} ms, {lost} frames lost by the counter");
    assert!(silence_ms > 400.0, "the sensor was unplugged for 600 ms: {silence_ms:.0} ms");
    assert_eq!(after.flags & thrust_flags::SENSOR_RESUMED, thrust_flags::SENSOR_RESUMED, "flagged on return");
    assert_ne!(after.flags & thrust_flags::FRAME_GAP, 0);
    assert!((lost as f64 - silence_ms / 10.0).abs() <= 3.0, "frame_seq counts the lost frames: {lost}");
    // Only samples after a silence (a missed 15 ms deadline) carry the flag;
    // on a busy machine a short scheduling stall can make one more.
    for j in (1..thrust.len()).filter(|&j| thrust[j].flags & thrust_flags::SENSOR_RESUMED != 0) {
        let waited_ms = (thrust[j].stamp_ns - thrust[j - 1].stamp_ns) as f64 * 1e-6;
        assert!(waited_ms > 15.0, "sample {j} flagged after only {waited_ms:.1} ms");
    }
    assert!(thrust.len() - i > 100, "readings continue after the return: {}", thrust.len() - i);

    // Sensing's health says "input overdue" within 3 cycles of the last reading, and all along the silence.
    let sensing: Vec<_> =
        recording.samples(channels::HEALTH).into_iter().filter(|h| h.service_id == ServiceId::Sensing as u32).collect();
    let overdue: Vec<_> = sensing
        .iter()
        .filter(|h| {
            h.stamp_ns > before.stamp_ns && h.stamp_ns < after.stamp_ns && h.flags & health_flags::INPUT_OVERDUE != 0
        })
        .collect();
    assert!(!overdue.is_empty(), "no overdue heartbeat during the silence");
    let reported_ms = (overdue[0].stamp_ns - before.stamp_ns) as f64 * 1e-6;
    println!("silence reported {reported_ms:.1} ms after the last reading; {} overdue heartbeats", overdue.len());
    assert!(reported_ms <= 30.0, "reported after {reported_ms:.1} ms, not within 3 cycles");
    // One heartbeat per 15 ms deadline, give or take scheduling on a busy machine.
    assert!(overdue.len() as f64 >= silence_ms / 30.0, "reported all along the silence: {}", overdue.len());
    // And it clears once the sensor is back.
    let back = sensing.iter().find(|h| h.stamp_ns > after.stamp_ns).expect("heartbeats after the return");
    assert_eq!(back.flags & health_flags::INPUT_OVERDUE, 0);
}

/// A copy of config/sim.toml with the simulated sensor's zero offset set.
fn config_with_zero(name: &str, zero: &str) -> PathBuf {
    let text = std::fs::read_to_string(common::repo_root().join("config/sim.toml")).expect("config/sim.toml");
    let text =
        text.replace("initial_throttle_pct = 25.0\n", &format!("initial_throttle_pct = 25.0\nsensor_zero = {zero}\n"));
    let path = common::scratch(SUITE, name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn tare_finds_the_simulated_zero_offset_and_writes_it() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let config = config_with_zero("tare.toml", "[1.5, -0.4, 0.2, 0.01, 0.0, -0.02]");
    let (status, out, err) = common::run(
        jetbench().args(["tare", "--seconds", "2", "--write", "--config"]).arg(&config),
        Duration::from_secs(60),
        "jetbench tare",
    );
    assert!(status.success(), "tare failed:\n{err}");
    assert!(err.contains("engine off, zero load"), "tare says what rest means:\n{err}");
    let line = out.lines().find(|l| l.starts_with("tare = [")).expect("a tare line on stdout");
    let values: Vec<f64> = line
        .trim_start_matches("tare = [")
        .trim_end_matches(']')
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect();
    let want = [1.5, -0.4, 0.2, 0.01, 0.0, -0.02];
    // Thrust axis: noise sd sqrt(7) = 2.6 N over ~200 readings -> sd of the mean 0.19 N; others 0.3 N -> 0.02 N.
    let tolerance = [0.8, 0.1, 0.1, 0.002, 0.002, 0.002];
    println!("{line}");
    for i in 0..6 {
        assert!((values[i] - want[i]).abs() <= tolerance[i], "axis {i}: {} vs {}", values[i], want[i]);
    }
    let written = std::fs::read_to_string(&config).unwrap();
    assert!(written.contains(line), "--write puts the line into [sensor]:\n{written}");
    assert_eq!(written.matches("\ntare = ").count(), 1);
    // The written config loads (can-decode reads it).
    let (status, _, err) = common::run(
        jetbench().args(["can-decode", "/dev/null", "--config"]).arg(&config),
        Duration::from_secs(30),
        "can-decode with the tared config",
    );
    assert!(status.success(), "{err}");
}

/// At the bench, a sensor whose CAN interface cannot be opened is said with
/// advice for a bench (the modules, the adapter, `ip link set ... up type can
/// bitrate ...`), not for the simulated bus: `jetbench tare` (the first
/// command of a bench run) with config/bench.example.toml naming an
/// interface that does not exist.
#[test]
fn a_missing_can_interface_at_the_bench_is_said_with_advice_for_the_bench() {
    let example = std::fs::read_to_string(common::repo_root().join("config/bench.example.toml")).unwrap();
    assert!(example.contains("can_interface = \"can0\""), "the example names can0");
    let config = common::scratch(SUITE, "bench-missing-can.toml");
    std::fs::write(&config, example.replace("can_interface = \"can0\"", "can_interface = \"jbcan7\"")).unwrap();
    let (code, out, err) = common::run_jetbench(
        SUITE,
        &["tare", "--config", config.to_str().unwrap(), "--seconds", "0.5"],
        Duration::from_secs(60),
    );
    let said = format!("{out}\n{err}");
    println!("{said}");
    assert_ne!(code, 0, "a sensor that cannot be opened is an error");
    assert!(said.contains("jbcan7"), "names the interface");
    assert!(said.contains("sudo ip link set jbcan7 up type can bitrate"), "says how to bring it up");
    match jetbench_io::can::socketcan::probe_af_can() {
        // This kernel: no CAN at all; the advice is the modules and the adapter.
        Err(_) => assert!(said.contains("modprobe can can_raw") && said.contains("adapter"), "the modules"),
        // A kernel with CAN: the interface is missing.
        Ok(()) => assert!(said.contains("No interface `jbcan7`") && said.contains("ip -br link"), "the interface"),
    }
}
