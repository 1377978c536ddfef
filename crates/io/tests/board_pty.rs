//! The throttle-board driver against the emulated board over a real
//! pseudo-terminal pair: garbage injected on the tty mid-run, a board that
//! goes silent and comes back. No mocks: the same driver opens the pty's
//! link path as it opens /dev/ttyUSB0 at the bench.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use jetbench_io::board::{self, encode, raw_frame, Frame, Throttle};
use jetbench_io::emulate::PtyBoard;
use jetbench_io::serial::{ThrottleBoard, SILENT_AFTER};
use jetbench_io::ThrottleOutput;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn clock() -> u64 {
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_nanos() as u64
}

fn link(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("jetbench-io-test-{}", std::process::id())).join(name)
}

/// One burst of line noise with every rejection kind in it. Values in the
/// corrupted frames (12.34 %, 150 %) are never sent by the test.
fn garbage(rng: &mut ChaCha8Rng) -> Vec<u8> {
    let never_sent = Throttle::from_raw(1234).unwrap();
    let mut g: Vec<u8> = (0..rng.random_range(1..24)).map(|_| rng.random()).collect();
    match rng.random_range(0..5) {
        0 => {
            let mut f = encode(&Frame::SetThrottle { seq: rng.random(), throttle: never_sent });
            let k = rng.random_range(1..f.len());
            f[k] ^= 1 << rng.random_range(0..8);
            g.extend(f);
        }
        1 => {
            let f = encode(&Frame::SetThrottle { seq: rng.random(), throttle: never_sent });
            g.extend(&f[..rng.random_range(1..f.len())]);
        }
        2 => g.extend(raw_frame(0x01, &[7, 0, 0x98, 0x3A])), // 150.00 %, valid CRC: out of range
        3 => g.extend(raw_frame(0x55, &[1, 2, 3])),          // unknown type
        _ => g.extend(raw_frame(0x01, &[7, 0, 0x98])),       // wrong length for set-throttle
    }
    g
}

#[test]
fn garbage_on_the_tty_is_rejected_and_the_link_resynchronises() {
    let board = PtyBoard::spawn(&link("board-garbage"), clock).expect("emulated board on a pty");
    let mut driver = ThrottleBoard::new(board.link(), 115_200, clock);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut sent = Vec::new();
    let (mut acked_clean, mut acked_noisy, mut noisy_writes, mut max_unacked, mut max_silent) = (0, 0, 0, 0, 0);
    let started = Instant::now();
    for k in 0..900u32 {
        assert!(started.elapsed() < Duration::from_secs(120), "watchdog: the loop hung");
        let pct = 25.0 + f64::from(k % 7500) / 100.0;
        sent.push(Throttle::from_pct(pct).unwrap());
        let noisy = (300..600).contains(&k);
        if noisy && k % 3 == 0 {
            // Mid-run: noise into both directions of the tty.
            board.inject_to_board(&garbage(&mut rng)).unwrap();
            board.inject_to_pc(&garbage(&mut rng)).unwrap();
        }
        driver.write(pct).expect("a valid throttle");
        max_unacked = max_unacked.max(driver.unacked_writes());
        max_silent = max_silent.max(driver.silent_writes());
        let acked = driver.unacked_writes() == 0;
        if noisy {
            noisy_writes += 1;
            acked_noisy += u32::from(acked);
        } else {
            acked_clean += u32::from(acked);
        }
        if acked {
            assert_eq!(driver.acknowledged().map(|a| a.applied_pct), Some(sent[k as usize].pct()));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let applied = board.applied();
    let fw = board.firmware();
    let to_board = *fw.counters();
    let to_pc = *driver.counters();
    let rtt = driver.acknowledged().map(|a| a.round_trip_ns).unwrap();
    println!(
        "{} commands applied; acked in time {acked_clean} of 600 clean and {acked_noisy} of {noisy_writes} noisy \
         cycles, {} late; max {max_unacked} unacked in a row; last round trip {:.3} ms\n  PC->board {to_board:?}\n  \
         board->PC {to_pc:?}",
        applied.len(),
        driver.late_acks(),
        rtt as f64 * 1e-6
    );
    // The board never applied a corrupted command: every applied value was
    // sent, and since the link resynchronises on the next valid frame, it
    // applied exactly the commands sent, once each, in order.
    let applied_values: Vec<Throttle> = applied.iter().map(|(_, t)| *t).collect();
    assert!(applied_values.iter().all(|t| sent.contains(t)), "the board applied a value that was never sent");
    assert_eq!(applied_values, sent, "the board missed or repeated commands");
    // Every command is acknowledged (in time, or late when the noise cost time),
    // and the link never fell silent.
    assert!(u64::from(acked_clean + acked_noisy) + driver.late_acks() >= 899, "acknowledgements went missing");
    assert!(max_silent < SILENT_AFTER, "the link went silent under noise");
    // Every rejection kind shows in the board's counters; the PC saw its share.
    assert!(to_board.crc_errors > 0 && to_board.truncated + to_board.crc_errors > 20, "{to_board:?}");
    assert!(to_board.out_of_range > 0 && to_board.unknown_type > 0 && to_board.bad_length > 0, "{to_board:?}");
    assert!(to_board.garbage_bytes > 1000, "{to_board:?}");
    assert!(to_pc.rejected() > 0 && to_pc.garbage_bytes > 1000, "{to_pc:?}");
    let status = driver.board_status().expect("the board reports its status");
    assert!(status.flags & board::board_flags::ARMED != 0);
    assert!(u64::from(status.rejected_frames) > 50, "{status:?}");
    driver.stop();
}

#[test]
fn a_silent_board_is_reported_within_3_cycles_and_reopened_when_back() {
    let board = PtyBoard::spawn(&link("board-silent"), clock).expect("emulated board on a pty");
    let mut driver = ThrottleBoard::new(board.link(), 115_200, clock);
    let started = Instant::now();
    let write = |d: &mut ThrottleBoard| {
        assert!(started.elapsed() < Duration::from_secs(60), "watchdog: the loop hung");
        d.write(40.0).unwrap();
        std::thread::sleep(Duration::from_millis(5));
        (d.unacked_writes(), d.silent_writes())
    };
    for _ in 0..20 {
        write(&mut driver);
    }
    assert_eq!(driver.unacked_writes(), 0);
    assert_eq!(driver.opens(), 1);
    assert_eq!(board.output_pct(clock()), Some(40.0));

    board.set_silent(true);
    let counts: Vec<(u32, u32)> = (0..SILENT_AFTER).map(|_| write(&mut driver)).collect();
    assert_eq!(counts, vec![(1, 1), (2, 2), (3, 3)], "silent from the third unanswered cycle");
    assert!(driver.link_error().is_some(), "the port is closed to be reopened");
    // The board's own watchdog idles the engine 100 ms after its last valid frame.
    std::thread::sleep(Duration::from_millis(120));
    assert_eq!(board.output_pct(clock()), None);

    board.set_silent(false);
    let mut cycles_to_recover = 0;
    while write(&mut driver) != (0, 0) {
        cycles_to_recover += 1;
        assert!(cycles_to_recover < 50, "the board never came back");
    }
    println!("recovered after {cycles_to_recover} cycles; port opened {} times", driver.opens());
    assert!(driver.opens() >= 2, "the port was reopened");
    assert_eq!(board.output_pct(clock()), Some(40.0), "re-armed and driving again");
    driver.stop();
    std::thread::sleep(Duration::from_millis(20));
    assert!(!board.firmware().is_armed(), "stop disarms the board");
}

#[test]
fn a_missing_port_is_silent_not_an_error() {
    let mut driver = ThrottleBoard::new(link("no-such-board"), 115_200, clock);
    for expected in 1..=4 {
        driver.write(30.0).expect("a missing board is reported through silence");
        assert_eq!((driver.unacked_writes(), driver.silent_writes()), (expected, expected));
    }
    assert!(driver.link_error().is_some_and(|e| !e.is_empty()));
    assert!(driver.write(f64::NAN).is_err() && driver.write(101.0).is_err(), "invalid values are errors");
}

#[test]
fn the_disarm_is_sent_again_until_a_busy_board_acknowledges_it() {
    let board = PtyBoard::spawn(&link("board-disarm"), clock).expect("emulated board on a pty");
    let mut driver = ThrottleBoard::new(board.link(), 115_200, clock);
    while driver.unacked_writes() > 0 || board.output_pct(clock()).is_none() {
        driver.write(40.0).expect("the board answers");
    }
    // The board hears nothing for 30 ms, as when the whole set stops at once
    // and both ends wait for a core: the first disarms are lost.
    board.set_silent(true);
    std::thread::scope(|s| {
        s.spawn(|| {
            std::thread::sleep(Duration::from_millis(30));
            board.set_silent(false);
        });
        driver.stop();
    });
    let ack = driver.acknowledged().expect("an acknowledgement");
    assert!(!ack.armed, "the disarm was acknowledged: {ack:?}");
    assert!(!board.firmware().is_armed(), "the board is disarmed");
}
