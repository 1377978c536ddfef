//! Actuation's algorithm: each command applied (clamped to the engine's range),
//! held while commands are late and idled when they stop, completed with what
//! the board acknowledged. Plain code that never touches the bus;
//! [`super::ActuationService`] wires it.

use jetbench_io::Acknowledgement;
use jetbench_model::{THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use jetbench_msgs::{actuation_flags, Actuation, Command};

/// Actuation: applies commands, and idles when they stop coming.
#[derive(Debug, Clone)]
pub struct ActuationStep {
    idle_after_missed: u32,
    missed: u32,
    last: Option<Command>,
}

impl ActuationStep {
    /// Idles the engine after `idle_after_missed` cycles without a command (at least 1).
    pub fn new(idle_after_missed: u32) -> Self {
        ActuationStep { idle_after_missed: idle_after_missed.max(1), missed: 0, last: None }
    }

    /// A fresh command: apply it (clamped to the engine range).
    pub fn on_command(&mut self, command: &Command) -> Actuation {
        self.missed = 0;
        self.last = Some(*command);
        let applied_pct = if command.throttle_pct.is_finite() {
            command.throttle_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT)
        } else {
            THROTTLE_MIN_PCT
        };
        self.output(applied_pct, 0)
    }

    /// A cycle without a fresh command, at `now_ns`: hold the last one, and
    /// after `idle_after_missed` such cycles command idle. Before any command
    /// the sample is stamped `now_ns` (a recording dates it by its stamp).
    pub fn on_missed(&mut self, now_ns: u64) -> Actuation {
        self.missed = self.missed.saturating_add(1);
        let mut out = match self.last {
            Some(c) if self.missed < self.idle_after_missed => {
                self.output(c.throttle_pct.clamp(THROTTLE_MIN_PCT, THROTTLE_MAX_PCT), actuation_flags::STALE)
            }
            _ => self.output(THROTTLE_MIN_PCT, actuation_flags::STALE | actuation_flags::IDLE_FALLBACK),
        };
        if self.last.is_none() {
            out.stamp_ns = now_ns;
        }
        out
    }

    /// Completes this cycle's sample with what the board acknowledged:
    /// `applied_pct` and `round_trip_ns` from the newest acknowledgement, and
    /// flags when the board has not acknowledged this cycle's command in time
    /// (`UNACKED`: the newest acknowledged value stands) or has said nothing
    /// for [`SILENT_AFTER`](jetbench_io::serial::SILENT_AFTER) cycles
    /// (`BOARD_SILENT`: the board idles by its own watchdog, so idle is reported).
    /// `ack = None` with zero counts (a device without acknowledgements)
    /// leaves the sample as it is.
    pub fn with_board(
        &self,
        mut out: Actuation,
        ack: Option<Acknowledgement>,
        unacked_writes: u32,
        silent_writes: u32,
    ) -> Actuation {
        if let Some(a) = ack {
            out.applied_pct = a.applied_pct;
            out.round_trip_ns = a.round_trip_ns;
            if a.idle_fallback {
                out.flags |= actuation_flags::BOARD_IDLE;
            }
        }
        if unacked_writes > 0 {
            out.flags |= actuation_flags::UNACKED;
        }
        if silent_writes >= jetbench_io::serial::SILENT_AFTER {
            out.flags |= actuation_flags::BOARD_SILENT;
            out.applied_pct = THROTTLE_MIN_PCT;
        }
        out
    }

    /// The sample of a stopped actuator: idle, whatever the last command was.
    pub fn on_stop(&self) -> Actuation {
        self.output(THROTTLE_MIN_PCT, actuation_flags::IDLE_FALLBACK)
    }

    /// True while idling for lack of commands.
    pub fn is_idle_fallback(&self) -> bool {
        self.missed >= self.idle_after_missed || (self.missed > 0 && self.last.is_none())
    }

    fn output(&self, applied_pct: f64, flags: u32) -> Actuation {
        let (stamp_ns, command_seq, commanded_pct) =
            self.last.map_or((0, 0, f64::NAN), |c| (c.stamp_ns, c.seq, c.throttle_pct));
        Actuation {
            seq: 0,
            stamp_ns,
            publish_ns: 0,
            written_ns: 0,
            command_seq,
            applied_pct,
            // No command yet: report idle rather than a NaN a reader must special-case.
            commanded_pct: if commanded_pct.is_nan() { THROTTLE_MIN_PCT } else { commanded_pct },
            round_trip_ns: 0,
            missed_cycles: self.missed,
            flags,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn command(seq: u64, throttle_pct: f64) -> Command {
        Command { seq, stamp_ns: seq * 10_000_000, throttle_pct, ..Command::default() }
    }

    #[test]
    fn actuator_idles_on_the_third_missed_cycle() {
        let mut a = ActuationStep::new(3);
        let before_any = a.on_missed(7_000);
        assert_eq!((before_any.stamp_ns, before_any.command_seq), (7_000, 0), "stamped now, not at boot");
        let mut a = ActuationStep::new(3);
        let applied = a.on_command(&command(5, 70.0));
        assert_eq!(applied.applied_pct, 70.0);
        assert_eq!(applied.flags, 0);
        let m1 = a.on_missed(1);
        let m2 = a.on_missed(2);
        let m3 = a.on_missed(3);
        assert_eq!((m1.applied_pct, m2.applied_pct), (70.0, 70.0));
        assert_eq!(m1.flags & actuation_flags::IDLE_FALLBACK, 0);
        assert_eq!(m3.applied_pct, THROTTLE_MIN_PCT);
        assert_ne!(m3.flags & actuation_flags::IDLE_FALLBACK, 0);
        assert_eq!(m3.missed_cycles, 3);
        assert_eq!(m3.command_seq, 5);
        assert!(a.is_idle_fallback());
        // A fresh command ends the fallback.
        assert_eq!(a.on_command(&command(6, 40.0)).flags, 0);
        assert!(!a.is_idle_fallback());
    }

    #[test]
    fn actuation_reports_the_acknowledged_command_and_a_silent_board() {
        let a = ActuationStep::new(3);
        let out = Actuation { applied_pct: 42.345, ..Actuation::default() };
        let ack =
            Acknowledgement { seq: 9, applied_pct: 42.35, round_trip_ns: 180_000, armed: true, idle_fallback: false };
        let acked = a.with_board(out, Some(ack), 0, 0);
        assert_eq!((acked.applied_pct, acked.round_trip_ns, acked.flags), (42.35, 180_000, 0));
        let late = a.with_board(out, Some(ack), 5, 0);
        assert_eq!((late.applied_pct, late.flags), (42.35, actuation_flags::UNACKED), "slow but alive");
        let silent = a.with_board(out, Some(ack), 3, 3);
        assert_eq!(silent.applied_pct, THROTTLE_MIN_PCT);
        assert_eq!(silent.flags, actuation_flags::UNACKED | actuation_flags::BOARD_SILENT);
        let never = a.with_board(out, None, 1, 1);
        assert_eq!((never.applied_pct, never.flags), (42.345, actuation_flags::UNACKED));
        assert_eq!(a.with_board(out, None, 0, 0), out, "a device without acknowledgements");
    }

    #[test]
    fn actuator_clamps_and_rejects_nan() {
        let mut a = ActuationStep::new(3);
        assert_eq!(a.on_command(&command(1, 140.0)).applied_pct, THROTTLE_MAX_PCT);
        assert_eq!(a.on_command(&command(2, f64::NAN)).applied_pct, THROTTLE_MIN_PCT);
    }
}
