//! `jetbench can-decode FILE.log`: a `candump -l` capture of the force
//! sensor as CSV, with the same codec and calibration the sensing service uses.
//!
//! stdout: `time_s,fx_n,fy_n,fz_n,tx_nm,ty_nm,tz_nm,thrust_n`, one row per
//! force/torque pair (time of its first frame; forces with 2 decimals and
//! torques with 3, the sensor's resolution, so with the identity calibration
//! every encoded value reads back exactly). stderr: rejection counts by kind.
//! Garbage in the log is counted, never fatal: the exit status is 0 whenever
//! the file could be read.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetbench_io::calib::Calibration;
use jetbench_io::can::{Codec, RejectKind, DEFAULT_BASE_ID};
use jetbench_io::candump::CandumpDecoder;
use jetbench_stack::config::{Axis, BenchConfig};

#[derive(clap::Args)]
pub struct CanDecodeArgs {
    /// `candump -l` log: lines `(seconds.micros) can0 ID#HEXDATA`.
    file: PathBuf,
    /// Bench config for the base ID, calibration, tare and thrust axis
    /// (default: base 0x100, identity calibration, no tare, thrust on x).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
}

/// `value` with `decimals` decimals, never `-0.00`.
fn fixed(value: f64, decimals: usize) -> String {
    let s = format!("{value:.decimals$}");
    match s.strip_prefix('-') {
        Some(rest) if rest.bytes().all(|b| b == b'0' || b == b'.') => rest.to_string(),
        _ => s,
    }
}

pub fn run(args: CanDecodeArgs) -> anyhow::Result<ExitCode> {
    let (codec, calibration, axis) = match &args.config {
        Some(path) => {
            let config = BenchConfig::load(path)?;
            let s = &config.sensor;
            (s.codec()?, s.calibration()?, s.thrust_axis)
        }
        None => (Codec::new(DEFAULT_BASE_ID)?, Calibration::identity(), Axis::X),
    };
    let file = std::fs::File::open(&args.file).with_context(|| format!("cannot open {}", args.file.display()))?;
    let mut reader = BufReader::new(file);
    let mut decoder = CandumpDecoder::new(codec);
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    writeln!(out, "time_s,fx_n,fy_n,fz_n,tx_nm,ty_nm,tz_nm,thrust_n")?;
    let mut line = Vec::new();
    loop {
        line.clear();
        let n = reader.read_until(b'\n', &mut line).with_context(|| format!("cannot read {}", args.file.display()))?;
        if n == 0 {
            break;
        }
        if line.last() == Some(&b'\n') {
            line.pop();
        }
        if let Some(r) = decoder.push_bytes(&line) {
            let c = calibration.apply(&r.physical());
            // Forces to 0.01 N and torques to 0.001 N·m: the sensor's resolution.
            let wrench: Vec<String> = c.iter().enumerate().map(|(i, v)| fixed(*v, if i < 3 { 2 } else { 3 })).collect();
            writeln!(out, "{},{},{}", r.at, wrench.join(","), fixed(c[axis.index()], 2))?;
        }
    }
    decoder.finish();
    out.flush()?;
    let counts = decoder.counts();
    let mut err = std::io::stderr().lock();
    writeln!(
        err,
        "can-decode: {} lines, {} force/torque pairs, {} lines rejected (base ID {:#x})",
        decoder.lines_in(),
        decoder.pairs_out(),
        counts.frames_rejected(),
        codec.base_id()
    )?;
    writeln!(err, "rejected by kind:")?;
    for kind in RejectKind::ALL {
        let note = if kind == RejectKind::SequenceJump { " (events, not lines)" } else { "" };
        writeln!(err, "  {:<14} {}{note}", kind.name(), counts.get(kind))?;
    }
    writeln!(err, "  {:<14} {}", "lost_pairs", counts.lost_pairs)?;
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::fixed;

    #[test]
    fn fixed_point_without_negative_zero() {
        assert_eq!(fixed(-0.004, 2), "0.00");
        assert_eq!(fixed(-327.67, 2), "-327.67");
        assert_eq!(fixed(0.001 * 12.0, 3), "0.012");
        // Every i16 count prints back exactly at 0.01 N.
        for c in [i16::MIN, -12345, -1, 0, 1, 9999, i16::MAX] {
            let s = fixed(f64::from(c) * 0.01, 2);
            assert_eq!((s.parse::<f64>().unwrap() * 100.0).round() as i16, c, "{s}");
        }
    }
}
