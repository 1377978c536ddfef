//! The throttle path: what happens to a commanded throttle before the engine follows
//! it. One type, [`ThrottlePath`], runs the input delay, the rate limit and the
//! actuator lag for every user of the model: the plant (tick by tick, [`SUBSTEPS`]
//! ticks per [`STEP_S`] cycle), the estimator (the throttle the engine followed over
//! each cycle) and the controllers' predictor (through the plant it copies). One rule,
//! [`DelaySplit`], splits a delay into whole cycles and a fraction of one more.
//!
//! ```
//! use jetbench_model::{DelaySplit, Effects, ThrottlePath};
//!
//! // 125 ms of delay: twelve whole cycles and half of one more.
//! let effects = Effects::new(["input_delay:delay_s=0.125".parse()?])?;
//! assert_eq!(DelaySplit::of(0.125).cycles_to_full_effect(), 13);
//! let mut path = ThrottlePath::new(&effects);
//! path.start_at(25.0);
//! let followed: Vec<f64> = (0..14).map(|_| path.cycle_mean(80.0)).collect();
//! // Twelve cycles of idle, one half way (the step fills half of that cycle), then 80 %.
//! assert!(followed[..12].iter().all(|&u| u == 25.0));
//! assert_eq!((followed[12], followed[13]), (52.5, 80.0));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::{EffectKind, Effects, STEP_S, SUBSTEPS};

/// The longest input delay a model file may hold, s (its `input_delay` effect's
/// bound): the estimator predicts through any of them.
pub const MAX_INPUT_DELAY_S: f64 = 2.0;

/// One tick of the throttle path, s: [`STEP_S`] / [`SUBSTEPS`] (1 ms).
pub const TICK_S: f64 = STEP_S / SUBSTEPS as f64;

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

/// The commanded throttles of the last cycles, newest first, in a fixed ring (a
/// path never allocates, so copying a plant every control cycle is free of the heap).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Rows {
    ring: [f64; RING],
    /// Where the newest throttle is; `None` before the first.
    newest: Option<usize>,
    /// How far back a read may reach: a read further back gets the oldest row kept.
    depth: usize,
}

impl Rows {
    fn push(&mut self, pct: f64) {
        let newest = match self.newest {
            Some(i) => (i + 1) % RING,
            None => {
                self.ring = [pct; RING];
                0
            }
        };
        self.ring[newest] = pct;
        self.newest = Some(newest);
    }

    /// The throttle commanded `cycles` cycles before the newest (0: the newest).
    fn back(&self, cycles: usize) -> f64 {
        let newest = self.newest.unwrap_or(0);
        self.ring[(newest + RING - cycles.min(self.depth)) % RING]
    }

    /// Row `j` relative to the newest (0: the newest, −1 the one before, …).
    fn row(&self, j: i64) -> f64 {
        self.back(j.min(0).unsigned_abs() as usize)
    }
}

/// The input delay of a path: in seconds (what the tick-level path reads at) and
/// split into cycles (what the cycle-level path reads at).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Delay {
    delay_s: f64,
    split: DelaySplit,
}

/// How the rows a window of commanded throttle covers share it
/// ([`ThrottlePath::window`]): at most two, as rows are held for a whole cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Window {
    /// The whole window lies in one row: this throttle, %.
    Held(f64),
    /// The window starts in `early` and ends in `late` (both %); `early_weight` is the
    /// share of the window in `early`, in `[0, 1]`.
    Spans {
        /// The earlier row's throttle, %.
        early: f64,
        /// The later row's throttle, %.
        late: f64,
        /// Share of the window in the earlier row.
        early_weight: f64,
    },
}

/// The throttle path from the command to the throttle the engine follows, in the
/// model's physical order: input delay (ECU processing and fuel transport), rate limit
/// (the ECU's acceleration schedule), actuator lag (fuel-pump dynamics). Built from a
/// model's effects ([`ThrottlePath::new`]); each absent effect is skipped.
///
/// Stepped once a cycle with the commanded throttle ([`ThrottlePath::push`]), then
/// read either tick by tick ([`ThrottlePath::tick`], what the plant integrates with)
/// or as the mean over the cycle ([`ThrottlePath::cycle_mean`], what the estimator
/// predicts with). Every throttle is in % of the ECU's range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThrottlePath {
    delay: Option<Delay>,
    /// The most the throttle may rise and fall in one tick, %.
    rate_limit: Option<(f64, f64)>,
    /// The lag's step response after one tick, `1 − e^(−tick/τ)`.
    lag_alpha: Option<f64>,
    rows: Rows,
    rate_limited_pct: f64,
    lagged_pct: f64,
    followed_pct: f64,
}

impl ThrottlePath {
    /// The path of a model's `input_delay`, `rate_limit` and `actuator_lag` effects (a
    /// zero delay or time constant is none), not yet started: the first
    /// [`ThrottlePath::push`] settles it at its throttle, or [`ThrottlePath::start_at`]
    /// does.
    pub fn new(effects: &Effects) -> Self {
        let values = |kind: EffectKind| effects.get(kind).map(|e| e.values());
        let delay_s = Some(effects.input_delay_s()).filter(|d| *d > 0.0);
        Self::with(
            delay_s,
            values(EffectKind::RateLimit).map(|v| (v[0], v[1])),
            values(EffectKind::ActuatorLag).map(|v| v[0]),
        )
    }

    /// A path with only an input delay of `delay_s` (0: none), s.
    pub fn delay_only(delay_s: f64) -> Self {
        Self::with(Some(delay_s).filter(|d| *d > 0.0), None, None)
    }

    fn with(delay_s: Option<f64>, rate_limit_pct_per_s: Option<(f64, f64)>, lag_time_constant_s: Option<f64>) -> Self {
        let split = delay_s.map(DelaySplit::of);
        // Rows the delay reaches back into, one more for a tick's mean across a row boundary.
        let depth = split.map_or(0, |s| s.cycles_to_full_effect() + 1);
        Self {
            delay: delay_s.zip(split).map(|(delay_s, split)| Delay { delay_s, split }),
            rate_limit: rate_limit_pct_per_s.map(|(up, down)| (up * TICK_S, down * TICK_S)),
            lag_alpha: lag_time_constant_s.filter(|tau| *tau > 0.0).map(|tau| 1.0 - (-TICK_S / tau).exp()),
            rows: Rows { ring: [0.0; RING], newest: None, depth },
            rate_limited_pct: 0.0,
            lagged_pct: 0.0,
            followed_pct: 0.0,
        }
    }

    /// Settles the path at `pct`, %: every throttle in flight is `pct`, the rate limit
    /// and the lag are at rest on it.
    pub fn start_at(&mut self, pct: f64) {
        self.rows.newest = None;
        self.rows.push(pct);
        self.rate_limited_pct = pct;
        self.lagged_pct = pct;
        self.followed_pct = pct;
    }

    /// Forgets every throttle: the next [`ThrottlePath::push`] starts the path again.
    pub fn clear(&mut self) {
        self.rows.newest = None;
    }

    /// The input delay, s (0: none).
    pub fn delay_s(&self) -> f64 {
        self.delay.map_or(0.0, |d| d.delay_s)
    }

    /// The path's settings, bit for bit: two paths with the same settings shape the same
    /// throttles alike (the input delay, the rate limit's steps per tick, the lag's
    /// step response after one tick).
    pub(crate) fn settings(&self) -> [Option<u64>; 4] {
        [
            self.delay.map(|d| d.delay_s.to_bits()),
            self.rate_limit.map(|r| r.0.to_bits()),
            self.rate_limit.map(|r| r.1.to_bits()),
            self.lag_alpha.map(f64::to_bits),
        ]
    }

    /// True when the path changes the throttle at all (any of its three effects).
    pub fn shapes(&self) -> bool {
        self.delay.is_some() || self.rate_limit.is_some() || self.lag_alpha.is_some()
    }

    /// True for an input delay alone: then the throttle over any window is a mean of
    /// held rows, in closed form ([`ThrottlePath::window`]).
    pub fn is_pure_delay(&self) -> bool {
        self.delay.is_some() && self.rate_limit.is_none() && self.lag_alpha.is_none()
    }

    /// The throttle the engine followed at the end of the last tick read, %.
    pub fn followed_pct(&self) -> f64 {
        self.followed_pct
    }

    /// Starts a cycle with `commanded_pct`, %, commanded over it (the first push of an
    /// unstarted path settles it there: [`ThrottlePath::start_at`]).
    pub fn push(&mut self, commanded_pct: f64) {
        if self.rows.newest.is_none() {
            self.start_at(commanded_pct);
        } else {
            self.rows.push(commanded_pct);
        }
    }

    /// The throttle the engine follows over tick `tick` (`0..SUBSTEPS`) of the cycle
    /// just pushed, %: the commanded throttle averaged over the tick one delay earlier
    /// (averaging makes the response a smooth function of the delay, which a fit
    /// needs), then rate-limited, then lagged. Ticks must be read in order, each once.
    ///
    /// A delay that is no whole number of ticks puts a change of the command
    /// inside a tick. The rate limit then runs that tick in two parts, toward the
    /// earlier command and then toward the later one, as a limiter in continuous
    /// time would: limited from the tick's mean instead, a step larger than one
    /// tick's travel would start its ramp on the same tick for any delay within
    /// the tick, and a fit of a delay beside a rate limit would find no gradient
    /// to follow (its Jacobian column zero). A change on a tick's edge comes out
    /// as before.
    #[inline]
    pub fn tick(&mut self, tick: usize) -> f64 {
        match self.delay {
            None => self.shape(self.rows.back(0)),
            Some(d) => {
                let (early_share, early, late) = self.delayed_span(tick as f64 * TICK_S - d.delay_s, TICK_S);
                match self.rate_limit {
                    Some((up, down)) if early_share > 0.0 && early_share < 1.0 => {
                        let late_share = 1.0 - early_share;
                        let mut r = self.rate_limited_pct;
                        r += (early - r).clamp(-down * early_share, up * early_share);
                        r += (late - r).clamp(-down * late_share, up * late_share);
                        self.rate_limited_pct = r;
                        self.lag(r)
                    }
                    _ => self.shape(early_share * early + (1.0 - early_share) * late),
                }
            }
        }
    }

    /// [`ThrottlePath::tick`] for ticks `first..first + count` in order, each throttle
    /// handed to `each`: the same values, with what does not change from tick to tick
    /// (the row without a delay) read once.
    #[inline]
    pub fn ticks(&mut self, first: usize, count: usize, mut each: impl FnMut(f64)) {
        match self.delay {
            None => {
                let u = self.rows.back(0);
                for _ in 0..count {
                    each(self.shape(u));
                }
            }
            Some(_) => {
                for tick in first..first + count {
                    each(self.tick(tick));
                }
            }
        }
    }

    /// The rate limit and the lag over one tick, from the delayed command `u`, %.
    #[inline(always)]
    fn shape(&mut self, mut u: f64) -> f64 {
        if let Some((up, down)) = self.rate_limit {
            self.rate_limited_pct += (u - self.rate_limited_pct).clamp(-down, up);
            u = self.rate_limited_pct;
        }
        self.lag(u)
    }

    /// The lag over one tick from the rate-limited command `u`, %: what the engine follows.
    #[inline(always)]
    fn lag(&mut self, mut u: f64) -> f64 {
        if let Some(alpha) = self.lag_alpha {
            self.lagged_pct += (u - self.lagged_pct) * alpha;
            u = self.lagged_pct;
        }
        self.followed_pct = u;
        u
    }

    /// For a pure delay ([`ThrottlePath::is_pure_delay`]): the rows of commanded
    /// throttle over ticks `first_tick..first_tick + ticks` of the cycle just pushed,
    /// one delay earlier, in closed form. [`ThrottlePath::followed_pct`] becomes the
    /// row holding the window's end.
    pub fn window(&mut self, first_tick: usize, ticks: usize) -> Window {
        let delay_s = self.delay_s();
        let (from_s, h) = (first_tick as f64 * TICK_S - delay_s, ticks as f64 * TICK_S);
        let first = (from_s / STEP_S + 1e-9).floor() as i64;
        let last = ((from_s + h) / STEP_S - 1e-9).floor() as i64;
        let late = self.rows.row(last);
        self.followed_pct = late;
        if last <= first {
            return Window::Held(late);
        }
        let early_weight = (((first + 1) as f64 * STEP_S - from_s) / h).clamp(0.0, 1.0);
        Window::Spans { early: self.rows.row(first), late, early_weight }
    }

    /// Pushes `commanded_pct`, %, and returns the mean throttle the engine follows over
    /// the cycle. With a delay alone, a delay of `n + f` cycles spans the end of the
    /// throttle commanded `n` cycles back and the start of the one `n + 1` back,
    /// weighted `1 − f` and `f`; with a rate limit or a lag, the mean of the cycle's
    /// [`SUBSTEPS`] ticks.
    pub fn cycle_mean(&mut self, commanded_pct: f64) -> f64 {
        self.push(commanded_pct);
        match self.delay {
            Some(Delay { split, .. }) if self.is_pure_delay() => {
                let followed = if split.fraction == 0.0 {
                    self.rows.back(split.cycles)
                } else {
                    (1.0 - split.fraction) * self.rows.back(split.cycles)
                        + split.fraction * self.rows.back(split.cycles + 1)
                };
                self.followed_pct = followed;
                followed
            }
            _ => (0..SUBSTEPS).map(|k| self.tick(k)).sum::<f64>() / SUBSTEPS as f64,
        }
    }

    /// The commanded throttle over `[from_s, from_s + h]`, times relative to the start
    /// of the newest row (negative: earlier rows), as (the share of the interval in the
    /// earlier row, that row's throttle, the later row's throttle); its mean is
    /// `share · early + (1 − share) · late`. An interval within one row has share 0.
    fn delayed_span(&self, from_s: f64, h: f64) -> (f64, f64, f64) {
        // Row holding the end of the interval (a tolerance keeps an end exactly on a
        // row boundary in the earlier row).
        let j_end = ((from_s + h) / STEP_S - 1e-9).floor().min(0.0) as i64;
        let boundary_s = j_end as f64 * STEP_S;
        let late = self.rows.row(j_end);
        if from_s < boundary_s {
            (((boundary_s - from_s) / h).min(1.0), self.rows.row(j_end - 1), late)
        } else {
            (0.0, late, late)
        }
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
        let mut path = ThrottlePath::delay_only(0.03);
        let followed: Vec<f64> = (0..6).map(|k| path.cycle_mean(10.0 * k as f64)).collect();
        assert_eq!(followed, [0.0, 0.0, 0.0, 0.0, 10.0, 20.0]);
        let path = ThrottlePath::delay_only(0.12);
        assert_eq!(path.delay.map(|d| d.split), Some(DelaySplit { cycles: 12, fraction: 0.0 }));
    }

    #[test]
    fn a_fractional_delay_weights_the_two_throttles_it_spans() {
        let mut path = ThrottlePath::delay_only(0.0125); // 1.25 cycles
        let followed: Vec<f64> = [0.0, 100.0, 100.0, 100.0].into_iter().map(|u| path.cycle_mean(u)).collect();
        // Cycle 2 follows 0.75 of the step applied at cycle 1 and 0.25 of the idle before it.
        assert_eq!(followed, [0.0, 0.0, 75.0, 100.0]);
    }

    #[test]
    fn the_longest_delay_reaches_back_without_wrapping_onto_new_throttles() {
        let mut path = ThrottlePath::delay_only(MAX_INPUT_DELAY_S);
        for k in 0..500 {
            let followed = path.cycle_mean(k as f64);
            assert_eq!(followed, (k as f64 - 200.0).max(0.0));
        }
        path.clear();
        assert_eq!(path.cycle_mean(7.0), 7.0);
    }

    #[test]
    fn the_cycle_mean_of_a_delay_is_the_mean_of_its_ticks() {
        for delay_s in [0.0125, 0.0333, 0.07, 0.1999, 1.234] {
            let (mut by_cycle, mut by_tick) = (ThrottlePath::delay_only(delay_s), ThrottlePath::delay_only(delay_s));
            for k in 0..300 {
                let u = 25.0 + (k * 37 % 75) as f64;
                let mean = by_cycle.cycle_mean(u);
                by_tick.push(u);
                let ticks = (0..SUBSTEPS).map(|j| by_tick.tick(j)).sum::<f64>() / SUBSTEPS as f64;
                assert!((mean - ticks).abs() < 1e-9, "{delay_s} s, cycle {k}: {mean} vs {ticks}");
            }
        }
    }

    #[test]
    fn beside_a_rate_limit_a_delay_moves_the_response_within_a_tick() {
        // A step much larger than a tick's travel at 40 %/s, delayed by 50.0 ms to 51.0 ms:
        // each 0.1 ms of delay starts the ramp 0.1 ms later, so the throttle followed
        // over the next second loses the same amount each time (a fit of the delay has
        // a gradient), and a delay on a tick's edge gives what a tick-wise limit gives.
        let followed_sum = |delay_s: f64| {
            let effects = Effects::new([
                format!("input_delay:delay_s={delay_s}").parse().unwrap(),
                "rate_limit:up_pct_per_s=40,down_pct_per_s=40".parse().unwrap(),
            ])
            .unwrap();
            let mut path = ThrottlePath::new(&effects);
            path.start_at(20.0);
            (0..100).map(|_| path.cycle_mean(80.0)).sum::<f64>()
        };
        let sums: Vec<f64> = (0..=10).map(|k| followed_sum(0.05 + 1e-4 * k as f64)).collect();
        let steps: Vec<f64> = sums.windows(2).map(|w| w[0] - w[1]).collect();
        // 40 %/s for 0.1 ms is 0.004 % a tick, 0.4 of a cycle mean, over the ramp's rows.
        for step in &steps {
            assert!((step - steps[0]).abs() < 1e-9 * sums[0] && *step > 1e-3, "{steps:?}");
        }
        let mut tickwise = ThrottlePath::new(
            &Effects::new(["rate_limit:up_pct_per_s=40,down_pct_per_s=40".parse().unwrap()]).unwrap(),
        );
        tickwise.start_at(20.0);
        let held: f64 = (0..100).map(|k| tickwise.cycle_mean(if k < 5 { 20.0 } else { 80.0 })).sum();
        assert!((held - sums[0]).abs() < 1e-9 * held, "{held} vs {}", sums[0]);
    }

    #[test]
    fn rate_limit_and_lag_slow_a_step_and_settle_on_it() {
        let effects = Effects::new([
            "rate_limit:up_pct_per_s=100,down_pct_per_s=200".parse().unwrap(),
            "actuator_lag:time_constant_s=0.1".parse().unwrap(),
        ])
        .unwrap();
        let mut path = ThrottlePath::new(&effects);
        path.start_at(25.0);
        let followed: Vec<f64> = (0..200).map(|_| path.cycle_mean(75.0)).collect();
        // 50 % at 100 %/s takes 0.5 s, behind a 0.1 s lag.
        assert!(followed[0] < 25.0 + 1.0 && followed[30] < 55.0 && followed[30] > 40.0, "{:?}", &followed[..31]);
        assert!((followed[199] - 75.0).abs() < 1e-4, "{}", followed[199]);
        assert!(followed.windows(2).all(|w| w[1] >= w[0]));
    }
}
