//! `jetbench latency` end to end: the service set over iceoryx2, the same set
//! over Unix sockets and the eventfd floor run for real under a CPU load, and
//! the report adds up.
//!
//! These tests assert what the run measured (cycles, completeness, losses,
//! the JSON contract), never how fast: the latency figures themselves are in
//! docs/latency/REPORT.md, measured by the command under the acceptance load.

mod common;

use std::process::Stdio;
use std::time::Duration;

use common::{jetbench, scratch, wait_with_watchdog};
use serde_json::Value;

const SUITE: &str = "latency";

fn run_latency(args: &[&str]) -> (std::process::ExitStatus, String, String) {
    let mut child = jetbench(SUITE)
        .arg("latency")
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start jetbench latency");
    let stdout = child.stdout.take().expect("stdout");
    let stderr = child.stderr.take().expect("stderr");
    let out = std::thread::spawn(move || std::io::read_to_string(stdout).unwrap_or_default());
    let err = std::thread::spawn(move || std::io::read_to_string(stderr).unwrap_or_default());
    let status = wait_with_watchdog(&mut child, Duration::from_secs(240), "jetbench latency");
    (status, out.join().expect("stdout reader"), err.join().expect("stderr reader"))
}

fn percentiles_ok(report: &Value, key: &str) {
    let p = &report[key];
    let values: Vec<f64> = ["p50", "p90", "p99", "p999", "max"]
        .iter()
        .map(|q| p[q].as_f64().unwrap_or_else(|| panic!("{key}.{q} missing in {p}")))
        .collect();
    assert!(values[0] > 0.0, "{key}: p50 must be a measured latency: {p}");
    assert!(values.windows(2).all(|w| w[0] <= w[1]), "{key}: percentiles must not decrease: {p}");
}

#[test]
fn latency_under_cpu_load_with_rt_measures_every_cycle() {
    let plot = scratch(SUITE, "latency.png");
    let seconds = 4.0;
    let (status, stdout, stderr) = run_latency(&[
        "--duration",
        &seconds.to_string(),
        "--warmup",
        "1",
        "--load",
        "cpu",
        "--rt",
        "--json",
        "--plot",
        plot.to_str().expect("utf-8 path"),
    ]);
    assert!(status.success(), "jetbench latency failed: {stderr}");
    let report: Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {stdout}"));
    for key in ["e2e_us", "floor_us", "uds_us", "period_jitter_us"] {
        percentiles_ok(&report, key);
    }
    for hop in ["sensing", "estimation", "control", "actuation"] {
        percentiles_ok(&report["hops_us"], hop);
        percentiles_ok(&report["uds"]["hops_us"], hop);
    }
    assert_eq!(report["rounds"].as_u64(), Some(2), "the default splits the run in two rounds");
    // 100 Hz for `seconds` after the warm-up: every cycle is judged, and every
    // judged cycle but those of the last half second reached the board.
    let cycles = report["cycles"].as_u64().expect("cycles");
    let expected = (seconds * 100.0) as u64;
    assert!(cycles.abs_diff(expected) <= expected / 10, "{cycles} cycles judged, expected about {expected}");
    let completed = report["completed"].as_u64().expect("completed");
    let unfinished = report["unfinished"].as_u64().expect("unfinished");
    assert!(completed + unfinished <= cycles && completed + 60 >= cycles, "{completed} of {cycles} completed");
    // The e2e distribution is exactly the completed cycles.
    assert_eq!(report["e2e_us"]["count"].as_u64(), Some(completed));
    // The copying baseline ran the same service set for as long.
    let uds = &report["uds"];
    let uds_cycles = uds["cycles"].as_u64().expect("uds.cycles");
    assert!(uds_cycles.abs_diff(expected) <= expected / 10, "{uds_cycles} baseline cycles, expected about {expected}");
    assert_eq!(report["uds_us"]["count"].as_u64(), uds["completed"].as_u64());
    assert_eq!(report["floor_lost"].as_u64(), Some(0), "the floor chain lost cycles: {report}");
    assert!(report["deadline_misses"].as_u64().is_some() && report["lost"].as_u64().is_some());
    assert!(report["load"].as_str().is_some_and(|l| l.contains("cpu")), "{}", report["load"]);
    // With real-time permission (root here) nothing is refused; without it the
    // refusals are named, and the run still completes.
    let refused = report["rt_refused"].as_array().expect("rt_refused");
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } == 0 {
        assert!(refused.is_empty(), "root was refused real-time settings: {refused:?}");
        assert_eq!(report["lost"].as_u64(), Some(0), "samples lost under --rt: {report}");
        assert_eq!(uds["lost"].as_u64(), Some(0), "samples lost over Unix sockets under --rt: {report}");
    } else {
        assert!(!refused.is_empty(), "a non-root run must say what it could not set");
    }
    for file in [plot.clone(), plot.with_extension("svg")] {
        let size = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
        assert!(size > 1000, "{} was not written", file.display());
    }
}

#[test]
fn bad_options_are_refused_with_the_reason() {
    let (status, _, stderr) = run_latency(&["--duration", "0"]);
    assert!(!status.success());
    assert!(stderr.contains("--duration"), "{stderr}");
    let (status, _, stderr) = run_latency(&["--load", "gpu"]);
    assert!(!status.success());
    assert!(stderr.contains("gpu"), "{stderr}");
    let (status, _, stderr) = run_latency(&["--duration", "3", "--rounds", "4"]);
    assert!(!status.success());
    assert!(stderr.contains("--rounds"), "{stderr}");
}
