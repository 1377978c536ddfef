//! The data a diagnosis works on: recordings on the model's 10 ms grid, with what a
//! bench does to them (lost rows, spikes, coloured noise) accounted for.
//!
//! - **Gaps.** Rows are placed on the 10 ms grid by the time between them. A run
//!   carries on through a gap of up to [`MAX_HELD_GAP_S`] with the last throttle held
//!   (the convention of every recording: a row's throttle holds until the next row),
//!   so a lost row costs one comparison, not a restart. Longer gaps split runs. Where
//!   the throttle steps inside a gap (its rows on either side differ by more than the
//!   throttle's slope before the gap carries it, by enough throttle-time to matter), when
//!   the engine got the new command is not known: the [`UNKNOWN_STEP_S`] after the gap
//!   are left out of every comparison (a bench whose actuation board acknowledges late
//!   loses exactly those rows).
//! - **Outliers.** A sample further than [`OUTLIER_Z`] robust standard deviations
//!   from the median of its neighbours (a CAN spike, a garbled frame) is left out of
//!   every comparison and counted; the simulation runs on through it.
//! - **Noise.** The sensor noise is modelled as an AR process from the data alone
//!   ([`crate::noise::estimate`]). Fits and scores use its innovations (the residual
//!   prewhitened), the likelihood of coloured noise.
//!
//! Every candidate model is simulated over each whole run from the state fitted to
//! its first two seconds, as a bench engineer would replay a recording through a
//! simulator: no measurement corrects it. Parameters are fitted on the calibration
//! samples (the first part of each file) and judged on the validation samples (the
//! rest). A run is never restarted at the split, because the slow states some
//! effects add (a sensor bias, a sagging gain) are known only by running through the
//! recording from its start.
//!
//! A recording starts some time after the sensor was tared and the engine started, so
//! the slow first-order states (a sensor drift's bias, a discrepancy's thrust history)
//! are in general still on their way at a run's start. Where a hypothesis has them,
//! their starting values are fitted per run with the rest of it ([`RunStart`]), over
//! the calibration part (two seconds do not show a decay of tens of seconds), and
//! charged as parameters like every other fitted value.

use std::cell::RefCell;
use std::ops::Range;

use jetbench_model::{DriveKey, DriveTrack, Plant, SlowStart, State, STEP_S};
use serde::Serialize;

use crate::noise::{self, ArModel, NoiseEstimate};
use crate::series::Series;
use crate::validate::{fit_initial_state_at, Started};
use crate::IdentError;

/// Longest gap a run is simulated through with the throttle held, s.
pub const MAX_HELD_GAP_S: f64 = 1.0;

/// How long after a gap in which the throttle stepped the samples are left out, s: the
/// engine's answer to a step whose time is unknown within the gap (an engine settles in
/// about a second; a lag or a delay it has adds to its answer, not to how far a step's
/// timing carries).
pub const UNKNOWN_STEP_S: f64 = 1.0;

/// A throttle change across a gap further from where the slope before it leads than this,
/// times the grid steps the gap spans (its lost rows and one), is a step inside the gap whose
/// time matters, % · steps: the throttle held through a gap is off by at most that much
/// throttle-time. A 15 % step across one lost row is one, 7.5 % across three; a closed loop's
/// throttle, which moves a per cent or two from row to row, is not (leaving out the second
/// after every gap with any change had left out 41 % of a live closed-loop recording whose
/// board acknowledged 8 % of its rows late).
const STEP_IN_GAP_PCT_STEPS: f64 = 30.0;
/// A sample this many robust standard deviations from its neighbours' median is an outlier.
pub const OUTLIER_Z: f64 = 5.5;
/// Neighbours on each side in the outlier test's median.
const OUTLIER_HALF_WINDOW: usize = 5;
/// RK4 steps per 10 ms in every simulation of a diagnosis: within 0.005 N of the
/// reference 1 kHz integration on every effect, ten times cheaper.
pub const SUBSTEPS: usize = 1;

/// Where a run's simulation starts: the engine's state, fitted to the run's first two
/// seconds, and its slow states, fitted over the calibration part when the hypothesis has
/// them (settled, the model's default, otherwise).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct RunStart {
    pub state: State,
    pub slow: SlowStart,
}

impl From<State> for RunStart {
    fn from(state: State) -> Self {
        Self { state, slow: SlowStart::SETTLED }
    }
}

/// Which samples a sum runs over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Part {
    Calibration,
    Validation,
}

/// One run of consecutive rows, on the 10 ms grid.
#[derive(Clone, Debug)]
pub(crate) struct Run {
    pub series: usize,
    /// The recording's rows in the run.
    pub rows: Range<usize>,
    /// Grid index of each row, from the run's first.
    pub grid: Vec<usize>,
    /// Throttle on the grid (held over lost rows), %.
    pub u: Vec<f64>,
    /// Measured thrust on the grid: NaN where a row is lost or an outlier, N.
    pub y: Vec<f64>,
    /// First grid index of the validation part (`y.len()` when the run has none).
    pub cut: usize,
    /// Grid steps between the run's samples (1 at 100 Hz, 2 for a 50 Hz file): the
    /// spacing the noise model and the prewhitening work at.
    pub stride: usize,
    pub t0_s: f64,
    pub initial: State,
    /// The parts the other way round ([`Problem::reversed`]): fitted after the split,
    /// judged before it.
    pub reversed: bool,
}

impl Run {
    /// Leaves out the [`UNKNOWN_STEP_S`] after each gap in which the throttle stepped (see
    /// the module docs): `u_pct` is the recording's throttle by row. Returns the gaps and the
    /// samples left out.
    fn mask_steps_in_gaps(&mut self, u_pct: &[f64]) -> (usize, usize) {
        let window = (UNKNOWN_STEP_S / STEP_S).round() as usize;
        let (mut stepped, mut masked) = (0, 0);
        for j in 0..self.grid.len().saturating_sub(1) {
            let gap = self.grid[j + 1] - self.grid[j];
            if gap <= self.stride {
                continue;
            }
            let k = self.rows.start + j;
            // Where the throttle's slope before the gap (a ramp) carries it across.
            let slope = match j.checked_sub(1) {
                Some(i) if self.grid[j] - self.grid[i] == self.stride => u_pct[k] - u_pct[k - 1],
                _ => 0.0,
            };
            let steps = (gap / self.stride) as f64;
            let carried = u_pct[k] + slope * steps;
            if (u_pct[k + 1] - carried).abs() * steps <= STEP_IN_GAP_PCT_STEPS {
                continue;
            }
            stepped += 1;
            let (from, len) = (self.grid[j + 1], self.y.len());
            for y in &mut self.y[from..(from + window).min(len)] {
                if y.is_finite() {
                    *y = f64::NAN;
                    masked += 1;
                }
            }
        }
        (stepped, masked)
    }

    pub(crate) fn in_part(&self, k: usize, part: Part) -> bool {
        (k < self.cut) == ((part == Part::Calibration) != self.reversed)
    }

    /// Grid samples a simulation covers: up to the split when only the calibration part is
    /// asked for and it comes first, the whole run otherwise.
    fn end(&self, calibration_only: bool) -> usize {
        if calibration_only && !self.reversed {
            self.cut.min(self.u.len())
        } else {
            self.u.len()
        }
    }
}

/// A sample left out as an outlier.
#[derive(Clone, Debug, Serialize)]
pub struct Outlier {
    /// Which file (index in the order given).
    pub file: usize,
    /// Its time in the recording, s.
    pub t_s: f64,
    /// Its distance from its neighbours' median, N.
    pub deviation_n: f64,
}

/// What the data was like, and what was done about it.
#[derive(Clone, Debug, Serialize)]
pub struct DataReport {
    /// The sensor noise model (AR, from the data alone).
    pub model: String,
    /// The AR coefficients of the noise model, lag 1 first (empty: white noise).
    pub ar: Vec<f64>,
    /// Standard deviation of the noise, N.
    pub sigma_n: f64,
    /// Standard deviation of the noise model's innovations (what prewhitening leaves), N.
    pub innovation_sigma_n: f64,
    /// The noise floor: the mean absolute value of the noise on the held-out part, N
    /// ([`noise::held_out_floor`]).
    pub floor_n: f64,
    /// Samples left out as outliers.
    pub outliers_removed: usize,
    /// The first of them, where and how far off.
    pub outliers: Vec<Outlier>,
    /// Gaps inside runs (simulated through with the throttle held).
    pub gaps: usize,
    /// Rows missing in those gaps.
    pub lost_rows: usize,
    /// Gaps longer than [`MAX_HELD_GAP_S`], where a run ends and the next starts afresh.
    pub run_splits: usize,
    /// Gaps in which the throttle stepped, the [`UNKNOWN_STEP_S`] after each left out.
    pub steps_in_gaps: usize,
    /// Samples left out after them.
    pub after_steps_in_gaps: usize,
    /// Runs of consecutive rows the recordings make, each simulated from its own start.
    pub runs: usize,
    /// Notes from loading (another sampling rate, ...).
    pub notes: Vec<String>,
    /// True when nothing explained the residual and the noise model (and the floor) were
    /// refitted on it: the data's second differences miss a noise's slow parts.
    pub from_residual: bool,
    /// The floor from the data alone, before that, N.
    pub floor_from_data_n: f64,
    /// Rows where the force reading sat at the end of its range (a clipping sensor): an
    /// artefact of the recording, left out like gaps, never modelled as engine physics.
    pub clipped_rows: usize,
    /// The readings it clipped at, N (top, bottom).
    pub clipped_at_n: Vec<f64>,
}

/// Recordings split into calibration and validation samples.
#[derive(Clone)]
pub(crate) struct Problem<'a> {
    pub data: &'a [Series],
    pub runs: Vec<Run>,
    /// Per series: the first validation row.
    pub cut: Vec<usize>,
    pub n_cal: usize,
    pub n_val: usize,
    pub noise: NoiseEstimate,
    pub report: DataReport,
    /// The drives of the last simulations, read again by every simulation with the same
    /// throttle path and map ([`DriveCache`]).
    drives: RefCell<DriveCache>,
}

/// Plants with the same throttle path and throttle map ([`Plant::drive_key`]) drive their
/// engines alike over a run's throttles: a refit's Jacobian columns of the ten
/// parameters but `B_UU`, a gain drift's, a sensor-side effect's, and every probe and fit
/// that leaves the path alone. The drives of the last few paths are kept per run
/// ([`DriveTrack`]), each track checking its own key and throttles when read, so that
/// a reading is the same, bit for bit, as one that runs the path.
#[derive(Debug, Default)]
struct DriveCache {
    slots: Vec<DriveSlot>,
    /// Counts lookups, to give up the least recently used path.
    clock: u64,
}

/// The drives of one throttle path, per run.
#[derive(Debug)]
struct DriveSlot {
    key: DriveKey,
    used: u64,
    runs: Vec<DriveTrack>,
}

/// Paths kept: a fit alternates between its point and a column or two that move the path
/// (a rate limit's two values, a delay), each about 2 MB of drives per 600 s run.
const DRIVE_SLOTS: usize = 4;

impl Clone for DriveCache {
    /// Empty: a copy of a problem may be given other throttles (the tracks would not be
    /// read on those, but would be copied for nothing).
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl DriveCache {
    /// The tracks of `key`'s path, one per run: kept ones, or those of the least recently
    /// used path (to be overwritten, reusing their memory).
    fn tracks(&mut self, key: DriveKey, runs: usize) -> &mut [DriveTrack] {
        self.clock += 1;
        let at = match self.slots.iter().position(|s| s.key == key) {
            Some(i) => i,
            None if self.slots.len() < DRIVE_SLOTS => {
                self.slots.push(DriveSlot { key, used: 0, runs: Vec::new() });
                self.slots.len() - 1
            }
            None => {
                let oldest = (0..self.slots.len()).min_by_key(|&i| self.slots[i].used).unwrap_or(0);
                self.slots[oldest].key = key;
                oldest
            }
        };
        let slot = &mut self.slots[at];
        slot.used = self.clock;
        slot.runs.resize_with(runs, DriveTrack::default);
        &mut slot.runs
    }
}

/// Simulated measured thrust per run, on its grid.
pub(crate) type Sim = Vec<Vec<f64>>;

/// What consecutive simulations of a fit share, so that none is computed twice:
///
/// - the engine's path in the last simulation by [`Problem::simulate_reusing`]: a plant that
///   differs from that one on the sensor side alone (a stand, a drift, a bearing's play) is
///   simulated by running its sensor side on the path, without stepping the engine again
///   (a fit of a sensor-side effect, and the grid it starts from, step the engine once);
/// - the powers of a sensor drift's decay per grid step, which
///   [`Problem::fit_bias_starts`] regresses on, for the last time constant.
///
/// Every value is the one computed afresh, bit for bit.
#[derive(Clone, Debug, Default)]
pub(crate) struct SimCache {
    /// `e^(−STEP_S/τ)` (its bits) and its powers `0, 1, …`.
    decay_powers: (u64, Vec<f64>),
    /// Whose engine path it is.
    key: Option<EngineKey>,
    /// Per run: the engine's thrust at every substep, and where it diverged (s from the
    /// run's start).
    runs: Vec<(Vec<f64>, Option<f64>)>,
}

/// What fixes the engine's path in a simulation of every run.
#[derive(Clone, Debug, PartialEq)]
struct EngineKey {
    /// The plant's engine side ([`Plant::engine_side`]).
    plant: Plant,
    /// Each run's engine state and thrust-history start.
    starts: Vec<(State, f64)>,
    /// True when the validation part was run too.
    whole: bool,
}

impl<'a> Problem<'a> {
    /// Puts `data` on the grid, rejects outliers, estimates the noise, splits each file
    /// at `1 − holdout` of its duration and fits each run's initial state under `nominal`.
    pub fn new(data: &'a [Series], nominal: &Plant, holdout: f64) -> Result<Self, IdentError> {
        let mut runs = Vec::new();
        let mut cut = Vec::with_capacity(data.len());
        let (mut gaps, mut lost_rows, mut run_splits) = (0, 0, 0);
        let (mut steps_in_gaps, mut after_steps_in_gaps) = (0, 0);
        for (i, s) in data.iter().enumerate() {
            let (first, last) = (s.t_s[0], s.t_s[s.len() - 1]);
            let split_s = first + (1.0 - holdout) * (last - first);
            cut.push(s.t_s.partition_point(|&t| t < split_s));
            let steps = s.grid_steps();
            let max_steps = (MAX_HELD_GAP_S / STEP_S).round() as usize;
            // The file's own spacing (2 steps for 50 Hz): only more than that is a gap.
            let mut sorted: Vec<usize> = steps[1..].to_vec();
            sorted.sort_unstable();
            let spacing = sorted.get(sorted.len() / 2).copied().unwrap_or(1).max(1);
            let mut start = 0;
            for k in 1..=s.len() {
                if k < s.len() && steps[k] <= max_steps {
                    if steps[k] > spacing {
                        gaps += 1;
                        lost_rows += steps[k].div_ceil(spacing) - 1;
                    }
                    continue;
                }
                if k < s.len() {
                    run_splits += 1;
                }
                if k - start >= 3 {
                    let mut run = Self::run(s, i, start..k, &steps, cut[i]);
                    let (stepped, masked) = run.mask_steps_in_gaps(&s.u_pct);
                    (steps_in_gaps, after_steps_in_gaps) = (steps_in_gaps + stepped, after_steps_in_gaps + masked);
                    runs.push(run);
                }
                start = k;
            }
        }
        // Spikes first: a spike on a clipped row reads above the sensor's limit, and the limit
        // is found as the end of the range of what is left.
        let outliers = reject_outliers(&mut runs);
        let clipped = remove_clipped(&mut runs);
        let mut notes = Vec::new();
        if !clipped.is_empty() {
            let moved = hold_out_measured(&mut runs, &mut cut, holdout);
            if moved > 0 {
                notes.push(format!(
                    "the held-out part is the last {:.0} % of the rows the force sensor measured, not of the recording's \
                     time: the rows at its limit lie unevenly over the run ({moved} file(s) split earlier)",
                    100.0 * holdout
                ));
            }
        }
        let stretches: Vec<Vec<f64>> = runs.iter().map(|r| r.y.iter().copied().step_by(r.stride).collect()).collect();
        let mut noise = noise::estimate(&stretches)
            .ok_or_else(|| IdentError::TooLittleData("too few samples to estimate the sensor noise".into()))?;
        if let Some((quiet, note)) = quiet_noise(&runs, &noise) {
            noise = quiet;
            notes.push(note);
        }
        // The floor the held-out MAE is judged against is the noise's on the held-out part:
        // a noise that grows with thrust has its own scale there.
        let held_out_from: Vec<usize> = runs.iter().map(|r| r.cut.div_ceil(r.stride)).collect();
        if let Some(floor_n) = noise::held_out_floor(noise.sigma_n, &stretches, &held_out_from) {
            noise.mae_n = floor_n;
        }
        let count = |part: Part| -> usize {
            runs.iter()
                .map(|r| r.y.iter().enumerate().filter(|(k, y)| y.is_finite() && r.in_part(*k, part)).count())
                .sum()
        };
        let (n_cal, n_val) = (count(Part::Calibration), count(Part::Validation));
        if n_cal < 1000 || n_val < 500 {
            // Rows left out are part of why so little is left: say how many, and why.
            let clipped_rows: usize = clipped.iter().map(|c| c.1).sum();
            let mut left_out = Vec::new();
            if clipped_rows > 0 {
                let limits: Vec<String> = clipped.iter().map(|c| format!("{:.1} N", c.0)).collect();
                left_out.push(format!(
                    "{clipped_rows} rows were left out where the force sensor read at or near its limit ({}), \
                     no measurement of the thrust; keep the thrust within the sensor's range",
                    limits.join(", ")
                ));
            }
            if !outliers.is_empty() {
                left_out.push(format!("{} spikes were left out", outliers.len()));
            }
            let why = if left_out.is_empty() {
                String::new()
            } else {
                format!(" Of the rows recorded, {}.", left_out.join("; "))
            };
            return Err(IdentError::TooLittleData(format!(
                "{n_cal} calibration and {n_val} validation samples; a diagnosis needs at least 1000 and 500 \
                 (a few minutes of data; typical recordings are 300 s; the last {:.0} % of each recording is held \
                 out).{why}",
                100.0 * holdout
            )));
        }
        let report = DataReport {
            model: noise.model.describe(),
            ar: noise.model.phi.clone(),
            sigma_n: noise.sigma_n,
            innovation_sigma_n: noise.model.innovation_var.sqrt(),
            floor_n: noise.mae_n,
            outliers_removed: outliers.len(),
            outliers: outliers.into_iter().take(20).collect(),
            gaps,
            lost_rows,
            run_splits,
            steps_in_gaps,
            after_steps_in_gaps,
            runs: runs.len(),
            notes,
            from_residual: false,
            floor_from_data_n: noise.mae_n,
            clipped_rows: clipped.iter().map(|c| c.1).sum(),
            clipped_at_n: clipped.iter().map(|c| c.0).collect(),
        };
        let mut problem = Self { data, runs, cut, n_cal, n_val, noise, report, drives: RefCell::default() };
        let states = problem.initial_states(nominal);
        for (run, state) in problem.runs.iter_mut().zip(states) {
            run.initial = state;
        }
        Ok(problem)
    }

    fn run(s: &Series, series: usize, rows: Range<usize>, steps: &[usize], cut_row: usize) -> Run {
        let mut grid = Vec::with_capacity(rows.len());
        let mut at = 0;
        for k in rows.clone() {
            if k > rows.start {
                at += steps[k];
            }
            grid.push(at);
        }
        let len = at + 1;
        let (mut u, mut y) = (vec![0.0; len], vec![f64::NAN; len]);
        for (j, k) in rows.clone().enumerate() {
            let end = grid.get(j + 1).copied().unwrap_or(len);
            u[grid[j]..end].fill(s.u_pct[k]);
            y[grid[j]] = s.thrust_n[k];
        }
        let cut = rows.clone().position(|k| k >= cut_row).map_or(len, |j| grid[j]);
        let mut gaps: Vec<usize> = grid.windows(2).map(|w| w[1] - w[0]).collect();
        gaps.sort_unstable();
        let stride = gaps.get(gaps.len() / 2).copied().unwrap_or(1).max(1);
        Run {
            series,
            t0_s: s.t_s[rows.start],
            rows,
            grid,
            u,
            y,
            cut,
            stride,
            initial: State::default(),
            reversed: false,
        }
    }

    /// Each run's initial state fitted to its first two seconds under `plant`.
    pub fn initial_states(&self, plant: &Plant) -> Vec<State> {
        self.runs.iter().map(|run| fit_initial_state_at(plant, run.t0_s, &run.y, &run.u)).collect()
    }

    /// `starts` with each run's engine state fitted anew to its first two seconds under
    /// `plant`, its slow states kept where they start.
    pub fn restarted(&self, plant: &Plant, starts: &[RunStart]) -> Vec<RunStart> {
        self.runs
            .iter()
            .zip(starts)
            .map(|(run, start)| RunStart {
                state: fit_initial_state_at(&Started { plant, slow: start.slow }, run.t0_s, &run.y, &run.u),
                slow: start.slow,
            })
            .collect()
    }

    /// This problem with its parts the other way round: fitted on the held-out part of each
    /// recording, judged on its calibration part. A second, disjoint view of how well each
    /// explanation predicts data it was not fitted on (two-fold cross-validation); the noise
    /// model, the floor and the runs' starts are the same.
    pub fn reversed(&self) -> Self {
        let mut other = self.clone();
        for run in &mut other.runs {
            run.reversed = !run.reversed;
        }
        std::mem::swap(&mut other.n_cal, &mut other.n_val);
        other
    }

    /// The highest reading of the recordings, N: no thrust history and no sensor bias
    /// (a share of the thrust) starts above what the thrust ever was.
    pub fn reading_max_n(&self) -> f64 {
        self.runs.iter().flat_map(|r| r.y.iter().copied()).filter(|y| y.is_finite()).fold(0.0, f64::max)
    }

    /// Fits each run's sensor-bias start to the residual of `sim` over `part` and adds its
    /// decay to `sim`: the bias offset `b₀` adds `b₀·e^(−t/τ)` to the reading and nothing
    /// else (the bias is a linear first-order state, [`SlowStart`]), so it is a linear
    /// least-squares fit on the prewhitened residual, one column per run. `sim` must have
    /// been simulated with the bias starting at 0. A bias follows `gain·T` from a tare, so it
    /// starts between 0 and `gain` times the highest reading: the fit is held there.
    /// Returns the starts, one per run.
    pub fn fit_bias_starts(
        &self,
        sim: &mut Sim,
        gain: f64,
        time_constant_s: f64,
        part: Part,
        cache: &mut SimCache,
    ) -> Vec<f64> {
        let reach = gain * self.reading_max_n();
        let (lo, hi) = (reach.min(0.0), reach.max(0.0));
        let decay = (-STEP_S / time_constant_s).exp();
        let longest = self.runs.iter().map(|r| r.y.len()).max().unwrap_or(0);
        let (bits, powers) = &mut cache.decay_powers;
        if *bits != decay.to_bits() || powers.len() < longest {
            *bits = decay.to_bits();
            powers_by_squaring(decay, longest, powers);
        }
        let powers = &cache.decay_powers.1;
        let (mut wr, mut wz) = (Vec::new(), Vec::new());
        let mut out = Vec::with_capacity(self.runs.len());
        for (i, run) in self.runs.iter().enumerate() {
            let Some(m) = sim.get_mut(i) else {
                out.push(0.0);
                continue;
            };
            let residual = |k: usize| run.y.get(k).map_or(f64::NAN, |y| y - m.get(k).copied().unwrap_or(f64::NAN));
            self.run_innovations(i, residual, part, &mut wr);
            self.run_innovations(i, |k| if residual(k).is_finite() { powers[k] } else { f64::NAN }, part, &mut wz);
            let (zz, zr) = wz.iter().zip(&wr).fold((0.0, 0.0), |(zz, zr), (z, r)| (zz + z * z, zr + z * r));
            let b = if zz > 0.0 && zr.is_finite() { (zr / zz).clamp(lo, hi) } else { 0.0 };
            let mut z = 1.0;
            for v in m.iter_mut() {
                *v += b * z;
                z *= decay;
            }
            out.push(b);
        }
        out
    }

    /// The longest run, s.
    pub fn longest_run_s(&self) -> f64 {
        self.runs.iter().map(|r| r.u.len() as f64 * STEP_S).fold(0.0, f64::max)
    }

    /// The initial states fitted under the given model.
    pub fn given_states(&self) -> Vec<State> {
        self.runs.iter().map(|run| run.initial).collect()
    }

    /// This problem with the noise model refitted on the residual of `sim` (see
    /// [`noise::fit_to_series`]), when that can be done.
    pub fn with_noise_from(&self, sim: &Sim) -> Option<Self> {
        let residuals: Vec<Vec<f64>> = (0..self.runs.len())
            .map(|i| self.residual(i, sim).into_iter().step_by(self.runs[i].stride).collect())
            .collect();
        let model = noise::fit_to_series(&residuals)?;
        let mut refined = self.clone();
        let sigma_n = model.marginal_var().sqrt();
        // The held-out part's scale against the whole's, as the data's own floor measured it.
        let held_out_scale = self.noise.mae_n / self.noise.sigma_n;
        refined.noise = NoiseEstimate {
            sigma_n,
            mae_n: sigma_n * held_out_scale,
            contrasts: self.noise.contrasts,
            bic: Vec::new(),
            model,
        };
        let report = &mut refined.report;
        report.model = format!("{} (from the residual)", refined.noise.model.describe());
        report.ar = refined.noise.model.phi.clone();
        report.sigma_n = sigma_n;
        report.innovation_sigma_n = refined.noise.model.innovation_var.sqrt();
        report.floor_n = refined.noise.mae_n;
        report.from_residual = true;
        Some(refined)
    }

    /// This problem with the noise model's colour estimated again, as [`Problem::new`]
    /// estimated it (second differences, [`noise::estimate`]), on the residual of `sim`
    /// instead of the recording, when that gives a model of lower order; the noise's scale
    /// and floor stay the data's. `None` when the residual gives no estimate, or one of the
    /// same order or higher.
    ///
    /// The recording's second differences carry the engine's signal too. A slow engine's is
    /// hundredths of a newton, but after throttle steps taken in one cycle a fast one's
    /// transients leave a few hundredths of autocorrelation over the first lags, and BIC
    /// may then pick an AR(3) with φ ≈ 0.025 for noise that is white. Whitened with that
    /// model, the residual of the right explanation (white noise alone) shows −0.02 at lag
    /// 1, which a Ljung–Box test on thirty thousand samples rejects (p 4e-5, a delay with
    /// nothing else beside it, on the live bench). What an explanation leaves holds no
    /// more of the engine's signal than the recording does, and a misfit that is slow
    /// shows in second differences no more than the signal does.
    ///
    /// Both estimates carry something besides the noise, the engine's fast transients in one,
    /// the misfit's in the other, and either can only add structure the noise does not have.
    /// So the residual's is used only when it is of lower order, a model with less structure:
    /// never to whiten a fast misfit away (a resonance left out makes the residual's estimate
    /// the more coloured one), and not for the scatter of two estimates of the same order.
    pub fn with_colour_from(&self, sim: &Sim) -> Option<Self> {
        let residuals: Vec<Vec<f64>> = (0..self.runs.len())
            .map(|i| self.residual(i, sim).into_iter().step_by(self.runs[i].stride).collect())
            .collect();
        let found = noise::estimate(&residuals)?;
        if found.model.order() >= self.noise.model.order() {
            return None;
        }
        let mut refined = self.clone();
        let model = found.model.with_marginal_var(self.noise.sigma_n * self.noise.sigma_n);
        refined.report.innovation_sigma_n = model.innovation_var.sqrt();
        refined.noise = NoiseEstimate { model, ..self.noise.clone() };
        Some(refined)
    }

    /// The noise model fits and scores use.
    pub fn ar(&self) -> &ArModel {
        &self.noise.model
    }

    /// Simulates `plant` over every run from `starts` (engine states alone start the slow
    /// states settled; only up to the split when `calibration_only`). `Err` carries
    /// (series, time s) of a divergence.
    pub fn simulate<S: Copy + Into<RunStart>>(
        &self,
        plant: &Plant,
        starts: &[S],
        calibration_only: bool,
        out: &mut Sim,
    ) -> Result<(), (usize, f64)> {
        out.resize_with(self.runs.len(), Vec::new);
        let mut failure = None;
        let mut drives = self.drives.borrow_mut();
        let mut tracks = plant.drive_key(SUBSTEPS).map(|key| drives.tracks(key, self.runs.len()));
        for (i, ((run, sim), &start)) in self.runs.iter().zip(out.iter_mut()).zip(starts).enumerate() {
            let end = run.end(calibration_only);
            if end == 0 {
                sim.clear();
                continue;
            }
            let RunStart { state, slow } = start.into();
            let track = tracks.as_deref_mut().map(|t| &mut t[i]);
            if let Some(at) = plant.free_run_keeping(SUBSTEPS, run.t0_s, state, slow, &run.u[..end], sim, None, track) {
                failure.get_or_insert((run.series, run.t0_s + at));
            }
        }
        failure.map_or(Ok(()), Err)
    }

    /// [`Problem::simulate`], the same values bit for bit, on the engine path in `cache`
    /// when it is this plant's (see [`SimCache`]); otherwise simulated in full and its
    /// path kept there.
    pub fn simulate_reusing(
        &self,
        plant: &Plant,
        starts: &[RunStart],
        calibration_only: bool,
        cache: &mut SimCache,
        out: &mut Sim,
    ) -> Result<(), (usize, f64)> {
        if plant.turbojet.is_some() {
            return self.simulate(plant, starts, calibration_only, out);
        }
        let engine = plant.engine_side();
        let engine_starts: Vec<(State, f64)> = starts.iter().map(|s| (s.state, s.slow.history_offset_n)).collect();
        let end = |run: &Run| run.end(calibration_only);
        let whole = self.runs.iter().all(|run| end(run) == run.u.len());
        out.resize_with(self.runs.len(), Vec::new);
        let mut failure = None;
        let reusable = cache.key.as_ref().is_some_and(|key| {
            (key.whole || !whole)
                && key.plant == engine
                && key.starts == engine_starts
                && cache.runs.len() == self.runs.len()
        });
        if reusable {
            for (((run, sim), start), (path, diverged_s)) in
                self.runs.iter().zip(out.iter_mut()).zip(starts).zip(&cache.runs)
            {
                let end = end(run);
                plant.replay_sensor(SUBSTEPS, start.state, start.slow, path, end, *diverged_s, sim);
                // A divergence the run reaches (within the samples asked for) fails it.
                if let Some(at) = diverged_s.filter(|at| (at / STEP_S).round() as usize <= end.saturating_sub(1)) {
                    failure.get_or_insert((run.series, run.t0_s + at));
                }
            }
            return failure.map_or(Ok(()), Err);
        }
        cache.runs.resize_with(self.runs.len(), Default::default);
        let mut drives = self.drives.borrow_mut();
        let mut tracks = plant.drive_key(SUBSTEPS).map(|key| drives.tracks(key, self.runs.len()));
        for (i, (((run, sim), start), (path, diverged_s))) in
            self.runs.iter().zip(out.iter_mut()).zip(starts).zip(cache.runs.iter_mut()).enumerate()
        {
            let end = end(run);
            *diverged_s = None;
            if end == 0 {
                sim.clear();
                path.clear();
                continue;
            }
            let track = tracks.as_deref_mut().map(|t| &mut t[i]);
            let u = &run.u[..end];
            *diverged_s =
                plant.free_run_keeping(SUBSTEPS, run.t0_s, start.state, start.slow, u, sim, Some(path), track);
            if let Some(at) = *diverged_s {
                failure.get_or_insert((run.series, run.t0_s + at));
            }
        }
        cache.key = Some(EngineKey { plant: engine, starts: engine_starts, whole });
        failure.map_or(Ok(()), Err)
    }

    /// [`Problem::simulate`] of several plants, each from its own `starts`, stepped in
    /// lockstep ([`Plant::free_runs_in_lockstep`]): the same values, bit for bit, in
    /// `outs`, and per plant whether it ran without diverging. Plants of one throttle path
    /// and map read its kept drives ([`DriveCache`]; the first runs and keeps them when
    /// they are not there); others run their own paths, kept nowhere (a fit's columns that
    /// move the path are not simulated again). Leaves every [`SimCache`] alone.
    pub fn simulate_in_lockstep(
        &self,
        plants: &[&Plant],
        starts: &[&[RunStart]],
        calibration_only: bool,
        outs: &mut [Sim],
    ) -> Vec<bool> {
        let count = plants.len().min(starts.len()).min(outs.len());
        let mut ran = vec![true; count];
        for out in outs.iter_mut() {
            out.resize_with(self.runs.len(), Vec::new);
        }
        let keys: Vec<_> = plants[..count].iter().map(|p| p.drive_key(SUBSTEPS)).collect();
        let shared = keys.first().copied().flatten().filter(|key| keys.iter().all(|k| *k == Some(*key)));
        let mut drives = self.drives.borrow_mut();
        let mut tracks = shared.map(|key| drives.tracks(key, self.runs.len()));
        let (mut sims, mut diverged_s) = (vec![Vec::new(); count], vec![None; count]);
        for (i, run) in self.runs.iter().enumerate() {
            let end = run.end(calibration_only);
            if end == 0 {
                outs.iter_mut().for_each(|out| out[i].clear());
                continue;
            }
            let u = &run.u[..end];
            let run_starts: Vec<(State, SlowStart)> = starts[..count].iter().map(|s| (s[i].state, s[i].slow)).collect();
            for (sim, out) in sims.iter_mut().zip(outs.iter_mut()) {
                std::mem::swap(sim, &mut out[i]);
            }
            let mut first = 0;
            let track = tracks.as_deref_mut().map(|t| &mut t[i]);
            let track = match track {
                Some(track) if !track.holds_run_of(plants[0], SUBSTEPS, u) => {
                    // The first plant keeps its drives for the others.
                    let (state, slow) = run_starts[0];
                    diverged_s[0] =
                        plants[0].free_run_keeping(SUBSTEPS, run.t0_s, state, slow, u, &mut sims[0], None, Some(track));
                    first = 1;
                    Some(&*track)
                }
                track => track.map(|t| &*t),
            };
            Plant::free_runs_in_lockstep(
                &plants[first..count],
                SUBSTEPS,
                run.t0_s,
                &run_starts[first..],
                u,
                track,
                &mut sims[first..],
                &mut diverged_s[first..],
            );
            for (j, (sim, out)) in sims.iter_mut().zip(outs.iter_mut()).enumerate() {
                std::mem::swap(sim, &mut out[i]);
                ran[j] &= diverged_s[j].is_none();
            }
        }
        ran
    }

    /// Residual `y − ŷ` of run `i` on its grid (NaN where there is no sample or no simulation).
    pub fn residual(&self, i: usize, sim: &Sim) -> Vec<f64> {
        let run = &self.runs[i];
        (0..run.y.len()).map(|k| run.y[k] - sim[i].get(k).copied().unwrap_or(f64::NAN)).collect()
    }

    /// The innovations of `x` (a grid vector of run `i`, NaN where there is no sample)
    /// under the noise model, at the run's stride: element `j` belongs to grid index
    /// `j·stride`, NaN where a sample it needs is missing.
    pub fn whiten(&self, i: usize, x: &[f64]) -> Vec<f64> {
        let strided: Vec<f64> = x.iter().copied().step_by(self.runs[i].stride).collect();
        (0..strided.len()).map(|j| self.ar().innovation(&strided, j).unwrap_or(f64::NAN)).collect()
    }

    /// Innovations of grid vectors `x` (one per run) over `part`, in a fixed order.
    pub fn whiten_part(&self, x: &[Vec<f64>], part: Part, out: &mut Vec<f64>) {
        out.clear();
        for (i, run) in self.runs.iter().enumerate() {
            let w = self.whiten(i, &x[i]);
            out.extend(
                w.iter().enumerate().filter(|(j, w)| w.is_finite() && run.in_part(j * run.stride, part)).map(|p| *p.1),
            );
        }
    }

    /// Innovations (prewhitened residuals) over `part`, in a fixed order: the same values
    /// as [`Problem::whiten_part`] of every run's [`Problem::residual`], computed in place
    /// over `part` alone (every fit evaluates this once per simulation).
    pub fn innovations(&self, sim: &Sim, part: Part, out: &mut Vec<f64>) {
        out.clear();
        let mut w = Vec::new();
        for (i, run) in self.runs.iter().enumerate() {
            let m = sim.get(i).map_or(&[][..], Vec::as_slice);
            // Residual at grid index `k`, NaN without a sample or a simulation.
            let r = |k: usize| run.y.get(k).map_or(f64::NAN, |y| y - m.get(k).copied().unwrap_or(f64::NAN));
            self.run_innovations(i, r, part, &mut w);
            out.extend_from_slice(&w);
        }
    }

    /// The innovations over `part` of run `i`'s grid vector `x(k)` (NaN where there is no
    /// value), at the run's stride, in the order [`Problem::innovations`] puts them.
    fn run_innovations(&self, i: usize, x: impl Fn(usize) -> f64, part: Part, out: &mut Vec<f64>) {
        out.clear();
        let phi = &self.ar().phi;
        let run = &self.runs[i];
        let stride = run.stride;
        let r = |j: usize| x(j * stride);
        let n = run.y.len().div_ceil(stride);
        let split = run.cut.min(run.y.len()).div_ceil(stride);
        let (lo, hi) = if (part == Part::Calibration) != run.reversed { (0, split) } else { (split, n) };
        'samples: for j in lo.max(phi.len())..hi {
            let mut w = r(j);
            if !w.is_finite() {
                continue;
            }
            for (q, p) in phi.iter().enumerate() {
                let past = r(j - 1 - q);
                if !past.is_finite() {
                    continue 'samples;
                }
                w -= p * past;
            }
            if w.is_finite() {
                out.push(w);
            }
        }
    }

    /// Sum of squared innovations over `part`, and how many.
    pub fn sse(&self, sim: &Sim, part: Part) -> (f64, usize) {
        let mut w = Vec::new();
        self.innovations(sim, part, &mut w);
        let sse = w.iter().map(|v| v * v).sum::<f64>();
        (if sse.is_finite() { sse } else { f64::INFINITY }, w.len())
    }

    /// (measured, simulated) over the samples of `part`.
    pub fn pairs<'s>(&'s self, sim: &'s Sim, part: Part) -> impl Iterator<Item = (f64, f64)> + Clone + 's {
        self.runs.iter().zip(sim).flat_map(move |(run, m)| {
            (0..run.y.len())
                .filter(move |&k| run.y[k].is_finite() && run.in_part(k, part))
                .map(move |k| (run.y[k], m.get(k).copied().unwrap_or(f64::NAN)))
        })
    }

    /// Mean absolute error over `part` (infinite when the simulation is missing).
    pub fn mae(&self, sim: &Sim, part: Part) -> f64 {
        let (sum, n) = self.pairs(sim, part).fold((0.0, 0usize), |(a, n), (y, m)| (a + (y - m).abs(), n + 1));
        let mae = sum / n.max(1) as f64;
        if mae.is_finite() {
            mae
        } else {
            f64::INFINITY
        }
    }

    /// A simulation on the rows of each recording (NaN where there is none), for plots.
    pub fn per_row(&self, sim: &Sim) -> Vec<Vec<f64>> {
        let mut out: Vec<Vec<f64>> = self.data.iter().map(|s| vec![f64::NAN; s.len()]).collect();
        for (run, m) in self.runs.iter().zip(sim) {
            for (j, k) in run.rows.clone().enumerate() {
                out[run.series][k] = m.get(run.grid[j]).copied().unwrap_or(f64::NAN);
            }
        }
        out
    }
}

/// Replaces `out` with `base.powi(k)` for `k` in `0..count`, the same values bit for bit,
/// one product each. `powi` is binary exponentiation (`__powidf2`: the product of the
/// squares `base^(2^j)` at the exponent's set bits, lowest first, each square the one
/// before squared), so the power of `k` is that of `k` without its highest bit times
/// that bit's square; `powi` itself squares again for every `k` (3 % of a 600 s
/// diagnosis).
fn powers_by_squaring(base: f64, count: usize, out: &mut Vec<f64>) {
    let mut squares = [base; usize::BITS as usize];
    for j in 1..squares.len() {
        squares[j] = squares[j - 1] * squares[j - 1];
    }
    out.clear();
    out.reserve(count);
    for k in 0..count {
        let power = match k.checked_ilog2() {
            None => 1.0,
            Some(highest) => out[k - (1 << highest)] * squares[highest as usize],
        };
        out.push(power);
    }
}

/// Throttle held this long before a sample makes it quiet, s: a fast engine's transients
/// have died out.
const QUIET_AFTER_S: f64 = 1.0;
/// A throttle that moves less than this over [`QUIET_AFTER_S`] is held, points.
const QUIET_BAND_PCT: f64 = 0.5;
/// Quiet contrasts needed before their estimate is trusted over the whole data's.
const MIN_QUIET_CONTRASTS: usize = 1500;
/// The whole data's noise more coloured than the quiet part's by this factor: the signal
/// leaked into it.
const MAX_COLOUR_RATIO: f64 = 2.0;

/// The noise estimated where the throttle has been held for [`QUIET_AFTER_S`], when the
/// whole data's estimate has taken in the engine's signal.
///
/// Second differences remove the signal of a slow engine (its `T̈·Δt²` is hundredths of a
/// newton at 100 Hz), not of one that answers a step within tens of milliseconds: there the
/// transients after each throttle move pass into the contrasts as strongly coloured "noise",
/// and a near-unit-root AR model multiplies the floor (a white 7 N² noise read as 19.5 N
/// with AR(6)). Where the throttle has been held for a second every engine of this class
/// has settled. When the whole data's noise is more than [`MAX_COLOUR_RATIO`] times as
/// coloured as the quiet part's (its variance over its innovations' variance), the signal
/// leaked: the quiet estimate is used and the note says so. The test is on the colour, not
/// the scale, so a noise that grows with thrust, with holds at other thrusts than the
/// moves, does not trip it. Otherwise (on slow engines, whose two estimates agree within
/// their scatter, and on recordings without holds) nothing changes.
fn quiet_noise(runs: &[Run], whole: &NoiseEstimate) -> Option<(NoiseEstimate, String)> {
    // The noise's colour, free of its scale: its variance over its innovations' (1 for white
    // noise, 5.3 for AR(1) with φ = 0.9, never below 1).
    let colour = |m: &ArModel| m.marginal_var() / m.innovation_var.max(f64::MIN_POSITIVE);
    if colour(&whole.model) <= MAX_COLOUR_RATIO {
        return None; // no quiet estimate can be half as coloured: spare its fit
    }
    let settle = (QUIET_AFTER_S / STEP_S).round() as usize;
    let quiet: Vec<Vec<f64>> = runs
        .iter()
        .map(|r| {
            let held = |k: usize| {
                let window = &r.u[k.saturating_sub(settle)..=k];
                k >= settle && {
                    let (lo, hi) =
                        window.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &u| (lo.min(u), hi.max(u)));
                    hi - lo <= QUIET_BAND_PCT
                }
            };
            (0..r.y.len()).map(|k| if held(k) { r.y[k] } else { f64::NAN }).step_by(r.stride).collect()
        })
        .collect();
    let found = noise::estimate(&quiet).filter(|q| q.contrasts >= MIN_QUIET_CONTRASTS)?;
    if colour(&whole.model) <= MAX_COLOUR_RATIO * colour(&found.model) {
        return None;
    }
    let note = format!(
        "noise estimated where the throttle had been held for {QUIET_AFTER_S:.0} s ({} contrasts): over the whole \
         data the engine's fast transients read as noise ({}, σ {:.2} N; held: {}, σ {:.2} N)",
        found.contrasts,
        whole.model.describe(),
        whole.sigma_n,
        found.model.describe(),
        found.sigma_n
    );
    Some((found, note))
}

/// Marks samples far from their neighbours' median as missing; returns them.
fn reject_outliers(runs: &mut [Run]) -> Vec<Outlier> {
    let mut deviations: Vec<Vec<f64>> = Vec::with_capacity(runs.len());
    for run in runs.iter() {
        let y = &run.y;
        let mut window = Vec::with_capacity(2 * OUTLIER_HALF_WINDOW + 1);
        deviations.push(
            (0..y.len())
                .map(|k| {
                    if !y[k].is_finite() {
                        return f64::NAN;
                    }
                    window.clear();
                    let lo = k.saturating_sub(OUTLIER_HALF_WINDOW);
                    window.extend(y[lo..(k + OUTLIER_HALF_WINDOW + 1).min(y.len())].iter().filter(|v| v.is_finite()));
                    window.sort_by(f64::total_cmp);
                    y[k] - window[window.len() / 2]
                })
                .collect(),
        );
    }
    let mut abs: Vec<f64> = deviations.iter().flatten().filter(|d| d.is_finite()).map(|d| d.abs()).collect();
    if abs.is_empty() {
        return Vec::new();
    }
    let mid = abs.len() / 2;
    let (_, median, _) = abs.select_nth_unstable_by(mid, f64::total_cmp);
    let scale = 1.4826 * *median;
    let mut outliers = Vec::new();
    for (run, dev) in runs.iter_mut().zip(&deviations) {
        for (k, d) in dev.iter().enumerate() {
            if d.abs() > OUTLIER_Z * scale && scale > 0.0 {
                run.y[k] = f64::NAN;
                outliers.push(Outlier { file: run.series, t_s: run.t0_s + k as f64 * STEP_S, deviation_n: *d });
            }
        }
    }
    outliers
}

/// Moves each file's split earlier where rows left out at the sensor's limit leave its
/// held-out part short of `holdout` of the rows it measured: the held-out part is then the last
/// `holdout` of the measured rows, not of the time. A recording clipped mostly near its end
/// (a fresh campaign's case: 100 s, the sensor at its limit through most of the last 30 s)
/// kept 217 held-out samples against 6518 calibration ones and was refused as too short,
/// though it held 67 s of measured thrust. The split never moves later. Returns how many
/// files' splits moved; `cut` (per file, a row) and each run's `cut` (a grid index) agree.
fn hold_out_measured(runs: &mut [Run], cut: &mut [usize], holdout: f64) -> usize {
    let mut moved = 0;
    for (series, cut_row) in cut.iter_mut().enumerate() {
        // The file's measured rows, in order.
        let mut measured: Vec<usize> = runs
            .iter()
            .filter(|r| r.series == series)
            .flat_map(|r| r.rows.clone().zip(&r.grid).filter(|(_, g)| r.y[**g].is_finite()).map(|(k, _)| k))
            .collect();
        measured.sort_unstable();
        let held = measured.iter().filter(|&&k| k >= *cut_row).count();
        let wanted = (holdout * measured.len() as f64).round() as usize;
        if wanted == 0 || held >= wanted {
            continue;
        }
        *cut_row = measured[measured.len() - wanted];
        moved += 1;
        for run in runs.iter_mut().filter(|r| r.series == series) {
            run.cut = run.rows.clone().position(|k| k >= *cut_row).map_or(run.y.len(), |j| run.grid[j]);
        }
    }
    moved
}

/// Rows at the very end of the reading's range: a sensor that clips (or an amplifier that
/// saturates) repeats its limit exactly, where noisy readings near the top are all
/// different. A limit repeated in at least [`CLIP_MIN_ROWS`] rows and 0.2 % of them is a
/// range; those rows are left out (as gaps) and reported. Returns (limit, rows) per end.
fn remove_clipped(runs: &mut [Run]) -> Vec<(f64, usize)> {
    let present: Vec<f64> = runs.iter().flat_map(|r| r.y.iter().copied().filter(|y| y.is_finite())).collect();
    let n = present.len();
    let (hi, lo) = present.iter().fold((f64::NEG_INFINITY, f64::INFINITY), |(h, l), &y| (h.max(y), l.min(y)));
    let mut found = Vec::new();
    // A reading that barely moves is not a range with ends: it is a stuck or disconnected
    // sensor, which the noise model and the residual report as such.
    if hi - lo <= 100.0 * CLIP_RESOLUTION_N {
        return found;
    }
    for limit in [hi, lo] {
        if !limit.is_finite() {
            continue;
        }
        let at = |y: f64| (y - limit).abs() <= CLIP_RESOLUTION_N;
        let count = present.iter().filter(|y| at(**y)).count();
        // Most readings at one end is a stuck sensor, not one that clips now and then.
        if count >= CLIP_MIN_ROWS && count as f64 >= 0.002 * n as f64 && 2 * count < n {
            // The rows around a clipped one are left out too: while the thrust is near the
            // limit only the readings that happened to fall below it survive, a bias that
            // would look like a flatter engine map.
            let mut left_out = 0;
            for run in runs.iter_mut() {
                let clipped: Vec<usize> = (0..run.y.len()).filter(|&k| run.y[k].is_finite() && at(run.y[k])).collect();
                let mut drop = vec![false; run.y.len()];
                for &k in &clipped {
                    let (a, b) = (k.saturating_sub(CLIP_MARGIN), (k + CLIP_MARGIN + 1).min(run.y.len()));
                    drop[a..b].iter_mut().for_each(|d| *d = true);
                }
                for (y, d) in run.y.iter_mut().zip(drop) {
                    if d && y.is_finite() {
                        *y = f64::NAN;
                        left_out += 1;
                    }
                }
            }
            found.push((limit, left_out));
        }
    }
    found
}

/// Grid steps either side of a clipped reading also left out (1 s).
const CLIP_MARGIN: usize = 100;
/// Fewest rows at one value that make a sensor range.
const CLIP_MIN_ROWS: usize = 20;
/// Readings this close to the limit count as at it, N (the bench's resolution is 0.01 N).
const CLIP_RESOLUTION_N: f64 = 0.004;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::residual;
    use crate::{excite, synth};
    use jetbench_model::{Effects, Preset};

    /// The drift's decay powers are `powi`'s, bit for bit, for decays over the range of
    /// time constants a fit explores and over a 600 s run.
    #[test]
    fn powers_by_squaring_are_powi_bit_for_bit() {
        for time_constant_s in [0.5, 1.0, 7.3, 20.0, 31.49, 250.0, 1000.0] {
            let decay = (-STEP_S / time_constant_s).exp();
            let mut powers = Vec::new();
            powers_by_squaring(decay, 70_000, &mut powers);
            for (k, p) in powers.iter().enumerate() {
                assert_eq!(p.to_bits(), decay.powi(k as i32).to_bits(), "τ = {time_constant_s} s, k = {k}");
            }
        }
    }

    /// A gap in which the throttle stepped leaves the second after it out (when the engine
    /// got the step is not known); a gap in a ramp, which the ramp's slope carries across, a
    /// gap in a hold, and one across a step of 2 % (what a closed loop moves from row to row)
    /// leave nothing out.
    #[test]
    fn the_second_after_a_step_inside_a_gap_is_left_out() {
        let plant = Plant::new(Preset::P100Diesel.params(), Effects::none());
        let mut profile = Series { name: "steps".into(), ..Series::default() };
        for k in 0..30_000usize {
            // Holds of 20 s at 40 % and 70 % (72 % from 30 s), a ramp of 2 %/s from 60 to 80 s.
            let t = k as f64 * STEP_S;
            let u = match t {
                t if (60.0..80.0).contains(&t) => 40.0 + (t - 60.0) * 2.0,
                t if (30.0..40.0).contains(&t) => 72.0,
                t if ((t / 20.0) as usize).is_multiple_of(2) => 40.0,
                _ => 70.0,
            };
            profile.t_s.push(t);
            profile.u_pct.push(u);
        }
        let bench = synth::Bench { noise_var_n2: 4.0, ..synth::Bench::default() };
        let full = synth::record_bench(&plant, &profile, &bench, 7).expect("recording");
        // Rows lost: at the step at 20 s (the last old row and the first new ones), inside
        // the ramp at 70 s, in the hold at 25 s, and at the small step at 30 s.
        let lost = |k: usize| (1999..2003).contains(&k) || (7000..7002).contains(&k) || k == 2500 || k == 3000;
        let keep: Vec<usize> = (0..full.len()).filter(|&k| !lost(k)).collect();
        let pick = |v: &[f64]| keep.iter().map(|&k| v[k]).collect::<Vec<f64>>();
        let data = [Series {
            name: "gaps".into(),
            t_s: pick(&full.t_s),
            u_pct: pick(&full.u_pct),
            thrust_n: pick(&full.thrust_n),
        }];
        let problem = Problem::new(&data, &plant, 0.3).expect("problem");
        assert_eq!(problem.report.gaps, 4);
        assert_eq!(problem.report.steps_in_gaps, 1, "{:?}", problem.report);
        assert_eq!(problem.report.after_steps_in_gaps, 100);
        let run = &problem.runs[0];
        assert!(run.y[2003..2103].iter().all(|y| y.is_nan()) && run.y[2103].is_finite());
    }

    /// A fast engine's transients are not taken for noise: on the turbojet (white noise of
    /// 7 N²) the noise is estimated where the throttle was held, white or nearly, at its true
    /// scale, and the data notes say so; on a slow engine with coloured noise the whole data's
    /// estimate stands, colour and all.
    #[test]
    fn a_fast_engines_transients_are_not_taken_for_noise() {
        use jetbench_model::turbojet::TurbojetParams;
        let bench = synth::Bench { noise_var_n2: 7.0, ..synth::Bench::default() };
        let fast = Plant::with_turbojet(TurbojetParams::p100(), Effects::none());
        let data = [synth::record_bench(&fast, &excite::campaign(300.0, 12).profile, &bench, 512).expect("recording")];
        let nominal = Plant::new(Preset::P100Diesel.params(), Effects::none());
        let problem = Problem::new(&data, &nominal, 0.3).expect("problem");
        let sigma = problem.noise.sigma_n;
        assert!((sigma - 7f64.sqrt()).abs() < 0.15, "σ {sigma:.2} N against {:.2} N", 7f64.sqrt());
        assert!(problem.ar().phi.iter().map(|p| p.abs()).sum::<f64>() < 0.2, "{:?}", problem.ar().phi);
        assert!(
            problem.report.notes.iter().any(|n| n.contains("where the throttle had been held")),
            "{:?}",
            problem.report.notes
        );

        let slow = Plant::new(Preset::P220Kerosene.params(), Effects::none());
        let coloured = synth::Bench { noise_var_n2: 9.0, noise_ar: vec![0.6], ..synth::Bench::default() };
        let data = [synth::record_bench(&slow, &excite::campaign(300.0, 12).profile, &coloured, 7).expect("recording")];
        let problem = Problem::new(&data, &slow, 0.3).expect("problem");
        assert!(problem.report.notes.is_empty(), "{:?}", problem.report.notes);
        assert!((problem.ar().phi[0] - 0.6).abs() < 0.05, "{:?}", problem.ar().phi);
        assert!((problem.noise.sigma_n - 3.0).abs() < 0.2, "σ {:.2} N", problem.noise.sigma_n);
    }

    /// Throttle steps taken in one cycle, every few tenths of a second, leave a fast engine's
    /// transients in the recording's second differences: the noise, white, is estimated as
    /// an AR model, and the right model's residual (the noise alone) fails Ljung–Box under
    /// it. Estimated again on that residual, the noise is white, and the residual passes. On
    /// coloured noise of a slow engine both estimates are AR(1), and the recording's stands.
    #[test]
    fn the_noise_under_which_a_residual_is_judged_is_estimated_again_on_it() {
        let plant = Plant::new(Preset::P100Diesel.params(), Effects::none());
        let bench = synth::Bench { noise_var_n2: 0.5, ..synth::Bench::default() };
        // A step every 0.2-0.7 s between 25 and 100 %, no holds long enough to settle.
        let mut profile = Series { name: "steps".into(), ..Series::default() };
        let (mut u, mut left) = (25.0, 0usize);
        for k in 0..30_000usize {
            if left == 0 {
                let r = (k as u64).wrapping_mul(6_364_136_223_846_793_005).rotate_left(17);
                u = 25.0 + (r % 7_500) as f64 / 100.0;
                left = 20 + (r >> 20) as usize % 50;
            }
            left -= 1;
            profile.t_s.push(k as f64 * STEP_S);
            profile.u_pct.push(u);
        }
        let data = [synth::record_bench(&plant, &profile, &bench, 3).expect("recording")];
        let problem = Problem::new(&data, &plant, 0.3).expect("problem");
        let mut sim = Sim::new();
        problem.simulate(&plant, &problem.given_states(), false, &mut sim).expect("simulates");
        let leaked = residual::analyse(&problem, &sim);
        assert!(!problem.ar().phi.is_empty(), "the data's noise model took in no signal: {:?}", problem.ar());
        assert!(!leaked.whiteness.white, "p {}", leaked.whiteness.p_value);
        let again = problem.with_colour_from(&sim).expect("another noise model");
        assert!(again.ar().phi.is_empty(), "{:?}", again.ar());
        assert_eq!(again.noise.sigma_n, problem.noise.sigma_n, "the scale stays the data's");
        let judged = residual::analyse(&again, &sim);
        assert!(judged.whiteness.white, "p {}", judged.whiteness.p_value);

        // Coloured noise on a slow engine: the residual's estimate is of the same order, and the
        // recording's model stands.
        let slow = Plant::new(Preset::P220Kerosene.params(), Effects::none());
        let coloured = synth::Bench { noise_var_n2: 9.0, noise_ar: vec![0.6], ..synth::Bench::default() };
        let data = [synth::record_bench(&slow, &excite::campaign(300.0, 12).profile, &coloured, 7).expect("recording")];
        let problem = Problem::new(&data, &slow, 0.3).expect("problem");
        problem.simulate(&slow, &problem.given_states(), false, &mut sim).expect("simulates");
        assert_eq!(problem.ar().order(), 1, "{:?}", problem.ar());
        assert!(problem.with_colour_from(&sim).is_none());
    }

    /// The in-place innovations are the residuals whitened run by run, value for value, on a
    /// recording with coloured noise, lost rows and spikes (strides and gaps included).
    #[test]
    fn innovations_in_place_match_the_whitened_residuals() {
        let plant = Plant::new(Preset::P220Kerosene.params(), Effects::none());
        let bench = synth::Bench {
            noise_var_n2: 9.0,
            noise_ar: vec![0.6, -0.1],
            spike_fraction: 0.002,
            drop_fraction: 0.02,
            ..synth::Bench::default()
        };
        let data = [synth::record_bench(&plant, &excite::campaign(120.0, 5).profile, &bench, 6).expect("recording")];
        let problem = Problem::new(&data, &plant, 0.3).expect("problem");
        assert!(!problem.ar().phi.is_empty(), "the test needs a coloured noise model");
        let mut sim = Sim::new();
        // A slightly different plant, so that the residual is not just noise; calibration only too.
        let mut other = Preset::P220Kerosene.params().to_array();
        other[0] *= 1.05;
        let other = Plant::new(jetbench_model::Params::from_array(other), Effects::none());
        for calibration_only in [false, true] {
            problem.simulate(&other, &problem.given_states(), calibration_only, &mut sim).expect("simulates");
            for part in [Part::Calibration, Part::Validation] {
                let residuals: Vec<Vec<f64>> = (0..problem.runs.len()).map(|i| problem.residual(i, &sim)).collect();
                let (mut expected, mut got) = (Vec::new(), Vec::new());
                problem.whiten_part(&residuals, part, &mut expected);
                problem.innovations(&sim, part, &mut got);
                assert_eq!(expected, got, "{part:?}, calibration only {calibration_only}");
            }
        }
    }

    /// The problem the other way round fits on the held-out part and judges on the
    /// calibration part: its parts are the original's swapped, sample for sample, its
    /// calibration-only simulation runs through the whole run (the held-out part comes
    /// last), and its counts are swapped too.
    #[test]
    fn the_problem_the_other_way_round_swaps_its_parts() {
        let plant = Plant::new(Preset::P100Diesel.params(), Effects::none());
        let bench = synth::Bench { drop_fraction: 0.02, ..synth::Bench::default() };
        let data = [synth::record_bench(&plant, &excite::campaign(120.0, 7).profile, &bench, 8).expect("recording")];
        let problem = Problem::new(&data, &plant, 0.3).expect("problem");
        let reversed = problem.reversed();
        assert_eq!((reversed.n_cal, reversed.n_val), (problem.n_val, problem.n_cal));
        let mut other = Preset::P100Diesel.params().to_array();
        other[0] *= 1.05;
        let other = Plant::new(jetbench_model::Params::from_array(other), Effects::none());
        let mut sim = Sim::new();
        problem.simulate(&other, &problem.given_states(), false, &mut sim).expect("simulates");
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for (part, swapped) in [(Part::Calibration, Part::Validation), (Part::Validation, Part::Calibration)] {
            problem.innovations(&sim, part, &mut a);
            reversed.innovations(&sim, swapped, &mut b);
            assert!(!a.is_empty() && a == b, "{part:?}");
            assert_eq!(problem.sse(&sim, part), reversed.sse(&sim, swapped), "{part:?}");
        }
        let mut short = Sim::new();
        reversed.simulate(&other, &problem.given_states(), true, &mut short).expect("simulates");
        assert_eq!(short, sim, "fitting the held-out part needs the whole run");
        problem.simulate(&other, &problem.given_states(), true, &mut short).expect("simulates");
        assert!(short[0].len() < sim[0].len(), "the calibration part first stops at the split");
    }
    /// A recording whose force sensor clips only near its end is split where the last 30 % of
    /// its measured rows begin, earlier than 30 % of its time: the held-out part keeps its
    /// share of the thrust measured, and the split of a recording clipped nowhere stays.
    #[test]
    fn a_recording_clipped_near_its_end_holds_out_its_share_of_the_measured_rows() {
        let plant = Plant::new(Preset::P100Diesel.params(), Effects::none());
        let bench = synth::Bench { noise_var_n2: 2.0, ..synth::Bench::default() };
        // Steps between 30 % and 60 % for 110 s, then between 85 % and 95 %.
        let mut profile = Series { name: "steps".into(), ..Series::default() };
        for k in 0..15_000usize {
            let t = k as f64 * STEP_S;
            let high = ((t / 4.0) as usize).is_multiple_of(2);
            let u = match (t < 110.0, high) {
                (true, true) => 60.0,
                (true, false) => 30.0,
                (false, true) => 95.0,
                (false, false) => 85.0,
            };
            profile.t_s.push(t);
            profile.u_pct.push(u);
        }
        let clean = [synth::record_bench(&plant, &profile, &bench, 3).expect("recording")];
        let whole = Problem::new(&clean, &plant, 0.3).expect("problem");
        // The sensor's limit: below most readings after 110 s, above every one before.
        let n = clean[0].len();
        let mut late: Vec<f64> = clean[0].thrust_n[11_000..].to_vec();
        late.sort_by(f64::total_cmp);
        let limit = late[late.len() / 4];
        assert!(clean[0].thrust_n[..11_000].iter().all(|&y| y < limit - 1.0), "the limit {limit:.1} N");
        let mut data = clean.clone();
        for y in &mut data[0].thrust_n {
            *y = y.min(limit);
        }
        let clipped = Problem::new(&data, &plant, 0.3).expect("problem");
        assert!(clipped.report.clipped_rows > 0, "{:?}", clipped.report);
        assert!(clipped.cut[0] < whole.cut[0], "{} {}", clipped.cut[0], whole.cut[0]);
        let measured = |p: &Problem<'_>, part: Part| -> usize {
            p.runs.iter().map(|r| (0..r.y.len()).filter(|&k| r.y[k].is_finite() && r.in_part(k, part)).count()).sum()
        };
        let (cal, val) = (measured(&clipped, Part::Calibration), measured(&clipped, Part::Validation));
        let share = val as f64 / (cal + val) as f64;
        assert!((share - 0.3).abs() < 0.002, "held-out share {share:.4} of {} measured rows", cal + val);
        assert_eq!(whole.cut[0], clean[0].t_s.partition_point(|&t| t < 0.7 * clean[0].t_s[n - 1]));
        assert!(whole.report.notes.iter().all(|note| !note.contains("measured")), "{:?}", whole.report.notes);
        assert!(clipped.report.notes.iter().any(|note| note.contains("measured")), "{:?}", clipped.report.notes);
        // Each run's split is the file's.
        let run = &clipped.runs[0];
        let first_held = run.rows.clone().zip(&run.grid).find(|(_, g)| **g >= run.cut).map(|(k, _)| k);
        assert_eq!(first_held, Some(clipped.cut[0]));
    }
}
