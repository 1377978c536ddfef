//! `jetbench metrics` end to end: a recorded simulated run, a written recording with two
//! controllers and known errors, and bad input.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use jetbench_control::Controller;
use jetbench_msgs::{channels, command_flags, Command, Reference, SimTruth, StateEstimate, Thrust};
use jetbench_record::McapWriter;
use serde_json::Value;

mod common;

const SUITE: &str = "metrics";

fn scratch(name: &str) -> PathBuf {
    common::scratch(SUITE, name)
}

/// Runs `jetbench ARGS` under the watchdog: exit code, stdout, stderr.
fn jetbench(args: &[&str]) -> (i32, String, String) {
    common::run_jetbench(SUITE, args, Duration::from_secs(60))
}

/// `jetbench metrics ARGS --json`, which must succeed: its runs.
fn metrics_json(args: &[&str]) -> Vec<Value> {
    let (code, out, err) = jetbench(&[&["metrics", "--json"], args].concat());
    assert_eq!(code, 0, "jetbench metrics {args:?} failed:\n{err}");
    serde_json::from_str::<Value>(&out)
        .unwrap_or_else(|e| panic!("not JSON ({e}):\n{out}"))
        .as_array()
        .expect("an array of runs")
        .clone()
}

fn number(run: &Value, key: &str) -> f64 {
    run["metrics"][key].as_f64().unwrap_or_else(|| panic!("metrics.{key} is not a number: {}", run["metrics"][key]))
}

fn p(path: &Path) -> &str {
    path.to_str().expect("UTF-8 path")
}

#[test]
fn a_simulated_fbl_run_has_sane_tracking_figures() {
    let record = scratch("sim.mcap");
    let duration_s = 8.0;
    let mut child = common::jetbench(SUITE)
        .args(["up", "--sim", "--quiet", "--duration", &duration_s.to_string(), "--record", p(&record)])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start jetbench up");
    let stderr = common::lines_of(child.stderr.take().expect("stderr"));
    let status = common::wait_with_watchdog(&mut child, Duration::from_secs(120), "jetbench up");
    assert!(status.success(), "jetbench up failed:\n{}", stderr.try_iter().collect::<Vec<_>>().join("\n"));

    let runs = metrics_json(&[p(&record)]);
    assert_eq!(runs.len(), 1, "one controller, one run: {runs:?}");
    let run = &runs[0];
    assert_eq!(run["controller"], "fbl");
    assert_eq!(run["thrust_source"], "truth", "the simulated bench records the true thrust");
    // One sample per 10 ms control cycle, for about the run's duration (start-up and
    // shutdown make it a little shorter or longer).
    let (samples, run_s) = (number(run, "samples"), number(run, "duration_s"));
    assert!((0.8 * duration_s..=duration_s + 1.5).contains(&run_s), "a run of {run_s} s");
    assert!((samples / run_s - 100.0).abs() < 3.0, "{samples} samples in {run_s} s");
    let mae_n = number(run, "mae_n");
    assert!(mae_n.is_finite() && mae_n < 10.0, "MAE {mae_n} N");
    assert!((0.0..=100.0).contains(&number(run, "within_5pct")));
    // The default steps profile holds 20, 50 and 35 N in 8 s: steady-state errors on each.
    let holds = run["metrics"]["holds"].as_array().expect("holds");
    assert!(holds.len() >= 2, "holds: {holds:?}");
    for (i, hold) in holds.iter().enumerate() {
        let error_pct = hold["steady_state_error_pct"].as_f64().expect("a steady-state error per hold");
        // The first hold starts with the engine at idle; the others follow steps.
        assert!(i == 0 || error_pct.abs() < 10.0, "steady-state error {error_pct} % on {hold}");
    }
    assert!(!run["metrics"]["steps"].as_array().expect("steps").is_empty());
    assert!(number(run, "throttle_tv_pct_per_s").is_finite());

    // The estimate and the measured thrust work too; the measured one carries the sensor noise.
    let estimate = metrics_json(&[p(&record), "--thrust", "estimate"]);
    assert_eq!(estimate[0]["thrust_source"], "estimate");
    assert!(number(&estimate[0], "mae_n").is_finite());
    let measured = metrics_json(&[p(&record), "--thrust", "measured"]);
    assert!(number(&measured[0], "mae_n") > mae_n, "noise adds to the measured error");

    // The human report: the table and the per-hold lines.
    let (code, out, err) = jetbench(&["metrics", p(&record), "--skip", "1"]);
    assert_eq!(code, 0, "{err}");
    for wanted in
        ["thrust from sim/truth", "fbl", "MAE N", "within ±5 %", "SS error worst/mean %", "holds and the steps"]
    {
        assert!(out.contains(wanted), "{wanted:?} missing from:\n{out}");
    }
}

/// 100 Hz cycles from 1 s: `fbl` for 6 s, then `mpc` for 6 s. The reference holds 30 N
/// and steps to 60 N in the middle of each run; the true thrust is 0.5 N below it, the
/// measured 2 N below. Every 50th MPC cycle falls back to FBL; MPC solves take 1-100 µs.
fn write_two_controller_recording(path: &Path) {
    let mut writer = McapWriter::create(path).expect("create MCAP");
    for k in 0..1200u64 {
        let stamp_ns = 1_000_000_000 + k * 10_000_000;
        let (controller, run_k) = if k < 600 { (Controller::Fbl.code(), k) } else { (Controller::Mpc.code(), k - 600) };
        let reference_n = if run_k < 300 { 30.0 } else { 60.0 };
        let truth =
            SimTruth { seq: k, stamp_ns: stamp_ns - 300_000, thrust_n: reference_n - 0.5, ..SimTruth::default() };
        let thrust = Thrust { seq: k, stamp_ns, thrust_n: reference_n - 2.0, ..Thrust::default() };
        let state =
            StateEstimate { seq: k, stamp_ns, source_seq: k, thrust_n: reference_n - 1.0, ..StateEstimate::default() };
        let reference = Reference {
            seq: k,
            stamp_ns,
            source_seq: k,
            profile_time_s: run_k as f64 * 0.01,
            thrust_n: reference_n,
            ..Reference::default()
        };
        let mpc = controller == Controller::Mpc.code();
        let command = Command {
            seq: k,
            stamp_ns,
            source_seq: k,
            throttle_pct: 50.0,
            unclamped_pct: 50.0,
            flags: if mpc && run_k % 50 == 0 { command_flags::FALLBACK } else { 0 },
            controller,
            solve_us: if mpc { (run_k % 100 + 1) as u32 } else { 0 },
            ..Command::default()
        };
        writer.write_sample(channels::SIM_TRUTH, stamp_ns, &truth).unwrap();
        writer.write_sample(channels::THRUST, stamp_ns, &thrust).unwrap();
        writer.write_sample(channels::STATE, stamp_ns, &state).unwrap();
        writer.write_sample(channels::REFERENCE, stamp_ns, &reference).unwrap();
        writer.write_sample(channels::COMMAND, stamp_ns, &command).unwrap();
    }
    writer.finish().expect("finish MCAP");
}

#[test]
fn a_file_with_two_controllers_gives_one_run_each_with_known_figures() {
    let record = scratch("two-controllers.mcap");
    write_two_controller_recording(&record);
    let runs = metrics_json(&[p(&record)]);
    let controllers: Vec<&str> = runs.iter().map(|r| r["controller"].as_str().unwrap()).collect();
    assert_eq!(controllers, ["fbl", "mpc"]);
    for run in &runs {
        assert_eq!(number(run, "samples"), 600.0);
        assert!((number(run, "mae_n") - 0.5).abs() < 1e-12, "{run}");
        // Holds at 30 N and 60 N, 0.5 N below each: 1.667 % and 0.833 %.
        let holds = run["metrics"]["holds"].as_array().unwrap();
        assert_eq!(holds.len(), 2, "{holds:?}");
        assert!((holds[0]["steady_state_error_pct"].as_f64().unwrap() - 50.0 / 30.0).abs() < 1e-9);
        assert!((number(run, "worst_steady_state_error_pct") - 50.0 / 30.0).abs() < 1e-9);
        let steps = run["metrics"]["steps"].as_array().unwrap();
        assert_eq!(steps.len(), 1);
        assert_eq!((steps[0]["from_n"].as_f64(), steps[0]["to_n"].as_f64()), (Some(30.0), Some(60.0)));
    }
    assert!((runs[1]["start_s"].as_f64().unwrap() - 6.0).abs() < 1e-9, "times from the file's first cycle");
    assert_eq!(number(&runs[1], "fallbacks"), 12.0);
    let solve = &runs[1]["metrics"]["solve_us"];
    assert_eq!((solve["p50"].as_u64(), solve["p99"].as_u64(), solve["max"].as_u64()), (Some(50), Some(99), Some(100)));

    let measured = metrics_json(&[p(&record), "--thrust", "measured"]);
    assert!((number(&measured[0], "mae_n") - 2.0).abs() < 1e-12);
    let estimate = metrics_json(&[p(&record), "--thrust", "estimate"]);
    assert!((number(&estimate[1], "mae_n") - 1.0).abs() < 1e-12);

    let (code, out, err) = jetbench(&["metrics", p(&record)]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("solve µs p50/p99/max") && out.contains("50 / 99 / 100"), "MPC columns:\n{out}");
}

/// Runs `jetbench metrics ARGS`, which must fail: its stderr.
fn failure(args: &[&str]) -> String {
    let (code, out, err) = jetbench(&[&["metrics"], args].concat());
    assert_ne!(code, 0, "jetbench metrics {args:?} must fail; printed:\n{out}");
    assert!(!err.contains("panicked"), "a panic instead of an error:\n{err}");
    err
}

#[test]
fn bad_input_gives_a_clear_error() {
    let missing = scratch("no-such-file.mcap");
    let err = failure(&[p(&missing)]);
    assert!(err.contains("cannot read") && err.contains("no-such-file.mcap"), "{err}");
    assert_eq!(err.matches("No such file").count(), 1, "the cause once: {err}");

    let csv = scratch("run.csv");
    std::fs::write(&csv, "time_s,throttle_pct,thrust_n\n0,25,0\n").unwrap();
    let err = failure(&[p(&csv)]);
    assert!(err.contains("not an MCAP file"), "{err}");

    // A recording without the controller's channels: says what is missing and how to record it.
    let open_loop = scratch("thrust-only.mcap");
    let mut writer = McapWriter::create(&open_loop).unwrap();
    writer.write_sample(channels::THRUST, 1, &Thrust { stamp_ns: 1, thrust_n: 3.0, ..Thrust::default() }).unwrap();
    writer.finish().unwrap();
    let err = failure(&[p(&open_loop)]);
    for wanted in ["lacks /bench/reference and /bench/command", "jetbench up --sim"] {
        assert!(err.contains(wanted), "{wanted:?} missing from: {err}");
    }

    let empty = scratch("empty.mcap");
    McapWriter::create(&empty).unwrap().finish().unwrap();
    let err = failure(&[p(&empty)]);
    assert!(err.contains("holds no messages"), "{err}");

    // Asking for the true thrust of a recording without it.
    let no_truth = scratch("no-truth.mcap");
    let mut writer = McapWriter::create(&no_truth).unwrap();
    for k in 0..10u64 {
        let stamp_ns = k * 10_000_000;
        writer.write_sample(channels::REFERENCE, stamp_ns, &Reference { stamp_ns, ..Reference::default() }).unwrap();
        writer.write_sample(channels::COMMAND, stamp_ns, &Command { stamp_ns, ..Command::default() }).unwrap();
    }
    writer.finish().unwrap();
    let err = failure(&[p(&no_truth), "--thrust", "truth"]);
    assert!(err.contains("no sim/truth") && err.contains("--thrust measured"), "{err}");

    let err = failure(&[p(&no_truth), "--skip", "-1"]);
    assert!(err.contains("--skip"), "{err}");
}
