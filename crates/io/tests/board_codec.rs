//! Throttle-board codec: round trips, every rejection kind, resynchronisation.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_io::board::{
    self, crc16, decode, encode, raw_frame, BoardStatus, Deframer, Frame, FrameError, Throttle, SYNC,
};
use proptest::prelude::*;

fn frames_of(bytes: &[u8]) -> (Vec<Frame>, board::Counters) {
    let mut d = Deframer::new();
    let mut frames = Vec::new();
    d.push(bytes, |f| frames.push(f));
    (frames, *d.counters())
}

/// A frame with a valid CRC over arbitrary type and payload.
fn any_throttle() -> impl Strategy<Value = Throttle> {
    (0..=Throttle::MAX_RAW).prop_map(|r| Throttle::from_raw(r).unwrap())
}

fn any_frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        (any::<u16>(), any_throttle()).prop_map(|(seq, throttle)| Frame::SetThrottle { seq, throttle }),
        any::<u16>().prop_map(|seq| Frame::Arm { seq }),
        any::<u16>().prop_map(|seq| Frame::Disarm { seq }),
        (any::<u16>(), any_throttle(), any::<u8>()).prop_map(|(seq, applied, flags)| Frame::Ack {
            seq,
            applied,
            flags
        }),
        (any::<u8>(), any_throttle(), any::<u32>(), any::<u32>(), any::<u32>()).prop_map(|(f, a, v, r, w)| {
            Frame::Status(BoardStatus { flags: f, applied: a, valid_frames: v, rejected_frames: r, watchdog_trips: w })
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    #[test]
    fn every_valid_frame_round_trips(frame in any_frame()) {
        let bytes = encode(&frame);
        prop_assert_eq!(decode(&bytes), Ok((frame, bytes.len())));
        let (frames, counters) = frames_of(&bytes);
        prop_assert_eq!(frames, vec![frame]);
        prop_assert_eq!(counters.rejected() + counters.garbage_bytes, 0);
    }

    #[test]
    fn frames_split_at_any_point_are_reassembled(frames in prop::collection::vec(any_frame(), 1..8), cut in any::<prop::sample::Index>()) {
        let stream: Vec<u8> = frames.iter().flat_map(encode).collect();
        let cut = cut.index(stream.len() + 1);
        let mut d = Deframer::new();
        let mut got = Vec::new();
        d.push(&stream[..cut], |f| got.push(f));
        d.push(&stream[cut..], |f| got.push(f));
        prop_assert_eq!(got, frames);
    }

    #[test]
    fn percent_survives_the_wire_to_0_01(pct in 0.0f64..=100.0) {
        let t = Throttle::from_pct(pct).unwrap();
        prop_assert!((t.pct() - pct).abs() <= 0.005 + 1e-12);
    }
}

#[test]
fn crc_is_ccitt_false_and_frames_are_little_endian() {
    assert_eq!(crc16(b"123456789"), 0x29B1);
    let bytes = encode(&Frame::SetThrottle { seq: 0x0102, throttle: Throttle::from_raw(4250).unwrap() });
    assert_eq!(&bytes[..7], &[0xA5, 0x01, 0x04, 0x02, 0x01, 0x9A, 0x10]);
    assert_eq!(u16::from_le_bytes([bytes[7], bytes[8]]), crc16(&bytes[1..7]));
}

#[test]
fn out_of_range_and_non_finite_throttles_cannot_be_encoded() {
    for bad in [-0.01, 100.01, f64::NAN, f64::INFINITY, -0.0 - 1.0] {
        assert_eq!(Throttle::from_pct(bad), None, "{bad}");
    }
    assert_eq!(Throttle::from_raw(10_001), None);
    assert_eq!(Throttle::from_pct(100.0).map(Throttle::raw), Some(10_000));
}

#[test]
fn each_rejection_kind_is_counted_and_the_next_frame_is_found() {
    let good = Frame::SetThrottle { seq: 5, throttle: Throttle::from_raw(3300).unwrap() };
    let mut bad_crc = encode(&good);
    bad_crc[4] ^= 0x40;
    type Count = fn(&board::Counters) -> u64;
    let cases: Vec<(&str, Vec<u8>, Count)> = vec![
        ("crc", bad_crc, |c| c.crc_errors),
        ("bad length (too long)", vec![SYNC, 0x01, 200, 1, 2, 3], |c| c.bad_length),
        ("bad length for type", raw_frame(0x01, &[1, 0, 0x10]), |c| c.bad_length),
        ("unknown type", raw_frame(0x44, &[1, 2, 3]), |c| c.unknown_type),
        ("out of range", raw_frame(0x01, &[1, 0, 0x11, 0x27]), |c| c.out_of_range), // 10001
        ("noise", vec![0x00, 0x13, 0xFF, 0x5A], |c| u64::from(c.garbage_bytes == 4)),
    ];
    for (what, junk, count) in cases {
        let mut stream = junk.clone();
        stream.extend(encode(&good));
        let (frames, c) = frames_of(&stream);
        assert_eq!(frames, vec![good], "{what}: the valid frame after it is recovered");
        assert_eq!(count(&c), 1, "{what}: {c:?}");
        assert_eq!(c.garbage_bytes, junk.len() as u64, "{what}: every junk byte is accounted for");
    }
}

#[test]
fn a_truncated_frame_is_counted_when_the_line_goes_quiet() {
    let good = encode(&Frame::Arm { seq: 1 });
    let mut d = Deframer::new();
    let mut frames = Vec::new();
    d.push(&good[..4], |f| frames.push(f));
    assert_eq!(d.pending(), 4);
    d.expire_partial(|f| frames.push(f));
    assert_eq!(d.counters().truncated, 1);
    assert_eq!(d.pending(), 0);
    d.push(&good, |f| frames.push(f));
    assert_eq!(frames, vec![Frame::Arm { seq: 1 }]);
    assert!(matches!(decode(&good[..6]), Err(FrameError::Truncated { have: 6, need: 7 })));
}
