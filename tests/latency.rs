//! `jetbench latency` end to end: the service set over iceoryx2, the same set
//! over Unix sockets and the eventfd floor run for real under a CPU load, and
//! the report adds up.
//!
//! These tests assert what the run measured (cycles, completeness, losses,
//! the JSON contract), never how fast: the latency figures themselves are in
//! docs/latency/REPORT.md, measured by the command under the acceptance load.

mod common;

use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::Duration;

use common::{jetbench, scratch, wait_with_watchdog};
use serde_json::Value;

const SUITE: &str = "latency";

/// One measurement at a time: they measure the machine, and two service sets
/// would share it.
static MACHINE: Mutex<()> = Mutex::new(());

/// `jetbench` in a bus namespace of the test's own (`tag`), so that no two
/// runs meet even if they overlap.
fn jetbench_in(tag: &str) -> Command {
    let mut command = jetbench(SUITE);
    command.env(jetbench_bus::NAMESPACE_ENV, format!("{SUITE}{}{tag}", std::process::id()));
    command
}

fn run_latency(tag: &str, args: &[&str]) -> (std::process::ExitStatus, String, String) {
    let mut command = jetbench_in(tag);
    command.arg("latency").args(args);
    run(command)
}

fn run(mut command: Command) -> (std::process::ExitStatus, String, String) {
    let _machine = MACHINE.lock().unwrap_or_else(|e| e.into_inner());
    let mut child = command
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
    let (status, stdout, stderr) = run_latency(
        "load",
        &[
            "--duration",
            &seconds.to_string(),
            "--warmup",
            "1",
            "--load",
            "cpu",
            "--rt",
            "--json",
            "--control-room",
            "--plot",
            plot.to_str().expect("utf-8 path"),
        ],
    );
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
    // A run's duration counts from the engine running: each of the two rounds also
    // judges the cycles while the set waited for the emulated ECU's first report of
    // run (actuation polls it at 15 Hz on the simulated bench): up to half a second each.
    let waited = 2 * 50;
    assert!(
        cycles + expected / 10 >= expected && cycles <= expected + expected / 10 + waited,
        "{cycles} cycles judged, expected about {expected} (plus up to {waited} while waiting for run)"
    );
    let completed = report["completed"].as_u64().expect("completed");
    let unfinished = report["unfinished"].as_u64().expect("unfinished");
    assert!(completed + unfinished <= cycles && completed + 60 >= cycles, "{completed} of {cycles} completed");
    // The e2e distribution is exactly the completed cycles.
    assert_eq!(report["e2e_us"]["count"].as_u64(), Some(completed));
    // The copying baseline ran the same service set for as long.
    let uds = &report["uds"];
    let uds_cycles = uds["cycles"].as_u64().expect("uds.cycles");
    // It too judges the cycles while it waited for the ECU's first report of run.
    assert!(
        uds_cycles + expected / 10 >= expected && uds_cycles <= expected + expected / 10 + waited,
        "{uds_cycles} baseline cycles, expected about {expected} (plus up to {waited} while waiting for run)"
    );
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
    // The same set watched from the control room: as many cycles, every client served.
    let room = &report["control_room"];
    percentiles_ok(room, "e2e_us");
    let room_cycles = room["cycles"].as_u64().expect("control_room.cycles");
    assert!(
        room_cycles + expected / 10 >= expected && room_cycles <= expected + expected / 10 + waited,
        "{room_cycles} cycles watched, expected about {expected} (plus up to {waited} while waiting for run)"
    );
    for clients in room["clients"].as_array().expect("control_room.clients") {
        assert_eq!(clients["errors"], serde_json::json!([]), "control-room clients: {clients}");
        assert!(clients["foxglove_stalled"].as_bool() == Some(true), "the stalled client connected: {clients}");
        assert!(clients["foxglove_read"].as_u64().is_some_and(|n| n > 100), "the reading client read: {clients}");
        assert!(
            clients["foxglove_dropped_after"].as_u64().is_some_and(|n| n > 0),
            "the dropping client read first: {clients}"
        );
        assert!(
            clients["zenoh_received"].as_u64().is_some_and(|n| n > 100),
            "the Zenoh subscriber got samples: {clients}"
        );
        assert_eq!(clients["zenoh_gaps"].as_u64(), Some(0), "the Zenoh subscriber lost samples: {clients}");
        // The operator commanded the bench through the TLS gateway, and the bench recorded it.
        let commands = &clients["commands"];
        let count = |key: &str| commands[key].as_u64().unwrap_or_else(|| panic!("commands.{key} missing: {commands}"));
        assert_eq!(commands["took_control"].as_bool(), Some(true), "the operator took control: {commands}");
        assert!(count("accepted") > 0, "heartbeats were accepted: {commands}");
        assert_eq!(count("unanswered"), 0, "commands went unanswered while the set ran: {commands}");
        assert_eq!(
            count("sent"),
            count("accepted") + count("refused") + count("unanswered") + count("unanswered_at_end"),
            "every heartbeat sent is accounted for: {commands}"
        );
        // A refusal can only come from a lapsed link, after the deadman idled the engine.
        assert!(count("refused") == 0 || count("deadman_events") > 0, "refused without a lapse: {commands}");
        // The take and every accepted heartbeat are in the recording, with their decision.
        assert!(count("recorded") > count("accepted"), "commands recorded on bench/operator: {commands}");
        assert!(count("recorded_accepted") > count("accepted"), "acceptances recorded: {commands}");
        let (p50, p99) = (commands["answer_ms_p50"].as_f64().unwrap(), commands["answer_ms_p99"].as_f64().unwrap());
        assert!(p50 > 0.0 && p50 <= p99, "answer times: {commands}");
    }
    // Both halves, from the same rounds: with the control room and without it.
    assert_eq!(room["e2e_p99_us_without"].as_f64(), report["e2e_us"]["p99"].as_f64(), "{room}");
    assert_eq!(room["deadline_misses_without"].as_u64(), report["deadline_misses"].as_u64(), "{room}");
    let ratio = room["e2e_p99_ratio"].as_f64().expect("e2e_p99_ratio");
    let expected_ratio = room["e2e_us"]["p99"].as_f64().unwrap() / report["e2e_us"]["p99"].as_f64().unwrap();
    assert!((ratio - expected_ratio).abs() < 1e-9, "p99 ratio {ratio}, from the figures {expected_ratio}");
    assert!(room["deadline_misses"].as_u64().is_some(), "{room}");
    // And the same rounds with the control room only watching: the commands' cost alone.
    percentiles_ok(room, "watching_e2e_us");
    assert!(room["watching_deadline_misses"].as_u64().is_some(), "{room}");
    let commands_ratio = room["commands_e2e_p99_ratio"].as_f64().expect("commands_e2e_p99_ratio");
    let expected_ratio = room["e2e_us"]["p99"].as_f64().unwrap() / room["watching_e2e_us"]["p99"].as_f64().unwrap();
    assert!(
        (commands_ratio - expected_ratio).abs() < 1e-9,
        "commands' p99 ratio {commands_ratio}, from the figures {expected_ratio}"
    );
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } == 0 {
        assert_eq!(room["lost"].as_u64(), Some(0), "samples lost with the control room attached: {room}");
    }
    for file in [plot.clone(), plot.with_extension("svg")] {
        let size = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
        assert!(size > 1000, "{} was not written", file.display());
    }
}

#[test]
fn bad_options_are_refused_with_the_reason() {
    let (status, _, stderr) = run_latency("bad", &["--duration", "0"]);
    assert!(!status.success());
    assert!(stderr.contains("--duration"), "{stderr}");
    let (status, _, stderr) = run_latency("bad", &["--load", "gpu"]);
    assert!(!status.success());
    assert!(stderr.contains("gpu"), "{stderr}");
    let (status, _, stderr) = run_latency("bad", &["--duration", "3", "--rounds", "4"]);
    assert!(!status.success());
    assert!(stderr.contains("--rounds"), "{stderr}");
}

/// Without real-time permission `--rt` runs on and names what the kernel
/// refused. As root the permission is taken away for real: `setpriv` drops
/// CAP_SYS_NICE and CAP_IPC_LOCK from jetbench and everything it starts, which
/// leaves them the rtprio and memlock limits of an ordinary user.
#[test]
fn without_real_time_permission_the_run_goes_on_and_names_the_refusals() {
    let reference = jetbench_in("nort");
    let exe = reference.get_program().to_owned();
    // SAFETY: geteuid has no preconditions.
    let mut command = if unsafe { libc::geteuid() } == 0 {
        let mut c = Command::new("setpriv");
        c.args(["--bounding-set", "-sys_nice,-ipc_lock", "--inh-caps", "-sys_nice,-ipc_lock", "--"]).arg(&exe);
        c
    } else {
        Command::new(&exe)
    };
    for (key, value) in reference.get_envs() {
        if let Some(value) = value {
            command.env(key, value);
        }
    }
    command.args(["latency", "--duration", "2", "--rounds", "1", "--warmup", "1", "--load", "none", "--rt", "--json"]);
    let (status, stdout, stderr) = run(command);
    assert!(status.success(), "without real-time permission the run must go on: {stderr}");
    let report: Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {stdout}"));
    let refused: Vec<&str> =
        report["rt_refused"].as_array().expect("rt_refused").iter().filter_map(Value::as_str).collect();
    assert!(refused.iter().any(|r| r.contains("SCHED_FIFO")), "the priority refusal is named: {refused:?}");
    assert!(refused.iter().any(|r| r.contains("lock memory")), "the memory-lock refusal is named: {refused:?}");
    assert!(stderr.contains("warning:") && stderr.contains("SCHED_FIFO"), "and said while running: {stderr}");
    assert!(report["completed"].as_u64().is_some_and(|n| n > 0), "the service set still ran: {report}");
    assert!(report["uds"]["completed"].as_u64().is_some_and(|n| n > 0), "the baseline still ran: {report}");
    assert!(report["floor_us"]["count"].as_u64().is_some_and(|n| n > 0), "the floor still ran: {report}");
}
