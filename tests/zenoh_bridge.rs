//! The Zenoh bridge, seen from another machine: an independent Python
//! subscriber (PyPI eclipse-zenoh, set up by scripts/pyenv.sh) in its own
//! network namespace, joined to the bench's by a veth pair as two hosts
//! would be (loopback where this machine cannot make namespaces, said so);
//! and the remote side of the bridge crate, which `echo`, `hz` and `record`
//! use with `--remote`. Hangs are caught by watchdogs; no test asserts a runtime.

use std::path::PathBuf;
use std::process::Command;
use std::sync::Mutex;
use std::time::Duration;

use jetbench_bridge::{record_remote, Endpoint, RemoteBench};
use jetbench_msgs::{channels, visit_channels, Channel, ChannelVisitor, Sample};
use jetbench_record::clock::LogClock;
use jetbench_record::Recording;
use serde_json::Value;

mod clients;
mod common;

use clients::{compare_with_recording, free_port, in_netns, Process, TwoHosts};
use common::{python, repo_root, scratch, spawn_up, wait_with_watchdog};

/// One run at a time: each has the machine's cores to itself.
static RUN: Mutex<()> = Mutex::new(());

fn bridge(suite: &str, netns: Option<&str>, endpoint: &str) -> Process {
    let mut command = in_netns(netns, std::path::Path::new(env!("CARGO_BIN_EXE_jetbench-bridge")));
    command.env(jetbench_bus::NAMESPACE_ENV, clients::namespace(suite)).args(["--listen", endpoint]);
    Process::start(command, "ready", "jetbench-bridge")
}

/// Every channel: at least 95 % of the recorded samples decoded, each equal to the recording.
struct CompareAll<'a> {
    recording: &'a Recording,
    got: &'a Value,
    failures: Vec<String>,
}

impl ChannelVisitor for CompareAll<'_> {
    fn visit<T: Sample>(&mut self, channel: Channel<T>) {
        let decoded = self.got["messages"][channel.topic()].as_array().cloned().unwrap_or_default();
        let recorded = self.recording.samples(channel).len();
        let (matched, failures) = compare_with_recording(self.recording, channel, &decoded);
        self.failures.extend(failures);
        eprintln!("{:<18} {matched:>6} of {recorded:>6} recorded samples received and equal", channel.topic());
        if (matched as f64) < 0.95 * recorded as f64 {
            self.failures.push(format!("{}: only {matched} of {recorded} recorded samples arrived", channel.name));
        }
        let encoding = format!("application/cdr;{}", T::schema_name());
        if recorded > 0 && self.got["encodings"][channel.topic()] != encoding.as_str() {
            self.failures.push(format!("{}: encoding {}", channel.name, self.got["encodings"][channel.topic()]));
        }
    }
}

#[test]
fn a_python_subscriber_on_another_host_receives_every_channel_as_recorded() {
    let _run = RUN.lock().unwrap_or_else(|e| e.into_inner());
    const SUITE: &str = "zpy";
    let python = python();
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
    let bridge = bridge(SUITE, bench_ns, &endpoint);
    let record = scratch(SUITE, "bridged.mcap");
    let got_path = scratch(SUITE, "python-subscriber.json");
    let mut command = in_netns(control_ns, &python);
    command
        .arg(repo_root().join("tests/clients/zenoh_subscriber.py"))
        .args(["--connect", &endpoint, "--namespace", &clients::namespace(SUITE), "--out"])
        .arg(&got_path)
        .arg("--recording")
        .arg(&record);
    let subscriber = Process::start(command, "subscribed", "the Python Zenoh subscriber");

    let (mut up, _stdout, _stderr) = spawn_up(common::jetbench(SUITE), 10, &record);
    let status = wait_with_watchdog(&mut up, Duration::from_secs(100), "jetbench up");
    assert!(status.success(), "jetbench up failed: {status}");
    // Whatever is still on the way arrives within the bridge's poll period and a hop.
    std::thread::sleep(Duration::from_millis(500));
    let (subscriber_ok, subscriber_log) = subscriber.stop();
    let (bridge_ok, bridge_log) = bridge.stop();
    drop(hosts);
    assert!(subscriber_ok, "the Python subscriber failed:\n{subscriber_log}");
    assert!(bridge_ok, "the bridge did not stop cleanly:\n{bridge_log}");
    eprintln!("{bridge_log}");

    let recording = Recording::open(&record).expect("read the run's recording");
    let text = std::fs::read_to_string(&got_path).expect("the subscriber wrote its JSON");
    let got: Value = serde_json::from_str(&text).expect("JSON");
    assert_eq!(got["errors"], serde_json::json!([]), "payloads that did not decode");
    let mut compare = CompareAll { recording: &recording, got: &got, failures: Vec::new() };
    visit_channels(&mut compare);
    assert!(compare.failures.is_empty(), "{}", compare.failures.join("\n"));
}

#[test]
fn remote_tools_read_and_record_a_live_bench_over_zenoh() {
    let _run = RUN.lock().unwrap_or_else(|e| e.into_inner());
    const SUITE: &str = "zrem";
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let bridge = bridge(SUITE, None, &endpoint);
    let endpoint: Endpoint = endpoint.parse().expect("endpoint");
    let namespace = clients::namespace(SUITE);
    let bench = RemoteBench::connect(&endpoint, &namespace).expect("connect to the bridge");
    let mut thrust = bench.subscribe(channels::THRUST, 1024).expect("subscribe to bench/thrust");
    let mut everything = bench.subscribe_all(8192).expect("subscribe to every channel");

    let record = scratch(SUITE, "local.mcap");
    let (mut up, _stdout, _stderr) = spawn_up(common::jetbench(SUITE), 8, &record);
    // `jetbench echo bench/thrust --remote ... -n 10`: ten typed samples.
    let first: Vec<_> = (0..10).filter_map(|_| thrust.recv_timeout(Duration::from_secs(20))).collect();
    assert_eq!(first.len(), 10, "ten thrust samples over Zenoh");
    // `jetbench record --remote ... --duration 5`: a normal jetbench MCAP.
    let remote_path: PathBuf = scratch(SUITE, "remote.mcap");
    let report = record_remote(&mut everything, &remote_path, Some(Duration::from_secs(5)), &bench.describe())
        .expect("record remotely");
    eprint!("{report}");
    let status = wait_with_watchdog(&mut up, Duration::from_secs(100), "jetbench up");
    assert!(status.success(), "jetbench up failed: {status}");
    let (bridge_ok, bridge_log) = bridge.stop();
    assert!(bridge_ok, "the bridge did not stop cleanly:\n{bridge_log}");

    let local = Recording::open(&record).expect("read the local recording");
    for sample in &first {
        assert!(local.samples(channels::THRUST).contains(sample), "seq {} differs from the recording", sample.seq);
    }
    let (counts, dropped) = thrust.counts();
    assert_eq!((counts.malformed, dropped), (0, 0), "{counts:?}");

    let remote = Recording::open(&remote_path).expect("read the remote recording");
    assert!(!remote.truncated);
    assert_eq!(remote.time_base().log_clock, LogClock::Realtime, "a remote recording is dated by the wall clock");
    let remote_thrust = remote.samples(channels::THRUST);
    assert!(remote_thrust.len() >= 400, "{} thrust samples in 5 s", remote_thrust.len());
    let local_thrust = local.samples(channels::THRUST);
    for s in &remote_thrust {
        assert_eq!(Some(s), local_thrust.get(s.seq as usize), "remote seq {} differs from the local recording", s.seq);
    }
    assert_eq!(report.dropped + report.dropped_full + everything.malformed(), 0, "{report}");
    // Every offline command reads it: `jetbench info` here.
    let (status, out, err) = common::run(
        Command::new(env!("CARGO_BIN_EXE_jetbench")).arg("info").arg(&remote_path),
        Duration::from_secs(30),
        "jetbench info",
    );
    assert!(status.success() && out.contains("/bench/thrust"), "{out}\n{err}");
}
