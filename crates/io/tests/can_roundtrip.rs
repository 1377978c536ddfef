//! Property tests: every valid sensor frame survives encode → decode, as
//! frames, as `struct can_frame` bytes and as candump lines.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_io::can::{CanFrame, Codec, FrameDecoder, PartKind, SensorPart};
use jetbench_io::candump::{format_line, parse_line, CandumpDecoder, Timestamp};
use proptest::prelude::*;

fn part() -> impl Strategy<Value = SensorPart> {
    (any::<bool>(), any::<[i16; 3]>(), any::<u8>(), any::<u8>()).prop_map(|(torque, counts, seq, status)| SensorPart {
        kind: if torque { PartKind::Torque } else { PartKind::Force },
        counts,
        seq,
        status,
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    #[test]
    fn every_valid_frame_round_trips(part in part(), base in 0u16..=0x7fd) {
        let codec = Codec::new(base).unwrap();
        let frame = codec.encode_part(&part);
        prop_assert_eq!(codec.decode(&frame), Ok(part));
        prop_assert_eq!(CanFrame::from_bytes(&frame.to_bytes()), Ok(frame));
        let time = Timestamp { secs: 1_700_000_000, micros: 123_456 };
        let line = format_line(time, "can0", &frame);
        let parsed = parse_line(&line).unwrap();
        prop_assert_eq!((parsed.time, parsed.interface, parsed.frame), (time, "can0", frame));
    }

    #[test]
    fn every_valid_pair_decodes_to_its_counts(
        force in any::<[i16; 3]>(), torque in any::<[i16; 3]>(), seq in any::<u8>(), status in any::<u8>(),
        torque_first in any::<bool>(), secs in 0u64..4_000_000_000, micros in 0u32..1_000_000,
    ) {
        let codec = Codec::new(0x100).unwrap();
        let [f, t] = codec.encode(force, torque, seq, status);
        let (a, b) = if torque_first { (t, f) } else { (f, t) };
        let mut d = FrameDecoder::new(codec);
        prop_assert!(d.push(&a, 1).is_none());
        let r = d.push(&b, 2).unwrap();
        prop_assert_eq!((r.force_counts, r.torque_counts, r.seq, r.status, r.at), (force, torque, seq, status, 1));
        // Physical units: exactly counts × LSB.
        let p = r.physical();
        for i in 0..3 {
            prop_assert_eq!(p.force_n[i], f64::from(force[i]) * 0.01);
            prop_assert_eq!(p.torque_nm[i], f64::from(torque[i]) * 0.001);
        }
        // And through a candump log.
        let time = Timestamp { secs, micros };
        let mut log = CandumpDecoder::new(codec);
        prop_assert!(log.push_line(&format_line(time, "can0", &a)).is_none());
        let r = log.push_line(&format_line(time, "can0", &b)).unwrap();
        prop_assert_eq!((r.force_counts, r.torque_counts, r.at), (force, torque, time));
    }

    #[test]
    fn quantised_readings_come_back_within_half_a_count(
        f in prop::array::uniform3(-327.0f64..327.0), t in prop::array::uniform3(-32.0f64..32.0), counter in 0u32..256,
    ) {
        let codec = Codec::new(0x100).unwrap();
        let reading = jetbench_io::ForceReading { force_n: f, torque_nm: t, counter, status: 0 };
        let [a, b] = codec.encode_reading(&reading).unwrap();
        let mut d = FrameDecoder::new(codec);
        d.push(&a, ());
        let back = d.push(&b, ()).unwrap().physical();
        for i in 0..3 {
            prop_assert!((back.force_n[i] - f[i]).abs() <= 0.005 + 1e-9, "{} vs {}", back.force_n[i], f[i]);
            prop_assert!((back.torque_nm[i] - t[i]).abs() <= 0.0005 + 1e-9);
        }
        prop_assert_eq!((back.counter, back.status), (counter, 0));
    }
}
