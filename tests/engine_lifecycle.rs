//! The engine's lifecycle, end to end: `jetbench up` with sim-bench's
//! emulated ECU on its pseudo-terminal (the ECU emulator behind a real tty,
//! polled by actuation as at the bench), each run its own OS processes in its
//! own bus namespace. Checked over the recording, read back with the
//! project's reader (and, for one, with Python `mcap`).

mod common;

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use common::{repo_root, run, scratch};
use jetbench_msgs::{channels, ecu_states, end_reasons, event_kinds, off_conditions, Command, EcuTelemetry, Event};
use jetbench_record::Recording;

const SUITE: &str = "engine_lifecycle";

/// One set at a time: two cores.
static SETS: Mutex<()> = Mutex::new(());

const IDLE: f64 = jetbench_model::THROTTLE_MIN_PCT;

/// config/sim.toml with `[engine]` and `[limits]` replaced by `engine` and `limits`.
fn config(name: &str, engine: &str, limits: &str) -> PathBuf {
    let text = std::fs::read_to_string(repo_root().join("config/sim.toml")).expect("config/sim.toml");
    let base = text.split("\n[engine]").next().expect("sim.toml has [engine] last");
    let path = scratch(SUITE, &format!("{name}.toml"));
    std::fs::write(&path, format!("{base}\n[engine]\n{engine}\n\n[limits]\n{limits}\n")).expect("write config");
    path
}

/// `jetbench up --sim --quiet --config CONFIG --record RECORD ARGS` in its own
/// namespace: exit code, stdout, stderr.
fn up(name: &str, config: &Path, record: &Path, args: &[&str], limit_s: u64) -> (i32, String, String) {
    let mut command = common::jetbench(SUITE);
    command.env(jetbench_bus::NAMESPACE_ENV, format!("el{name}{}", std::process::id()));
    command.args(["up", "--sim", "--quiet", "--config"]).arg(config).arg("--record").arg(record).args(args);
    let (status, out, err) = run(&mut command, Duration::from_secs(limit_s), &format!("up {name}"));
    (status.code().unwrap_or(-1), out, err)
}

fn s(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

/// The first ECU sample not in run after one in run: when the ECU left run.
fn left_run(ecu: &[EcuTelemetry]) -> Option<&EcuTelemetry> {
    let run = ecu_states::RUN as u32;
    let first_run = ecu.iter().position(|t| t.flags == 0 && t.state == run)?;
    ecu[first_run..].iter().find(|t| t.flags == 0 && t.state != run)
}

/// The first command at idle, gated, stamped at or after `ns`.
fn idle_after(commands: &[Command], ns: u64) -> Option<&Command> {
    commands.iter().find(|c| c.stamp_ns >= ns && c.throttle_pct <= IDLE + 1e-9)
}

/// An ECU failure ends the run: the reason named by the launcher, in
/// `bench/events` and the recording; throttle at idle within the ECU's hold
/// plus 100 ms of the cause; nothing above idle after it.
fn ecu_failure(name: &str, inject: &str, off: i32, words: &str, cause: impl Fn(&EcuTelemetry) -> bool, hold_s: f64) {
    let _one = SETS.lock().unwrap_or_else(|e| e.into_inner());
    // No stack limits: the ECU's own check acts.
    let cfg = config(name, "start = \"running\"\nreference = \"profile\"\ncool_down_at_end = false", "");
    let record = scratch(SUITE, &format!("{name}.mcap"));
    let (code, out, err) = up(name, &cfg, &record, &["--duration", "40", "--inject", inject], 120);
    let log = format!("{out}\n{err}");
    assert_ne!(code, 0, "an ECU shutdown must end the launcher with an error\n{log}");
    assert!(err.contains("the test ended") && err.contains(words), "the launcher names the reason {words:?}\n{log}");

    let recording = Recording::open(&record).expect("a readable recording");
    assert!(!recording.truncated, "the recording was closed");
    let ecu = recording.samples(channels::ECU);
    let commands = recording.samples(channels::COMMAND);
    let events = recording.samples(channels::EVENTS);
    let left = left_run(&ecu).unwrap_or_else(|| panic!("the ECU never left run\n{log}"));
    // Slow-down, or off already: a flame-out's exhaust is cold by the time the ECU decides.
    assert!([ecu_states::SLOW_DOWN as u32, ecu_states::OFF as u32].contains(&left.state), "{left:?}");
    // The reason, in the events and the ECU's status.
    let shutdown: Vec<&Event> = events.iter().filter(|e| e.kind == event_kinds::SHUTDOWN).collect();
    assert_eq!(shutdown.len(), 1, "one shutdown event: {events:?}");
    assert_eq!(shutdown[0].code, off, "the shutdown's reason");
    let ended = events.iter().find(|e| e.kind == event_kinds::TEST_ENDED).expect("a TEST_ENDED event");
    assert_eq!((ended.code, ended.previous), (end_reasons::ECU_SHUTDOWN, off));
    // Idle within 100 ms of the ECU leaving run, and never above it after.
    let idle = idle_after(&commands, left.stamp_ns).expect("a command at idle after the shutdown");
    let react_ms = (s(idle.stamp_ns) - s(left.stamp_ns)) * 1e3;
    let above_after = commands.iter().filter(|c| c.stamp_ns >= idle.stamp_ns && c.throttle_pct > IDLE + 1e-9).count();
    assert_eq!(above_after, 0, "throttle above idle after the shutdown");
    // From the cause the ECU saw (where the telemetry shows it) to idle: its hold plus 100 ms.
    let from_cause = ecu.iter().find(|t| t.flags == 0 && cause(t)).map(|t| s(idle.stamp_ns) - s(t.stamp_ns));
    println!(
        "{name}: ECU left run at {:.3} s, idle {react_ms:.0} ms later; from the cause seen in the telemetry: {}",
        s(left.stamp_ns),
        from_cause.map_or("not observable in the telemetry".into(), |d| format!("{:.3} s (hold {hold_s} s)", d))
    );
    assert!(react_ms <= 100.0, "idle {react_ms:.0} ms after the ECU left run");
    let d = from_cause.unwrap_or_else(|| panic!("{name}: the cause never shows in the telemetry\n{log}"));
    assert!(d <= hold_s + 0.1, "{name}: idle {d:.3} s after the cause, hold {hold_s} s");
}

#[test]
fn over_temperature_ends_the_run() {
    ecu_failure(
        "overtemp",
        "ecu:overtemp_at_s=6",
        off_conditions::OVER_TEMPERATURE,
        "over-temperature",
        |t| t.egt_c > 800.0,
        1.0,
    );
    // The recording read by Python's mcap, independently of our reader.
    let record = scratch_path("overtemp.mcap");
    let script = r#"
import struct, sys
from mcap.reader import make_reader
kinds = []
with open(sys.argv[1], "rb") as f:
    for schema, channel, message in make_reader(f).iter_messages(topics=["/bench/events"]):
        assert schema.name == "jetbench_msgs/msg/Event", schema.name
        body = message.data[4:]
        assert len(body) == 96, len(body)
        seq, stamp, pub, value, limit, kind, code, source, previous, origin, authority = struct.unpack_from("<QQQddIiIiII", body)
        kinds.append((kind, code, previous))
assert any(k == (4, 2, 0) for k in kinds), kinds          # SHUTDOWN, over-temperature
assert any(k == (7, 2, 2) for k in kinds), kinds          # TEST_ENDED, ECU shutdown, over-temperature
print("python mcap:", len(kinds), "events")
"#;
    let out = std::process::Command::new(common::python()).arg("-c").arg(script).arg(&record).output().expect("python");
    assert!(out.status.success(), "{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{}", String::from_utf8_lossy(&out.stdout).trim());
}

fn scratch_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join(SUITE).join(name)
}

#[test]
fn over_rpm_ends_the_run() {
    ecu_failure("overrpm", "ecu:overrpm_at_s=6", off_conditions::OVER_RPM, "over-RPM", |t| t.rpm > 131_250.0, 0.5);
}

#[test]
fn a_flame_out_ends_the_run() {
    ecu_failure("flameout", "ecu:flameout_at_s=6", off_conditions::LOW_RPM, "flame-out", |t| t.rpm < 31_500.0, 3.0);
}

#[test]
fn low_battery_ends_the_run() {
    // The battery voltage is read with `RFI` about five times a second: the
    // cause is the first reading below the ECU's 6.4 V (its true onset is at
    // most one read earlier, so the bound holds a fortiori).
    ecu_failure(
        "lowbattery",
        "ecu:lowbattery_at_s=6",
        off_conditions::LOW_BATTERY,
        "low battery",
        |t| t.battery_v > 0.0 && t.battery_v < 6.4,
        1.0,
    );
}

#[test]
fn up_starts_the_engine_runs_it_and_records_its_cool_down() {
    let _one = SETS.lock().unwrap_or_else(|e| e.into_inner());
    let cfg = config(
        "lifecycle",
        "start = \"auto\"\nreference = \"profile\"\ncool_down_at_end = true\nstop_idle_s = 1.0\ncool_down_timeout_s = 60.0",
        "preset = \"p100\"\nsensor_silent_s = \"off\"",
    );
    let record = scratch(SUITE, "lifecycle.mcap");
    let (code, out, err) = up("lifecycle", &cfg, &record, &["--duration", "8"], 180);
    let log = format!("{out}\n{err}");
    assert_eq!(code, 0, "{log}");
    for line in
        ["starting the engine through the ECU", "engine running after", "bringing the engine down", "engine off"]
    {
        assert!(out.contains(line), "{line:?} in the launcher's output\n{log}");
    }
    let recording = Recording::open(&record).expect("a readable recording");
    let ecu = recording.samples(channels::ECU);
    let commands = recording.samples(channels::COMMAND);
    // The states in order: standby, the start sequence, run, slow-down, off.
    let mut states: Vec<u32> = Vec::new();
    for t in ecu.iter().filter(|t| t.flags == 0) {
        if states.last() != Some(&t.state) {
            states.push(t.state);
        }
    }
    // Each state of the sequence found after the one before it (off comes first too, at power-up).
    let order = [ecu_states::STANDBY, ecu_states::IGNITE, ecu_states::RUN, ecu_states::SLOW_DOWN, ecu_states::OFF];
    let mut from = 0;
    for s in order {
        let at = states[from..].iter().position(|x| *x == s as u32);
        assert!(at.is_some(), "state {s} after position {from} in {states:?}");
        from += at.unwrap_or(0) + 1;
    }
    // Throttle above idle only while the ECU says run: by the newest ECU sample published
    // before each command was. A command's `stamp_ns` is its sensor frame's, taken before the
    // ECU sample that control acted on may have been read, so publish times are compared.
    let mut violations = Vec::new();
    let mut above = 0;
    for c in commands.iter().filter(|c| c.throttle_pct > IDLE + 1e-9) {
        above += 1;
        let newest = ecu.iter().rfind(|t| t.flags == 0 && t.publish_ns <= c.publish_ns);
        if newest.is_none_or(|t| t.state != ecu_states::RUN as u32) {
            let next = ecu.iter().find(|t| t.flags == 0 && t.publish_ns > c.publish_ns);
            let at = |t: Option<&EcuTelemetry>| t.map(|t| (t.state, t.stamp_ns, t.publish_ns));
            violations.push(format!(
                "command {:.2} % (stamp {}, published {}): newest ECU sample (state, stamp, published) {:?}, next {:?}",
                c.throttle_pct,
                c.stamp_ns,
                c.publish_ns,
                at(newest),
                at(next)
            ));
        }
    }
    println!(
        "{} ECU samples, states {states:?}; {above} commands above idle, {} outside run",
        ecu.len(),
        violations.len()
    );
    // The battery voltage, read with `RFI`: the emulated ECU's charged pack.
    let battery: Vec<f64> = ecu.iter().filter(|t| t.flags == 0 && t.battery_v > 0.0).map(|t| t.battery_v).collect();
    assert!(battery.len() * 2 > ecu.len(), "the battery voltage is read: {} of {} samples", battery.len(), ecu.len());
    assert!(battery.iter().all(|v| (7.3..=7.5).contains(v)), "a charged pack reads 7.4 V");
    assert!(above > 300, "the profile ran: {above} commands above idle");
    assert!(violations.is_empty(), "throttle above idle outside run:\n{}", violations.join("\n"));
    // The operator's stop, accepted and recorded with who sent it.
    let events = recording.samples(channels::EVENTS);
    let stop = events
        .iter()
        .find(|e| e.kind == event_kinds::COMMAND_ACCEPTED && e.code == jetbench_msgs::operator_commands::STOP)
        .expect("the launcher's STOP, accepted");
    assert!(jetbench_msgs::identity_text(&stop.identity).starts_with("local:"), "{stop:?}");
}
