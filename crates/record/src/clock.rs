//! Which clock a recording's `log_time` is on, and when its messages happened.
//!
//! Recordings made before wall-clock log times have `log_time` on
//! `CLOCK_MONOTONIC` (ns since boot, dated 1970 by every viewer); newer ones
//! on `CLOCK_REALTIME` (ns since the Unix epoch), declared by the metadata key
//! [`KEY_LOG_TIME_CLOCK`](crate::meta::KEY_LOG_TIME_CLOCK). Both carry the two clocks read together at the
//! start of the run, so any message of either kind has a wall-clock time:
//!
//! ```
//! use std::collections::BTreeMap;
//! use jetbench_record::clock::{ClockOrigin, LogClock, TimeBase};
//! use jetbench_record::meta::RunMetadata;
//!
//! let origin = ClockOrigin { monotonic_ns: 5_000_000_000, realtime_ns: 1_780_000_000_000_000_000 };
//! // An old recording: monotonic log times and the origin, no clock key.
//! let old: BTreeMap<String, String> = [
//!     ("monotonic_ns_at_start".to_string(), "5000000000".to_string()),
//!     ("realtime_ns_at_start".to_string(), "1780000000000000000".to_string()),
//! ]
//! .into();
//! let base = TimeBase::new(&[("jetbench".to_string(), old)].into(), Some(5_000_000_000));
//! assert_eq!(base.log_clock, LogClock::Monotonic);
//! assert_eq!(base.unix_ns(6_000_000_000), Some(1_780_000_001_000_000_000));
//!
//! // A new one declares its clock; log times already are wall-clock times.
//! let (name, new) = RunMetadata::wall_clock(origin).record();
//! let base = TimeBase::new(&[(name, new)].into(), None);
//! assert_eq!(base.log_clock, LogClock::Realtime);
//! assert_eq!(base.unix_ns(1_780_000_001_000_000_000), Some(1_780_000_001_000_000_000));
//! ```

use std::collections::BTreeMap;

use crate::meta::{KEY_LOG_TIME_CLOCK, KEY_MONOTONIC_NS_AT_START, KEY_REALTIME_NS_AT_START};

/// Log times below this (2001-09-09) are monotonic: a machine would have to
/// run 31 years without a reboot for its monotonic clock to get there.
const EPOCH_TIMES_FROM_NS: u64 = 1_000_000_000_000_000_000;

/// The clock a recording's `log_time` is on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogClock {
    /// ns since boot (recordings before wall-clock log times).
    Monotonic,
    /// ns since the Unix epoch.
    Realtime,
}

impl LogClock {
    /// The POSIX name, as written under [`LOG_TIME_CLOCK_KEY`].
    pub fn name(self) -> &'static str {
        match self {
            LogClock::Monotonic => "CLOCK_MONOTONIC",
            LogClock::Realtime => "CLOCK_REALTIME",
        }
    }

    fn from_name(name: &str) -> Option<LogClock> {
        [LogClock::Monotonic, LogClock::Realtime].into_iter().find(|c| c.name() == name)
    }
}

/// The two clocks read together, ns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClockOrigin {
    /// `CLOCK_MONOTONIC`, ns.
    pub monotonic_ns: u64,
    /// `CLOCK_REALTIME`, ns since the Unix epoch.
    pub realtime_ns: u64,
}

impl ClockOrigin {
    /// Both clocks now.
    pub fn now() -> ClockOrigin {
        ClockOrigin { monotonic_ns: monotonic_ns(), realtime_ns: realtime_ns() }
    }
}

/// How to turn a recording's log times into wall-clock times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TimeBase {
    /// The clock the log times were taken on.
    pub log_clock: LogClock,
    /// Where the recording says both clocks stood at its start.
    pub origin: Option<ClockOrigin>,
}

impl TimeBase {
    /// From a recording's metadata records (the keys are looked up in every
    /// record) and its first log time, for files that do not declare their clock.
    pub fn new(metadata: &BTreeMap<String, BTreeMap<String, String>>, first_log_time_ns: Option<u64>) -> TimeBase {
        let find = |key: &str| metadata.values().find_map(|entries| entries.get(key));
        let number = |key: &str| find(key).and_then(|v| v.trim().parse::<u64>().ok());
        let declared = find(KEY_LOG_TIME_CLOCK).and_then(|name| LogClock::from_name(name.trim()));
        let log_clock = declared.unwrap_or(match first_log_time_ns {
            Some(t) if t >= EPOCH_TIMES_FROM_NS => LogClock::Realtime,
            _ => LogClock::Monotonic,
        });
        let origin = number(KEY_MONOTONIC_NS_AT_START)
            .zip(number(KEY_REALTIME_NS_AT_START))
            .map(|(monotonic_ns, realtime_ns)| ClockOrigin { monotonic_ns, realtime_ns });
        TimeBase { log_clock, origin }
    }

    /// The wall-clock time of a message logged at `log_time_ns`, ns since the
    /// Unix epoch; `None` for a monotonic recording without an origin.
    pub fn unix_ns(&self, log_time_ns: u64) -> Option<u64> {
        match (self.log_clock, self.origin) {
            (LogClock::Realtime, _) => Some(log_time_ns),
            (LogClock::Monotonic, Some(o)) => {
                let since_start = log_time_ns as i128 - o.monotonic_ns as i128;
                u64::try_from(o.realtime_ns as i128 + since_start).ok()
            }
            (LogClock::Monotonic, None) => None,
        }
    }
}

/// `CLOCK_REALTIME` now, ns since the Unix epoch.
pub fn realtime_ns() -> u64 {
    clock_ns(libc::CLOCK_REALTIME)
}

/// `CLOCK_MONOTONIC` now, ns: the clock of every sample's `stamp_ns`.
pub fn monotonic_ns() -> u64 {
    clock_ns(libc::CLOCK_MONOTONIC)
}

fn clock_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec, and both clocks exist on Linux.
    unsafe { libc::clock_gettime(clock, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// A wall-clock time in the machine's local time zone, e.g.
/// `2026-11-24 06:10:03.123 +0100`; `None` if it cannot be represented.
pub fn format_local(unix_ns: u64) -> Option<String> {
    let secs = libc::time_t::try_from(unix_ns / 1_000_000_000).ok()?;
    // SAFETY: an all-zero `tm` is a valid value to be overwritten.
    let mut tm: libc::tm = unsafe { std::mem::zeroed() };
    // SAFETY: both pointers are valid for the call; localtime_r is thread-safe.
    if unsafe { libc::localtime_r(&secs, &mut tm) }.is_null() {
        return None;
    }
    let offset_min = tm.tm_gmtoff / 60;
    let sign = if offset_min < 0 { '-' } else { '+' };
    Some(format!(
        "{:04}-{:02}-{:02} {:02}:{:02}:{:02}.{:03} {sign}{:02}{:02}",
        tm.tm_year + 1900,
        tm.tm_mon + 1,
        tm.tm_mday,
        tm.tm_hour,
        tm.tm_min,
        tm.tm_sec,
        unix_ns % 1_000_000_000 / 1_000_000,
        offset_min.abs() / 60,
        offset_min.abs() % 60,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(entries: &[(&str, &str)]) -> BTreeMap<String, BTreeMap<String, String>> {
        let record = entries.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        [("jetbench".to_string(), record)].into()
    }

    #[test]
    fn undeclared_files_are_judged_by_their_log_times() {
        assert_eq!(TimeBase::new(&BTreeMap::new(), Some(3_600_000_000_000)).log_clock, LogClock::Monotonic);
        assert_eq!(TimeBase::new(&BTreeMap::new(), Some(1_780_000_000_000_000_000)).log_clock, LogClock::Realtime);
        assert_eq!(TimeBase::new(&BTreeMap::new(), None).unix_ns(5), None);
    }

    #[test]
    fn a_declared_clock_wins_and_garbage_is_ignored() {
        let m = meta(&[(KEY_LOG_TIME_CLOCK, "CLOCK_MONOTONIC"), (KEY_MONOTONIC_NS_AT_START, "x")]);
        let base = TimeBase::new(&m, Some(1_780_000_000_000_000_000));
        assert_eq!(base, TimeBase { log_clock: LogClock::Monotonic, origin: None });
        let m = meta(&[(KEY_LOG_TIME_CLOCK, "CLOCK_TAI")]);
        assert_eq!(TimeBase::new(&m, Some(10)).log_clock, LogClock::Monotonic);
    }

    #[test]
    fn monotonic_times_before_the_origin_map_back_too() {
        let m = meta(&[(KEY_MONOTONIC_NS_AT_START, "5000"), (KEY_REALTIME_NS_AT_START, "1000000")]);
        let base = TimeBase::new(&m, Some(4000));
        assert_eq!(base.unix_ns(4000), Some(999_000));
        assert_eq!(base.unix_ns(0), Some(995_000));
    }

    #[test]
    fn local_time_has_the_date_and_the_offset() {
        let text = format_local(1_780_000_000_123_000_000).unwrap();
        assert!(text.starts_with("2026-05-2") || text.starts_with("2026-05-3"), "{text}");
        assert!(text.contains(".123 "), "{text}");
    }
}
