//! The throttle board's serial protocol: frame codec and stream deframer.
//!
//! Every frame is `0xA5, type, len, payload[len], crc16`, where the CRC is
//! CRC-16/CCITT-FALSE over `type, len, payload` and, like every multi-byte
//! field, little-endian. Throttle values are `u16` in 0.01 % units, so the
//! wire range is 0..=10000 (0..100 %); a negative throttle cannot be encoded
//! and a value above 10000 is rejected as out of range.
//!
//! | type | name          | payload (len)                                                   |
//! |------|---------------|-----------------------------------------------------------------|
//! | 0x01 | set throttle  | `seq u16, throttle u16` (4)                                     |
//! | 0x02 | arm           | `seq u16` (2)                                                   |
//! | 0x03 | disarm        | `seq u16` (2)                                                   |
//! | 0x81 | acknowledge   | `seq u16, applied u16, flags u8` (5): echoes the command's seq  |
//! | 0x82 | board status  | `flags u8, applied u16, valid u32, rejected u32, watchdog u32` (15) |
//!
//! `flags` bits: 0 armed, 1 idle fallback (the board's own 100 ms watchdog).
//! `applied` is the throttle the board outputs after the command (0 while
//! disarmed). The PC numbers its commands; the acknowledgement carries the
//! number back, so the PC matches each ack to its command and measures the
//! round trip.
//!
//! ```
//! use jetbench_io::board::{encode, Deframer, Frame, Throttle};
//!
//! let frame = Frame::SetThrottle { seq: 7, throttle: Throttle::from_pct(42.5).unwrap() };
//! let mut bytes = vec![0x00, 0x13]; // line noise before the frame
//! bytes.extend(encode(&frame));
//! let mut deframer = Deframer::new();
//! let mut frames = Vec::new();
//! deframer.push(&bytes, |f| frames.push(f));
//! assert_eq!(frames, vec![frame]);
//! assert_eq!(deframer.counters().garbage_bytes, 2);
//! ```

/// First byte of every frame.
pub const SYNC: u8 = 0xA5;
/// The longest payload any board frame may carry; a longer `len` is a bad length.
pub const MAX_PAYLOAD: usize = 32;
/// Bytes around the payload: sync, type, len and the two CRC bytes.
pub const OVERHEAD: usize = 5;
/// The longest frame on the wire.
pub const MAX_FRAME: usize = MAX_PAYLOAD + OVERHEAD;
/// The board drops to idle when no valid frame arrives for this long (its own watchdog).
pub const WATCHDOG_NS: u64 = 100_000_000;

/// Frame type codes.
pub mod kind {
    /// PC → board: set the throttle ([`super::Frame::SetThrottle`]).
    pub const SET_THROTTLE: u8 = 0x01;
    /// PC → board: arm the output ([`super::Frame::Arm`]).
    pub const ARM: u8 = 0x02;
    /// PC → board: disarm, output 0 ([`super::Frame::Disarm`]).
    pub const DISARM: u8 = 0x03;
    /// Board → PC: acknowledgement of one command ([`super::Frame::Ack`]).
    pub const ACK: u8 = 0x81;
    /// Board → PC: periodic status ([`super::Frame::Status`]).
    pub const STATUS: u8 = 0x82;
}

/// Bits of the `flags` byte in acknowledgements and status frames.
pub mod board_flags {
    /// The board is armed: it outputs the commanded throttle (disarmed: 0).
    pub const ARMED: u8 = 1 << 0;
    /// The board's watchdog fired (no valid frame for [`super::WATCHDOG_NS`]) and it
    /// holds idle until the next valid command.
    pub const IDLE_FALLBACK: u8 = 1 << 1;
}

/// A throttle value as on the wire: 0.01 % units, 0..=10000.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Throttle(u16);

impl Throttle {
    /// The largest valid wire value (100 %).
    pub const MAX_RAW: u16 = 10_000;

    /// From wire units; `None` above 100 %.
    pub fn from_raw(raw: u16) -> Option<Self> {
        (raw <= Self::MAX_RAW).then_some(Throttle(raw))
    }

    /// From percent, rounded to the nearest 0.01 %; `None` if not finite or outside 0..=100 %.
    pub fn from_pct(pct: f64) -> Option<Self> {
        if !pct.is_finite() || !(0.0..=100.0).contains(&pct) {
            return None;
        }
        Self::from_raw((pct * 100.0).round() as u16)
    }

    /// In wire units, 0.01 %.
    pub fn raw(self) -> u16 {
        self.0
    }

    /// In percent.
    pub fn pct(self) -> f64 {
        f64::from(self.0) / 100.0
    }
}

/// The board's periodic report (type 0x82).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BoardStatus {
    /// [`board_flags`] bits.
    pub flags: u8,
    /// Throttle the board outputs now.
    pub applied: Throttle,
    /// Valid frames received since power-up.
    pub valid_frames: u32,
    /// Frames and garbage runs the board rejected since power-up.
    pub rejected_frames: u32,
    /// Times the board's watchdog dropped it to idle.
    pub watchdog_trips: u32,
}

/// One decoded frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame {
    /// Set the throttle the board outputs while armed.
    SetThrottle {
        /// The PC's number for this command, echoed in its acknowledgement.
        seq: u16,
        /// The throttle to output.
        throttle: Throttle,
    },
    /// Arm the output: from now on the board outputs the commanded throttle.
    Arm {
        /// The PC's number for this command.
        seq: u16,
    },
    /// Disarm: the board outputs 0 until armed again.
    Disarm {
        /// The PC's number for this command.
        seq: u16,
    },
    /// The board's acknowledgement of command `seq`, with the throttle it now outputs.
    Ack {
        /// The acknowledged command's number.
        seq: u16,
        /// The throttle the board outputs after it.
        applied: Throttle,
        /// [`board_flags`] bits.
        flags: u8,
    },
    /// The board's periodic report.
    Status(BoardStatus),
}

impl Frame {
    /// Its type code on the wire ([`kind`]).
    pub fn kind(&self) -> u8 {
        match self {
            Frame::SetThrottle { .. } => kind::SET_THROTTLE,
            Frame::Arm { .. } => kind::ARM,
            Frame::Disarm { .. } => kind::DISARM,
            Frame::Ack { .. } => kind::ACK,
            Frame::Status(_) => kind::STATUS,
        }
    }
}

/// Why a frame was rejected. Each kind has its own counter in [`Counters`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The CRC does not match the bytes: a bit flipped on the line.
    #[error("CRC mismatch: frame says {found:#06x}, bytes give {computed:#06x}")]
    Crc {
        /// The CRC the frame carries.
        found: u16,
        /// The CRC of its bytes.
        computed: u16,
    },
    /// The bytes end before the frame does.
    #[error("truncated frame: {have} of {need} bytes")]
    Truncated {
        /// Bytes there are.
        have: usize,
        /// Bytes the frame's `len` needs.
        need: usize,
    },
    /// A `len` above [`MAX_PAYLOAD`] or not the payload length of its type.
    #[error("bad length {len} for frame type {kind:#04x}")]
    BadLength {
        /// The frame's type code.
        kind: u8,
        /// The `len` it gives.
        len: usize,
    },
    /// A type code this protocol does not have.
    #[error("unknown frame type {0:#04x}")]
    UnknownType(u8),
    /// A throttle above 100 % (wire value, 0.01 %).
    #[error("throttle {raw} (0.01 %) is outside 0..=10000")]
    OutOfRange {
        /// The wire value, 0.01 %.
        raw: u16,
    },
    /// The first byte is not [`SYNC`] (the byte found).
    #[error("frame does not start with 0xA5 (found {0:#04x})")]
    NoSync(u8),
}

/// CRC-16/CCITT-FALSE: polynomial 0x1021, initial value 0xFFFF, no reflection, no final XOR.
///
/// ```
/// assert_eq!(jetbench_io::board::crc16(b"123456789"), 0x29B1);
/// ```
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in bytes {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
        }
    }
    crc
}

fn payload_of(frame: &Frame) -> ([u8; MAX_PAYLOAD], usize) {
    let mut p = [0u8; MAX_PAYLOAD];
    let len = match *frame {
        Frame::SetThrottle { seq, throttle } => {
            p[..2].copy_from_slice(&seq.to_le_bytes());
            p[2..4].copy_from_slice(&throttle.raw().to_le_bytes());
            4
        }
        Frame::Arm { seq } | Frame::Disarm { seq } => {
            p[..2].copy_from_slice(&seq.to_le_bytes());
            2
        }
        Frame::Ack { seq, applied, flags } => {
            p[..2].copy_from_slice(&seq.to_le_bytes());
            p[2..4].copy_from_slice(&applied.raw().to_le_bytes());
            p[4] = flags;
            5
        }
        Frame::Status(s) => {
            p[0] = s.flags;
            p[1..3].copy_from_slice(&s.applied.raw().to_le_bytes());
            p[3..7].copy_from_slice(&s.valid_frames.to_le_bytes());
            p[7..11].copy_from_slice(&s.rejected_frames.to_le_bytes());
            p[11..15].copy_from_slice(&s.watchdog_trips.to_le_bytes());
            15
        }
    };
    (p, len)
}

/// The payload length each known frame type must have.
pub fn expected_len(kind: u8) -> Option<usize> {
    match kind {
        kind::SET_THROTTLE => Some(4),
        kind::ACK => Some(5),
        kind::ARM | kind::DISARM => Some(2),
        kind::STATUS => Some(15),
        _ => None,
    }
}

/// Encodes a frame into its wire bytes.
pub fn encode(frame: &Frame) -> Vec<u8> {
    let mut out = Vec::with_capacity(MAX_FRAME);
    encode_into(frame, &mut out);
    out
}

/// Encodes a frame into `out`, replacing its contents: the per-cycle form of
/// [`encode`], which allocates nothing once `out` holds [`MAX_FRAME`] bytes.
pub fn encode_into(frame: &Frame, out: &mut Vec<u8>) {
    let (payload, len) = payload_of(frame);
    out.clear();
    frame_into(frame.kind(), &payload[..len], out);
}

/// The wire bytes of a frame of any `kind` and `payload` with a valid CRC,
/// whether or not the board would accept them: what a misbehaving sender
/// puts on the line, for tests and tools.
pub fn raw_frame(kind: u8, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(payload.len() + 5);
    frame_into(kind, payload, &mut out);
    out
}

fn frame_into(kind: u8, payload: &[u8], out: &mut Vec<u8>) {
    out.extend_from_slice(&[SYNC, kind, payload.len() as u8]);
    out.extend_from_slice(payload);
    let crc = crc16(&out[1..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

fn u16_at(p: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([p[i], p[i + 1]])
}

fn u32_at(p: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]])
}

fn throttle(raw: u16) -> Result<Throttle, FrameError> {
    Throttle::from_raw(raw).ok_or(FrameError::OutOfRange { raw })
}

/// Decodes the frame at the start of `bytes`: the frame and the bytes it took.
///
/// A pure function: `bytes` must start with [`SYNC`]; bytes after the frame
/// are ignored. Checks, in order: sync, length bound, completeness, CRC,
/// type, length for the type, value range.
pub fn decode(bytes: &[u8]) -> Result<(Frame, usize), FrameError> {
    match bytes.first() {
        None => return Err(FrameError::Truncated { have: 0, need: OVERHEAD }),
        Some(&b) if b != SYNC => return Err(FrameError::NoSync(b)),
        Some(_) => {}
    }
    if bytes.len() < 3 {
        return Err(FrameError::Truncated { have: bytes.len(), need: OVERHEAD });
    }
    let (kind, len) = (bytes[1], usize::from(bytes[2]));
    if len > MAX_PAYLOAD {
        return Err(FrameError::BadLength { kind, len });
    }
    let total = len + OVERHEAD;
    if bytes.len() < total {
        return Err(FrameError::Truncated { have: bytes.len(), need: total });
    }
    let computed = crc16(&bytes[1..3 + len]);
    let found = u16_at(bytes, 3 + len);
    if computed != found {
        return Err(FrameError::Crc { found, computed });
    }
    let expected = expected_len(kind).ok_or(FrameError::UnknownType(kind))?;
    if len != expected {
        return Err(FrameError::BadLength { kind, len });
    }
    let p = &bytes[3..3 + len];
    let frame = match kind {
        kind::SET_THROTTLE => Frame::SetThrottle { seq: u16_at(p, 0), throttle: throttle(u16_at(p, 2))? },
        kind::ARM => Frame::Arm { seq: u16_at(p, 0) },
        kind::DISARM => Frame::Disarm { seq: u16_at(p, 0) },
        kind::ACK => Frame::Ack { seq: u16_at(p, 0), applied: throttle(u16_at(p, 2))?, flags: p[4] },
        _ => Frame::Status(BoardStatus {
            flags: p[0],
            applied: throttle(u16_at(p, 1))?,
            valid_frames: u32_at(p, 3),
            rejected_frames: u32_at(p, 7),
            watchdog_trips: u32_at(p, 11),
        }),
    };
    Ok((frame, total))
}

/// What a [`Deframer`] has seen, by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Valid frames delivered.
    pub frames: u64,
    /// Frames whose CRC did not match (a bit flipped on the line).
    pub crc_errors: u64,
    /// Partial frames given up on when the line went quiet ([`Deframer::expire_partial`]).
    pub truncated: u64,
    /// Frames whose `len` exceeds [`MAX_PAYLOAD`] or is not their type's.
    pub bad_length: u64,
    /// Frames of a type code this protocol does not have.
    pub unknown_type: u64,
    /// Frames with a throttle above 100 % (10000 wire units).
    pub out_of_range: u64,
    /// Every byte discarded outside a valid frame (noise before a sync, and
    /// the bytes of rejected frames).
    pub garbage_bytes: u64,
}

impl Counters {
    /// Rejected frames of every kind (garbage bytes not included).
    pub fn rejected(&self) -> u64 {
        self.crc_errors + self.truncated + self.bad_length + self.unknown_type + self.out_of_range
    }

    fn count(&mut self, e: &FrameError) {
        match e {
            FrameError::Crc { .. } => self.crc_errors += 1,
            FrameError::Truncated { .. } => self.truncated += 1,
            FrameError::BadLength { .. } => self.bad_length += 1,
            FrameError::UnknownType(_) => self.unknown_type += 1,
            FrameError::OutOfRange { .. } => self.out_of_range += 1,
            FrameError::NoSync(_) => {}
        }
    }
}

/// Splits a byte stream into frames, resynchronising on the next 0xA5
/// after noise or a rejected frame.
///
/// A candidate frame whose CRC fails (or whose length is impossible) gives up
/// only its sync byte, so a valid frame starting inside it is still found. A
/// frame that passes its CRC but is still invalid (unknown type, wrong length
/// for its type, value out of range) is skipped whole. Memory is bounded: at
/// most one frame is buffered.
#[derive(Clone, Debug, Default)]
pub struct Deframer {
    buf: Vec<u8>,
    counters: Counters,
    last_error: Option<FrameError>,
}

impl Deframer {
    /// An empty deframer, every counter 0.
    pub fn new() -> Self {
        Deframer { buf: Vec::with_capacity(2 * MAX_FRAME), counters: Counters::default(), last_error: None }
    }

    /// Feeds bytes; calls `on_frame` for every valid frame, in order.
    pub fn push(&mut self, mut bytes: &[u8], mut on_frame: impl FnMut(Frame)) {
        while !bytes.is_empty() {
            let room = (2 * MAX_FRAME).saturating_sub(self.buf.len()).max(1);
            let (now, rest) = bytes.split_at(room.min(bytes.len()));
            self.buf.extend_from_slice(now);
            bytes = rest;
            self.drain(&mut on_frame);
        }
    }

    fn drain(&mut self, on_frame: &mut impl FnMut(Frame)) {
        let mut start = 0;
        loop {
            // Hunt for the next sync byte.
            let skip = self.buf[start..].iter().position(|&b| b == SYNC).unwrap_or(self.buf.len() - start);
            self.counters.garbage_bytes += skip as u64;
            start += skip;
            if start == self.buf.len() {
                break;
            }
            match decode(&self.buf[start..]) {
                Ok((frame, used)) => {
                    self.counters.frames += 1;
                    start += used;
                    on_frame(frame);
                }
                Err(FrameError::Truncated { .. }) => break,
                Err(e) => {
                    self.counters.count(&e);
                    self.last_error = Some(e);
                    // Past the CRC the frame is known to be whole: skip it. Before,
                    // give up only the sync byte and look for the next one.
                    let used = match e {
                        FrameError::UnknownType(_) | FrameError::OutOfRange { .. } => {
                            usize::from(self.buf[start + 2]) + OVERHEAD
                        }
                        FrameError::BadLength { len, .. } if len <= MAX_PAYLOAD => len + OVERHEAD,
                        _ => 1,
                    };
                    self.counters.garbage_bytes += used as u64;
                    start += used;
                }
            }
        }
        self.buf.drain(..start);
    }

    /// The line went quiet with part of a frame buffered: count it as
    /// truncated and look for a sync in what remains.
    pub fn expire_partial(&mut self, mut on_frame: impl FnMut(Frame)) {
        if self.buf.is_empty() {
            return;
        }
        let e = FrameError::Truncated {
            have: self.buf.len(),
            need: self.buf.get(2).map_or(OVERHEAD, |&l| usize::from(l) + OVERHEAD),
        };
        self.counters.count(&e);
        self.last_error = Some(e);
        self.counters.garbage_bytes += 1;
        self.buf.remove(0);
        self.drain(&mut on_frame);
    }

    /// Bytes held while waiting for the rest of a frame.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// What it has seen so far, by kind.
    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// The most recent rejection, for logs.
    pub fn last_error(&self) -> Option<FrameError> {
        self.last_error
    }
}
