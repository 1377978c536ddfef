//! ECU line codec: round trips and every rejection kind.

use jetbench_io::ecu::{self, decode_line, encode_reply, EcuError, EcuReading, LineDecoder};
use proptest::prelude::*;

fn any_reading() -> impl Strategy<Value = EcuReading> {
    (0.0..=ecu::RPM_MAX, ecu::EGT_MIN_C..=ecu::EGT_MAX_C, 0.0..=ecu::PUMP_MAX_V, 0u32..=255, 0.0..=100.0)
        .prop_map(|(rpm, egt_c, pump_v, state, throttle_pct)| EcuReading { rpm, egt_c, pump_v, state, throttle_pct })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    /// Any valid reading, at full f64 precision, decodes to exactly itself.
    #[test]
    fn every_valid_line_round_trips(r in any_reading()) {
        let line = encode_reply(&r);
        prop_assert_eq!(decode_line(line.as_bytes()), Ok(r));
        let mut d = LineDecoder::new();
        let mut got = Vec::new();
        d.push(line.as_bytes(), |x| got.push(x));
        prop_assert_eq!(got, vec![r]);
        prop_assert_eq!(d.counters().lines, 1);
    }

    /// Replies on the grid the ECU prints (integer rpm, 0.1 °C, 0.01 V, 0.1 %).
    #[test]
    fn printed_grid_values_round_trip(rpm in 0u32..300_000, egt in -500i32..12_000, pump in 0u32..3000, state in 0u8..=255, t in 0u32..=1000) {
        let r = EcuReading { rpm: f64::from(rpm), egt_c: f64::from(egt) / 10.0, pump_v: f64::from(pump) / 100.0, state: u32::from(state), throttle_pct: f64::from(t) / 10.0 };
        prop_assert_eq!(decode_line(encode_reply(&r).as_bytes()), Ok(r));
    }
}

#[test]
fn each_rejection_kind_is_typed_and_counted() {
    type IsKind = fn(&EcuError) -> bool;
    let cases: &[(&str, IsKind)] = &[
        ("1,HS,ERR,3", |e| matches!(e, EcuError::Unknown(_))),
        ("1,RAC,1", |e| matches!(e, EcuError::Unknown(_))),
        ("1,HS,OK,61000,600.5", |e| matches!(e, EcuError::Truncated { fields: 5 })),
        ("1,HS", |e| matches!(e, EcuError::Truncated { fields: 2 })),
        ("1,HS,OK,61000,6x0.5,3.1,10,40", |e| matches!(e, EcuError::Garbled(_))),
        ("1,HS,OK,61000,600.5,3.1,10,40,7", |e| matches!(e, EcuError::Garbled(_))),
        ("1,HS,OK,6\u{1}1000,600.5,3.1,10,40", |e| matches!(e, EcuError::Garbled(_))),
        ("1,HS,OK,1e3,600.5,3.1,10,40", |e| matches!(e, EcuError::Garbled(_))),
        ("1,HS,OK,61000,600.5,3.1,10,140", |e| matches!(e, EcuError::OutOfRange { field: "throttle_pct", .. })),
        ("1,HS,OK,-5,600.5,3.1,10,40", |e| matches!(e, EcuError::OutOfRange { field: "rpm", .. })),
        ("1,HS,OK,61000,600.5,3.1,300,40", |e| matches!(e, EcuError::OutOfRange { field: "state", .. })),
        ("1,HS,OK,61000,NaN,3.1,10,40", |e| matches!(e, EcuError::NonFinite { field: "egt_c", .. })),
        ("1,HS,OK,inf,600.5,3.1,10,40", |e| matches!(e, EcuError::NonFinite { field: "rpm", .. })),
    ];
    let mut d = LineDecoder::new();
    for (line, is_kind) in cases {
        let e = decode_line(line.as_bytes()).expect_err(line);
        assert!(is_kind(&e), "{line}: {e:?}");
        d.push(format!("{line}\r").as_bytes(), |r| panic!("{line} decoded to {r:?}"));
    }
    let c = *d.counters();
    // `1,RAC,1` is not a reply, but in the stream it is the ECU's echo of the
    // poll: counted as an echo, not as a rejection.
    assert_eq!((c.unknown, c.truncated, c.garbled, c.out_of_range, c.non_finite), (1, 2, 4, 3, 2), "{c:?}");
    assert_eq!((c.lines, c.echoes), (0, 1));
}

#[test]
fn a_valid_line_after_noise_and_an_overlong_line_is_decoded() {
    let r = EcuReading { rpm: 70_000.0, egt_c: 640.2, pump_v: 2.4, state: 10, throttle_pct: 55.5 };
    let mut stream = vec![b'x'; 500];
    stream.push(b'\r');
    stream.extend(b"\r\n");
    stream.extend(encode_reply(&r).as_bytes());
    stream.push(b'\n');
    let mut d = LineDecoder::new();
    let mut got = Vec::new();
    d.push(&stream, |x| got.push(x));
    assert_eq!(got, vec![r]);
    assert_eq!(d.counters().garbled, 1, "the overlong line counts once");
    assert_eq!(d.counters().rejected(), 1, "blank lines are no errors");
}
