//! End-to-end tests of the service set: real processes, the real bus, real
//! MCAP files read back by an independent reader (Python `mcap` +
//! `mcap-ros2-support`, set up by scripts/pyenv.sh).
//!
//! The tests run in their own bus namespace, one at a time (a lock), so that
//! each has the machine's cores to itself.
//! Hangs are caught by a watchdog; no test asserts a runtime.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use jetbench_msgs::{actuation_flags, channels, visit_channels, Channel, ChannelVisitor, RosType, Sample, ServiceId};
use jetbench_record::{seq_gaps, Recording};
use serde_json::Value;

mod common;

use common::{python, repo_root, run, wait_with_watchdog};

static BUS: Mutex<()> = Mutex::new(());

fn jetbench() -> Command {
    common::jetbench("test")
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("service_set", name)
}

/// Runs `jetbench up --sim` for `duration_s` seconds, recording to `out`.
fn run_up(duration_s: u32, out: &Path) -> (ExitStatus, String) {
    let (mut child, stdout, stderr) = common::spawn_up(jetbench(), duration_s, out);
    let limit = Duration::from_secs(u64::from(duration_s) + 90);
    let status = wait_with_watchdog(&mut child, limit, "jetbench up");
    let mut log: Vec<String> = stdout.try_iter().collect();
    log.extend(stderr.try_iter());
    (status, log.join("\n"))
}

/// Runs a short command to completion under the watchdog: status, stdout, stderr.
fn run_short(command: &mut Command, what: &str) -> (ExitStatus, String, String) {
    run(command, Duration::from_secs(30), what)
}

/// Runs a command that must succeed; returns its stdout.
fn output_with_watchdog(command: &mut Command, what: &str) -> String {
    let (status, out, err) = run_short(command, what);
    assert!(status.success(), "{what} failed: {status}\n{out}\n{err}");
    out
}

/// Runs a command that must fail; returns its stderr.
fn failure_of(command: &mut Command, what: &str) -> String {
    let (status, _, err) = run_short(command, what);
    assert!(!status.success(), "{what} must fail");
    err
}

/// Decodes a recording with the Python reference reader.
fn python_decode(path: &Path) -> Value {
    let out = Command::new(python())
        .arg(repo_root().join("scripts/mcap_dump.py"))
        .arg(path)
        .output()
        .expect("run mcap_dump.py");
    assert!(out.status.success(), "mcap_dump.py failed:\n{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("mcap_dump.py prints JSON")
}

/// A sample's fields as JSON values, read from its bytes by the schema's
/// field table (what a published sample holds).
fn fields_json<T: Sample>(sample: &T) -> Value {
    let bytes = sample.as_bytes();
    let scalar = |ty: RosType, at: &[u8]| -> Value {
        let b8 = |n: usize| at[..n].to_vec();
        match ty.primitive().name() {
            "float64" => serde_json::json!(f64::from_le_bytes(b8(8).try_into().unwrap())),
            "uint64" => serde_json::json!(u64::from_le_bytes(b8(8).try_into().unwrap())),
            "uint32" => serde_json::json!(u32::from_le_bytes(b8(4).try_into().unwrap())),
            "int32" => serde_json::json!(i32::from_le_bytes(b8(4).try_into().unwrap())),
            "int64" => serde_json::json!(i64::from_le_bytes(b8(8).try_into().unwrap())),
            "uint16" => serde_json::json!(u16::from_le_bytes(b8(2).try_into().unwrap())),
            "uint8" => serde_json::json!(at[0]),
            other => panic!("add {other} to the test decoder"),
        }
    };
    let mut map = serde_json::Map::new();
    for f in T::FIELDS {
        let at = &bytes[f.offset..];
        let value = match f.ros_type {
            RosType::Scalar(_) => scalar(f.ros_type, at),
            RosType::Array(p, n) => {
                Value::Array((0..n).map(|i| scalar(RosType::Scalar(p), &at[i * p.size()..])).collect())
            }
        };
        map.insert(f.name.to_string(), value);
    }
    Value::Object(map)
}

/// Compares the Python decoding of every channel with the published bytes.
struct CompareWithPython<'a> {
    recording: &'a Recording,
    python: &'a Value,
    compared: usize,
    failures: Vec<String>,
}

impl ChannelVisitor for CompareWithPython<'_> {
    fn visit<T: Sample>(&mut self, channel: Channel<T>) {
        let ours = self.recording.samples(channel);
        let topic = channel.topic();
        let theirs = self.python["messages"][&topic].as_array().cloned().unwrap_or_default();
        if ours.len() != theirs.len() {
            self.failures.push(format!("{topic}: {} messages here, {} decoded by Python", ours.len(), theirs.len()));
            return;
        }
        if !ours.is_empty() {
            let meta = &self.python["channels"][&topic];
            if meta["schema"] != T::schema_name().as_str()
                || meta["schema_encoding"] != "ros2msg"
                || meta["message_encoding"] != "cdr"
            {
                self.failures.push(format!("{topic}: channel metadata {meta}"));
            }
        }
        for (i, (sample, decoded)) in ours.iter().zip(&theirs).enumerate() {
            let expected = fields_json(sample);
            if &expected != decoded {
                self.failures.push(format!("{topic}[{i}]: published {expected} but Python decoded {decoded}"));
                return;
            }
            self.compared += 1;
        }
    }
}

fn health_of(recording: &Recording, id: ServiceId) -> Vec<jetbench_msgs::Health> {
    recording.samples(channels::HEALTH).into_iter().filter(|h| h.service_id == id as u32).collect()
}

#[test]
fn up_records_a_complete_closed_loop_run() {
    let _bus = BUS.lock().unwrap_or_else(|e| e.into_inner());
    let out = scratch("run.mcap");
    let (status, log) = run_up(10, &out);
    assert!(status.success(), "jetbench up failed: {status}\n{log}");

    let recording = Recording::open(&out).expect("read the recording");
    assert!(!recording.truncated, "recording was not closed properly");

    // Every bench channel complete and gap-free.
    let thrust = recording.samples(channels::THRUST);
    let state = recording.samples(channels::STATE);
    let reference = recording.samples(channels::REFERENCE);
    let command = recording.samples(channels::COMMAND);
    let actuation = recording.samples(channels::ACTUATION);
    let counts = [thrust.len(), state.len(), reference.len(), command.len(), actuation.len()];
    assert!(counts.iter().all(|n| *n >= 990), "message counts {counts:?}\n{log}");
    let gaps = [seq_gaps(&thrust), seq_gaps(&state), seq_gaps(&reference), seq_gaps(&command), seq_gaps(&actuation)];
    assert_eq!(gaps, [0; 5], "seq gaps per channel");
    for samples_start_at_zero in [thrust[0].seq, state[0].seq, reference[0].seq, command[0].seq, actuation[0].seq] {
        assert_eq!(samples_start_at_zero, 0, "the recording must start with each publisher's first sample");
    }
    // Every service a recorded run of the simulated bench starts.
    for id in jetbench_stack::runtime::launch::start_order(true, true) {
        let h = health_of(&recording, id);
        assert!(h.len() > 100, "{} published {} heartbeats", id.name(), h.len());
        assert_eq!(seq_gaps(&h), 0, "{} heartbeats have gaps", id.name());
    }
    let recorder = health_of(&recording, ServiceId::Recorder);
    assert_eq!(recorder.last().map(|h| h.input_gaps), Some(0), "the recorder lost samples");

    // Downstream samples carry their source's seq and stamp.
    for s in &state {
        let t = &thrust[s.source_seq as usize];
        assert_eq!((t.seq, t.stamp_ns), (s.source_seq, s.stamp_ns), "state {} does not match its thrust sample", s.seq);
    }

    // Actuation goes through the throttle board on a real pty: each cycle's
    // sample carries the board's acknowledgement (the applied throttle, to the
    // wire's 0.01 %) and the measured round trip.
    assert!(log.contains("throttle board on /") && log.contains("baud answers"), "no board on a pty:\n{log}");
    let acked: Vec<_> = actuation.iter().filter(|a| a.flags == 0).collect();
    assert!(acked.len() >= 900, "only {} of {} actuation samples acknowledged in time", acked.len(), actuation.len());
    for a in &acked {
        assert!(
            (a.applied_pct - a.commanded_pct).abs() <= 0.005 + 1e-9,
            "seq {}: board applied {} for {}",
            a.seq,
            a.applied_pct,
            a.commanded_pct
        );
        assert!(a.round_trip_ns > 0, "seq {}: no round trip measured", a.seq);
    }
    // The run ends safely: control stopped first, actuation idled and then
    // disarmed the board, and sim-bench ran its engine down to idle.
    let last = actuation.last().expect("actuation samples");
    assert_ne!(last.flags & actuation_flags::DISARMED, 0, "the last actuation sample: {last:?}");
    assert_eq!(last.applied_pct, 25.0);
    let truth_end = recording.samples(channels::SIM_TRUTH);
    assert_eq!(truth_end.last().map(|t| t.engine_throttle_pct), Some(25.0), "the engine ends at idle");
    let mut rtt_us: Vec<f64> = acked.iter().map(|a| a.round_trip_ns as f64 * 1e-3).collect();
    rtt_us.sort_by(f64::total_cmp);
    println!("board round trip: median {:.0} us, max {:.0} us", rtt_us[rtt_us.len() / 2], rtt_us[rtt_us.len() - 1]);

    // ECU telemetry polled over its own pty, at least 100 samples, RPM
    // following thrust as the emulated ECU computes it: linear in √thrust
    // (its constants come with the engine's class), through a first-order lag.
    let ecu = recording.samples(channels::ECU);
    assert_eq!(seq_gaps(&ecu), 0);
    let fresh: Vec<_> = ecu.iter().filter(|e| e.flags == 0).collect();
    assert!(ecu.len() >= 100 && fresh.len() >= 100, "{} ECU messages, {} fresh", ecu.len(), fresh.len());
    let truth = recording.samples(channels::SIM_TRUTH);
    let tau_s = jetbench_io::ecu::emulator::RPM_TAU_S;
    let mut lagged = Vec::with_capacity(truth.len());
    let mut root = truth.first().map_or(0.0, |t| t.thrust_n.max(0.0).sqrt());
    for (k, t) in truth.iter().enumerate() {
        let dt_s = k.checked_sub(1).map_or(0.0, |j| (t.stamp_ns.saturating_sub(truth[j].stamp_ns)) as f64 * 1e-9);
        root += (1.0 - (-dt_s / tau_s).exp()) * (t.thrust_n.max(0.0).sqrt() - root);
        lagged.push(root);
    }
    // Judged once the lag has forgotten its start (the emulator's own start differs).
    let settled_ns = truth.first().map_or(0, |t| t.stamp_ns) + (5.0 * tau_s * 1e9) as u64;
    let pairs: Vec<(f64, f64)> = fresh
        .iter()
        .filter(|e| e.stamp_ns >= settled_ns)
        .map(|e| (e.rpm, lagged[truth.partition_point(|t| t.stamp_ns < e.stamp_ns).min(truth.len() - 1)]))
        .collect();
    let n = pairs.len() as f64;
    let (mean_rpm, mean_root) =
        (pairs.iter().map(|p| p.0).sum::<f64>() / n, pairs.iter().map(|p| p.1).sum::<f64>() / n);
    let cov: f64 = pairs.iter().map(|(r, q)| (r - mean_rpm) * (q - mean_root)).sum();
    let var_rpm: f64 = pairs.iter().map(|(r, _)| (r - mean_rpm).powi(2)).sum();
    let var_root: f64 = pairs.iter().map(|(_, q)| (q - mean_root).powi(2)).sum();
    let correlation = cov / (var_rpm * var_root).sqrt();
    println!("ECU RPM against lagged √thrust: correlation {correlation:.5} over {} samples", pairs.len());
    assert!(pairs.len() >= 50 && correlation >= 0.99, "RPM does not follow thrust: correlation {correlation}");

    // Every message decodes with the reference Python reader to the published values.
    let python = python_decode(&out);
    let mut compare = CompareWithPython { recording: &recording, python: &python, compared: 0, failures: vec![] };
    visit_channels(&mut compare);
    assert!(compare.failures.is_empty(), "{:#?}", compare.failures);
    assert_eq!(compare.compared, recording.messages.len());

    // The estimated thrust tracks the reference: median error over the
    // second half below 5 % of the reference span.
    let (lo, hi) = reference.iter().fold((f64::MAX, f64::MIN), |(a, b), r| (a.min(r.thrust_n), b.max(r.thrust_n)));
    let span = hi - lo;
    assert!(span > 20.0, "the reference barely moved: {lo:.1}..{hi:.1} N");
    let by_state: std::collections::HashMap<u64, f64> = reference.iter().map(|r| (r.source_seq, r.thrust_n)).collect();
    let half = state.len() / 2;
    let mut errors: Vec<f64> =
        state[half..].iter().filter_map(|s| by_state.get(&s.seq).map(|r| (s.thrust_n - r).abs())).collect();
    assert!(errors.len() > 400);
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    println!("median tracking error {median:.3} N over a {span:.1} N reference span ({:.2} %)", 100.0 * median / span);
    assert!(median < 0.05 * span, "median tracking error {median:.2} N is not below 5 % of {span:.1} N");
}

#[test]
fn killing_control_idles_actuation_and_a_restart_is_clean() {
    let _bus = BUS.lock().unwrap_or_else(|e| e.into_inner());
    let out = scratch("kill.mcap");
    let (mut child, stdout, stderr) = common::spawn_up(jetbench(), 60, &out);

    // Find the control process, wait for the loop to run, then SIGKILL it.
    let mut control_pid = None;
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let line = stdout.recv_timeout(Duration::from_secs(1));
        if let Ok(line) = &line {
            if let Some(pid) = line.strip_prefix("started control (pid ").and_then(|r| r.strip_suffix(')')) {
                control_pid = pid.parse::<i32>().ok();
            }
            if line.starts_with("all ") && line.contains("services ready") {
                break;
            }
        }
        assert!(Instant::now() < deadline, "the service set never became ready");
    }
    let pid = control_pid.expect("the launcher prints each service's pid");
    std::thread::sleep(Duration::from_secs(1));
    // Live introspection of the running set: list, echo, hz.
    let listed = output_with_watchdog(jetbench().arg("list"), "jetbench list");
    for channel in ["bench/thrust", "bench/state", "bench/command", "bench/health"] {
        assert!(listed.contains(channel), "jetbench list misses {channel}:\n{listed}");
    }
    let echoed = output_with_watchdog(jetbench().args(["echo", "bench/state", "-n", "3"]), "jetbench echo");
    let lines: Vec<&str> = echoed.lines().collect();
    assert_eq!(lines.len(), 3, "echo -n 3 printed:\n{echoed}");
    assert!(lines.iter().all(|l| l.starts_with("seq=") && l.contains("thrust_rate_n_per_s=")), "{echoed}");
    let hz =
        output_with_watchdog(jetbench().args(["hz", "bench/thrust", "-w", "50", "--duration", "2.5"]), "jetbench hz");
    let rates: Vec<f64> = hz.lines().filter_map(|l| l.split_whitespace().nth(1).and_then(|r| r.parse().ok())).collect();
    assert!(!rates.is_empty(), "jetbench hz printed no rate:\n{hz}");
    assert!(rates.iter().all(|r| (90.0..110.0).contains(r)), "bench/thrust is not at 100 Hz:\n{hz}");

    // SAFETY: kill(2) on the pid the launcher reported for its control child.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGKILL) }, 0);

    let status = wait_with_watchdog(&mut child, Duration::from_secs(60), "jetbench up after SIGKILL");
    let log: Vec<String> = stdout.try_iter().chain(stderr.try_iter()).collect();
    let log = log.join("\n");
    assert!(!status.success(), "jetbench up must fail when a service dies\n{log}");
    assert!(log.contains("service `control` was killed by signal 9"), "jetbench up must name the dead service\n{log}");

    // In the recording: after the last command, actuation holds for at most
    // two cycles and is at idle (flagged) by the third. (Regression: the
    // launcher used to stop sim-bench, and with it the board, as soon as it saw
    // the death, often before the idle command could be acknowledged; it now
    // lets the survivors finish the fail-safe first.)
    let recording = Recording::open(&out).expect("the recorder still closes its file");
    let commands = recording.samples(channels::COMMAND);
    let actuation = recording.samples(channels::ACTUATION);
    let last_command = commands.last().expect("commands were recorded").seq;
    let applied_at =
        actuation.iter().rposition(|a| a.command_seq == last_command && a.flags == 0).expect("last command applied");
    let after = &actuation[applied_at + 1..];
    // The launcher stops the set soon after the death; actuation must have
    // run at least the three cycles that decide the fallback.
    assert!(after.len() >= 3, "actuation published only {} samples after control died", after.len());
    let idle_at =
        after.iter().position(|a| a.flags & actuation_flags::IDLE_FALLBACK != 0).expect("actuation went to idle");
    assert!(idle_at < 3, "idle on cycle {} after the last command, not within 3", idle_at + 1);
    let waited_ms = (after[idle_at].publish_ns - actuation[applied_at].publish_ns) as f64 * 1e-6;
    println!("idle {waited_ms:.1} ms ({} cycles) after the last command", idle_at + 1);
    // A sample whose ack was late (UNACKED) reports the newest acknowledged value,
    // which may still be the last command's; every acknowledged one is at idle.
    let acked: Vec<_> = after[idle_at..].iter().filter(|a| a.flags & actuation_flags::UNACKED == 0).collect();
    assert!(
        !acked.is_empty() && acked.iter().all(|a| a.applied_pct == 25.0),
        "actuation left idle without a controller"
    );

    // A new run right after starts cleanly: no stale shared memory.
    let again = scratch("restart.mcap");
    let (status, log) = run_up(2, &again);
    assert!(status.success(), "restart failed: {status}\n{log}");
    let thrust = Recording::open(&again).expect("read restart recording").samples(channels::THRUST);
    assert!(thrust.len() >= 150, "restart recorded {} thrust samples in 2 s", thrust.len());
    assert_eq!(thrust[0].seq, 0, "the restarted set must record from its first sample");
    assert_eq!(seq_gaps(&thrust), 0);
}

/// `jetbench list` sees a running set over either transport: every channel and
/// every service's node.
#[test]
fn list_shows_a_running_set_over_either_transport() {
    let _bus = BUS.lock().unwrap_or_else(|e| e.into_inner());
    for transport in ["iceoryx2", "uds"] {
        let mut up = jetbench();
        up.args(["up", "--sim", "--quiet", "--duration", "4", "--transport", transport]);
        let (mut child, stdout, stderr) = common::spawn_reading(up);
        let ready = common::wait_for_line(&stdout, "services ready", Duration::from_secs(60));
        let listed = output_with_watchdog(jetbench().arg("list"), "jetbench list");
        let status = wait_with_watchdog(&mut child, Duration::from_secs(60), "jetbench up");
        if !(ready.is_ok() && status.success()) {
            // What `up` said on the way out (its lines still in flight, or all of them).
            let errors: Vec<String> = std::iter::from_fn(|| stderr.recv_timeout(Duration::from_secs(2)).ok()).collect();
            panic!("{transport}: the set did not run ({status}): {ready:?}\nstderr:\n{}", errors.join("\n"));
        }
        // `bench/events` exists on the bus once a service publishes an event; the engine's
        // lifecycle and limits will, but no service does yet, so a quiet run has none.
        let published = jetbench_msgs::channel_names().into_iter().filter(|c| *c != channels::EVENTS.name);
        for channel in published {
            assert!(listed.lines().any(|l| l.trim() == channel), "{transport}: {channel} is not listed:\n{listed}");
        }
        for node in ["sim-bench", "sensing", "estimation", "control", "actuation"] {
            assert!(listed.lines().any(|l| l.trim() == node), "{transport}: node {node} is not listed:\n{listed}");
        }
    }
}

#[test]
fn bad_input_is_a_clear_error_and_starts_nothing() {
    let typo = scratch("typo.toml");
    let config = std::fs::read_to_string(repo_root().join("config/sim.toml")).expect("config/sim.toml");
    std::fs::write(&typo, config.replace("hold_s", "hold_sec")).expect("write typo config");
    let err = failure_of(
        jetbench().args(["up", "--sim", "--duration", "1", "--config"]).arg(&typo),
        "jetbench up with a config typo",
    );
    assert!(err.contains("unknown field `hold_sec`"), "{err}");
    assert!(!err.contains("started"), "nothing may start on a bad config: {err}");

    let err = failure_of(jetbench().arg("list").env(jetbench_bus::NAMESPACE_ENV, "no spaces!"), "bad namespace");
    assert!(err.contains("JETBENCH_BUS may hold only"), "{err}");

    let csv = scratch("not.mcap");
    std::fs::write(&csv, "time_s,throttle_pct,thrust_n\n").expect("write csv");
    let err = failure_of(jetbench().arg("info").arg(&csv), "jetbench info on a CSV");
    assert!(err.contains("not an MCAP file"), "{err}");

    let err = failure_of(jetbench().args(["echo", "bench/nothing"]), "echo of an unknown channel");
    assert!(err.contains("unknown channel") && err.contains("bench/thrust"), "{err}");
}
