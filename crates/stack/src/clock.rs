//! Time on the bench: the one period every deadline derives from, and the
//! clocks every sample is stamped with.

use std::time::Duration;

/// The control period, ns (100 Hz): the model's step, [`jetbench_model::PERIOD_NS`].
pub const PERIOD_NS: u64 = jetbench_model::PERIOD_NS;

/// The control period.
pub const PERIOD: Duration = Duration::from_nanos(PERIOD_NS);

/// How long a consumer waits for its input before counting a missed cycle:
/// one and a half periods, so ordinary jitter is not a miss.
pub const INPUT_DEADLINE: Duration = Duration::from_nanos(PERIOD_NS + PERIOD_NS / 2);

/// Actuation's deadline: a missed cycle is counted every period after the
/// last command, plus a tenth of a period for jitter.
pub const COMMAND_DEADLINE: Duration = Duration::from_nanos(PERIOD_NS + PERIOD_NS / 10);

/// How far behind its schedule a clocked source (sim-bench's sensor, the
/// latency chain's source) may fall before it restarts its schedule instead
/// of catching up: ten periods, a machine that froze rather than hiccupped.
pub const STALL: Duration = Duration::from_nanos(10 * PERIOD_NS);

/// `CLOCK_MONOTONIC` now, in ns: comparable across processes on one machine.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    debug_assert_eq!(rc, 0);
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// `CLOCK_REALTIME` now, in ns since the Unix epoch (for recording metadata).
pub fn realtime_ns() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadlines_keep_their_meaning() {
        assert_eq!(PERIOD, Duration::from_millis(10));
        assert_eq!(INPUT_DEADLINE, Duration::from_millis(15));
        assert_eq!(COMMAND_DEADLINE, Duration::from_millis(11));
        assert_eq!(STALL, Duration::from_millis(100));
        assert_eq!(jetbench_model::STEP_S, 0.01);
    }
}
