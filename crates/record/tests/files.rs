//! Writing and reading recordings, including files cut off mid-write.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_msgs::{channels, Command, Sample, Thrust};
use jetbench_record::recover::recover;
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

/// A recording the way a recorder killed mid-run leaves it: metadata, `flushed`
/// thrust samples in whole chunks, then `unflushed` more in a chunk cut off
/// while it was written (or nothing more, when `unflushed` is 0).
fn killed_recording(name: &str, flushed: u64, unflushed: u64) -> (std::path::PathBuf, Vec<u8>) {
    let path = scratch(name);
    let mut w = McapWriter::create(&path).unwrap();
    w.write_metadata("jetbench", [("config".to_string(), "[bench]".to_string())].into()).unwrap();
    for seq in 0..flushed {
        w.write_sample(channels::THRUST, seq, &thrust(seq)).unwrap();
        if seq % 100 == 99 {
            w.flush().unwrap();
        }
    }
    w.flush().unwrap();
    let flushed_len = std::fs::metadata(&path).unwrap().len() as usize;
    for seq in flushed..flushed + unflushed {
        w.write_sample(channels::THRUST, seq, &thrust(seq)).unwrap();
    }
    w.finish().unwrap();
    let full = std::fs::read(&path).unwrap();
    // The chunk in progress was on disk up to its header (and perhaps a little
    // compressed data) when the process died.
    let cut = if unflushed > 0 { flushed_len + 40 } else { flushed_len };
    std::fs::write(&path, &full[..cut]).unwrap();
    (path, full)
}

fn summary_of(path: &std::path::Path) -> mcap::Summary {
    let bytes = std::fs::read(path).unwrap();
    mcap::Summary::read(&bytes).unwrap().expect("a recovered file has a summary")
}

#[test]
fn recover_rewrites_a_killed_recording_whole_and_says_what_was_lost() {
    let (cut, _) = killed_recording("killed.mcap", 350, 40);
    let truncated = Recording::open(&cut).unwrap();
    assert!(truncated.truncated);
    assert_eq!(truncated.samples(channels::THRUST).len(), 350, "the flushed chunks are read directly");
    assert_eq!(truncated.metadata["jetbench"]["config"], "[bench]", "metadata of a file without a summary");

    let fixed = scratch("killed-fixed.mcap");
    let report = recover(&cut, &fixed).unwrap();
    assert_eq!(report.messages, 350);
    assert!(report.cut_data && report.data_lost(), "the chunk being written is lost: {report}");
    assert!(report.to_string().contains("cut off while it was written"), "{report}");
    let r = Recording::open(&fixed).unwrap();
    assert!(!r.truncated);
    assert_eq!(r.samples(channels::THRUST), (0..350).map(thrust).collect::<Vec<_>>());
    assert_eq!(r.metadata["jetbench"]["config"], "[bench]");
    let summary = summary_of(&fixed);
    assert!(!summary.chunk_indexes.is_empty(), "chunked and indexed");
    assert_eq!(summary.stats.map(|s| s.message_count), Some(350));
    assert_eq!(summary.metadata_indexes.len(), 1);

    // Killed between two chunks: nothing was lost.
    let (between, _) = killed_recording("between.mcap", 300, 0);
    let report = recover(&between, &scratch("between-fixed.mcap")).unwrap();
    assert_eq!((report.messages, report.data_lost()), (300, false), "{report}");
}

#[test]
fn recover_skips_a_damaged_chunk_and_keeps_the_rest() {
    let (_, full) = killed_recording("whole.mcap", 300, 0);
    // Find the second chunk record and scramble its compressed data.
    let mut damaged = full.clone();
    let mut at = 8;
    let mut chunks = Vec::new();
    while at + 9 <= damaged.len() {
        let len = u64::from_le_bytes(damaged[at + 1..at + 9].try_into().unwrap()) as usize;
        if damaged[at] == 0x06 {
            chunks.push((at, len));
        }
        if damaged[at] == 0x0f {
            break; // data end
        }
        at += 9 + len;
    }
    // Chunk 0 holds the schemas and channels (written before the metadata),
    // then one chunk per 100 messages.
    assert!(chunks.len() >= 4, "{} chunks", chunks.len());
    let (start, len) = chunks[2];
    for b in &mut damaged[start + len - 20..start + len] {
        *b ^= 0x5a;
    }
    let path = scratch("damaged.mcap");
    std::fs::write(&path, &damaged).unwrap();
    let fixed = scratch("damaged-fixed.mcap");
    let report = recover(&path, &fixed).unwrap();
    assert_eq!(report.damaged, 1, "{report}");
    assert!(report.data_lost());
    assert_eq!(report.messages, 200, "the two whole chunks of 100: {report}");
    let r = Recording::open(&fixed).unwrap();
    let seqs: Vec<u64> = r.samples(channels::THRUST).iter().map(|t| t.seq).collect();
    assert_eq!(seqs, (0..100).chain(200..300).collect::<Vec<_>>());

    // Damage where the channels are defined: their messages cannot be placed.
    let mut no_channels = full.clone();
    let (start, len) = chunks[0];
    no_channels[start + len - 10] ^= 0xff;
    std::fs::write(&path, &no_channels).unwrap();
    let report = recover(&path, &scratch("orphans-fixed.mcap")).unwrap();
    assert_eq!((report.damaged, report.orphaned, report.messages), (1, 300, 0), "{report}");

    // A whole file is complete: nothing to recover, nothing lost.
    let whole = scratch("complete.mcap");
    std::fs::write(&whole, &full).unwrap();
    let report = recover(&whole, &scratch("complete-fixed.mcap")).unwrap();
    assert!(report.complete && !report.data_lost(), "{report}");
    assert_eq!(report.messages, 300);

    let csv = scratch("not-mcap.csv");
    std::fs::write(&csv, "time_s,throttle_pct,thrust_n\n").unwrap();
    assert!(matches!(recover(&csv, &scratch("x.mcap")), Err(RecordError::NotMcap { .. })));
}

#[test]
fn a_full_disk_is_a_clear_error() {
    // /dev/full answers every write with ENOSPC, as a full disk does.
    let error = spawn_writer(std::path::Path::new("/dev/full"), 64, vec![]).err().expect("/dev/full is full");
    assert!(matches!(error, RecordError::DiskFull { .. }), "{error}");
    let text = error.to_string();
    assert!(text.contains("is full") && text.contains("jetbench recover"), "{text}");
}
