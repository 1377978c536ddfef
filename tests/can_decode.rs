//! `jetbench can-decode` end to end: a generated candump log of the force
//! sensor with about 1 % garbage of every kind (bad DLC, unknown IDs,
//! truncated hex, lines that are not candump format, extended IDs, frames cut
//! out of a pair, skipped sequence numbers). Every valid pair must come out
//! with exactly its encoded values, each rejection kind must be counted
//! exactly, the exit status must be 0.
//!
//! The example log in recordings/can/ is made by the same generator (small,
//! fixed seed); a test checks it is up to date. Regenerate it with
//! `JETBENCH_REGENERATE=1 cargo test --release -p jetbench --test can_decode`.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use jetbench_io::can::{CanFrame, Codec};
use jetbench_io::candump::{format_line, Timestamp};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

mod common;

const SUITE: &str = "can_decode";

/// A generated log and what a correct decoder must make of it.
struct Generated {
    log: String,
    /// Expected CSV rows (no header).
    rows: Vec<String>,
    /// Expected count per rejection kind, by the names can-decode prints.
    counts: BTreeMap<&'static str, u64>,
    lines: u64,
}

/// `count × lsb` printed with `decimals` decimals, from the integer alone
/// (independent of the decoder's float path).
fn fixed(count: i16, decimals: u32) -> String {
    let scale = 10i64.pow(decimals);
    let c = i64::from(count);
    let sign = if c < 0 { "-" } else { "" };
    format!("{sign}{}.{:0width$}", c.abs() / scale, c.abs() % scale, width = decimals as usize)
}

/// The generator's state: the log so far, the clock, the expected counts.
struct Log {
    rng: ChaCha8Rng,
    lines: Vec<String>,
    micros: u64,
    counts: BTreeMap<&'static str, u64>,
}

impl Log {
    fn add(&mut self, kind: &'static str) {
        *self.counts.entry(kind).or_insert(0) += 1;
    }

    fn time(&mut self) -> Timestamp {
        self.micros += 4_000 + self.rng.random_range(0..2_000);
        Timestamp { secs: self.micros / 1_000_000, micros: (self.micros % 1_000_000) as u32 }
    }

    /// About 1 % of the time, a garbage line of a random kind.
    fn maybe_garbage(&mut self, sensor_frame: &CanFrame) {
        if !self.rng.random_bool(0.01) {
            return;
        }
        let at = self.time();
        let line = match self.rng.random_range(0..6) {
            0 => {
                self.add("bad_dlc");
                let len = if self.rng.random_bool(0.5) { self.rng.random_range(0..8) } else { 8 };
                let mut s = format_line(at, "can0", &CanFrame::standard(0x101, &[0x11; 8][..len]).unwrap());
                if len == 8 {
                    s.push_str("2233"); // 10 bytes
                }
                s
            }
            1 => {
                self.add("unknown_id");
                let id = [0x080u16, 0x100, 0x103, 0x200, 0x7ff][self.rng.random_range(0..5)];
                format_line(at, "can0", &CanFrame::standard(id, &[0u8; 8]).unwrap())
            }
            2 => {
                self.add("truncated");
                let mut s = format_line(at, "can0", sensor_frame);
                let cut = 2 * self.rng.random_range(1..8) - 1; // leaves an odd number of hex digits
                s.truncate(s.len() - cut);
                s
            }
            3 => {
                self.add("garbage");
                ["", "candump: interface can0 down", "(1700000000.1) can0", "# comment", "(x.y) can0 101#00"]
                    [self.rng.random_range(0..5)]
                .to_string()
            }
            4 => {
                self.add("out_of_range");
                format!("({at}) can0 00000101#0000000000000000")
            }
            _ => {
                self.add("out_of_range");
                format!("({at}) can0 101#R")
            }
        };
        self.lines.push(line);
    }
}

fn generate(pairs: usize, seed: u64) -> Generated {
    let codec = Codec::new(0x100).unwrap();
    let mut g = Log {
        rng: ChaCha8Rng::seed_from_u64(seed),
        lines: Vec::new(),
        micros: 1_700_000_000 * 1_000_000,
        counts: BTreeMap::new(),
    };
    let mut rows = Vec::new();
    let mut seq: u8 = 0;
    let mut emitted_seqs: Vec<u8> = Vec::new();
    for _ in 0..pairs {
        // Skipped sequence numbers: the sensor's frames lost upstream.
        if g.rng.random_bool(0.004) {
            seq = seq.wrapping_add(g.rng.random_range(1..4));
        }
        let force: [i16; 3] = [g.rng.random(), g.rng.random_range(-500..500), g.rng.random_range(-500..500)];
        let torque: [i16; 3] = [g.rng.random_range(-300..300), g.rng.random(), g.rng.random_range(-300..300)];
        let status = if g.rng.random_bool(0.01) { 1 } else { 0 };
        let [f, t] = codec.encode(force, torque, seq, status);
        let tf = g.time();
        let tt = g.time();
        g.maybe_garbage(&f);
        // Now and then one frame of a pair is cut mid-line: its partner is a mismatch.
        let cut = if g.rng.random_bool(0.002) { Some(g.rng.random_bool(0.5)) } else { None };
        let mut f_line = format_line(tf, "can0", &f);
        let mut t_line = format_line(tt, "can0", &t);
        match cut {
            Some(true) => f_line.truncate(f_line.len() - 3),
            Some(false) => t_line.truncate(t_line.len() - 5),
            None => {}
        }
        if cut.is_some() {
            g.add("truncated");
            g.add("pair_mismatch");
        }
        g.lines.push(f_line);
        g.maybe_garbage(&t);
        g.lines.push(t_line);
        if cut.is_none() {
            emitted_seqs.push(seq);
            rows.push(format!(
                "{tf},{},{},{},{},{},{},{}",
                fixed(force[0], 2),
                fixed(force[1], 2),
                fixed(force[2], 2),
                fixed(torque[0], 3),
                fixed(torque[1], 3),
                fixed(torque[2], 3),
                fixed(force[0], 2)
            ));
        }
        seq = seq.wrapping_add(1);
    }
    let mut jumps = 0;
    let mut lost = 0;
    for w in emitted_seqs.windows(2) {
        let step = w[1].wrapping_sub(w[0]);
        if step != 1 {
            jumps += 1;
            lost += u64::from(step.wrapping_sub(1));
        }
    }
    g.counts.insert("sequence_jump", jumps);
    g.counts.insert("lost_pairs", lost);
    let lines = g.lines.len() as u64;
    Generated { log: g.lines.join("\n") + "\n", rows, counts: g.counts, lines }
}

/// Runs can-decode: exit code, stdout, stderr.
fn can_decode(args: &[&str]) -> (i32, String, String) {
    let (status, out, err) = common::run(
        common::jetbench(SUITE).arg("can-decode").args(args),
        Duration::from_secs(120),
        "jetbench can-decode",
    );
    (status.code().unwrap_or(-1), out, err)
}

/// The `  kind count` lines of can-decode's stderr.
fn printed_counts(stderr: &str) -> BTreeMap<String, u64> {
    stderr
        .lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            let (k, v) = (f.next()?, f.next()?.parse().ok()?);
            l.starts_with("  ").then(|| (k.to_string(), v))
        })
        .collect()
}

#[test]
fn every_valid_pair_exactly_and_every_rejection_by_kind() {
    let g = generate(20_000, 7);
    let path = common::scratch(SUITE, "garbage.log");
    std::fs::write(&path, &g.log).unwrap();
    let (code, out, err) = can_decode(&[path.to_str().unwrap()]);
    assert_eq!(code, 0, "can-decode failed:\n{err}");
    let mut lines = out.lines();
    assert_eq!(lines.next(), Some("time_s,fx_n,fy_n,fz_n,tx_nm,ty_nm,tz_nm,thrust_n"));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), g.rows.len(), "decoded pairs\n{err}");
    for (i, (got, want)) in rows.iter().zip(&g.rows).enumerate() {
        assert_eq!(got, want, "row {i}");
    }
    let printed = printed_counts(&err);
    let garbage_lines: u64 = ["bad_dlc", "unknown_id", "truncated", "garbage", "out_of_range"]
        .iter()
        .map(|k| g.counts.get(k).copied().unwrap_or(0))
        .sum();
    println!(
        "{} lines, {} pairs, {garbage_lines} garbage lines ({:.2} %); expected counts {:?}",
        g.lines,
        g.rows.len(),
        100.0 * garbage_lines as f64 / g.lines as f64,
        g.counts
    );
    for kind in [
        "bad_dlc",
        "unknown_id",
        "sequence_jump",
        "pair_mismatch",
        "truncated",
        "garbage",
        "out_of_range",
        "lost_pairs",
    ] {
        let want = g.counts.get(kind).copied().unwrap_or(0);
        assert!(want > 0, "the generator made no {kind}");
        assert_eq!(printed.get(kind).copied(), Some(want), "{kind}\n{err}");
    }
    // Every line accounted for: two per pair plus the rejected ones.
    let rejected: u64 =
        printed.iter().filter(|(k, _)| !["sequence_jump", "lost_pairs"].contains(&k.as_str())).map(|(_, v)| v).sum();
    assert_eq!(2 * rows.len() as u64 + rejected, g.lines);
}

#[test]
fn a_config_applies_calibration_tare_and_base_id() {
    let g = generate(300, 11);
    let log = common::scratch(SUITE, "calibrated.log");
    // The same log on base 0x200: IDs 0x201/0x202.
    std::fs::write(&log, g.log.replace(") can0 101#", ") can0 201#").replace(") can0 102#", ") can0 202#")).unwrap();
    let config_text = std::fs::read_to_string(common::repo_root().join("config/sim.toml"))
        .unwrap()
        .replace("can_base_id = 0x100", "can_base_id = 0x200")
        .replace("[1.0, 0.0, 0.0, 0.0, 0.0, 0.0],", "[2.0, 0.0, 0.0, 0.0, 0.0, 0.0],")
        .replace("tare = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]", "tare = [0.5, 0.0, 0.0, 0.0, 0.0, 0.0]");
    let config = common::scratch(SUITE, "calibrated.toml");
    std::fs::write(&config, config_text).unwrap();
    let (code, out, err) = can_decode(&[log.to_str().unwrap(), "--config", config.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let rows: Vec<&str> = out.lines().skip(1).collect();
    assert_eq!(rows.len(), g.rows.len(), "{err}");
    for (got, want) in rows.iter().zip(&g.rows) {
        let got: Vec<f64> = got.split(',').map(|v| v.parse().unwrap()).collect();
        let want: Vec<f64> = want.split(',').map(|v| v.parse().unwrap()).collect();
        assert!((got[1] - (2.0 * want[1] - 0.5)).abs() < 0.0051, "fx {} from {}", got[1], want[1]);
        assert_eq!(got[7], got[1], "thrust is the calibrated fx");
        assert_eq!(&got[2..7], &want[2..7]);
    }
}

#[test]
fn a_missing_file_is_an_error_and_garbage_is_not() {
    let (code, _, err) = can_decode(&["/nonexistent/x.log"]);
    assert_ne!(code, 0);
    assert!(err.contains("cannot open /nonexistent/x.log"), "{err}");
    let bytes = common::scratch(SUITE, "binary.log");
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let noise: Vec<u8> = (0..200_000).map(|_| rng.random()).collect();
    std::fs::write(&bytes, noise).unwrap();
    let (code, out, err) = can_decode(&[bytes.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.lines().count(), 1, "only the header");
    assert!(printed_counts(&err)["garbage"] > 0);
}

/// The committed example: recordings/can/sensor-example.log.
fn example_path() -> PathBuf {
    common::repo_root().join("recordings/can/sensor-example.log")
}

#[test]
fn the_example_log_is_the_generators() {
    let g = generate(500, 2024);
    if std::env::var_os("JETBENCH_REGENERATE").is_some() {
        std::fs::write(example_path(), &g.log).unwrap();
    }
    let committed = std::fs::read_to_string(example_path()).expect("recordings/can/sensor-example.log");
    assert!(committed == g.log, "recordings/can/sensor-example.log is stale: regenerate it (see the module docs)");
    let (code, out, _) = can_decode(&[example_path().to_str().unwrap()]);
    assert_eq!(code, 0);
    assert_eq!(out.lines().count() - 1, g.rows.len());
}
