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

/// The clocks: `CLOCK_MONOTONIC` stamps every sample (comparable across the
/// processes of one machine); `CLOCK_REALTIME` dates recordings.
pub use jetbench_record::clock::{monotonic_ns, realtime_ns};

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
