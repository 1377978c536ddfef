//! The SocketCAN driver against a virtual CAN interface.
//!
//! Runs where the kernel has CAN and a vcan interface is up (`vcan0`, or the
//! one named in `JETBENCH_VCAN`):
//!
//! ```text
//! sudo modprobe vcan && sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0
//! ```
//!
//! Elsewhere it prints why it is skipped (e.g. this machine: the kernel has
//! no AF_CAN, so opening the socket fails with "Address family not supported
//! by protocol") and passes: live CAN cannot exist there.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::io::Write;
use std::time::Duration;

use jetbench_io::can::socketcan::SocketCan;
use jetbench_io::can::source::{CanForceSink, CanForceSource, CanInterface, CanTransport};
use jetbench_io::can::{CanFrame, Codec};
use jetbench_io::{ForceReading, ForceSink, ForceSource};

fn vcan() -> String {
    std::env::var("JETBENCH_VCAN").unwrap_or_else(|_| "vcan0".into())
}

/// Opens the vcan interface or says why it cannot.
fn open_or_skip(ifname: &str) -> Option<SocketCan> {
    match SocketCan::open(ifname) {
        Ok(s) => Some(s),
        Err(e) => {
            // Straight to stderr, past the test harness's capture, so the
            // reason shows in every run, not only with --nocapture.
            let _ = writeln!(std::io::stderr(), "SKIPPED: the SocketCAN test needs {ifname}: {e}");
            None
        }
    }
}

#[test]
fn socketcan_driver_round_trips_on_vcan() {
    let ifname = vcan();
    let Some(mut probe) = open_or_skip(&ifname) else { return };
    let interface = CanInterface::Kernel(ifname.clone());
    let codec = Codec::new(0x100).unwrap();
    let mut source = CanForceSource::open(&interface, codec).expect("open the listening socket");
    let mut sink = CanForceSink::open(&interface, codec).expect("open the sending socket");
    // A raw frame sent by one socket is received by the other (vcan loops back).
    probe.send(&CanFrame::standard(0x2a0, &[1, 2, 3]).unwrap()).unwrap();
    for k in 0..200u32 {
        let sent = ForceReading {
            force_n: [f64::from(k) * 0.5, 0.25, -0.01],
            torque_nm: [0.0, 0.001, -0.002],
            counter: k & 0xff,
            status: 0,
        };
        sink.emit(&sent, 0).unwrap();
        let r = source.read(Duration::from_secs(2)).unwrap().expect("reading over vcan");
        assert_eq!(r.counter, k & 0xff);
        assert!((r.force_n[0] - sent.force_n[0]).abs() < 1e-9);
        assert!((r.torque_nm[2] - sent.torque_nm[2]).abs() < 1e-9);
    }
    let c = *source.counts();
    assert_eq!((c.unknown_id, c.frames_rejected()), (1, 1), "{c}");
    // Silence: nothing for 30 ms is a timeout, not an error.
    assert_eq!(source.read(Duration::from_millis(30)).unwrap(), None);
    // A reopened socket keeps working.
    probe.reopen().unwrap();
    probe.send(&CanFrame::standard(0x2a1, &[0; 8]).unwrap()).unwrap();
    println!("SocketCAN on {ifname}: 200 readings round-tripped");
}

#[test]
fn a_missing_interface_is_a_clear_error() {
    let e = SocketCan::open("nosuchcan9").err().expect("no such interface").to_string();
    // Either reason names the interface and what to do.
    assert!(e.contains("nosuchcan9"), "{e}");
    assert!(e.contains("ip link") || e.contains("no CAN support") || e.contains("cannot open"), "{e}");
    println!("opening nosuchcan9: {e}");
}
