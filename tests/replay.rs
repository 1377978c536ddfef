//! End-to-end tests of `jetbench replay`: a live run of the real service set
//! is recorded, then replayed through the estimator, and must reproduce its
//! recorded `bench/state` bit for bit (the determinism contract).
//!
//! The live run uses its own bus namespace. Hangs are caught by a watchdog;
//! no test asserts a runtime.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Duration;

use jetbench_msgs::{channels, state_flags, RosType, Sample, StateEstimate, Thrust};
use jetbench_record::{McapWriter, Recording};
use serde_json::Value;

fn replay_cmd(args: &[&Path]) -> (Option<i32>, String, String) {
    let mut command = jetbench();
    command.arg("replay").args(args);
    run(&mut command, Duration::from_secs(60), "jetbench replay")
}

mod common;

fn jetbench() -> Command {
    common::jetbench("replay")
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("replay", name)
}

/// Runs under the watchdog: exit code, stdout, stderr.
fn run(command: &mut Command, limit: Duration, what: &str) -> (Option<i32>, String, String) {
    let (status, out, err) = common::run(command, limit, what);
    (status.code(), out, err)
}

/// The number after `key:` in the replay summary.
fn summary_count(out: &str, key: &str) -> usize {
    out.lines()
        .find_map(|l| l.trim().strip_prefix(key)?.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no `{key}` count in the summary:\n{out}"))
}

/// One 8 s live run of the simulated bench, recorded; shared by the tests. Its
/// sensor spikes and sticks for a while, so the estimator's gate acts: the
/// measurements it rejects are part of what replays bit for bit.
fn live_recording() -> &'static Path {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        let out = scratch("run.mcap");
        let mut command = jetbench();
        command.args(["up", "--sim", "--duration", "8", "--quiet", "--record"]).arg(&out);
        command.args(["--inject", "spikes:rate_per_s=2,size_n=30", "--inject", "stuck:at_s=4,for_s=0.5"]);
        let (code, stdout, stderr) = run(&mut command, Duration::from_secs(120), "jetbench up");
        assert_eq!(code, Some(0), "jetbench up failed\n{stdout}\n{stderr}");
        out
    })
}

/// A state's fields as JSON, read from its bytes by the schema's field table.
fn state_json(s: &StateEstimate) -> Value {
    let bytes = s.as_bytes();
    let mut map = serde_json::Map::new();
    for f in StateEstimate::FIELDS {
        let raw: [u8; 8] = bytes[f.offset..f.offset + 8].try_into().expect("8-byte field");
        let value = match f.ros_type {
            RosType::Scalar(p) if p.name() == "float64" => serde_json::json!(f64::from_le_bytes(raw)),
            RosType::Scalar(p) if p.name() == "uint64" => serde_json::json!(u64::from_le_bytes(raw)),
            other => panic!("add {other} to the test decoder"),
        };
        map.insert(f.name.to_string(), value);
    }
    Value::Object(map)
}

#[test]
fn a_live_run_replays_bit_for_bit() {
    let run_mcap = live_recording();
    let replayed_mcap = scratch("replayed.mcap");
    let (code, out, err) = replay_cmd(&[run_mcap, Path::new("--out"), &replayed_mcap]);
    println!("{out}\n{err}");
    assert_eq!(code, Some(0), "replay must match the live run\n{out}\n{err}");
    let compared = summary_count(&out, "compared:");
    let identical = summary_count(&out, "identical:");
    assert!(compared >= 700, "only {compared} estimates compared\n{out}");
    assert_eq!(identical, compared, "{out}");
    assert!(out.contains("samples/s"), "the summary gives the replay rate:\n{out}");
    assert!(out.contains("model_toml"), "the estimator comes from the recorded model:\n{out}");

    // The replayed file: bench/state equal to the recorded one, bit for bit,
    // every other channel copied.
    let recorded = Recording::open(run_mcap).expect("read the live recording");
    let replayed = Recording::open(&replayed_mcap).expect("read the replayed recording");
    assert!(!replayed.truncated);
    let (a, b) = (recorded.samples(channels::STATE), replayed.samples(channels::STATE));
    assert_eq!(a.len(), b.len());
    assert!(a.len() >= 700);
    for flag in [state_flags::MEASUREMENT_REJECTED, state_flags::SENSOR_STUCK] {
        assert!(b.iter().any(|s| s.flags & flag != 0), "the gate's flag {flag:#x} is replayed too");
    }
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.as_bytes(), y.as_bytes(), "state {} differs: {x:?} vs {y:?}", x.seq);
    }
    assert_eq!(recorded.counts(), replayed.counts(), "every channel is copied");
    assert_eq!(recorded.samples(channels::THRUST), replayed.samples(channels::THRUST));
    assert_eq!(replayed.metadata["jetbench"], recorded.metadata["jetbench"]);
    let meta = &replayed.metadata["replay"];
    assert_eq!(meta["identical"], compared.to_string());
    assert!(meta["source"].ends_with("run.mcap"), "{meta:?}");

    // The independent reader decodes the replayed states to the same values.
    let py = Command::new(common::python())
        .arg(common::repo_root().join("scripts/mcap_dump.py"))
        .arg(&replayed_mcap)
        .output()
        .expect("run mcap_dump.py");
    assert!(py.status.success(), "mcap_dump.py failed:\n{}", String::from_utf8_lossy(&py.stderr));
    let decoded: Value = serde_json::from_slice(&py.stdout).expect("mcap_dump.py prints JSON");
    let states = decoded["messages"]["/bench/state"].as_array().expect("Python decodes /bench/state");
    assert_eq!(states.len(), b.len());
    for (s, json) in b.iter().zip(states) {
        assert_eq!(&state_json(s), json, "Python decodes state {} differently", s.seq);
    }
}

/// `recording` as the recorder wrote it before log times were wall-clock time:
/// every `log_time` on `CLOCK_MONOTONIC` (the sample's stamp, as it received it
/// then), and no `log_time_clock` in the metadata.
fn as_before_wall_clock_log_times(recording: &Recording, path: &Path) {
    let mut writer = McapWriter::create(path).expect("create");
    for (name, entries) in &recording.metadata {
        let mut entries = entries.clone();
        entries.remove(jetbench_record::meta::KEY_LOG_TIME_CLOCK);
        writer.write_metadata(name, entries).expect("metadata");
    }
    for m in &recording.messages {
        let body = &m.data[jetbench_msgs::CDR_HEADER.len()..];
        let seq = u64::from_le_bytes(body[..8].try_into().expect("a seq"));
        let channel = m.topic.trim_start_matches('/');
        writer.write_raw(channel, seq, m.publish_time_ns, m.publish_time_ns, body).expect("write");
    }
    writer.finish().expect("finish");
}

#[test]
fn a_recording_from_before_wall_clock_log_times_replays_identifies_and_dates_alike() {
    let run_mcap = live_recording();
    let recorded = Recording::open(run_mcap).expect("read the live recording");
    let old = scratch("before-wall-clock.mcap");
    as_before_wall_clock_log_times(&recorded, &old);
    let old_recording = Recording::open(&old).expect("read it back");
    assert!(old_recording.messages[0].log_time_ns < 1_000_000_000_000_000_000, "monotonic log times");

    // Replay: bit for bit, as the new file.
    let (code, out, err) = replay_cmd(&[&old]);
    assert_eq!(code, Some(0), "an old recording must replay bit for bit\n{out}\n{err}");
    assert_eq!(summary_count(&out, "identical:"), summary_count(&out, "compared:"), "{out}");
    // Identification: the same data, so the same model.
    let identify = |file: &Path| {
        let mut command = jetbench();
        command.args(["identify", "--method", "ls", "--json"]).arg(file);
        let (code, out, err) = run(&mut command, Duration::from_secs(120), "jetbench identify");
        assert_eq!(code, Some(0), "identify {}: {err}", file.display());
        serde_json::from_str::<Value>(&out).expect("JSON")["methods"]["ls"]["params"].clone()
    };
    assert_eq!(identify(&old), identify(run_mcap), "the old and the new file identify alike");
    // Dated: both show the run's start at the same wall-clock time (to the ms).
    let start = |file: &Path| {
        let mut command = jetbench();
        command.arg("info").arg(file);
        let (code, out, err) = run(&mut command, Duration::from_secs(30), "jetbench info");
        assert_eq!(code, Some(0), "{err}");
        out.lines().find_map(|l| l.trim().strip_prefix("start ").map(str::to_string)).expect("a start line")
    };
    let (old_start, new_start) = (start(&old), start(run_mcap));
    assert!(old_start.starts_with("20") && !old_start.contains("unknown"), "{old_start}");
    // The old file's first log time is the first sample's stamp, a few ms before the recorder logged it.
    let seconds_of_day = |t: &str| -> f64 {
        let clock = t.split(' ').nth(1).expect("HH:MM:SS.mmm");
        clock.split(':').zip([3600.0, 60.0, 1.0]).map(|(v, unit)| v.parse::<f64>().expect("a number") * unit).sum()
    };
    let apart_s = (seconds_of_day(&old_start) - seconds_of_day(&new_start)).abs();
    assert!(apart_s < 1.0 && old_start[..10] == new_start[..10], "old {old_start}, new {new_start}");
}

#[test]
fn a_given_config_and_a_truncated_file_still_replay() {
    let run_mcap = live_recording();

    // The run's own config given explicitly: same estimator, so identical,
    // but the summary says a bit-exact match was not promised.
    let config = common::repo_root().join("config/sim.toml");
    let (code, out, err) = replay_cmd(&[run_mcap, Path::new("--config"), &config]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(err.contains("not expected"), "{err}");

    // Cut inside the data: the metadata at the start survives, the rest is replayed.
    let bytes = std::fs::read(run_mcap).expect("read run.mcap");
    let cut = scratch("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).expect("write cut.mcap");
    let (code, out, err) = replay_cmd(&[&cut]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(err.contains("truncated"), "{err}");
    assert!(summary_count(&out, "compared:") > 100, "{out}");
    assert_eq!(summary_count(&out, "compared:"), summary_count(&out, "identical:"), "{out}");
}

#[test]
fn bad_recordings_are_clear_errors() {
    // Not MCAP.
    let csv = scratch("not.mcap");
    std::fs::write(&csv, "time_s,throttle_pct,thrust_n\n0,25,0\n").expect("write csv");
    let (code, _, err) = replay_cmd(&[&csv]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("not an MCAP file"), "{err}");

    // An old recording: thrust but no metadata, so no estimator config.
    let old = scratch("old.mcap");
    let mut w = McapWriter::create(&old).expect("create old.mcap");
    for seq in 0..50u64 {
        let t =
            Thrust { seq, stamp_ns: 1_000 + seq * 10_000_000, thrust_n: 20.0 + seq as f64 * 0.1, ..Thrust::default() };
        w.write_sample(channels::THRUST, t.stamp_ns, &t).expect("write thrust");
    }
    w.finish().expect("finish old.mcap");
    let (code, out, err) = replay_cmd(&[&old]);
    assert_eq!(code, Some(2), "{out}\n{err}");
    assert!(err.contains("--config"), "the error suggests --config: {err}");
    // With --config it replays; without states there is nothing to compare.
    let config = common::repo_root().join("config/sim.toml");
    let (code, out, err) = replay_cmd(&[&old, Path::new("--config"), &config]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(out.contains("nothing to compare"), "{out}");
    assert_eq!(summary_count(&out, "replayed:"), 50);

    // No thrust at all.
    let empty = scratch("empty.mcap");
    McapWriter::create(&empty).expect("create empty.mcap").finish().expect("finish empty.mcap");
    let (code, _, err) = replay_cmd(&[&empty, Path::new("--config"), &config]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("no /bench/thrust samples"), "{err}");

    // --out must not overwrite the input.
    let (code, _, err) = replay_cmd(&[&old, Path::new("--out"), &old]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("is the recording being replayed"), "{err}");
}
