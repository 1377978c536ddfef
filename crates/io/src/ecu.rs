//! The engine ECU's serial protocol, JetCat's RS232 interface: ASCII lines
//! ending `\r`, each command `<address>,<MNEMONIC>,<parameter>` (address 1).
//!
//! | command | meaning | reply |
//! |---|---|---|
//! | `1,RAC,1` ([`POLL`]) | read actual values | `1,HS,OK,<rpm>,<egt_c>,<pump_v>,<state>,<throttle_pct>` |
//! | `1,RSS,1` ([`STATUS_POLL`]) | read system status | `1,HS,OK,<off_condition>,...` |
//! | `1,RFI,1` ([`FUEL_POLL`]) | read fuel information | `1,HS,OK,<fuel_ml_min>,<rest_fuel_ml>,<set_rpm>,<battery_v>,<last_run_s>` |
//! | `1,TCO,1` / `1,TCO,0` | turbine control: start / stop | `1,HS,OK`, or `1,HS,ERR,<n>` |
//! | `1,WPE,<pct>` | write the throttle, % | `1,HS,OK`, or `1,HS,ERR,<n>` |
//!
//! The ECU echoes every command line before its reply (`1,RAC,1\r1,HS,OK,...\r`);
//! [`LineDecoder`] takes an echo as the context of the next reply and counts
//! it, not as a rejection. `RAC` carries shaft speed in rev/min, exhaust gas
//! temperature in °C, fuel pump voltage in V, the state code (an integer
//! 0..=255, named by [`state::EcuState`]) and the throttle the ECU sees in %;
//! `RSS` the off condition ([`state::OffCondition`]); `RFI` (fuel flow, fuel
//! left, set RPM, the ECU's battery voltage, the last run's time) is read
//! for the battery voltage, every few polls. Numbers are plain
//! decimals (`61250`, `612.4`, `3.05`); a line feed after the `\r` is
//! tolerated. Where this differs from JetCat's document, and why, is in
//! crates/io/README.md.
//!
//! ```
//! use jetbench_io::ecu::{decode_line, encode_reply, EcuReading};
//!
//! let reading = EcuReading { rpm: 61250.0, egt_c: 612.5, pump_v: 3.05, state: 10, throttle_pct: 42.0 };
//! let line = encode_reply(&reading);
//! assert_eq!(line, "1,HS,OK,61250,612.5,3.05,10,42\r");
//! assert_eq!(decode_line(line.trim_end().as_bytes()), Ok(reading));
//! ```

pub mod emulator;
pub mod state;

/// The poll the PC sends: read actual values.
pub const POLL: &[u8] = b"1,RAC,1\r";
/// Read system status: the off condition.
pub const STATUS_POLL: &[u8] = b"1,RSS,1\r";
/// Read fuel information: fuel flow, fuel left, set RPM, battery voltage, last run time.
pub const FUEL_POLL: &[u8] = b"1,RFI,1\r";
/// The end of every line.
pub const EOL: u8 = b'\r';
/// The longest line accepted; longer ones are garbled.
pub const MAX_LINE: usize = 96;

// Valid ranges of the reply fields, inclusive: a value outside is counted
// as out of range and the line rejected (a garbled digit, not an engine).

/// The highest shaft speed a reply may carry, rev/min (from 0; the P100 runs
/// at about 120 000).
pub const RPM_MAX: f64 = 300_000.0;
/// The lowest exhaust gas temperature a reply may carry, °C (a cold winter bench).
pub const EGT_MIN_C: f64 = -50.0;
/// The highest exhaust gas temperature a reply may carry, °C (beyond any engine's).
pub const EGT_MAX_C: f64 = 1_200.0;
/// The highest fuel pump voltage a reply may carry, V (from 0).
pub const PUMP_MAX_V: f64 = 30.0;
/// The highest throttle a reply may carry, % (from 0).
pub const THROTTLE_MAX_PCT: f64 = 100.0;
/// The highest battery voltage an `RFI` reply may carry, V (from 0).
pub const BATTERY_MAX_V: f64 = 30.0;

/// One telemetry reply.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EcuReading {
    /// Shaft speed, rev/min.
    pub rpm: f64,
    /// Exhaust gas temperature, °C.
    pub egt_c: f64,
    /// Fuel pump voltage, V.
    pub pump_v: f64,
    /// The ECU's state code, 0..=255 ([`state::EcuState`] names it).
    pub state: u32,
    /// The throttle the ECU sees, %.
    pub throttle_pct: f64,
}

/// Why a line was rejected. Each kind has its own counter in [`EcuCounters`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum EcuError {
    /// A line that is no reply this decoder knows (not `1,HS,...`), as received.
    #[error("not a telemetry reply: {0:?}")]
    Unknown(String),
    /// A reply cut short: a poll's answer window closed mid-line, or fields missing.
    #[error("truncated reply: {fields} of 8 fields")]
    Truncated {
        /// The comma-separated fields the line had.
        fields: usize,
    },
    /// A reply whose fields do not parse (line noise, a wrong baud rate), and why.
    #[error("garbled reply: {0}")]
    Garbled(String),
    /// A number outside its field's valid range (e.g. above [`RPM_MAX`]).
    #[error("{field} = {value} is out of range")]
    OutOfRange {
        /// The field, e.g. `rpm`.
        field: &'static str,
        /// Its text as received.
        value: String,
    },
    /// A field that reads as a number but not a finite one (`NaN`, `inf`, `1e999`).
    #[error("{field} is not a finite number: {value:?}")]
    NonFinite {
        /// The field, e.g. `egt_c`.
        field: &'static str,
        /// Its text as received.
        value: String,
    },
}

/// Rejections by kind, and lines accepted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EcuCounters {
    /// Telemetry replies accepted.
    pub lines: u64,
    /// Command echoes seen (the ECU repeats every command line before its reply).
    pub echoes: u64,
    /// Status (`RSS`) and fuel-information (`RFI`) replies accepted.
    pub statuses: u64,
    /// Commands acknowledged (`1,HS,OK`).
    pub acks: u64,
    /// Commands refused (`1,HS,ERR,<n>`).
    pub refusals: u64,
    /// Lines rejected as [`EcuError::Unknown`].
    pub unknown: u64,
    /// Lines rejected as [`EcuError::Truncated`].
    pub truncated: u64,
    /// Lines rejected as [`EcuError::Garbled`].
    pub garbled: u64,
    /// Lines rejected as [`EcuError::OutOfRange`].
    pub out_of_range: u64,
    /// Lines rejected as [`EcuError::NonFinite`].
    pub non_finite: u64,
}

impl EcuCounters {
    /// Lines rejected, all kinds together.
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

/// A command line from the PC, by JetCat mnemonic.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PcCommand {
    /// `RAC,1`: read actual values (the telemetry poll).
    ReadActual,
    /// `RSS,1`: read system status (the off condition).
    ReadStatus,
    /// `RFI,1`: read fuel information (for the battery voltage).
    ReadFuel,
    /// `TCO,1`: start the engine.
    Start,
    /// `TCO,0`: stop the engine.
    Stop,
    /// `WPE,<pct>`: the throttle, %.
    Throttle(f64),
}

impl PcCommand {
    /// The line, `\r` included, for ECU address 1.
    pub fn encode(&self) -> String {
        match self {
            PcCommand::ReadActual => "1,RAC,1\r".into(),
            PcCommand::ReadStatus => "1,RSS,1\r".into(),
            PcCommand::ReadFuel => "1,RFI,1\r".into(),
            PcCommand::Start => "1,TCO,1\r".into(),
            PcCommand::Stop => "1,TCO,0\r".into(),
            PcCommand::Throttle(pct) => format!("1,WPE,{}\r", (pct * 10.0).round() / 10.0),
        }
    }

    /// The reply this command gets.
    fn context(&self) -> Context {
        match self {
            PcCommand::ReadActual => Context::Actual,
            PcCommand::ReadStatus => Context::Status,
            PcCommand::ReadFuel => Context::Fuel,
            _ => Context::Ack,
        }
    }
}

/// Why a command line was not understood, with JetCat's error number.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    /// Not `<address>,<MNEMONIC>,<parameter>` at all, the line as received.
    #[error("not a command line: {0:?}")]
    NotACommand(String),
    /// A mnemonic this ECU does not know (e.g. `XYZ`).
    #[error("unknown command {0}")]
    Unknown(String),
    /// A known mnemonic with too few or too many parameters.
    #[error("{0}: wrong parameter count")]
    ParameterCount(String),
    /// A known mnemonic with a parameter it cannot take (e.g. `WPE,150`).
    #[error("{0}: parameter out of range")]
    OutOfRange(String),
}

impl CommandError {
    /// JetCat's error number for the `HS,ERR` reply (1 unknown command,
    /// 2 wrong parameter count, 4 parameter out of range).
    pub fn code(&self) -> u8 {
        match self {
            CommandError::NotACommand(_) | CommandError::Unknown(_) => 1,
            CommandError::ParameterCount(_) => 2,
            CommandError::OutOfRange(_) => 4,
        }
    }
}

/// Parses a command line (without its `\r`): `<address>,<MNEMONIC>,<parameter>`.
/// Mnemonics are case-insensitive, as JetCat's ECU takes them.
pub fn parse_command(line: &[u8]) -> Result<PcCommand, CommandError> {
    let text = std::str::from_utf8(line).map_err(|_| CommandError::NotACommand(format!("{line:?}")))?;
    let fields: Vec<&str> = text.trim().split(',').map(str::trim).collect();
    let (Some(address), Some(mnemonic)) = (fields.first(), fields.get(1)) else {
        return Err(CommandError::NotACommand(text.chars().take(40).collect()));
    };
    if address.parse::<u8>().is_err() || mnemonic.len() != 3 || !mnemonic.bytes().all(|b| b.is_ascii_alphabetic()) {
        return Err(CommandError::NotACommand(text.chars().take(40).collect()));
    }
    let mnemonic = mnemonic.to_ascii_uppercase();
    if mnemonic == "HS" {
        return Err(CommandError::NotACommand(text.chars().take(40).collect()));
    }
    let [_, _, parameter] = fields[..] else { return Err(CommandError::ParameterCount(mnemonic)) };
    let out_of_range = || CommandError::OutOfRange(mnemonic.clone());
    match (mnemonic.as_str(), parameter) {
        ("RAC", "1") => Ok(PcCommand::ReadActual),
        ("RSS", "1") => Ok(PcCommand::ReadStatus),
        ("RFI", "1") => Ok(PcCommand::ReadFuel),
        ("TCO", "1") => Ok(PcCommand::Start),
        ("TCO", "0") => Ok(PcCommand::Stop),
        ("RAC" | "RSS" | "RFI" | "TCO", _) => Err(out_of_range()),
        ("WPE", p) => match p.parse::<f64>() {
            Ok(pct) if pct.is_finite() && (0.0..=THROTTLE_MAX_PCT).contains(&pct) => Ok(PcCommand::Throttle(pct)),
            _ => Err(out_of_range()),
        },
        _ => Err(CommandError::Unknown(mnemonic)),
    }
}

/// What a reply line answers, from the echo before it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Context {
    Actual,
    Status,
    Fuel,
    Ack,
}

/// One reply from the ECU.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EcuReply {
    /// `RAC`: the telemetry.
    Actual(EcuReading),
    /// `RSS`: the off condition's code (named by [`state::OffCondition::from_code`]).
    Status {
        /// JetCat's off-condition number, 0..=255.
        off_condition: u32,
    },
    /// `RFI`: the ECU's battery voltage (the fuel fields are not used).
    Fuel {
        /// The battery voltage, V, to 0.01 V.
        battery_v: f64,
    },
    /// A command was accepted.
    Ack,
    /// A command was refused, with JetCat's error number.
    Refused(u8),
}

/// The reply line for a status request: the off condition, then JetCat's
/// four speed-control fields, which this ECU leaves at 0.
pub fn encode_status(off_condition: u8) -> String {
    format!("1,HS,OK,{off_condition},0,0,0,0\r")
}

/// The reply line for a fuel-information request: fuel flow (ml/min), fuel
/// left (ml) and set RPM, which this ECU leaves at 0, the battery voltage
/// to 0.01 V, and the last run's time (s).
pub fn encode_fuel(battery_v: f64, last_run_s: u32) -> String {
    format!("1,HS,OK,0,0,0,{:.2},{last_run_s}\r", battery_v)
}

/// The acknowledgement line.
pub const ACK: &str = "1,HS,OK\r";

/// The refusal line with JetCat's error number.
pub fn encode_refusal(code: u8) -> String {
    format!("1,HS,ERR,{code}\r")
}

fn decode_small(field: &'static str, text: &str) -> Result<u32, EcuError> {
    match text.parse::<u8>() {
        Ok(v) => Ok(u32::from(v)),
        Err(_) if !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit()) => {
            Err(EcuError::OutOfRange { field, value: text.into() })
        }
        Err(_) => Err(EcuError::Garbled(format!("{field} is not an integer: {text:?}"))),
    }
}

/// Decodes a reply in its context (what the echo before it asked).
fn decode_in_context(line: &[u8], context: Context) -> Result<EcuReply, EcuError> {
    if context == Context::Actual {
        return decode_line(line).map(EcuReply::Actual);
    }
    let text = std::str::from_utf8(line)
        .ok()
        .filter(|t| t.bytes().all(|b| b.is_ascii_graphic() || b == b' '))
        .ok_or_else(|| EcuError::Garbled("bytes that are not printable ASCII".into()))?;
    let fields: Vec<&str> = text.trim_end_matches(['\r', '\n']).split(',').map(str::trim).collect();
    match (context, &fields[..]) {
        (_, ["1", "HS", "ERR", code]) => Ok(EcuReply::Refused(decode_small("error", code)? as u8)),
        (Context::Ack, ["1", "HS", "OK"]) => Ok(EcuReply::Ack),
        (Context::Status, ["1", "HS", "OK", off, ..]) => {
            Ok(EcuReply::Status { off_condition: decode_small("off_condition", off)? })
        }
        (Context::Fuel, ["1", "HS", "OK", _flow, _rest, _set_rpm, battery, ..]) => {
            Ok(EcuReply::Fuel { battery_v: number("battery_v", battery, 0.0, BATTERY_MAX_V)? })
        }
        (_, ["1", "HS", ..] | ["1"]) => Err(EcuError::Truncated { fields: fields.len() }),
        _ => Err(EcuError::Unknown(text.chars().take(40).collect())),
    }
}

/// Splits a byte stream into `\r`-terminated lines and decodes each,
/// counting rejections. A line longer than [`MAX_LINE`] is dropped up to the
/// next `\r` and counted once as garbled.
#[derive(Clone, Debug, Default)]
pub struct LineDecoder {
    line: Vec<u8>,
    /// What the next reply answers, from the last echo.
    context: Option<Context>,
    overlong: bool,
    counters: EcuCounters,
    last_error: Option<EcuError>,
}

impl LineDecoder {
    /// A decoder at the start of a line, with no reply expected yet (the
    /// first reply without an echo before it is taken as telemetry).
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds bytes; calls `on_reading` for every valid telemetry reply, in order.
    pub fn push(&mut self, bytes: &[u8], mut on_reading: impl FnMut(EcuReading)) {
        self.push_replies(bytes, |reply| {
            if let EcuReply::Actual(r) = reply {
                on_reading(r)
            }
        })
    }

    /// Feeds bytes; calls `on_reply` for every valid reply of any kind, in order.
    /// Command echoes set what the next reply answers (telemetry when no
    /// echo came before it) and are counted in `echoes`.
    pub fn push_replies(&mut self, bytes: &[u8], mut on_reply: impl FnMut(EcuReply)) {
        for &b in bytes {
            if b == EOL {
                // Blank lines (e.g. a stray `\r\n` pair) are no replies and no errors.
                let blank = !self.overlong && self.line.iter().all(|b| b.is_ascii_whitespace());
                if !blank {
                    self.finish_line(&mut on_reply);
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

    fn finish_line(&mut self, on_reply: &mut impl FnMut(EcuReply)) {
        if !self.overlong {
            if let Ok(command) = parse_command(&self.line) {
                self.counters.echoes += 1;
                self.context = Some(command.context());
                return;
            }
        }
        let result = if self.overlong {
            Err(EcuError::Garbled(format!("line longer than {MAX_LINE} bytes")))
        } else {
            decode_in_context(&self.line, self.context.take().unwrap_or(Context::Actual))
        };
        match result {
            Ok(reply) => {
                match reply {
                    EcuReply::Actual(_) => self.counters.lines += 1,
                    EcuReply::Status { .. } | EcuReply::Fuel { .. } => self.counters.statuses += 1,
                    EcuReply::Ack => self.counters.acks += 1,
                    EcuReply::Refused(_) => self.counters.refusals += 1,
                }
                on_reply(reply);
            }
            Err(e) => {
                self.counters.count::<()>(&Err(e.clone()));
                self.last_error = Some(e);
            }
        }
    }

    /// Drops a partial line (e.g. when a poll went unanswered), counting it as truncated.
    pub fn expire_partial(&mut self) {
        self.context = None;
        if !self.line.is_empty() || self.overlong {
            let e = EcuError::Truncated { fields: self.line.split(|b| *b == b',').count() };
            self.counters.count::<()>(&Err(e.clone()));
            self.last_error = Some(e);
            self.line.clear();
            self.overlong = false;
        }
    }

    /// Lines accepted and rejected so far, by kind.
    pub fn counters(&self) -> &EcuCounters {
        &self.counters
    }

    /// Why the latest rejected line was rejected (`None` if none was).
    pub fn last_error(&self) -> Option<&EcuError> {
        self.last_error.as_ref()
    }
}
