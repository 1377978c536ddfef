//! The data a diagnosis works on, and output-error fits of effect parameters.
//!
//! Every candidate model is simulated over each whole contiguous run, from the state
//! fitted to the run's first two seconds, exactly as a bench engineer would replay a
//! recording through a simulator: no measurement corrects it. Parameters are fitted
//! on the calibration rows (the first part of each file) and judged on the
//! validation rows (the rest). A run is never restarted at the split, because the
//! slow states some effects add (a sensor bias, a sagging gain) are known only by
//! running through the recording from its start.

use std::ops::Range;

use jetbench_model::{Effect, EffectKind, Effects, Params, Plant, State};
use nalgebra::{DMatrix, DVector};

use crate::series::Series;
use crate::validate::fit_initial_state_at;
use crate::IdentError;

/// Which rows a sum runs over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Part {
    Calibration,
    Validation,
    All,
}

/// One contiguous run and the state it starts from.
#[derive(Clone, Debug)]
struct Run {
    series: usize,
    rows: Range<usize>,
    t0_s: f64,
    initial: State,
}

/// Recordings split into calibration and validation rows.
pub(crate) struct Problem<'a> {
    pub data: &'a [Series],
    runs: Vec<Run>,
    /// Per series: the first validation row.
    pub cut: Vec<usize>,
    pub n_cal: usize,
    pub n_val: usize,
}

/// Simulated (noise-free) measured thrust, one vector per series; NaN on rows not simulated.
pub(crate) type Sim = Vec<Vec<f64>>;

impl<'a> Problem<'a> {
    /// Splits each file at `1 − holdout` of its duration and fits each run's initial
    /// state under `nominal`.
    pub fn new(data: &'a [Series], nominal: &Plant, holdout: f64) -> Result<Self, IdentError> {
        let mut runs = Vec::new();
        let mut cut = Vec::with_capacity(data.len());
        for (i, s) in data.iter().enumerate() {
            let (first, last) = (s.t_s[0], s.t_s[s.len() - 1]);
            let split_s = first + (1.0 - holdout) * (last - first);
            cut.push(s.t_s.partition_point(|&t| t < split_s));
            for rows in s.runs() {
                if rows.len() < 3 {
                    continue;
                }
                let initial =
                    fit_initial_state_at(nominal, s.t_s[rows.start], &s.thrust_n[rows.clone()], &s.u_pct[rows.clone()]);
                runs.push(Run { series: i, t0_s: s.t_s[rows.start], rows, initial });
            }
        }
        let count = |part: Part| -> usize {
            runs.iter().map(|r| r.rows.clone().filter(|&k| Self::in_part(&cut, r.series, k, part)).count()).sum()
        };
        let (n_cal, n_val) = (count(Part::Calibration), count(Part::Validation));
        if n_cal < 1000 || n_val < 500 {
            return Err(IdentError::TooLittleData(format!(
                "{n_cal} calibration and {n_val} validation samples; a diagnosis needs at least 1000 and 500 \
                 (a few minutes of data; typical recordings are 300 s)"
            )));
        }
        Ok(Self { data, runs, cut, n_cal, n_val })
    }

    fn in_part(cut: &[usize], series: usize, row: usize, part: Part) -> bool {
        match part {
            Part::Calibration => row < cut[series],
            Part::Validation => row >= cut[series],
            Part::All => true,
        }
    }

    /// Rows of `part` in series `i`, within runs.
    pub fn rows(&self, i: usize, part: Part) -> impl Iterator<Item = usize> + Clone + '_ {
        self.runs
            .iter()
            .filter(move |r| r.series == i)
            .flat_map(move |r| r.rows.clone().filter(move |&k| Self::in_part(&self.cut, i, k, part)))
    }

    /// Simulates `plant` over every run (only up to the split when `calibration_only`).
    /// `Err` carries (series, time s) of a divergence.
    pub fn simulate(&self, plant: &Plant, calibration_only: bool, out: &mut Sim) -> Result<(), (usize, f64)> {
        out.resize_with(self.data.len(), Vec::new);
        for (i, s) in self.data.iter().enumerate() {
            out[i].clear();
            out[i].resize(s.len(), f64::NAN);
        }
        let mut buffer = Vec::new();
        for run in &self.runs {
            let end = if calibration_only { run.rows.end.min(self.cut[run.series]) } else { run.rows.end };
            if end <= run.rows.start {
                continue;
            }
            let u = &self.data[run.series].u_pct[run.rows.start..end];
            if let Some(at) = plant.free_run(run.t0_s, run.initial, u, &mut buffer) {
                return Err((run.series, run.t0_s + at));
            }
            out[run.series][run.rows.start..end].copy_from_slice(&buffer);
        }
        Ok(())
    }

    /// (measured, simulated) over the rows of `part`, in a fixed order.
    pub fn pairs<'s>(&'s self, sim: &'s Sim, part: Part) -> impl Iterator<Item = (f64, f64)> + Clone + 's {
        self.data
            .iter()
            .zip(sim)
            .enumerate()
            .flat_map(move |(i, (s, m))| self.rows(i, part).map(move |k| (s.thrust_n[k], m[k])))
    }

    /// Sum of squared errors over `part`.
    pub fn sse(&self, sim: &Sim, part: Part) -> f64 {
        self.pairs(sim, part).map(|(y, m)| (y - m).powi(2)).sum()
    }

    /// Mean absolute error over `part`.
    pub fn mae(&self, sim: &Sim, part: Part) -> f64 {
        let (sum, n) = self.pairs(sim, part).fold((0.0, 0usize), |(a, n), (y, m)| (a + (y - m).abs(), n + 1));
        sum / n.max(1) as f64
    }

    /// Calibration residuals `y − ŷ` in a fixed row order.
    fn residuals(&self, sim: &Sim, out: &mut Vec<f64>) {
        out.clear();
        out.extend(self.pairs(sim, Part::Calibration).map(|(y, m)| y - m));
    }
}

/// Typical size of each parameter: the unit the fit works in, and the scale of its
/// finite-difference steps.
fn scale(kind: EffectKind, index: usize) -> f64 {
    match (kind, index) {
        (EffectKind::InputDelay, _) => 0.05,
        (EffectKind::ActuatorLag, _) => 0.1,
        (EffectKind::RateLimit, _) => 50.0,
        (EffectKind::SensorDrift, 0) => 0.02,
        (EffectKind::SensorDrift, _) => 20.0,
        (EffectKind::GainDrift, _) => 0.005,
        (EffectKind::BearingFriction, _) => 1.0,
    }
}

/// The range a fit may explore: the model-file bounds, kept away from values where
/// the effect degenerates (a zero time constant).
fn fit_bounds(kind: EffectKind, index: usize) -> (f64, f64) {
    let (lo, hi) = kind.bounds()[index];
    match (kind, index) {
        (EffectKind::ActuatorLag, _) => (lo.max(0.002), hi.min(3.0)),
        (EffectKind::RateLimit, _) => (lo.max(1.0), hi.min(2000.0)),
        (EffectKind::SensorDrift, 1) => (lo.max(0.5), hi.min(1000.0)),
        (EffectKind::InputDelay, _) => (lo, hi.min(1.0)),
        _ => (lo, hi),
    }
}

/// Starting points for a fit of one effect: a coarse grid over its plausible range
/// (plant.md), the best of which starts the local search.
pub(crate) fn start_grid(kind: EffectKind) -> Vec<Vec<f64>> {
    let one = |values: &[f64]| values.iter().map(|&v| vec![v]).collect::<Vec<_>>();
    let two = |a: &[f64], b: &[f64]| a.iter().flat_map(|&x| b.iter().map(move |&y| vec![x, y])).collect::<Vec<_>>();
    match kind {
        EffectKind::InputDelay => one(&[0.02, 0.04, 0.07, 0.1, 0.15, 0.22, 0.3, 0.45]),
        EffectKind::ActuatorLag => one(&[0.03, 0.06, 0.1, 0.15, 0.22, 0.3, 0.45, 0.7, 1.0]),
        EffectKind::RateLimit => two(&[15.0, 30.0, 60.0, 120.0, 250.0], &[15.0, 30.0, 60.0, 120.0, 250.0]),
        EffectKind::SensorDrift => two(&[-0.06, -0.02, 0.02, 0.06], &[5.0, 15.0, 40.0, 100.0]),
        EffectKind::GainDrift => one(&[-0.02, -0.008, -0.003, 0.003, 0.008, 0.02]),
        EffectKind::BearingFriction => one(&[0.3, 0.7, 1.2, 2.0, 3.0, 5.0]),
    }
}

/// A fitted set of effects.
#[derive(Clone, Debug)]
pub(crate) struct Fit {
    /// Every effect of the model: the fixed ones and the fitted ones.
    pub effects: Effects,
    /// Standard errors of the fitted parameters, per fitted kind, in key order.
    pub stderr: Vec<(EffectKind, Vec<f64>)>,
}

/// Output-error fit of the parameters of `free` (kinds with starting values) on the
/// calibration rows by Levenberg–Marquardt with forward-difference Jacobians, with
/// `fixed` effects held as they are. `None` when every start diverges.
pub(crate) fn fit(
    problem: &Problem<'_>,
    params: Params,
    fixed: &Effects,
    free: &[(EffectKind, Vec<f64>)],
) -> Option<Fit> {
    let layout: Vec<(EffectKind, usize)> =
        free.iter().flat_map(|(kind, values)| (0..values.len()).map(move |i| (*kind, i))).collect();
    let scales: Vec<f64> = layout.iter().map(|&(k, i)| scale(k, i)).collect();
    let bounds: Vec<(f64, f64)> = layout.iter().map(|&(k, i)| fit_bounds(k, i)).collect();
    let build = |x: &[f64]| -> Option<Effects> {
        let mut effects = fixed.clone();
        let mut at = 0;
        for (kind, values) in free {
            let v: Vec<f64> = (0..values.len())
                .map(|i| (x[at + i] * scales[at + i]).clamp(bounds[at + i].0, bounds[at + i].1))
                .collect();
            at += values.len();
            effects = effects.with(Effect::new(*kind, &v).ok()?);
        }
        Some(effects)
    };
    let clamp = |x: &mut [f64]| {
        for (i, xi) in x.iter_mut().enumerate() {
            *xi = xi.clamp(bounds[i].0 / scales[i], bounds[i].1 / scales[i]);
        }
    };
    let mut sim = Sim::new();
    let mut evaluate = |x: &[f64], r: &mut Vec<f64>| -> Option<f64> {
        let plant = Plant::new(params, build(x)?);
        problem.simulate(&plant, true, &mut sim).ok()?;
        problem.residuals(&sim, r);
        Some(r.iter().map(|v| v * v).sum())
    };

    let mut x: Vec<f64> = free.iter().flat_map(|(_, v)| v.iter().copied()).zip(&scales).map(|(v, s)| v / s).collect();
    clamp(&mut x);
    let k = x.len();
    let mut r = Vec::new();
    let mut sse = evaluate(&x, &mut r)?;
    let mut lambda = 1e-3;
    let mut jac = DMatrix::<f64>::zeros(r.len(), k);
    let mut trial_r = Vec::new();
    for _ in 0..30 {
        // Forward differences, stepping inward at an upper bound.
        for j in 0..k {
            let mut xj = x.clone();
            let mut h = 1e-4 * x[j].abs().max(1.0);
            if xj[j] + h > bounds[j].1 / scales[j] {
                h = -h;
            }
            xj[j] += h;
            evaluate(&xj, &mut trial_r)?;
            // `r = y − ŷ`, so the column of ∂ŷ/∂x is −∂r/∂x.
            for (row, (a, b)) in r.iter().zip(&trial_r).enumerate() {
                jac[(row, j)] = (a - b) / h;
            }
        }
        let jtj = jac.tr_mul(&jac);
        let jtr = jac.tr_mul(&DVector::from_column_slice(&r));
        let mut improved = false;
        for _ in 0..12 {
            let mut a = jtj.clone();
            for j in 0..k {
                a[(j, j)] += lambda * jtj[(j, j)].max(1e-12) + 1e-12;
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let mut next: Vec<f64> = x.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
            clamp(&mut next);
            match evaluate(&next, &mut trial_r) {
                Some(s) if s < sse => {
                    let gain = (sse - s) / sse;
                    x = next;
                    sse = s;
                    std::mem::swap(&mut r, &mut trial_r);
                    lambda = (lambda / 4.0).max(1e-9);
                    improved = gain > 1e-9;
                    break;
                }
                _ => lambda *= 5.0,
            }
        }
        if !improved {
            break;
        }
    }
    // Standard errors from the last Jacobian: σ²·(JᵀJ)⁻¹ with σ² from the residual.
    let dof = (r.len().saturating_sub(k)).max(1) as f64;
    let sigma2 = sse / dof;
    let cov = jac.tr_mul(&jac).try_inverse();
    let mut stderr = Vec::new();
    let mut at = 0;
    for (kind, values) in free {
        let e: Vec<f64> = (0..values.len())
            .map(|i| {
                let j = at + i;
                cov.as_ref().map_or(f64::NAN, |c| (sigma2 * c[(j, j)]).max(0.0).sqrt() * scales[j])
            })
            .collect();
        at += values.len();
        stderr.push((*kind, e));
    }
    Some(Fit { effects: build(&x)?, stderr })
}
