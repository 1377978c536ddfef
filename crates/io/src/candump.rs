//! `candump -l` logs: `(seconds.micros) can0 ID#HEXDATA`, one frame a line.
//!
//! [`parse_line`] turns a line into a timestamped [`CanFrame`] or a
//! [`RejectKind`]; [`CandumpDecoder`] runs lines through the sensor's
//! [`FrameDecoder`], so a capture from the bench decodes exactly as the live
//! frames did.
//!
//! ```
//! use jetbench_io::can::{Codec, DEFAULT_BASE_ID};
//! use jetbench_io::candump::CandumpDecoder;
//!
//! let mut log = CandumpDecoder::new(Codec::new(DEFAULT_BASE_ID).unwrap());
//! assert!(log.push_line("(1700000000.000100) can0 101#A00F000000000700").is_none());
//! let r = log.push_line("(1700000000.000200) can0 102#0000000000000700").unwrap();
//! assert_eq!((r.at.to_string().as_str(), r.force_counts[0]), ("1700000000.000100", 4000));
//! log.push_line("not a candump line");
//! assert_eq!(log.counts().garbage, 1);
//! ```
//!
//! What each defect counts as:
//! - not three fields (a fourth `R`/`T` direction field is allowed), no
//!   `(seconds.micros)`, no `#`, an ID of other than 3 or 8 hex digits, non-hex
//!   data, CAN FD (`ID##...`), invalid UTF-8: **garbage**;
//! - an odd number of data hex digits (a line cut mid-byte): **truncated**;
//! - more than 16 data hex digits (over 8 bytes): **bad DLC**, like a sensor
//!   frame of other than 8 bytes;
//! - an 8-digit (extended) ID, a 3-digit ID above `7FF`, a remote frame (`ID#R`): **out of range**;
//! - a well-formed frame of another ID: **unknown ID**.

use std::fmt;

use crate::can::{CanFrame, Codec, FrameDecoder, RejectCounts, RejectKind, SensorReading, CAN_EFF_FLAG, CAN_RTR_FLAG};

/// A candump timestamp, kept exact: whole seconds and microseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Timestamp {
    /// Whole seconds (candump `-L`: since the epoch).
    pub secs: u64,
    /// 0..1_000_000.
    pub micros: u32,
}

impl Timestamp {
    /// In seconds (rounded to the nearest `f64`).
    pub fn as_secs_f64(&self) -> f64 {
        self.secs as f64 + f64::from(self.micros) * 1e-6
    }
}

impl fmt::Display for Timestamp {
    /// `seconds.micros` with six digits, as candump writes it.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{:06}", self.secs, self.micros)
    }
}

/// One log line, parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LogFrame<'a> {
    /// When the kernel received the frame.
    pub time: Timestamp,
    /// The CAN interface it came in on, e.g. `vcan0`.
    pub interface: &'a str,
    /// The frame.
    pub frame: CanFrame,
}

fn hex_digit(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

fn parse_hex_u32(s: &str) -> Option<u32> {
    s.bytes().try_fold(0u32, |acc, c| Some(acc.checked_mul(16)? | u32::from(hex_digit(c)?)))
}

fn parse_time(s: &str) -> Option<Timestamp> {
    let inner = s.strip_prefix('(')?.strip_suffix(')')?;
    let (secs, frac) = inner.split_once('.')?;
    if secs.is_empty() || !secs.bytes().all(|c| c.is_ascii_digit()) {
        return None;
    }
    if frac.is_empty() || frac.len() > 6 || !frac.bytes().all(|c| c.is_ascii_digit()) {
        return None;
    }
    let secs = secs.parse().ok()?;
    // "(1.5)" is 1.500000 s.
    let micros = frac.parse::<u32>().ok()? * 10u32.pow(6 - frac.len() as u32);
    Some(Timestamp { secs, micros })
}

fn parse_frame(s: &str) -> Result<CanFrame, RejectKind> {
    let (id, data) = s.split_once('#').ok_or(RejectKind::Garbage)?;
    let mut can_id = match id.len() {
        3 => parse_hex_u32(id).ok_or(RejectKind::Garbage)?,
        8 => match parse_hex_u32(id).ok_or(RejectKind::Garbage)? {
            v if v > 0x1fff_ffff => return Err(RejectKind::OutOfRange),
            v => v | CAN_EFF_FLAG,
        },
        _ => return Err(RejectKind::Garbage),
    };
    if data.starts_with('#') {
        return Err(RejectKind::Garbage); // CAN FD
    }
    if let Some(rest) = data.strip_prefix('R') {
        // A remote frame, with an optional length digit.
        let len = match rest.as_bytes() {
            [] => 0,
            [d @ b'0'..=b'8'] => d - b'0',
            _ => return Err(RejectKind::Garbage),
        };
        can_id |= CAN_RTR_FLAG;
        return Ok(CanFrame { id: can_id, len, data: [0; 8] });
    }
    let digits = data.as_bytes();
    if !digits.iter().all(|c| hex_digit(*c).is_some()) {
        return Err(RejectKind::Garbage);
    }
    if digits.len() % 2 == 1 {
        return Err(RejectKind::Truncated);
    }
    if digits.len() > 16 {
        return Err(RejectKind::BadDlc);
    }
    let mut frame = CanFrame { id: can_id, len: (digits.len() / 2) as u8, data: [0; 8] };
    for (i, pair) in digits.chunks_exact(2).enumerate() {
        // Checked above: every digit is hex.
        frame.data[i] = (hex_digit(pair[0]).unwrap_or(0) << 4) | hex_digit(pair[1]).unwrap_or(0);
    }
    Ok(frame)
}

/// Parses one line (a trailing `\r` is ignored). Pure; never panics.
pub fn parse_line(line: &str) -> Result<LogFrame<'_>, RejectKind> {
    let line = line.strip_suffix('\r').unwrap_or(line);
    let mut fields = line.split_ascii_whitespace();
    let (Some(time), Some(interface), Some(frame)) = (fields.next(), fields.next(), fields.next()) else {
        return Err(RejectKind::Garbage);
    };
    match (fields.next(), fields.next()) {
        (None, _) | (Some("R" | "T"), None) => {}
        _ => return Err(RejectKind::Garbage),
    }
    let time = parse_time(time).ok_or(RejectKind::Garbage)?;
    let frame = parse_frame(frame)?;
    if frame.id & CAN_EFF_FLAG == 0 && frame.id & 0x1fff_ffff > crate::can::MAX_STANDARD_ID {
        // A 3-digit ID above 7FF: not a classic identifier.
        return Err(RejectKind::OutOfRange);
    }
    Ok(LogFrame { time, interface, frame })
}

/// Writes a frame as a `candump -l` line (no newline).
pub fn format_line(time: Timestamp, interface: &str, frame: &CanFrame) -> String {
    use fmt::Write;
    let mut s = String::with_capacity(48);
    let _ = write!(s, "({time}) {interface} ");
    if frame.id & CAN_EFF_FLAG != 0 {
        let _ = write!(s, "{:08X}#", frame.id & 0x1fff_ffff);
    } else {
        let _ = write!(s, "{:03X}#", frame.id & 0x7ff);
    }
    if frame.id & CAN_RTR_FLAG != 0 {
        s.push('R');
    } else {
        for b in frame.data() {
            let _ = write!(s, "{b:02X}");
        }
    }
    s
}

/// Decodes a candump log line by line into sensor readings.
#[derive(Clone, Debug)]
pub struct CandumpDecoder {
    decoder: FrameDecoder<Timestamp>,
}

impl CandumpDecoder {
    /// A decoder for the sensor `codec` describes (its IDs and scales).
    pub fn new(codec: Codec) -> Self {
        CandumpDecoder { decoder: FrameDecoder::new(codec) }
    }

    /// One line; a reading when the line completes a force/torque pair.
    pub fn push_line(&mut self, line: &str) -> Option<SensorReading<Timestamp>> {
        match parse_line(line) {
            Ok(f) => self.decoder.push(&f.frame, f.time),
            Err(kind) => {
                self.decoder.reject(kind);
                None
            }
        }
    }

    /// One line as bytes (without its `\n`); invalid UTF-8 is garbage.
    pub fn push_bytes(&mut self, line: &[u8]) -> Option<SensorReading<Timestamp>> {
        match std::str::from_utf8(line) {
            Ok(line) => self.push_line(line),
            Err(_) => {
                self.decoder.reject(RejectKind::Garbage);
                None
            }
        }
    }

    /// End of the log: a frame still waiting for its partner is a mismatch.
    pub fn finish(&mut self) {
        self.decoder.finish();
    }

    /// Lines rejected so far, by kind.
    pub fn counts(&self) -> &RejectCounts {
        self.decoder.counts()
    }

    /// Lines read.
    pub fn lines_in(&self) -> u64 {
        self.decoder.frames_in()
    }

    /// Readings decoded (force/torque pairs).
    pub fn pairs_out(&self) -> u64 {
        self.decoder.pairs_out()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_candump_line_exactly() {
        let f = parse_line("(1436509052.249713) can0 101#A00F0000FFFF0701").unwrap();
        assert_eq!(f.time, Timestamp { secs: 1436509052, micros: 249713 });
        assert_eq!(f.interface, "can0");
        assert_eq!(f.frame, CanFrame::standard(0x101, &[0xa0, 0x0f, 0, 0, 0xff, 0xff, 7, 1]).unwrap());
        assert_eq!(format_line(f.time, "can0", &f.frame), "(1436509052.249713) can0 101#A00F0000FFFF0701");
        assert_eq!(parse_line("(1.5) vcan0 101#\r").unwrap().time, Timestamp { secs: 1, micros: 500_000 });
        assert!(parse_line("(1.000001) can0 101#0011 T").is_ok());
    }

    #[test]
    fn each_line_defect_has_its_kind() {
        let cases = [
            ("", RejectKind::Garbage),
            ("hello world", RejectKind::Garbage),
            ("(1.0) can0", RejectKind::Garbage),
            ("1.0 can0 101#00", RejectKind::Garbage),
            ("(1.0000001) can0 101#00", RejectKind::Garbage),
            ("(1.0) can0 101", RejectKind::Garbage),
            ("(1.0) can0 1011#00", RejectKind::Garbage),
            ("(1.0) can0 10G#00", RejectKind::Garbage),
            ("(1.0) can0 101#0X", RejectKind::Garbage),
            ("(1.0) can0 101##100", RejectKind::Garbage),
            ("(1.0) can0 101#00 extra", RejectKind::Garbage),
            ("(1.0) can0 101#A00F0", RejectKind::Truncated),
            ("(1.0) can0 101#000102030405060708", RejectKind::BadDlc),
            ("(1.0) can0 FFFFFFFF#00", RejectKind::OutOfRange),
            ("(1.0) can0 801#0001020304050607", RejectKind::OutOfRange),
        ];
        for (line, kind) in cases {
            assert_eq!(parse_line(line).map(|_| ()), Err(kind), "{line:?}");
        }
        // Parsed but rejected by the sensor codec.
        let mut d = CandumpDecoder::new(Codec::new(0x100).unwrap());
        d.push_line("(1.0) can0 00000101#0001020304050607");
        d.push_line("(1.0) can0 101#R");
        d.push_line("(1.0) can0 101#00010203");
        d.push_line("(1.0) can0 123#0001020304050607");
        let c = d.counts();
        assert_eq!((c.out_of_range, c.bad_dlc, c.unknown_id), (2, 1, 1));
    }
}
