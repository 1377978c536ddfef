//! The input delay, cycle by cycle: the one rule that splits a delay into whole
//! 10 ms cycles and a fraction of one more ([`DelaySplit`]), used by the plant (how
//! many rows of throttle it keeps), the estimator ([`ThrottleHistory`]: the throttle
//! the engine followed over each cycle) and the controllers' predictor (how far ahead
//! a command takes full effect).

use crate::STEP_S;

/// The longest input delay a model file may hold, s (its `input_delay` effect's
/// bound): the estimator predicts through any of them.
pub const MAX_INPUT_DELAY_S: f64 = 2.0;

/// A delay in whole [`STEP_S`] cycles and the fraction of one more.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DelaySplit {
    /// Whole cycles.
    pub cycles: usize,
    /// The fraction of one more cycle, in `[0, 1)`; 0 for a whole number of cycles.
    pub fraction: f64,
}

impl DelaySplit {
    /// `delay_s` (clamped to `[0, MAX_INPUT_DELAY_S]`) in cycles. 0.12 s is 11.999…
    /// cycles in binary: a delay within a nanosecond of whole cycles is whole.
    pub fn of(delay_s: f64) -> Self {
        let in_cycles = delay_s.clamp(0.0, MAX_INPUT_DELAY_S) / STEP_S;
        let whole = (in_cycles - in_cycles.round()).abs() < 1e-7;
        let cycles = if whole { in_cycles.round() } else { in_cycles.floor() };
        DelaySplit { cycles: cycles as usize, fraction: if whole { 0.0 } else { in_cycles - cycles } }
    }

    /// The cycles a throttle takes to reach the engine in full: the whole cycles, and
    /// one more when there is a fraction.
    pub fn cycles_to_full_effect(&self) -> usize {
        self.cycles + usize::from(self.fraction > 0.0)
    }
}

/// Cycles of history: the longest delay in whole cycles, one more for its fraction,
/// and the cycle that just ended.
const RING: usize = 202;

/// The applied throttles of the last cycles and the delay to read them at.
#[derive(Clone, Debug)]
pub struct ThrottleHistory {
    /// The delay in whole cycles,
    cycles: usize,
    /// and the fraction of one more (0 for a whole number of cycles).
    fraction: f64,
    ring: [f64; RING],
    /// Where the newest throttle is; `None` before the first.
    newest: Option<usize>,
}

impl ThrottleHistory {
    /// A history for a delay in `(0, MAX_INPUT_DELAY_S]` s (checked by the caller).
    pub fn new(delay_s: f64) -> Self {
        let DelaySplit { cycles, fraction } = DelaySplit::of(delay_s);
        Self { cycles, fraction, ring: [0.0; RING], newest: None }
    }

    /// Records the throttle applied over the cycle that just ended, %, and returns the
    /// one the engine followed over it: applied `delay` earlier. A delay of `n + f`
    /// cycles spans the end of the throttle applied `n` cycles back and the start of
    /// the one `n + 1` back, weighted `1 − f` and `f`. Before the history reaches back
    /// that far, the engine is taken to have followed the first throttle (settled at it).
    pub fn push(&mut self, applied_pct: f64) -> f64 {
        let newest = match self.newest {
            Some(i) => (i + 1) % RING,
            None => {
                self.ring = [applied_pct; RING];
                0
            }
        };
        self.ring[newest] = applied_pct;
        self.newest = Some(newest);
        let back = |cycles: usize| self.ring[(newest + RING - cycles) % RING];
        if self.fraction == 0.0 {
            back(self.cycles)
        } else {
            (1.0 - self.fraction) * back(self.cycles) + self.fraction * back(self.cycles + 1)
        }
    }

    /// Forgets every throttle.
    pub fn clear(&mut self) {
        self.newest = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ring_covers_the_longest_delay_and_its_fraction() {
        assert!(MAX_INPUT_DELAY_S / STEP_S + 2.0 <= RING as f64);
        let bound = crate::EffectKind::InputDelay.bounds()[0].1;
        assert_eq!(MAX_INPUT_DELAY_S, bound, "the model's input_delay bound");
    }

    #[test]
    fn a_whole_delay_returns_the_throttle_applied_that_many_cycles_back() {
        let mut history = ThrottleHistory::new(0.03);
        let followed: Vec<f64> = (0..6).map(|k| history.push(10.0 * k as f64)).collect();
        assert_eq!(followed, [0.0, 0.0, 0.0, 0.0, 10.0, 20.0]);
        let history = ThrottleHistory::new(0.12);
        assert_eq!((history.cycles, history.fraction), (12, 0.0));
    }

    #[test]
    fn a_fractional_delay_weights_the_two_throttles_it_spans() {
        let mut history = ThrottleHistory::new(0.0125); // 1.25 cycles
        let followed: Vec<f64> = [0.0, 100.0, 100.0, 100.0].into_iter().map(|u| history.push(u)).collect();
        // Cycle 2 follows 0.75 of the step applied at cycle 1 and 0.25 of the idle before it.
        assert_eq!(followed, [0.0, 0.0, 75.0, 100.0]);
    }

    #[test]
    fn the_longest_delay_reaches_back_without_wrapping_onto_new_throttles() {
        let mut history = ThrottleHistory::new(MAX_INPUT_DELAY_S);
        for k in 0..500 {
            let followed = history.push(k as f64);
            assert_eq!(followed, (k as f64 - 200.0).max(0.0));
        }
        history.clear();
        assert_eq!(history.push(7.0), 7.0);
    }
}
