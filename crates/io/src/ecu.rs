//! The engine ECU's telemetry protocol: ASCII lines ending `\r`.
//!
//! The PC sends [`POLL`] (`1,RAC,1\r`); the ECU answers
//! `1,HS,OK,<rpm>,<egt_c>,<pump_v>,<state>,<throttle_pct>\r`: shaft speed in
//! rev/min, exhaust gas temperature in °C, fuel pump voltage in V, the ECU's
//! state code (an integer 0..=255) and the throttle it sees in %. Numbers are
//! plain decimals (`61250`, `612.4`, `3.05`); a line feed after the `\r` is
//! tolerated.
//!
//! ```
//! use jetbench_io::ecu::{decode_line, encode_reply, EcuReading};
//!
//! let reading = EcuReading { rpm: 61250.0, egt_c: 612.5, pump_v: 3.05, state: 10, throttle_pct: 42.0 };
//! let line = encode_reply(&reading);
//! assert_eq!(line, "1,HS,OK,61250,612.5,3.05,10,42\r");
//! assert_eq!(decode_line(line.trim_end().as_bytes()), Ok(reading));
//! ```

/// The poll the PC sends.
pub const POLL: &[u8] = b"1,RAC,1\r";
/// The end of every line.
pub const EOL: u8 = b'\r';
/// The longest line accepted; longer ones are garbled.
pub const MAX_LINE: usize = 96;

/// Valid ranges, inclusive.
pub const RPM_MAX: f64 = 300_000.0;
pub const EGT_MIN_C: f64 = -50.0;
pub const EGT_MAX_C: f64 = 1_200.0;
pub const PUMP_MAX_V: f64 = 30.0;
pub const THROTTLE_MAX_PCT: f64 = 100.0;

/// One telemetry reply.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EcuReading {
    pub rpm: f64,
    pub egt_c: f64,
    pub pump_v: f64,
    pub state: u32,
    pub throttle_pct: f64,
}

/// Why a line was rejected. Each kind has its own counter in [`EcuCounters`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum EcuError {
    #[error("not a telemetry reply: {0:?}")]
    Unknown(String),
    #[error("truncated reply: {fields} of 8 fields")]
    Truncated { fields: usize },
    #[error("garbled reply: {0}")]
    Garbled(String),
    #[error("{field} = {value} is out of range")]
    OutOfRange { field: &'static str, value: String },
    #[error("{field} is not a finite number: {value:?}")]
    NonFinite { field: &'static str, value: String },
}

/// Rejections by kind, and lines accepted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EcuCounters {
    pub lines: u64,
    pub unknown: u64,
    pub truncated: u64,
    pub garbled: u64,
    pub out_of_range: u64,
    pub non_finite: u64,
}

impl EcuCounters {
    pub fn rejected(&self) -> u64 {
        self.unknown + self.truncated + self.garbled + self.out_of_range + self.non_finite
    }

    /// Counts one decode result.
    pub fn count<T>(&mut self, result: &Result<T, EcuError>) {
        match result {
            Ok(_) => self.lines += 1,
            Err(EcuError::Unknown(_)) => self.unknown += 1,
            Err(EcuError::Truncated { .. }) => self.truncated += 1,
            Err(EcuError::Garbled(_)) => self.garbled += 1,
            Err(EcuError::OutOfRange { .. }) => self.out_of_range += 1,
            Err(EcuError::NonFinite { .. }) => self.non_finite += 1,
        }
    }
}

/// The reply line for a reading, `\r` included. `Display` of `f64` is the
/// shortest decimal that parses back to the same value, so a reply decodes
/// to exactly the reading encoded.
pub fn encode_reply(r: &EcuReading) -> String {
    format!("1,HS,OK,{},{},{},{},{}\r", r.rpm, r.egt_c, r.pump_v, r.state, r.throttle_pct)
}

fn number(field: &'static str, text: &str, lo: f64, hi: f64) -> Result<f64, EcuError> {
    match text.parse::<f64>() {
        // `inf`, `NaN`, `1e999`: numbers, but not finite ones.
        Ok(v) if !v.is_finite() => Err(EcuError::NonFinite { field, value: text.into() }),
        // Plain decimals only (Rust would also take `1e3`).
        Ok(v) if text.bytes().all(|b| b.is_ascii_digit() || b"+-.".contains(&b)) => {
            if (lo..=hi).contains(&v) {
                Ok(v)
            } else {
                Err(EcuError::OutOfRange { field, value: text.into() })
            }
        }
        _ => Err(EcuError::Garbled(format!("{field} is not a number: {text:?}"))),
    }
}

/// Decodes one reply line (without its `\r`). A pure function.
pub fn decode_line(line: &[u8]) -> Result<EcuReading, EcuError> {
    let line = line.strip_suffix(b"\n").unwrap_or(line);
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    if line.len() > MAX_LINE {
        return Err(EcuError::Garbled(format!("line of {} bytes", line.len())));
    }
    if let Some(b) = line.iter().find(|b| !(b.is_ascii_graphic() || **b == b' ')) {
        return Err(EcuError::Garbled(format!("byte {b:#04x} in line")));
    }
    // Only printable ASCII is left, so this is valid UTF-8.
    let text = std::str::from_utf8(line).map_err(|e| EcuError::Garbled(e.to_string()))?;
    let fields: Vec<&str> = text.split(',').map(str::trim).collect();
    let head = fields.get(..3.min(fields.len())).unwrap_or(&[]);
    match head {
        ["1", "HS", "OK"] => {}
        ["1", "HS"] | ["1"] | [""] if fields.len() < 3 => return Err(EcuError::Truncated { fields: fields.len() }),
        _ => return Err(EcuError::Unknown(text.chars().take(40).collect())),
    }
    if fields.len() < 8 {
        return Err(EcuError::Truncated { fields: fields.len() });
    }
    if fields.len() > 8 {
        return Err(EcuError::Garbled(format!("{} fields, expected 8", fields.len())));
    }
    let state = match fields[6].parse::<u8>() {
        Ok(s) => u32::from(s),
        Err(_) if !fields[6].is_empty() && fields[6].bytes().all(|b| b.is_ascii_digit()) => {
            return Err(EcuError::OutOfRange { field: "state", value: fields[6].into() })
        }
        Err(_) => return Err(EcuError::Garbled(format!("state is not an integer: {:?}", fields[6]))),
    };
    Ok(EcuReading {
        rpm: number("rpm", fields[3], 0.0, RPM_MAX)?,
        egt_c: number("egt_c", fields[4], EGT_MIN_C, EGT_MAX_C)?,
        pump_v: number("pump_v", fields[5], 0.0, PUMP_MAX_V)?,
        state,
        throttle_pct: number("throttle_pct", fields[7], 0.0, THROTTLE_MAX_PCT)?,
    })
}

/// Splits a byte stream into `\r`-terminated lines and decodes each,
/// counting rejections. A line longer than [`MAX_LINE`] is dropped up to the
/// next `\r` and counted once as garbled.
#[derive(Clone, Debug, Default)]
pub struct LineDecoder {
    line: Vec<u8>,
    overlong: bool,
    counters: EcuCounters,
    last_error: Option<EcuError>,
}

impl LineDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds bytes; calls `on_reading` for every valid reply, in order.
    pub fn push(&mut self, bytes: &[u8], mut on_reading: impl FnMut(EcuReading)) {
        for &b in bytes {
            if b == EOL {
                let result = if self.overlong {
                    Err(EcuError::Garbled(format!("line longer than {MAX_LINE} bytes")))
                } else {
                    decode_line(&self.line)
                };
                // Blank lines (e.g. a stray `\r\n` pair) are no replies and no errors.
                let blank = !self.overlong && self.line.iter().all(|b| b.is_ascii_whitespace());
                if !blank {
                    self.counters.count(&result);
                    match result {
                        Ok(r) => on_reading(r),
                        Err(e) => self.last_error = Some(e),
                    }
                }
                self.line.clear();
                self.overlong = false;
            } else if b == b'\n' && self.line.is_empty() {
                // The `\n` of a `\r\n` ending.
            } else if self.line.len() < MAX_LINE {
                self.line.push(b);
            } else {
                self.overlong = true;
            }
        }
    }

    /// Drops a partial line (e.g. when a poll went unanswered), counting it as truncated.
    pub fn expire_partial(&mut self) {
        if !self.line.is_empty() || self.overlong {
            let e = EcuError::Truncated { fields: self.line.split(|b| *b == b',').count() };
            self.counters.count::<()>(&Err(e.clone()));
            self.last_error = Some(e);
            self.line.clear();
            self.overlong = false;
        }
    }

    pub fn counters(&self) -> &EcuCounters {
        &self.counters
    }

    pub fn last_error(&self) -> Option<&EcuError> {
        self.last_error.as_ref()
    }
}
