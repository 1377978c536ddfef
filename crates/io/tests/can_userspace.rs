//! The userspace CAN bus end to end within one process: a simulated sensor
//! (sender) and the sensing side (listener) exchanging real 16-byte frames
//! over Unix datagrams, decoded by the bench's codec. Silence, resumption and
//! a vanished socket are exercised; hangs are bounded by loop limits, and no
//! test asserts a runtime.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::os::unix::net::UnixDatagram;
use std::time::Duration;

use jetbench_io::can::source::{CanForceSink, CanForceSource, CanInterface};
use jetbench_io::can::userspace::bus_dir;
use jetbench_io::can::{CanFrame, Codec};
use jetbench_io::{ForceReading, ForceSink, ForceSource};

fn bus(tag: &str) -> CanInterface {
    CanInterface::userspace(&format!("t{}{tag}", std::process::id()), "iotest")
}

fn reading(k: u32) -> ForceReading {
    ForceReading {
        force_n: [f64::from(k) * 0.25, -1.5, 0.01],
        torque_nm: [0.001, -0.002, f64::from(k) * 0.003],
        counter: k & 0xff,
        status: 0,
    }
}

fn pair(interface: &CanInterface) -> (CanForceSource, CanForceSink) {
    let codec = Codec::new(0x100).unwrap();
    let source = CanForceSource::open(interface, codec).expect("listen");
    let sink = CanForceSink::open(interface, codec).expect("send");
    (source, sink)
}

/// Sends reading `k` until the source yields a reading (at most `tries` times).
fn deliver(source: &mut CanForceSource, sink: &mut CanForceSink, k: u32, tries: usize) -> Option<ForceReading> {
    for _ in 0..tries {
        sink.emit(&reading(k), 0).unwrap();
        if let Some(r) = source.read(Duration::from_millis(20)).unwrap() {
            return Some(r);
        }
    }
    None
}

#[test]
fn frames_arrive_exactly_and_in_order() {
    let interface = bus("a");
    let (mut source, mut sink) = pair(&interface);
    for k in 0..600u32 {
        sink.emit(&reading(k), 0).unwrap();
        let r = source.read(Duration::from_secs(5)).unwrap().expect("a reading within the watchdog");
        let want = reading(k);
        assert_eq!(r.counter, k & 0xff);
        for i in 0..3 {
            assert!((r.force_n[i] - want.force_n[i]).abs() < 0.005 + 1e-9, "k={k} axis {i}");
            assert!((r.torque_nm[i] - want.torque_nm[i]).abs() < 0.0005 + 1e-9);
        }
    }
    assert_eq!(*source.counts(), Default::default(), "600 readings, no rejection");
    assert_eq!(source.frames_and_pairs(), (1200, 600));
}

#[test]
fn garbage_on_the_bus_is_counted_by_kind() {
    let interface = bus("b");
    let (mut source, mut sink) = pair(&interface);
    // Datagrams that are not frames, sent straight to the listener's socket.
    let raw = UnixDatagram::unbound().unwrap();
    let dir = match &interface {
        CanInterface::Userspace { name, namespace } => bus_dir(namespace, name).unwrap(),
        CanInterface::Kernel(_) => unreachable!(),
    };
    let listener = std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.path()).next().expect("listener socket");
    raw.send_to(&[1, 2, 3], &listener).unwrap(); // truncated
    raw.send_to(&[0; 20], &listener).unwrap(); // garbage (not 16 bytes)
    let mut bad_len = CanFrame::standard(0x101, &[0; 8]).unwrap().to_bytes();
    bad_len[4] = 12;
    raw.send_to(&bad_len, &listener).unwrap(); // bad DLC
    sink.send_raw(&CanFrame::standard(0x101, &[0; 7]).unwrap()).unwrap(); // bad DLC
    sink.send_raw(&CanFrame::standard(0x2a0, &[0; 8]).unwrap()).unwrap(); // unknown ID
    sink.send_raw(&CanFrame { id: 0x101 | jetbench_io::can::CAN_EFF_FLAG, len: 8, data: [0; 8] }).unwrap(); // out of range
    let r = deliver(&mut source, &mut sink, 5, 100).expect("the good reading after the garbage");
    assert_eq!(r.counter, 5);
    let c = *source.counts();
    assert_eq!((c.truncated, c.garbage, c.bad_dlc, c.unknown_id, c.out_of_range), (1, 1, 2, 1, 1), "{c}");
    assert_eq!(source.rejected(), 6);
}

#[test]
fn silence_is_seen_within_three_cycles_and_the_sensor_resumes() {
    let interface = bus("c");
    let (mut source, mut sink) = pair(&interface);
    for k in 0..10 {
        assert_eq!(deliver(&mut source, &mut sink, k, 100).map(|r| r.counter), Some(k));
    }
    // The sensor goes quiet: a read with a 3-cycle (30 ms) deadline says so.
    assert_eq!(source.read(Duration::from_millis(30)).unwrap(), None);
    assert_eq!(source.read(Duration::from_millis(30)).unwrap(), None);
    // It comes back 50 readings later; the same source (nothing reopened by hand) gets it.
    let r = deliver(&mut source, &mut sink, 60, 100).expect("frames resume");
    assert_eq!(r.counter, 60);
    let c = *source.counts();
    assert_eq!((c.sequence_jump, c.lost_pairs, c.frames_rejected()), (1, 50, 0), "{c}");
}

#[test]
fn a_vanished_socket_is_bound_again() {
    let interface = bus("d");
    let (mut source, mut sink) = pair(&interface);
    assert!(deliver(&mut source, &mut sink, 0, 100).is_some());
    // Someone cleans the temp folder under the running stack.
    let CanInterface::Userspace { name, namespace } = &interface else { unreachable!() };
    std::fs::remove_dir_all(bus_dir(namespace, name).unwrap()).unwrap();
    // The listener notices on its next quiet read and binds again; the
    // sender re-lists the bus and reaches it.
    let mut back = None;
    for k in 1..500 {
        let _ = source.read(Duration::from_millis(5)).unwrap();
        if let Some(r) = deliver(&mut source, &mut sink, k, 1) {
            back = Some(r);
            break;
        }
    }
    let r = back.expect("frames reach the re-bound listener");
    assert!(r.counter >= 1);
}
