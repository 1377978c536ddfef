//! End to end through real pseudo-terminals: `jetbench up --sim` with
//! garbage bytes injected on the throttle board's tty mid-run. The link
//! resynchronises on the next valid frame, the board never applies a
//! corrupted command, and the rejections show in the board's counters.
//! Hangs are caught by a watchdog; no test asserts a runtime.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use jetbench_io::board::{crc16, encode, Frame, Throttle, SYNC};
use jetbench_model::THROTTLE_MIN_PCT;
use jetbench_msgs::{actuation_flags, channels};
use jetbench_record::{seq_gaps, Recording};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

mod common;

use common::wait_with_watchdog;

/// A burst of line noise: random bytes, then a corrupted set-throttle frame
/// (a flipped bit or a cut), a valid-CRC frame out of range (150 %), one of
/// an unknown type, or one of a wrong length. The corrupted frames carry
/// 12.34 %, a throttle the controller never commands (it stays within 25..100).
fn garbage(rng: &mut ChaCha8Rng) -> Vec<u8> {
    let raw = |kind: u8, payload: &[u8]| {
        let mut f = vec![SYNC, kind, payload.len() as u8];
        f.extend_from_slice(payload);
        let crc = crc16(&f[1..]);
        f.extend_from_slice(&crc.to_le_bytes());
        f
    };
    let mut g: Vec<u8> = (0..rng.random_range(1..32)).map(|_| rng.random()).collect();
    let forged = encode(&Frame::SetThrottle { seq: rng.random(), throttle: Throttle::from_raw(1234).unwrap() });
    match rng.random_range(0..5) {
        0 => {
            let mut f = forged;
            let k = rng.random_range(1..f.len());
            f[k] ^= 1 << rng.random_range(0..8);
            g.extend(f);
        }
        1 => g.extend(&forged[..rng.random_range(1..forged.len() - 1)]),
        2 => g.extend(raw(0x01, &[7, 0, 0x98, 0x3A])),
        3 => g.extend(raw(0x66, &[1, 2])),
        _ => g.extend(raw(0x01, &[7, 0, 0x98])),
    }
    g
}

/// The counter `name=N` in a log line.
fn counter(line: &str, name: &str) -> u64 {
    line.split([' ', ',', ';'])
        .find_map(|w| w.strip_prefix(&format!("{name}=")))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no {name}= in {line}"))
}

#[test]
fn garbage_on_the_board_tty_mid_run_is_rejected_and_the_link_resynchronises() {
    let out = common::scratch("serial_bench", "garbage.mcap");
    let namespace_suite = "serial";
    let (mut child, stdout, stderr) = common::spawn_up(common::jetbench(namespace_suite), 8, &out);
    let deadline = Instant::now() + Duration::from_secs(60);
    while !stdout.recv_timeout(Duration::from_secs(1)).is_ok_and(|l| l.starts_with("all ") && l.contains("ready")) {
        assert!(Instant::now() < deadline, "the service set never became ready");
    }

    // The board's tty, where sim-bench links it for this bus namespace.
    let link: PathBuf = std::env::temp_dir()
        .join(format!("jetbench-sim-{namespace_suite}{}", std::process::id()))
        .join("throttle-board");
    std::thread::sleep(Duration::from_secs(2));
    // Writing into the slave end puts the bytes on the line to the board,
    // between actuation's frames. Actuation holds the port exclusively
    // (TIOCEXCL), which only root may bypass.
    let tty = std::fs::OpenOptions::new().write(true).custom_flags(libc::O_NOCTTY).open(&link);
    let mut tty = match tty {
        Ok(t) => t,
        Err(e) => {
            let _ = child.kill();
            let _ = child.wait();
            println!("SKIPPED: cannot open {} to inject noise ({e}); this test needs root", link.display());
            return;
        }
    };
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let mut injected = 0;
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(3) {
        tty.write_all(&garbage(&mut rng)).expect("write noise into the tty");
        injected += 1;
        std::thread::sleep(Duration::from_millis(25));
    }
    drop(tty);

    let status = wait_with_watchdog(&mut child, Duration::from_secs(90), "jetbench up");
    let log: Vec<String> = stdout.try_iter().chain(stderr.try_iter()).collect();
    let log = log.join("\n");
    assert!(status.success(), "jetbench up failed: {status}\n{log}");

    // The board's own counters: every kind of noise was rejected.
    let line = log.lines().find(|l| l.contains("throttle board emulator:")).expect("sim-bench reports its board");
    println!("{injected} noise bursts injected\n{line}");
    assert!(counter(line, "crc") + counter(line, "truncated") > 0, "{line}");
    assert!(counter(line, "out_of_range") > 0 && counter(line, "unknown_type") > 0, "{line}");
    assert!(counter(line, "bad_length") > 0 && counter(line, "garbage_bytes") > 1000, "{line}");

    // The recording: the board acknowledged the commanded throttle and never
    // anything else; the link never fell silent while the noise was on.
    let recording = Recording::open(&out).expect("read the recording");
    let actuation = recording.samples(channels::ACTUATION);
    assert_eq!(seq_gaps(&actuation), 0);
    let first_ack = actuation.iter().position(|a| a.flags == 0).expect("the board answered");
    let running = &actuation[first_ack..];
    let acked: Vec<_> = running.iter().filter(|a| a.flags & actuation_flags::UNACKED == 0).collect();
    let silent = running.iter().filter(|a| a.flags & actuation_flags::BOARD_SILENT != 0).count();
    println!("{} of {} cycles acknowledged in time, {silent} silent", acked.len(), running.len());
    assert!(acked.len() * 10 >= running.len() * 9, "{} of {} acknowledged", acked.len(), running.len());
    for a in &acked {
        // Without fresh commands (control stops before actuation at the end)
        // actuation idles the board; otherwise it writes the command.
        let written = if a.flags & actuation_flags::IDLE_FALLBACK != 0 { THROTTLE_MIN_PCT } else { a.commanded_pct };
        assert!(
            (a.applied_pct - written).abs() <= 0.005 + 1e-9,
            "seq {}: board applied {} for {written} (flags {:#x})",
            a.seq,
            a.applied_pct,
            a.flags
        );
    }
    // Only the stop at the end (sim-bench stops first) may silence the board.
    let last_live = running.iter().rposition(|a| a.flags & actuation_flags::BOARD_SILENT == 0).unwrap();
    assert!(running[..last_live].iter().all(|a| a.flags & actuation_flags::BOARD_SILENT == 0), "the link fell silent");
    assert!(running.iter().all(|a| a.applied_pct >= 25.0), "a corrupted 12.34 % command was applied");
}
