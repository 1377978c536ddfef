//! Fuzz-style hammering of the CAN decoders on stable Rust: seeded random and
//! mutated `struct can_frame` byte streams and candump lines, millions in a
//! release run (`cargo test --release`), fewer in a debug run. Nothing may
//! panic, and every input is accounted for:
//! `2 × readings + rejected == inputs`.
//! Iterations and time are printed (`--nocapture`), never asserted.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::time::Instant;

use jetbench_io::can::{CanFrame, Codec, FrameDecoder, RejectKind, CAN_FRAME_BYTES};
use jetbench_io::candump::{format_line, CandumpDecoder, Timestamp};
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Inputs per stream: millions in release mode.
fn iterations() -> u64 {
    if cfg!(debug_assertions) {
        50_000
    } else {
        2_000_000
    }
}

fn codec() -> Codec {
    Codec::new(0x100).unwrap()
}

/// A valid frame stream: force and torque frames of consecutive readings.
fn valid_frame(rng: &mut ChaCha8Rng, k: u64) -> CanFrame {
    let seq = ((k / 2) & 0xff) as u8;
    let counts = [rng.random(), rng.random(), rng.random()];
    let status = if rng.random_bool(0.01) { rng.random() } else { 0 };
    let [f, t] = codec().encode(counts, counts, seq, status);
    if k.is_multiple_of(2) {
        f
    } else {
        t
    }
}

fn mutate_bytes(rng: &mut ChaCha8Rng, bytes: &mut Vec<u8>) {
    for _ in 0..rng.random_range(1..4) {
        match rng.random_range(0..6) {
            0 if !bytes.is_empty() => {
                let i = rng.random_range(0..bytes.len());
                bytes[i] ^= 1 << rng.random_range(0..8);
            }
            1 if !bytes.is_empty() => {
                let i = rng.random_range(0..bytes.len());
                bytes[i] = rng.random();
            }
            2 => bytes.truncate(rng.random_range(0..=bytes.len())),
            3 => bytes.push(rng.random()),
            4 if bytes.len() > 4 => bytes[4] = rng.random_range(0..16), // the length byte
            _ if bytes.len() >= 4 => bytes[..2].copy_from_slice(&rng.random_range(0x0ffu16..0x104).to_ne_bytes()),
            _ => {}
        }
    }
}

fn mutate_text(rng: &mut ChaCha8Rng, line: &mut Vec<u8>) {
    const ALPHABET: &[u8] = b"0123456789ABCDEFabcdefXR#()._ \t\r-";
    for _ in 0..rng.random_range(1..4) {
        match rng.random_range(0..5) {
            0 if !line.is_empty() => {
                let i = rng.random_range(0..line.len());
                line[i] = ALPHABET[rng.random_range(0..ALPHABET.len())];
            }
            1 if !line.is_empty() => {
                line.remove(rng.random_range(0..line.len()));
            }
            2 => {
                let i = rng.random_range(0..=line.len());
                line.insert(i, ALPHABET[rng.random_range(0..ALPHABET.len())]);
            }
            3 => line.truncate(rng.random_range(0..=line.len())),
            _ if !line.is_empty() => {
                let i = rng.random_range(0..line.len());
                line[i] = rng.random(); // may break UTF-8
            }
            _ => {}
        }
    }
}

fn report(what: &str, n: u64, pairs: u64, counts: &jetbench_io::can::RejectCounts, started: Instant) {
    let s = started.elapsed().as_secs_f64();
    println!("{what}: {n} inputs in {s:.2} s ({:.1} M/s), {pairs} readings; {counts}", n as f64 / s / 1e6);
}

/// A seeded stream of `iterations()` inputs into `input` (cleared each time):
/// noise with probability `noise` (`noise_bytes` long), else the next valid one
/// (`valid(rng, k, n_valid, input)`), mutated with probability 0.3; each goes to
/// `decode(k, input)`. The time it started, for the report.
fn hammer(
    seed: u64,
    noise: f64,
    noise_bytes: usize,
    mut valid: impl FnMut(&mut ChaCha8Rng, u64, u64, &mut Vec<u8>),
    mutate: fn(&mut ChaCha8Rng, &mut Vec<u8>),
    mut decode: impl FnMut(u64, &[u8]),
) -> Instant {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let started = Instant::now();
    let mut input = Vec::with_capacity(64);
    let mut n_valid = 0;
    for k in 0..iterations() {
        input.clear();
        if rng.random_bool(noise) {
            input.resize(rng.random_range(0..noise_bytes), 0);
            rng.fill_bytes(&mut input);
        } else {
            valid(&mut rng, k, n_valid, &mut input);
            n_valid += 1;
            if rng.random_bool(0.3) {
                mutate(&mut rng, &mut input);
            }
        }
        decode(k, &input);
    }
    started
}

#[test]
fn random_and_mutated_frame_bytes() {
    let n = iterations();
    let mut d = FrameDecoder::new(codec());
    // Pure noise of any length around a frame's.
    let started = hammer(
        0x5eed_0001,
        0.2,
        2 * CAN_FRAME_BYTES,
        |rng, _, valid, buf| buf.extend_from_slice(&valid_frame(rng, valid).to_bytes()),
        mutate_bytes,
        |k, buf| match CanFrame::from_bytes(buf) {
            Ok(frame) => {
                if let Some(r) = d.push(&frame, k) {
                    assert!(r.at < k, "a reading is tagged with its first frame");
                }
            }
            Err(kind) => d.reject(kind),
        },
    );
    d.finish();
    let c = d.counts();
    report("frame bytes", n, d.pairs_out(), c, started);
    assert_eq!(d.frames_in(), n);
    assert_eq!(2 * d.pairs_out() + c.frames_rejected(), n, "{c}");
    // Every kind the byte path can produce was seen.
    for kind in [
        RejectKind::BadDlc,
        RejectKind::UnknownId,
        RejectKind::PairMismatch,
        RejectKind::Truncated,
        RejectKind::Garbage,
        RejectKind::OutOfRange,
        RejectKind::SequenceJump,
    ] {
        assert!(c.get(kind) > 0, "{kind} never seen: {c}");
    }
    // 80 % of the inputs are frames of the valid stream, 70 % of those unmutated.
    assert!(d.pairs_out() > n / 5, "the valid stream must mostly decode: {}", d.pairs_out());
}

#[test]
fn random_and_mutated_candump_lines() {
    let n = iterations();
    let mut log = CandumpDecoder::new(codec());
    let started = hammer(
        0x5eed_0002,
        0.1,
        48,
        |rng, k, valid, line| {
            let time = Timestamp { secs: 1_700_000_000 + k / 100_000, micros: (k % 100_000 * 10) as u32 };
            line.extend_from_slice(format_line(time, "can0", &valid_frame(rng, valid)).as_bytes());
        },
        mutate_text,
        // One line per input: a newline inside is not this input's.
        |_, line| {
            let line: Vec<u8> = line.iter().copied().filter(|b| *b != b'\n').collect();
            log.push_bytes(&line);
        },
    );
    log.finish();
    let c = log.counts();
    report("candump lines", n, log.pairs_out(), c, started);
    assert_eq!(log.lines_in(), n);
    assert_eq!(2 * log.pairs_out() + c.frames_rejected(), n, "{c}");
    for kind in RejectKind::ALL {
        assert!(c.get(kind) > 0, "{kind} never seen: {c}");
    }
}

#[test]
fn a_clean_stream_decodes_completely() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let n = iterations() / 10 * 2;
    let mut d = FrameDecoder::new(codec());
    let mut log = CandumpDecoder::new(codec());
    let mut readings = 0;
    for k in 0..n {
        let frame = valid_frame(&mut rng, k);
        let time = Timestamp { secs: k, micros: 0 };
        let a = d.push(&CanFrame::from_bytes(&frame.to_bytes()).unwrap(), ());
        let b = log.push_line(&format_line(time, "can0", &frame));
        assert_eq!(a.is_some(), b.is_some());
        if let (Some(a), Some(b)) = (a, b) {
            assert_eq!((a.force_counts, a.torque_counts, a.seq), (b.force_counts, b.torque_counts, b.seq));
            readings += 1;
        }
    }
    d.finish();
    log.finish();
    assert_eq!(readings, n / 2);
    assert_eq!(*d.counts(), Default::default());
    assert_eq!(*log.counts(), Default::default());
}
