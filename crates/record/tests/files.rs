//! Writing and reading recordings, including files cut off mid-write.

use jetbench_msgs::{channels, Command, Sample, Thrust};
use jetbench_record::{seq_gaps, spawn_writer, McapWriter, RawRecord, RecordError, Recording};

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("jetbench-record-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn thrust(seq: u64) -> Thrust {
    Thrust { seq, stamp_ns: 1_000 + seq * 10_000_000, thrust_n: seq as f64 * 0.5, ..Thrust::default() }
}

#[test]
fn samples_round_trip_through_a_file() {
    let path = scratch("round_trip.mcap");
    let mut w = McapWriter::create(&path).unwrap();
    for seq in 0..500 {
        w.write_sample(channels::THRUST, 5 + seq, &thrust(seq)).unwrap();
    }
    let c = Command { throttle_pct: 61.5, ..Command::default() };
    w.write_sample(channels::COMMAND, 10, &c).unwrap();
    assert_eq!(w.finish().unwrap(), 501);
    let r = Recording::open(&path).unwrap();
    assert!(!r.truncated);
    assert_eq!(r.samples(channels::THRUST), (0..500).map(thrust).collect::<Vec<_>>());
    assert_eq!(r.samples(channels::COMMAND), vec![c]);
    assert_eq!(r.malformed(channels::THRUST), 0);
    let m = r.messages.iter().find(|m| m.topic == "/bench/command").unwrap();
    assert_eq!(m.schema_name, "jetbench_msgs/msg/Command");
    assert_eq!(&m.data[..4], &[0, 1, 0, 0]);
}

#[test]
fn a_file_cut_off_mid_write_keeps_every_flushed_chunk() {
    let path = scratch("cut.mcap");
    let mut w = McapWriter::create(&path).unwrap();
    for seq in 0..300 {
        w.write_sample(channels::THRUST, seq, &thrust(seq)).unwrap();
    }
    w.flush().unwrap();
    for seq in 300..400 {
        w.write_sample(channels::THRUST, seq, &thrust(seq)).unwrap();
    }
    w.finish().unwrap();
    let full = std::fs::read(&path).unwrap();
    // Cut the file inside the summary, then inside the last chunk: a crashed recorder.
    for cut in [full.len() - 40, full.len() * 3 / 4] {
        let cut_path = scratch("cut_short.mcap");
        std::fs::write(&cut_path, &full[..cut]).unwrap();
        let r = Recording::open(&cut_path).unwrap();
        assert!(r.truncated, "a cut file must be flagged");
        let got = r.samples(channels::THRUST);
        assert!(got.len() >= 300, "lost flushed data: {} samples at cut {cut}", got.len());
        assert_eq!(got[..300], (0..300).map(thrust).collect::<Vec<_>>()[..]);
        assert_eq!(seq_gaps(&got), 0);
    }
}

#[test]
fn not_an_mcap_file_is_a_clear_error() {
    let path = scratch("data.csv");
    std::fs::write(&path, "time_s,throttle_pct,thrust_n\n0,25,0\n").unwrap();
    let e = Recording::open(&path).unwrap_err();
    assert!(matches!(e, RecordError::NotMcap { .. }), "{e}");
    assert!(e.to_string().contains("not an MCAP file"));
}

#[test]
fn the_writer_thread_writes_everything_queued() {
    let path = scratch("thread.mcap");
    let mut h = spawn_writer(&path, 64, vec![("run".into(), [("k".to_string(), "v".to_string())].into())]).unwrap();
    let mut sent = 0;
    for seq in 0..2000u64 {
        let t = thrust(seq);
        let record = RawRecord::new(channels::THRUST.name, seq, seq, t.stamp_ns, t.as_bytes()).unwrap();
        // A full queue is counted, never waited on; retry here so all land.
        while !h.send(record).unwrap() {
            std::thread::yield_now();
        }
        sent += 1;
    }
    let dropped = h.dropped_full;
    let stats = h.finish().unwrap();
    assert_eq!(stats.written, sent);
    let r = Recording::open(&path).unwrap();
    assert_eq!(r.samples(channels::THRUST).len(), 2000);
    assert_eq!(r.metadata["run"]["k"], "v");
    println!("queue was full {dropped} times");
    assert!(RawRecord::new("x", 0, 0, 0, &[0u8; 200]).is_none(), "oversized samples are refused");
}
