//! The SocketCAN path for real, in a kernel that has CAN: each test runs
//! itself again inside Debian's user-mode Linux kernel (scripts/uml-can.sh:
//! the host's filesystem as root, the CAN modules loaded, vcan0 up), so the
//! frames travel through the kernel's own CAN stack, `candump`, `cansend`,
//! `cangen` and `slcand` (can-utils) are the real tools, and `jetbench up`
//! runs its real processes over `vcan0`.
//!
//! On the host each test boots a guest (about 2 s) with this test binary as
//! its command, filtered to the one test, and asserts that it ran there and
//! passed; inside the guest (`JETBENCH_IN_UML` set) the test's body runs. The
//! tests skip, printing why, only where user-mode-linux cannot be installed.
//! Hangs are caught by watchdogs (the guest's and each child's); no runtime
//! is asserted.

use std::io::{Read, Write};
use std::os::fd::{FromRawFd, OwnedFd};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use jetbench_io::can::source::{CanForceSink, CanForceSource, CanInterface};
use jetbench_io::can::{CanFrame, Codec, RejectCounts};
use jetbench_io::{ForceReading, ForceSink, ForceSource};
use jetbench_msgs::channels;
use jetbench_record::{seq_gaps, Recording};

mod common;

const SUITE: &str = "cankernel";
/// Set inside the guest: the test's body runs there.
const IN_GUEST: &str = "JETBENCH_IN_UML";
/// scripts/uml-can.sh's status when user-mode-linux cannot be installed.
const SKIP: i32 = 77;

/// One guest at a time: two cores are not enough for more.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// On the host: runs test `name` of this binary inside the guest, asserts it
/// passed there, and returns false (nothing more to do here). Inside the
/// guest: returns true, so the caller runs the test's body.
fn inside_guest(name: &str, limit: Duration) -> bool {
    if std::env::var_os(IN_GUEST).is_some() {
        return true;
    }
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let exe = std::env::current_exe().expect("this test binary");
    let mut command = Command::new(common::repo_root().join("scripts/uml-can.sh"));
    command
        .arg(exe)
        .args(["--exact", name, "--nocapture", "--test-threads", "1"])
        .env(IN_GUEST, "1")
        .env("UML_CAN_TIMEOUT", limit.as_secs().to_string())
        .env("IOX2_LOG_LEVEL", "Error");
    let started = Instant::now();
    // The guest has its own timeout; this watchdog catches a hang of the script itself.
    let (status, out, err) = common::run(&mut command, limit + Duration::from_secs(30), "the user-mode kernel");
    if status.code() == Some(SKIP) {
        let _ = writeln!(std::io::stderr(), "SKIPPED {name}: {}", err.trim());
        return false;
    }
    println!("{out}\n{err}");
    println!("{name}: the guest ran for {:.1} s", started.elapsed().as_secs_f64());
    assert!(status.success(), "{name} failed inside the user-mode kernel ({status}):\n{out}\n{err}");
    assert!(out.contains("1 passed"), "{name} did not run inside the guest:\n{out}\n{err}");
    false
}

fn codec() -> Codec {
    Codec::new(0x100).expect("base id")
}

fn vcan0() -> CanInterface {
    CanInterface::Kernel("vcan0".into())
}

/// Runs a shell command line inside the guest to completion; panics on failure.
fn sh(line: &str) -> String {
    let (status, out, err) = common::run(Command::new("sh").args(["-c", line]), Duration::from_secs(30), line);
    assert!(status.success(), "`{line}` failed ({status}):\n{out}\n{err}");
    out
}

/// Reads readings until `n` arrived or `limit` passed.
fn read_n(source: &mut CanForceSource, n: usize, limit: Duration) -> Vec<ForceReading> {
    let deadline = Instant::now() + limit;
    let mut got = Vec::new();
    while got.len() < n && Instant::now() < deadline {
        if let Some(r) = source.read(Duration::from_millis(100)).expect("read") {
            got.push(r);
        }
    }
    got
}

/// Drains whatever is still on the wire, counting it, until 200 ms of silence.
fn drain(source: &mut CanForceSource) -> Vec<ForceReading> {
    let mut got = Vec::new();
    while let Some(r) = source.read(Duration::from_millis(200)).expect("read") {
        got.push(r);
    }
    got
}

fn reading(k: u32) -> ForceReading {
    ForceReading {
        force_n: [f64::from(k) * 0.25 - 40.0, 1.5, -0.03],
        torque_nm: [0.002, -0.001 * f64::from(k % 7), 0.125],
        counter: k & 0xff,
        status: k % 3,
    }
}

fn assert_same(got: &ForceReading, want: &ForceReading) {
    assert_eq!((got.counter, got.status), (want.counter, want.status));
    for i in 0..3 {
        assert!((got.force_n[i] - want.force_n[i]).abs() < 1e-9, "force {i}: {got:?} vs {want:?}");
        assert!((got.torque_nm[i] - want.torque_nm[i]).abs() < 1e-9, "torque {i}: {got:?} vs {want:?}");
    }
}

#[test]
fn frames_from_cansend_and_our_sink_are_decoded_exactly_and_bad_frames_counted() {
    if !inside_guest(
        "frames_from_cansend_and_our_sink_are_decoded_exactly_and_bad_frames_counted",
        Duration::from_secs(60),
    ) {
        return;
    }
    let mut source = CanForceSource::open(&vcan0(), codec()).expect("open vcan0");
    assert_eq!(source.describe(), "force/torque sensor (CAN base 0x100) on SocketCAN vcan0");

    // One pair written by hand in the sensor's format: forces 4000, -1234, 7
    // counts (0.01 N), torques 12, -5, 300 counts (0.001 N·m), sequence 9.
    sh("cansend vcan0 101#A00F2EFB07000900 && cansend vcan0 102#0C00FBFF2C010900");
    let got = read_n(&mut source, 1, Duration::from_secs(5));
    assert_eq!(got.len(), 1, "the hand-written pair");
    assert_same(
        &got[0],
        &ForceReading { force_n: [40.0, -12.34, 0.07], torque_nm: [0.012, -0.005, 0.3], counter: 9, status: 0 },
    );

    // 300 readings from the simulated sensor's end (sim-bench's code), in order.
    let mut sink = CanForceSink::open(&vcan0(), codec()).expect("open the sending socket");
    let reader = std::thread::spawn(move || {
        let got = read_n(&mut source, 300, Duration::from_secs(20));
        (source, got)
    });
    for k in 0..300 {
        sink.emit(&reading(k), 0).expect("send");
        // 1 ms apart, ten times the sensor's rate: a burst would overrun the
        // reader's socket buffer in this slow guest kernel (frames are then
        // lost in the kernel, which is not what this test is about).
        std::thread::sleep(Duration::from_millis(1));
    }
    let (mut source, got) = reader.join().expect("reader");
    assert_eq!(got.len(), 300, "every reading arrived");
    for (k, r) in got.iter().enumerate() {
        assert_same(r, &reading(k as u32));
    }
    assert_eq!(source.counts().frames_rejected(), 0, "{}", source.counts());

    // Bad frames on the wire, each counted by kind, none decoded:
    // 50 frames of another node, 20 sensor frames of length 5, 10 extended
    // frames and one remote frame on the sensor's identifier.
    sh("cangen vcan0 -I 2A0 -L 8 -n 50 -g 1 && cangen vcan0 -I 101 -L 5 -n 20 -g 1 \
        && cangen vcan0 -e -I 101 -L 8 -n 10 -g 1 && cansend vcan0 102#R");
    // Read them before more arrive: a socket holds a few hundred frames, and
    // this test is about counting, not about the kernel dropping frames.
    let mut decoded = drain(&mut source);
    // Then random traffic from cangen: every frame is counted somewhere.
    sh("cangen vcan0 -I r -L r -D r -n 100 -g 1");
    decoded.extend(drain(&mut source));
    let c: RejectCounts = *source.counts();
    println!("after the bad and random frames: {c}; {} pairs decoded from random traffic", decoded.len());
    assert!(c.unknown_id >= 50, "{c}");
    assert!(c.bad_dlc >= 20, "{c}");
    assert!(c.out_of_range >= 11, "{c}");
    let (frames, pairs) = source.frames_and_pairs();
    // 2 hand-written + 600 from the sink + 81 bad + 100 random frames.
    assert_eq!(frames, 2 + 600 + 81 + 100, "frames received");
    assert_eq!(pairs, 301 + decoded.len() as u64);
    // Every frame is part of a pair or rejected once (a force frame still
    // waiting for its torque frame is neither yet).
    let unpaired = frames - 2 * pairs - c.frames_rejected();
    assert!(unpaired <= 1, "frames unaccounted for: {unpaired} ({c})");
}

/// Starts `candump -L vcan0` writing to a file; returns once it hears frames.
// The child is returned: the caller kills and waits for it.
#[allow(clippy::zombie_processes)]
fn start_candump(log: &std::path::Path) -> Child {
    let child = Command::new("candump")
        .args(["-L", "vcan0"])
        .stdout(std::fs::File::create(log).expect("candump log"))
        .stderr(Stdio::null())
        .spawn()
        .expect("start candump");
    // candump has no ready signal: send a marker until it shows in the log.
    let mut marker = CanForceSink::open(&vcan0(), codec()).expect("marker socket");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        marker.send_raw(&CanFrame::standard(0x7ff, &[0xaa]).expect("frame")).expect("marker");
        std::thread::sleep(Duration::from_millis(50));
        if std::fs::read_to_string(log).unwrap_or_default().contains("7FF#AA") {
            return child;
        }
        if Instant::now() > deadline {
            let mut child = child;
            let _ = child.kill();
            let _ = child.wait();
            panic!("candump never heard the marker");
        }
    }
}

#[test]
fn candump_sees_exactly_our_frames_byte_for_byte() {
    if !inside_guest("candump_sees_exactly_our_frames_byte_for_byte", Duration::from_secs(60)) {
        return;
    }
    let log = PathBuf::from("/tmp/candump.log");
    let mut candump = start_candump(&log);
    let mut sink = CanForceSink::open(&vcan0(), codec()).expect("open vcan0");
    let mut want = Vec::new();
    for k in 0..200 {
        let r = reading(k);
        for frame in codec().encode_reading(&r).expect("encode") {
            want.push(format!("vcan0 {:03X}#{}", frame.id, hex(frame.data())));
        }
        sink.emit(&r, 0).expect("send");
        std::thread::sleep(Duration::from_millis(1));
    }
    sink.send_raw(&CanFrame::standard(0x7fe, &[0x55]).expect("frame")).expect("end marker");
    let deadline = Instant::now() + Duration::from_secs(10);
    while !std::fs::read_to_string(&log).unwrap_or_default().contains("7FE#55") {
        assert!(Instant::now() < deadline, "candump never heard the end marker");
        std::thread::sleep(Duration::from_millis(20));
    }
    candump.kill().expect("stop candump");
    candump.wait().expect("candump");
    let text = std::fs::read_to_string(&log).expect("candump log");
    // Lines look like "(1795640918.105661) vcan0 101#A00F2EFB07000900".
    let seen: Vec<&str> = text
        .lines()
        .filter_map(|l| l.split_once(") ").map(|(_, rest)| rest))
        .filter(|f| !f.contains("7FF#") && !f.contains("7FE#"))
        .collect();
    assert_eq!(seen.len(), want.len(), "frame count");
    for (i, (s, w)) in seen.iter().zip(&want).enumerate() {
        assert_eq!(s, w, "frame {i}");
    }
    // And the project's own candump reader decodes the log back to the readings.
    let mut decoder = jetbench_io::candump::CandumpDecoder::new(codec());
    let readings: Vec<_> = text.lines().filter_map(|l| decoder.push_line(l)).collect();
    assert_eq!(readings.len(), 200);
    for (k, r) in readings.iter().enumerate() {
        assert_same(&r.physical(), &reading(k as u32));
    }
    println!("candump agrees on {} frames", seen.len());
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

/// Sends a reading every 5 ms on vcan0 until told to stop; returns how many it sent.
fn steady_sender(stop: std::sync::Arc<std::sync::atomic::AtomicBool>) -> std::thread::JoinHandle<u32> {
    std::thread::spawn(move || {
        let mut sink = CanForceSink::open(&vcan0(), codec()).expect("open the sending socket");
        let mut k = 0;
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            // A down interface loses the frames (the sender reopens as well).
            let _ = sink.emit(&reading(k), 0);
            k += 1;
            std::thread::sleep(Duration::from_millis(5));
        }
        k
    })
}

#[test]
fn a_downed_or_removed_interface_is_reopened_and_sensing_resumes() {
    if !inside_guest("a_downed_or_removed_interface_is_reopened_and_sensing_resumes", Duration::from_secs(90)) {
        return;
    }
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let sender = steady_sender(stop.clone());
    let mut source = CanForceSource::open(&vcan0(), codec()).expect("open vcan0");
    assert_eq!(read_n(&mut source, 50, Duration::from_secs(10)).len(), 50, "readings before");

    // Taken down for 500 ms (an adapter reset), then the interface removed
    // and created again (an adapter unplugged and plugged back: a new index).
    for (what, down, up) in [
        ("down/up", "ip link set vcan0 down", "ip link set vcan0 up"),
        ("removed/added", "ip link del vcan0", "ip link add dev vcan0 type vcan && ip link set up vcan0"),
    ] {
        let before = source.link_stats();
        sh(down);
        let downed = Instant::now();
        // Silence while down: reads time out; nothing panics or errors.
        while downed.elapsed() < Duration::from_millis(500) {
            let _ = source.read(Duration::from_millis(20)).expect("a down link reads as silence");
        }
        let during = source.link_stats();
        sh(up);
        let upped = Instant::now();
        let got = read_n(&mut source, 20, Duration::from_secs(10));
        let back_ms = upped.elapsed().as_secs_f64() * 1e3;
        let after = source.link_stats();
        println!(
            "{what}: {before:?} -> {during:?} -> {after:?}; 20 readings {back_ms:.0} ms after the interface came back"
        );
        assert_eq!(got.len(), 20, "{what}: sensing resumed");
        assert!(during.errors > before.errors, "{what}: the error was seen: {during:?}");
        assert!(after.reopens > before.reopens, "{what}: the socket was reopened: {after:?}");
        // Reopened at most every 100 ms, plus scheduling on a busy machine.
        assert!(back_ms < 2000.0, "{what}: back after {back_ms:.0} ms");
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    assert!(sender.join().expect("sender") > 100);
}

/// A copy of config/sim.toml with the sensor on `interface`.
fn config_on(interface: &str) -> PathBuf {
    let text = std::fs::read_to_string(common::repo_root().join("config/sim.toml")).expect("config/sim.toml");
    let line = "can_interface = \"user:simcan0\"";
    assert!(text.contains(line), "config/sim.toml names the sensor's interface");
    let path = PathBuf::from(format!("/tmp/sim-{interface}.toml"));
    std::fs::write(&path, text.replace(line, &format!("can_interface = \"{interface}\""))).expect("config");
    path
}

#[test]
fn jetbench_up_over_vcan0_runs_at_100_hz_without_gaps() {
    if !inside_guest("jetbench_up_over_vcan0_runs_at_100_hz_without_gaps", Duration::from_secs(120)) {
        return;
    }
    let config = config_on("vcan0");
    let out = PathBuf::from("/tmp/up-vcan0.mcap");
    // candump alongside: the frames sim-bench puts on the kernel's bus.
    let log = PathBuf::from("/tmp/up-candump.log");
    let mut candump = start_candump(&log);
    let mut command = common::jetbench(SUITE);
    command
        .arg("up")
        .arg("--sim")
        .arg("--config")
        .arg(&config)
        .args(["--quiet", "--duration", "20", "--record"])
        .arg(&out);
    let (status, stdout, stderr) = common::run(&mut command, Duration::from_secs(90), "jetbench up over vcan0");
    candump.kill().expect("stop candump");
    candump.wait().expect("candump");
    assert!(status.success(), "jetbench up over vcan0 failed ({status}):\n{stdout}\n{stderr}");
    let log_text = format!("{stdout}\n{stderr}");
    assert!(log_text.contains("vcan0"), "the launcher names the interface:\n{log_text}");

    let recording = Recording::open(&out).expect("read the recording");
    let thrust = recording.samples(channels::THRUST);
    let span_s = (thrust.last().expect("samples").stamp_ns - thrust[0].stamp_ns) as f64 * 1e-9;
    let rate = (thrust.len() - 1) as f64 / span_s;
    let frame_gaps = thrust.windows(2).filter(|w| w[1].frame_seq != w[0].frame_seq + 1).count();
    println!(
        "over vcan0: {} thrust samples in {span_s:.2} s ({rate:.2} Hz), {} seq gaps, {frame_gaps} sensor frame gaps",
        thrust.len(),
        seq_gaps(&thrust)
    );
    for (name, n) in recording.counts() {
        println!("  {name}: {n}");
    }
    assert!(span_s > 19.0, "20 s recorded: {span_s:.2} s");
    assert!((rate - 100.0).abs() < 1.0, "100 Hz: {rate:.2} Hz");
    assert_eq!(seq_gaps(&thrust), 0, "thrust seq gaps");
    assert_eq!(frame_gaps, 0, "every sensor frame pair decoded");
    assert_eq!(seq_gaps(&recording.samples(channels::STATE)), 0, "state seq gaps");
    assert_eq!(seq_gaps(&recording.samples(channels::COMMAND)), 0, "command seq gaps");
    // The frames really went through the kernel: candump heard sim-bench's pairs.
    let text = std::fs::read_to_string(&log).expect("candump log");
    let force = text.lines().filter(|l| l.contains(" vcan0 101#")).count();
    let torque = text.lines().filter(|l| l.contains(" vcan0 102#")).count();
    println!("candump heard {force} force and {torque} torque frames");
    assert!(force >= thrust.len() && torque >= thrust.len(), "{force} {torque} vs {}", thrust.len());
}

/// A pseudo-terminal pair: the master (the adapter's side) and the slave's path.
fn pty() -> (std::fs::File, OwnedFd, String) {
    let (mut master, mut slave) = (-1, -1);
    // SAFETY: openpty writes two descriptors; null name, termios and winsize are allowed.
    let rc =
        unsafe { libc::openpty(&mut master, &mut slave, std::ptr::null_mut(), std::ptr::null(), std::ptr::null()) };
    assert_eq!(rc, 0, "openpty: {}", std::io::Error::last_os_error());
    // SAFETY: both descriptors were just opened and are owned from here on.
    let (master, slave) = unsafe { (std::fs::File::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    let path = std::fs::read_link(format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(&slave)))
        .expect("the slave's path")
        .to_string_lossy()
        .into_owned();
    (master, slave, path)
}

/// A frame in the slcan (Lawicel) serial format: `t`, 3 hex digits of
/// identifier, the length, the data in hex, carriage return.
fn slcan_line(frame: &CanFrame) -> String {
    format!("t{:03X}{}{}\r", frame.id, frame.len, hex(frame.data()))
}

#[test]
fn an_slcan_adapter_on_a_pseudo_terminal_is_read_the_same_way() {
    if !inside_guest("an_slcan_adapter_on_a_pseudo_terminal_is_read_the_same_way", Duration::from_secs(60)) {
        return;
    }
    let (mut adapter, _slave, tty) = pty();
    // slcand puts the slcan line discipline on the tty: the kernel's slcan0
    // is then a CAN interface whose frames travel as text on the serial line.
    // -o opens the channel, -s8 sets 1 Mbit/s, -F stays in the foreground.
    let mut slcand = Command::new("slcand")
        .args(["-o", "-s8", "-F", &tty, "slcan0"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start slcand");
    let deadline = Instant::now() + Duration::from_secs(10);
    while !std::path::Path::new("/sys/class/net/slcan0").exists() {
        assert!(Instant::now() < deadline, "slcand never made slcan0");
        std::thread::sleep(Duration::from_millis(20));
    }
    sh("ip link set up slcan0");
    // The adapter receives slcand's set-up commands first: bit rate, open.
    let mut setup = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    while !setup.ends_with(b"O\r") {
        assert!(Instant::now() < deadline, "no open command from slcand: {:?}", String::from_utf8_lossy(&setup));
        let mut byte = [0];
        adapter.read_exact(&mut byte).expect("read the adapter side");
        setup.push(byte[0]);
    }
    // slcand closes the channel first (C), sets 1 Mbit/s (S8) and opens it (O).
    assert_eq!(String::from_utf8_lossy(&setup), "C\rS8\rO\r", "slcand's set-up commands");

    let slcan0 = CanInterface::Kernel("slcan0".into());
    let mut source = CanForceSource::open(&slcan0, codec()).expect("open slcan0");
    let reader = std::thread::spawn(move || {
        let got = read_n(&mut source, 100, Duration::from_secs(20));
        (source, got)
    });
    // The adapter sends 100 readings, then a line the line discipline drops
    // and a frame of another node.
    for k in 0..100 {
        for frame in codec().encode_reading(&reading(k)).expect("encode") {
            adapter.write_all(slcan_line(&frame).as_bytes()).expect("write to the adapter side");
        }
    }
    let (mut source, got) = reader.join().expect("reader");
    assert_eq!(got.len(), 100, "every reading arrived over slcan0");
    for (k, r) in got.iter().enumerate() {
        assert_same(r, &reading(k as u32));
    }
    adapter.write_all(b"garbage\rt2A01FF\r").expect("write");
    assert!(drain(&mut source).is_empty());
    assert_eq!(source.counts().unknown_id, 1, "{}", source.counts());
    assert_eq!(source.counts().frames_rejected(), 1, "{}", source.counts());

    // And the other way: a frame sent on slcan0 reaches the adapter as text, byte for byte.
    let frames = codec().encode_reading(&reading(42)).expect("encode");
    let mut sink = CanForceSink::open(&slcan0, codec()).expect("open slcan0 to send");
    sink.emit(&reading(42), 0).expect("send on slcan0");
    let want: String = frames.iter().map(slcan_line).collect();
    let mut line = vec![0; want.len()];
    adapter.read_exact(&mut line).expect("read what slcan0 sent");
    assert_eq!(String::from_utf8_lossy(&line), want);
    println!("slcan0: 100 readings in, 2 frames out, byte for byte");

    let _ = slcand.kill();
    let _ = slcand.wait();
}
