//! The Zenoh bridge, seen from another machine: an independent Python
//! subscriber (PyPI eclipse-zenoh, set up by scripts/pyenv.sh) in its own
//! network namespace, joined to the bench's by a veth pair as two hosts
//! would be (loopback where this machine cannot make namespaces, said so);
//! and `jetbench echo`, `hz` and `record` with `--remote`, run against a live
//! `jetbench up --zenoh` as a user in the control room would. Hangs are caught by watchdogs; no test asserts a runtime.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Duration;

use jetbench_msgs::channels;
use jetbench_record::clock::LogClock;
use jetbench_record::Recording;
use serde_json::Value;

mod clients;
mod common;

use clients::{free_port, in_netns, Process, TwoHosts};
use common::scratch;

/// One run at a time: each has the machine's cores to itself.
static RUN: Mutex<()> = Mutex::new(());

/// `jetbench up --sim --record RECORD --zenoh ENDPOINT` for `duration_s`, in
/// network namespace `netns` (the bench's host), started and ready.
fn up_with_bridge(
    suite: &str,
    netns: Option<&str>,
    endpoint: &str,
    duration_s: u32,
    record: &std::path::Path,
) -> Process {
    let mut command = in_netns(netns, std::path::Path::new(env!("CARGO_BIN_EXE_jetbench")));
    command
        .env(jetbench_bus::NAMESPACE_ENV, clients::namespace(suite))
        .args(["up", "--sim", "--quiet", "--duration", &duration_s.to_string(), "--zenoh", endpoint, "--record"])
        .arg(record);
    Process::start(command, "services ready", "jetbench up --zenoh")
}

#[test]
fn a_python_subscriber_on_another_host_receives_every_channel_as_recorded() {
    let _run = RUN.lock().unwrap_or_else(|e| e.into_inner());
    const SUITE: &str = "zpy";
    let hosts = TwoHosts::create();
    let (bench_ns, control_ns, bench_ip) = match &hosts {
        Ok(h) => {
            eprintln!("bridge in network namespace {}, subscriber in {} (veth pair)", h.bench, h.control_room);
            (Some(h.bench.as_str()), Some(h.control_room.as_str()), h.bench_ip.clone())
        }
        Err(why) => {
            eprintln!("NOTE: no network namespaces here ({why}); bridge and subscriber meet on loopback");
            (None, None, "127.0.0.1".to_string())
        }
    };
    let endpoint = format!("tcp/{bench_ip}:{}", free_port());
    let record = scratch(SUITE, "bridged.mcap");
    // The acceptance command: the bridge is a service of the set.
    let up = up_with_bridge(SUITE, bench_ns, &endpoint, 10, &record);
    let got_path = scratch(SUITE, "python-subscriber.json");
    let subscriber = clients::zenoh_subscriber(control_ns, &endpoint, SUITE, &got_path, &record);
    let (up_ok, up_log) = up.wait(Duration::from_secs(100));
    assert!(up_ok, "jetbench up --zenoh failed:\n{up_log}");
    let (subscriber_ok, subscriber_log) = subscriber.stop();
    drop(hosts);
    assert!(subscriber_ok, "the Python subscriber failed:\n{subscriber_log}");

    let recording = Recording::open(&record).expect("read the run's recording");
    let text = std::fs::read_to_string(&got_path).expect("the subscriber wrote its JSON");
    let got: Value = serde_json::from_str(&text).expect("JSON");
    assert_eq!(got["errors"], serde_json::json!([]), "payloads that did not decode");
    let failures = clients::compare_every_channel(&recording, &got);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn remote_echo_hz_and_record_read_a_live_bench_over_zenoh() {
    let _run = RUN.lock().unwrap_or_else(|e| e.into_inner());
    const SUITE: &str = "zrem";
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let record = scratch(SUITE, "local.mcap");
    let up = up_with_bridge(SUITE, None, &endpoint, 12, &record);
    let remote = |args: &[&str]| {
        common::run_jetbench(SUITE, &[args, &["--remote", &endpoint]].concat(), Duration::from_secs(60))
    };
    // The acceptance commands, as a user in the control room types them.
    let (echo_code, echo, echo_err) = remote(&["echo", "bench/thrust", "-n", "10"]);
    let remote_path: PathBuf = scratch(SUITE, "remote.mcap");
    let (record_code, _, record_err) =
        remote(&["record", "--duration", "5", "--out", remote_path.to_str().expect("UTF-8")]);
    let (hz_code, hz, hz_err) = remote(&["hz", "bench/state", "--duration", "2.5"]);
    let (up_ok, up_log) = up.wait(Duration::from_secs(100));
    assert!(up_ok, "jetbench up --zenoh failed:\n{up_log}");
    assert_eq!(echo_code, 0, "jetbench echo --remote failed:\n{echo_err}");
    assert_eq!(record_code, 0, "jetbench record --remote failed:\n{record_err}");
    assert_eq!(hz_code, 0, "jetbench hz --remote failed:\n{hz_err}");

    let local = Recording::open(&record).expect("read the local recording");
    let local_thrust = local.samples(channels::THRUST);
    // Ten samples, each printed as the recording has it.
    let echoed: Vec<&str> = echo.lines().filter(|l| l.starts_with("seq=")).collect();
    assert_eq!(echoed.len(), 10, "{echo}");
    for line in echoed {
        let seq: usize = line["seq=".len()..].split(',').next().and_then(|s| s.parse().ok()).expect("seq");
        assert_eq!(
            line,
            jetbench_msgs::format_fields(&local_thrust[seq]),
            "echoed seq {seq} differs from the recording"
        );
    }
    // The rate over Zenoh, with nothing lost.
    let rates: Vec<f64> =
        hz.lines().filter_map(|l| l.strip_prefix("bench/state: ")?.split(' ').next()?.parse().ok()).collect();
    assert!(!rates.is_empty() && rates.iter().all(|r| (95.0..105.0).contains(r)), "{hz}");
    assert!(hz.lines().all(|l| !l.starts_with("bench/state") || l.ends_with("lost 0")), "{hz}");

    // A normal jetbench MCAP, dated by the wall clock, its samples the bench's.
    let remote = Recording::open(&remote_path).expect("read the remote recording");
    assert!(!remote.truncated);
    assert_eq!(remote.time_base().log_clock, LogClock::Realtime, "a remote recording is dated by the wall clock");
    let remote_thrust = remote.samples(channels::THRUST);
    assert!(remote_thrust.len() >= 400, "{} thrust samples in 5 s", remote_thrust.len());
    for s in &remote_thrust {
        assert_eq!(Some(s), local_thrust.get(s.seq as usize), "remote seq {} differs from the local recording", s.seq);
    }
    for c in remote.summary() {
        assert_eq!(c.seq_gaps, 0, "{} lost samples over Zenoh", c.topic);
    }
}
