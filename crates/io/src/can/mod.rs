//! The force/torque sensor on CAN: frames, codec, pairing, transports.
//!
//! Wire contract (docs/io/README.md): classic frames, 11-bit IDs,
//! base ID configurable (default `0x100`), little-endian, DLC 8:
//! - `base+1`: Fx, Fy, Fz as `i16` at 0.01 N/LSB; byte 6 sequence counter; byte 7 status;
//! - `base+2`: Tx, Ty, Tz as `i16` at 0.001 N·m/LSB; byte 6 the same counter; byte 7 status.
//!
//! Decoding is a pure function from a [`CanFrame`] to a [`SensorPart`] or a
//! [`RejectKind`]; a [`FrameDecoder`] joins the force and torque parts of one
//! sequence number into a [`SensorReading`] and counts every rejection by
//! kind in [`RejectCounts`]. The same code decodes live frames (SocketCAN,
//! [`userspace`]) and `candump -l` logs ([`crate::candump`]).
//!
//! ```
//! use jetbench_io::can::{Codec, FrameDecoder, DEFAULT_BASE_ID};
//!
//! let codec = Codec::new(DEFAULT_BASE_ID).unwrap();
//! // 40.00 N on x, 0.012 N·m about z, sequence 7, no status bits.
//! let [force, torque] = codec.encode([4000, 0, 0], [0, 0, 12], 7, 0);
//! assert_eq!(force.id, 0x101);
//! assert_eq!(force.data(), &[0xa0, 0x0f, 0, 0, 0, 0, 7, 0]);
//!
//! let mut decoder = FrameDecoder::new(codec);
//! assert!(decoder.push(&force, 0.0).is_none()); // waits for its torque frame
//! let reading = decoder.push(&torque, 0.01).unwrap();
//! assert_eq!(reading.force_counts, [4000, 0, 0]);
//! assert_eq!(reading.physical().force_n[0], 40.0);
//! assert_eq!(decoder.counts().frames_rejected(), 0);
//! ```
//!
//! **Out-of-range values.** Every `i16` is a valid reading on this sensor, so
//! the out-of-range rejection is about the frame itself: an identifier that is
//! not a classic 11-bit data frame (extended-format flag, an ID above `0x7FF`,
//! a remote or error frame). The encoder saturates values at ±32767 counts and
//! sets the overload status bit, as the sensor does.

pub mod socketcan;
pub mod source;
pub mod userspace;

use std::fmt;

/// The default base identifier of the sensor.
pub const DEFAULT_BASE_ID: u16 = 0x100;
/// Force LSB, N.
pub const FORCE_N_PER_COUNT: f64 = 0.01;
/// Torque LSB, N·m.
pub const TORQUE_NM_PER_COUNT: f64 = 0.001;
/// Bytes of a classic frame in the kernel's `struct can_frame` layout.
pub const CAN_FRAME_BYTES: usize = 16;
/// Highest classic (11-bit) identifier.
pub const MAX_STANDARD_ID: u32 = 0x7ff;
/// `struct can_frame` identifier flag: an extended (29-bit) identifier.
pub const CAN_EFF_FLAG: u32 = 0x8000_0000;
/// `struct can_frame` identifier flag: a remote transmission request (no data).
pub const CAN_RTR_FLAG: u32 = 0x4000_0000;
/// `struct can_frame` identifier flag: an error frame the controller reports.
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// Status bit the encoder sets when it saturates a value (as `sensor_status::OVERLOAD`).
pub const STATUS_OVERLOAD: u8 = 1;

/// One classic CAN frame as the kernel's `struct can_frame` holds it:
/// `can_id` with its flag bits, the data length and up to 8 data bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct CanFrame {
    /// Identifier with the EFF/RTR/ERR flag bits, as in `struct can_frame`.
    pub id: u32,
    /// Data length code, 0..=8 for a well-formed frame.
    pub len: u8,
    /// The data bytes; those past `len` are 0.
    pub data: [u8; 8],
}

impl CanFrame {
    /// A classic data frame; `None` if `id > 0x7FF` or more than 8 bytes.
    pub fn standard(id: u16, data: &[u8]) -> Option<Self> {
        if u32::from(id) > MAX_STANDARD_ID || data.len() > 8 {
            return None;
        }
        let mut frame = CanFrame { id: id.into(), len: data.len() as u8, data: [0; 8] };
        frame.data[..data.len()].copy_from_slice(data);
        Some(frame)
    }

    /// The data bytes (at most 8, whatever `len` says).
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len.min(8))]
    }

    /// The `struct can_frame` bytes: `can_id` (host order), `len`, three
    /// padding/reserved bytes, 8 data bytes.
    pub fn to_bytes(&self) -> [u8; CAN_FRAME_BYTES] {
        let mut b = [0; CAN_FRAME_BYTES];
        b[..4].copy_from_slice(&self.id.to_ne_bytes());
        b[4] = self.len;
        b[8..].copy_from_slice(&self.data);
        b
    }

    /// Reads a `struct can_frame`. Fewer than 16 bytes is a truncated frame,
    /// more is not a classic frame (garbage), a length above 8 a bad DLC.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, RejectKind> {
        if bytes.len() < CAN_FRAME_BYTES {
            return Err(RejectKind::Truncated);
        }
        if bytes.len() > CAN_FRAME_BYTES {
            return Err(RejectKind::Garbage);
        }
        let id = u32::from_ne_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
        let len = bytes[4];
        if len > 8 {
            return Err(RejectKind::BadDlc);
        }
        let mut data = [0; 8];
        data.copy_from_slice(&bytes[8..16]);
        Ok(CanFrame { id, len, data })
    }
}

/// Why an input (frame, datagram or log line) was not used. Each kind has
/// its own counter in [`RejectCounts`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RejectKind {
    /// A sensor frame whose data length is not 8 (or a length above 8).
    BadDlc,
    /// A classic frame with an identifier that is not the sensor's.
    UnknownId,
    /// The sequence counter skipped: pairs were lost. An event, not a frame:
    /// the pair after the jump is still used.
    SequenceJump,
    /// A force frame without its torque frame, or the reverse (different
    /// sequence numbers, or one of the two lost).
    PairMismatch,
    /// A frame or log line cut short (fewer than 16 bytes, odd hex digits).
    Truncated,
    /// Input that is not a frame at all: a line not in candump format, a
    /// datagram of the wrong size, non-hex digits.
    Garbage,
    /// Not a classic 11-bit data frame: extended ID, ID above 0x7FF, remote or error frame.
    OutOfRange,
}

impl RejectKind {
    /// Every kind, in the order [`RejectCounts`] prints them.
    pub const ALL: [RejectKind; 7] = [
        RejectKind::BadDlc,
        RejectKind::UnknownId,
        RejectKind::SequenceJump,
        RejectKind::PairMismatch,
        RejectKind::Truncated,
        RejectKind::Garbage,
        RejectKind::OutOfRange,
    ];

    /// The counter's name, as printed by [`RejectCounts`].
    pub fn name(self) -> &'static str {
        match self {
            RejectKind::BadDlc => "bad_dlc",
            RejectKind::UnknownId => "unknown_id",
            RejectKind::SequenceJump => "sequence_jump",
            RejectKind::PairMismatch => "pair_mismatch",
            RejectKind::Truncated => "truncated",
            RejectKind::Garbage => "garbage",
            RejectKind::OutOfRange => "out_of_range",
        }
    }
}

impl fmt::Display for RejectKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Rejections counted by kind.
///
/// Every input frame is either part of a decoded pair or counted once in a
/// frame kind, so `2 * pairs + frames_rejected() == frames in` (after
/// [`FrameDecoder::finish`]). `sequence_jump` counts events and
/// `lost_pairs` the pairs they skipped; neither is a rejected frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RejectCounts {
    /// [`RejectKind::BadDlc`] frames.
    pub bad_dlc: u64,
    /// [`RejectKind::UnknownId`] frames.
    pub unknown_id: u64,
    /// [`RejectKind::SequenceJump`] events (not frames).
    pub sequence_jump: u64,
    /// [`RejectKind::PairMismatch`] frames.
    pub pair_mismatch: u64,
    /// [`RejectKind::Truncated`] frames or lines.
    pub truncated: u64,
    /// [`RejectKind::Garbage`] inputs.
    pub garbage: u64,
    /// [`RejectKind::OutOfRange`] frames.
    pub out_of_range: u64,
    /// Pairs skipped by sequence jumps (from the counter difference).
    pub lost_pairs: u64,
}

impl RejectCounts {
    /// Counts one rejection of `kind`.
    pub fn add(&mut self, kind: RejectKind) {
        *self.slot(kind) += 1;
    }

    /// The count of `kind`.
    pub fn get(&self, kind: RejectKind) -> u64 {
        match kind {
            RejectKind::BadDlc => self.bad_dlc,
            RejectKind::UnknownId => self.unknown_id,
            RejectKind::SequenceJump => self.sequence_jump,
            RejectKind::PairMismatch => self.pair_mismatch,
            RejectKind::Truncated => self.truncated,
            RejectKind::Garbage => self.garbage,
            RejectKind::OutOfRange => self.out_of_range,
        }
    }

    fn slot(&mut self, kind: RejectKind) -> &mut u64 {
        match kind {
            RejectKind::BadDlc => &mut self.bad_dlc,
            RejectKind::UnknownId => &mut self.unknown_id,
            RejectKind::SequenceJump => &mut self.sequence_jump,
            RejectKind::PairMismatch => &mut self.pair_mismatch,
            RejectKind::Truncated => &mut self.truncated,
            RejectKind::Garbage => &mut self.garbage,
            RejectKind::OutOfRange => &mut self.out_of_range,
        }
    }

    /// Inputs rejected (every kind but the sequence-jump events).
    pub fn frames_rejected(&self) -> u64 {
        RejectKind::ALL.iter().filter(|k| **k != RejectKind::SequenceJump).map(|k| self.get(*k)).sum()
    }
}

impl fmt::Display for RejectCounts {
    /// `bad_dlc=0 unknown_id=2 ... out_of_range=0 (lost pairs 3)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, kind) in RejectKind::ALL.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{}={}", kind.name(), self.get(*kind))?;
        }
        write!(f, " (lost pairs {})", self.lost_pairs)
    }
}

/// Which half of a reading a frame carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PartKind {
    /// The `base+1` frame: Fx, Fy, Fz.
    Force,
    /// The `base+2` frame: Tx, Ty, Tz.
    Torque,
}

/// One decoded sensor frame, in counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SensorPart {
    /// Which of the pair it is.
    pub kind: PartKind,
    /// Three axes: 0.01 N (force) or 0.001 N·m (torque) per count.
    pub counts: [i16; 3],
    /// The sensor's sequence counter (byte 6), the same in both frames of a pair.
    pub seq: u8,
    /// Status bits (byte 7): [`STATUS_OVERLOAD`] when a value saturated.
    pub status: u8,
}

/// A force/torque reading as the sensor sent it: counts, sequence and status.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorReading<T> {
    /// Fx, Fy, Fz at [`FORCE_N_PER_COUNT`].
    pub force_counts: [i16; 3],
    /// Tx, Ty, Tz at [`TORQUE_NM_PER_COUNT`].
    pub torque_counts: [i16; 3],
    /// The pair's sequence counter, wrapping at 256.
    pub seq: u8,
    /// Status bits of the force frame ORed with the torque frame's.
    pub status: u8,
    /// Pairs skipped since the previous reading (sequence jump), 0 normally.
    pub lost_before: u8,
    /// The first frame's tag (e.g. its receive time).
    pub at: T,
}

impl<T> SensorReading<T> {
    /// In physical units (N, N·m), uncalibrated.
    pub fn physical(&self) -> crate::ForceReading {
        crate::ForceReading {
            force_n: self.force_counts.map(|c| f64::from(c) * FORCE_N_PER_COUNT),
            torque_nm: self.torque_counts.map(|c| f64::from(c) * TORQUE_NM_PER_COUNT),
            counter: self.seq.into(),
            status: self.status.into(),
        }
    }
}

/// Why the codec cannot be built or a reading cannot be encoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodecError {
    /// The base ID leaves `base+2` outside 11 bits (the ID given).
    #[error("CAN base ID {0:#x}: base+2 must be a classic 11-bit identifier (base <= 0x7fd)")]
    BaseId(u32),
    /// A value to encode is NaN or infinite.
    #[error("{axis} = {value} is not a number; the sensor cannot send it")]
    NotFinite {
        /// The axis, e.g. `Fx`.
        axis: &'static str,
        /// The value.
        value: f64,
    },
}

/// Encodes and decodes the sensor's two frames for one base ID.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Codec {
    base_id: u16,
}

impl Codec {
    /// `base_id + 2` must fit 11 bits.
    pub fn new(base_id: u16) -> Result<Self, CodecError> {
        if u32::from(base_id) + 2 > MAX_STANDARD_ID {
            return Err(CodecError::BaseId(base_id.into()));
        }
        Ok(Codec { base_id })
    }

    /// The sensor's base identifier (config `[sensor] can_base_id`).
    pub fn base_id(&self) -> u16 {
        self.base_id
    }

    /// The force frame's identifier, `base+1`.
    pub fn force_id(&self) -> u16 {
        self.base_id + 1
    }

    /// The torque frame's identifier, `base+2`.
    pub fn torque_id(&self) -> u16 {
        self.base_id + 2
    }

    /// Decodes one frame. Pure: the same frame always gives the same result.
    pub fn decode(&self, frame: &CanFrame) -> Result<SensorPart, RejectKind> {
        if frame.id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG) != 0 || frame.id > MAX_STANDARD_ID {
            return Err(RejectKind::OutOfRange);
        }
        let kind = if frame.id == u32::from(self.force_id()) {
            PartKind::Force
        } else if frame.id == u32::from(self.torque_id()) {
            PartKind::Torque
        } else {
            return Err(RejectKind::UnknownId);
        };
        if frame.len != 8 {
            return Err(RejectKind::BadDlc);
        }
        let d = &frame.data;
        let axis = |i: usize| i16::from_le_bytes([d[2 * i], d[2 * i + 1]]);
        Ok(SensorPart { kind, counts: [axis(0), axis(1), axis(2)], seq: d[6], status: d[7] })
    }

    /// Encodes one part.
    pub fn encode_part(&self, part: &SensorPart) -> CanFrame {
        let id = match part.kind {
            PartKind::Force => self.force_id(),
            PartKind::Torque => self.torque_id(),
        };
        let mut data = [0u8; 8];
        for (i, c) in part.counts.iter().enumerate() {
            data[2 * i..2 * i + 2].copy_from_slice(&c.to_le_bytes());
        }
        data[6] = part.seq;
        data[7] = part.status;
        CanFrame { id: id.into(), len: 8, data }
    }

    /// The force and torque frames of one reading (both carry `status`).
    pub fn encode(&self, force_counts: [i16; 3], torque_counts: [i16; 3], seq: u8, status: u8) -> [CanFrame; 2] {
        [
            self.encode_part(&SensorPart { kind: PartKind::Force, counts: force_counts, seq, status }),
            self.encode_part(&SensorPart { kind: PartKind::Torque, counts: torque_counts, seq, status }),
        ]
    }

    /// Quantises a reading in N and N·m (rounded to the nearest count) and
    /// encodes it. Values beyond ±32767 counts saturate and set the overload
    /// bit; a value that is not a number is an error.
    pub fn encode_reading(&self, reading: &crate::ForceReading) -> Result<[CanFrame; 2], CodecError> {
        const AXES: [&str; 6] = ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"];
        let mut status = (reading.status & 0xff) as u8;
        let mut counts = [0i16; 6];
        let values = reading
            .force_n
            .iter()
            .map(|v| v / FORCE_N_PER_COUNT)
            .chain(reading.torque_nm.iter().map(|v| v / TORQUE_NM_PER_COUNT));
        for (i, v) in values.enumerate() {
            if !v.is_finite() {
                let value = if i < 3 { reading.force_n[i] } else { reading.torque_nm[i - 3] };
                return Err(CodecError::NotFinite { axis: AXES[i], value });
            }
            let r = v.round();
            if r.abs() > f64::from(i16::MAX) {
                status |= STATUS_OVERLOAD;
            }
            counts[i] = r.clamp(-f64::from(i16::MAX), f64::from(i16::MAX)) as i16;
        }
        let seq = (reading.counter & 0xff) as u8;
        Ok(self.encode([counts[0], counts[1], counts[2]], [counts[3], counts[4], counts[5]], seq, status))
    }
}

/// Decodes frames and pairs force with torque by sequence number, counting
/// every rejection. `T` tags each frame (a receive time, a log timestamp).
///
/// Pairing: a part waits until the other kind with the same sequence number
/// arrives. Any other sensor part arriving meanwhile rejects the waiting one
/// as a pair mismatch and waits in its place, so the two frames may come in
/// either order and a lost frame costs exactly its partner.
#[derive(Clone, Debug)]
pub struct FrameDecoder<T> {
    codec: Codec,
    pending: Option<(SensorPart, T)>,
    last_seq: Option<u8>,
    counts: RejectCounts,
    frames: u64,
    pairs: u64,
}

impl<T> FrameDecoder<T> {
    /// A decoder for `codec`'s identifiers, nothing pending, every count 0.
    pub fn new(codec: Codec) -> Self {
        FrameDecoder { codec, pending: None, last_seq: None, counts: RejectCounts::default(), frames: 0, pairs: 0 }
    }

    /// The codec it decodes with.
    pub fn codec(&self) -> &Codec {
        &self.codec
    }

    /// One frame; a reading when it completes a pair.
    pub fn push(&mut self, frame: &CanFrame, at: T) -> Option<SensorReading<T>> {
        self.frames += 1;
        match self.codec.decode(frame) {
            Ok(part) => self.push_part(part, at),
            Err(kind) => {
                self.counts.add(kind);
                None
            }
        }
    }

    /// One input that failed before it became a frame (a bad datagram, a bad log line).
    pub fn reject(&mut self, kind: RejectKind) {
        self.frames += 1;
        self.counts.add(kind);
    }

    fn push_part(&mut self, part: SensorPart, at: T) -> Option<SensorReading<T>> {
        match self.pending.take() {
            Some((waiting, first_at)) if waiting.kind != part.kind && waiting.seq == part.seq => {
                let (force, torque) = if waiting.kind == PartKind::Force { (waiting, part) } else { (part, waiting) };
                let lost_before = match self.last_seq {
                    Some(last) if part.seq != last.wrapping_add(1) => {
                        self.counts.sequence_jump += 1;
                        let lost = part.seq.wrapping_sub(last).wrapping_sub(1);
                        self.counts.lost_pairs += u64::from(lost);
                        lost
                    }
                    _ => 0,
                };
                self.last_seq = Some(part.seq);
                self.pairs += 1;
                Some(SensorReading {
                    force_counts: force.counts,
                    torque_counts: torque.counts,
                    seq: part.seq,
                    status: force.status | torque.status,
                    lost_before,
                    at: first_at,
                })
            }
            Some(_) => {
                self.counts.pair_mismatch += 1;
                self.pending = Some((part, at));
                None
            }
            None => {
                self.pending = Some((part, at));
                None
            }
        }
    }

    /// Ends the stream: a part still waiting for its partner is a mismatch.
    pub fn finish(&mut self) {
        if self.pending.take().is_some() {
            self.counts.pair_mismatch += 1;
        }
    }

    /// Gives up on a waiting part (after a link reset or a silence, when its
    /// partner can no longer come), counting it as a mismatch; returns whether
    /// one was waiting.
    pub fn drop_pending(&mut self) -> bool {
        let had = self.pending.take().is_some();
        if had {
            self.counts.pair_mismatch += 1;
        }
        had
    }

    /// Rejections so far, by kind.
    pub fn counts(&self) -> &RejectCounts {
        &self.counts
    }

    /// Inputs seen (frames, datagrams, lines).
    pub fn frames_in(&self) -> u64 {
        self.frames
    }

    /// Readings produced.
    pub fn pairs_out(&self) -> u64 {
        self.pairs
    }

    /// True while a part waits for its partner.
    pub fn has_pending(&self) -> bool {
        self.pending.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn codec() -> Codec {
        Codec::new(DEFAULT_BASE_ID).unwrap()
    }

    #[test]
    fn frame_bytes_have_the_kernel_layout() {
        let f = CanFrame::standard(0x101, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
        let b = f.to_bytes();
        assert_eq!(&b[..5], &[0x01, 0x01, 0, 0, 8]);
        assert_eq!(&b[8..], &[1, 2, 3, 4, 5, 6, 7, 8]);
        assert_eq!(CanFrame::from_bytes(&b), Ok(f));
        assert_eq!(CanFrame::from_bytes(&b[..15]), Err(RejectKind::Truncated));
        let mut long = b.to_vec();
        long.push(0);
        assert_eq!(CanFrame::from_bytes(&long), Err(RejectKind::Garbage));
        let mut bad = b;
        bad[4] = 9;
        assert_eq!(CanFrame::from_bytes(&bad), Err(RejectKind::BadDlc));
    }

    #[test]
    fn each_frame_defect_has_its_kind() {
        let c = codec();
        let [force, _] = c.encode([1, 2, 3], [4, 5, 6], 9, 0);
        let mut short = force;
        short.len = 7;
        assert_eq!(c.decode(&short), Err(RejectKind::BadDlc));
        let mut other = force;
        other.id = 0x123;
        assert_eq!(c.decode(&other), Err(RejectKind::UnknownId));
        for id in [force.id | CAN_EFF_FLAG, force.id | CAN_RTR_FLAG, force.id | CAN_ERR_FLAG, 0x901] {
            assert_eq!(c.decode(&CanFrame { id, ..force }), Err(RejectKind::OutOfRange), "{id:#x}");
        }
        assert_eq!(Codec::new(0x7fe), Err(CodecError::BaseId(0x7fe)));
    }

    #[test]
    fn encoding_rounds_saturates_and_refuses_nan() {
        let c = codec();
        let reading = crate::ForceReading {
            force_n: [40.004, -0.006, 400.0],
            torque_nm: [0.0124, -40.0, 0.0],
            counter: 258,
            status: 0,
        };
        let [f, t] = c.encode_reading(&reading).unwrap();
        let (f, t) = (c.decode(&f).unwrap(), c.decode(&t).unwrap());
        assert_eq!(f.counts, [4000, -1, i16::MAX]);
        assert_eq!(t.counts, [12, -i16::MAX, 0]);
        assert_eq!((f.seq, f.status & STATUS_OVERLOAD), (2, STATUS_OVERLOAD));
        let nan = crate::ForceReading { torque_nm: [0.0, f64::NAN, 0.0], ..reading };
        assert!(matches!(c.encode_reading(&nan), Err(CodecError::NotFinite { axis: "ty_nm", .. })));
    }

    #[test]
    fn pairing_counts_mismatches_and_jumps() {
        let c = codec();
        let mut d = FrameDecoder::new(c);
        let pair = |seq: u8| c.encode([seq.into(), 0, 0], [0, 0, seq.into()], seq, 0);
        let [f0, t0] = pair(0);
        assert!(d.push(&f0, 0).is_none());
        assert_eq!(d.push(&t0, 1).unwrap().at, 0);
        // Torque first is fine too.
        let [f1, t1] = pair(1);
        assert!(d.push(&t1, 2).is_none());
        assert_eq!(d.push(&f1, 3).unwrap().force_counts, [1, 0, 0]);
        // Force 2 lost: torque 2 waits, force 3 rejects it.
        let [_, t2] = pair(2);
        let [f3, t3] = pair(3);
        d.push(&t2, 4);
        d.push(&f3, 5);
        let r3 = d.push(&t3, 6).unwrap();
        assert_eq!((r3.seq, r3.lost_before), (3, 1));
        assert_eq!(d.counts().pair_mismatch, 1);
        assert_eq!((d.counts().sequence_jump, d.counts().lost_pairs), (1, 1));
        // Wrap 255 -> 0 is no jump.
        let mut w = FrameDecoder::new(c);
        for seq in [254u8, 255, 0] {
            let [f, t] = pair(seq);
            w.push(&f, ());
            assert!(w.push(&t, ()).is_some());
        }
        assert_eq!(w.counts().sequence_jump, 0);
        d.push(&f0, 7);
        d.finish();
        assert_eq!(d.counts().pair_mismatch, 2);
        assert_eq!(2 * d.pairs_out() + d.counts().frames_rejected(), d.frames_in());
    }

    #[test]
    fn counts_print_every_kind() {
        let mut c = RejectCounts::default();
        c.add(RejectKind::Garbage);
        c.add(RejectKind::Garbage);
        c.add(RejectKind::SequenceJump);
        assert_eq!(
            c.to_string(),
            "bad_dlc=0 unknown_id=0 sequence_jump=1 pair_mismatch=0 truncated=0 garbage=2 out_of_range=0 (lost pairs 0)"
        );
        assert_eq!(c.frames_rejected(), 2);
    }
}
