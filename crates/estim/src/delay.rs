//! The throttle the engine follows through an input delay: the applied throttles of
//! the last cycles, kept in a fixed ring so that a step never allocates.

use jetbench_model::STEP_S;

/// The longest input delay the observer predicts through, s: the longest a model file
/// may hold (its `input_delay` effect's bound).
pub const MAX_INPUT_DELAY_S: f64 = 2.0;

/// Cycles of history: the longest delay in whole cycles, one more for its fraction,
/// and the cycle that just ended.
const RING: usize = 202;

/// The applied throttles of the last cycles and the delay to read them at.
#[derive(Clone, Debug)]
pub(crate) struct ThrottleHistory {
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
    pub(crate) fn new(delay_s: f64) -> Self {
        let in_cycles = delay_s.clamp(0.0, MAX_INPUT_DELAY_S) / STEP_S;
        // 0.12 s is 11.999… cycles in binary: a delay within a nanosecond of whole
        // cycles is whole.
        let whole = (in_cycles - in_cycles.round()).abs() < 1e-7;
        let cycles = if whole { in_cycles.round() } else { in_cycles.floor() };
        Self {
            cycles: cycles as usize,
            fraction: if whole { 0.0 } else { in_cycles - cycles },
            ring: [0.0; RING],
            newest: None,
        }
    }

    /// Records the throttle applied over the cycle that just ended, %, and returns the
    /// one the engine followed over it: applied `delay` earlier. A delay of `n + f`
    /// cycles spans the end of the throttle applied `n` cycles back and the start of
    /// the one `n + 1` back, weighted `1 − f` and `f`. Before the history reaches back
    /// that far, the engine is taken to have followed the first throttle (settled at it).
    pub(crate) fn push(&mut self, applied_pct: f64) -> f64 {
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
    pub(crate) fn clear(&mut self) {
        self.newest = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ring_covers_the_longest_delay_and_its_fraction() {
        assert!(MAX_INPUT_DELAY_S / STEP_S + 2.0 <= RING as f64);
        let bound = jetbench_model::EffectKind::InputDelay.bounds()[0].1;
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
