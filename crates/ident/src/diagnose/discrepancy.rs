//! Which terms of the discrepancy library ([`jetbench_model::discrepancy`]) explain
//! what the current model leaves: a sparse selection on output sensitivities.
//!
//! The terms act inside the engine (extra thrust acceleration), so what they do to
//! the measured thrust is found by simulation: each term of the library, at each of a
//! few shapes (the knots of [`knots`] within the recorded range, thrust- and throttle-history
//! time constants from 5 s to 3 min; the spool-down factor and the input-gain terms have
//! none), is added with a small coefficient and the
//! change of the simulated output, per unit coefficient, is its sensitivity column.
//! Linearised around the current model, the residual is then a sparse combination
//! of columns. Forward selection picks, term by term, the column that lowers the
//! calibration error most (one shape per term family); each prefix is scored on the
//! validation samples with the same BIC penalty as every hypothesis (a coefficient,
//! plus its knot or time constant), and the best prefix is kept only if it beats no
//! term at all. Its coefficients start the joint nonlinear fit of the hypothesis.
//!
//! The selection frees what that fit frees. When the hypothesis refits the ten
//! parameters, their sensitivities are columns of every prefix (and of the "no term"
//! it must beat), so a term is credited only with what a refit cannot give, as in
//! `identify`'s structure search ([`crate::structure`]). Selected with the parameters
//! held, a term could win for mending the held parameters' static map and then stay once
//! the fit moved them: on the iRonCub group's jet (input gain in `T²`, `Ṫ²`, `T·Ṫ`) a
//! hinge 10 % flatter above 85 % throttle, which that engine does not have, was picked
//! first, in place of the refit's own map.

use jetbench_model::discrepancy::{DiscrepancyTerm, DISCREPANCY_DEFAULTS, DISCREPANCY_KEYS, DISCREPANCY_TERMS};
use jetbench_model::{EffectKind, Effects, Params, Plant};
use nalgebra::{DMatrix, DVector};

use super::fit::{Fit, Spec};
use super::problem::{Part, Problem, Sim};

/// Most terms a discrepancy takes.
pub const MAX_TERMS: usize = 4;
/// Thrust-history time constants tried, s.
const HISTORY_S: [f64; 5] = [5.0, 12.0, 30.0, 75.0, 180.0];
/// Spacing of the throttle-map knots tried, % throttle.
const KNOT_STEP_PCT: f64 = 5.0;

/// One column of the library: a term at one shape.
#[derive(Clone, Copy, Debug)]
struct Column {
    term: DiscrepancyTerm,
    /// The shape value (knot %, time constant s), when the term has one.
    shape: Option<f64>,
    /// Coefficient used to probe the sensitivity (small: the output moves by a fraction of a newton).
    probe: f64,
}

impl Column {
    /// Parameters it costs: the coefficient and its shape.
    fn cost(&self) -> usize {
        1 + usize::from(self.shape.is_some())
    }

    fn label(&self) -> String {
        let key = DISCREPANCY_KEYS[self.term.coefficient];
        match (self.term.shape, self.shape) {
            (Some(s), Some(v)) => format!("{key} ({} = {v})", DISCREPANCY_KEYS[s]),
            _ => key.to_owned(),
        }
    }
}

/// The terms chosen and where the nonlinear fit starts.
#[derive(Clone, Debug)]
pub(crate) struct Selection {
    /// Every value of the discrepancy effect (chosen coefficients and shapes; the rest 0 or default).
    pub values: Vec<f64>,
    /// Which of them are free in the fit.
    pub free: Vec<usize>,
    /// Their scales: the change that moves the output by about 1 N RMS.
    pub scale: Vec<f64>,
    /// The columns chosen, in words.
    pub columns: Vec<String>,
}

/// The throttle-map knots a search tries on `problem`'s recordings: every
/// [`KNOT_STEP_PCT`] strictly inside 0–100 % (5, 10, ..., 95), within the recorded
/// throttle's 5–95 % quantiles drawn in by 1 %. At least a twentieth of the samples then
/// lies on either side of every knot, so no hinge is fitted to the last few rows of the
/// data. Knots below idle (25 %) count: an engine whose throttle runs 0–100 % (the iRonCub
/// group's) can bend there, and a recording that stays above idle never reaches them. A
/// knot at 100 % could never lie inside the range. `diagnose` and `identify`'s structure
/// search ([`crate::structure`]) both take their knots from here.
pub(crate) fn knots(problem: &Problem<'_>) -> Vec<f64> {
    let mut u: Vec<f64> = problem.runs.iter().flat_map(|r| r.u.iter().copied()).filter(|u| u.is_finite()).collect();
    if u.is_empty() {
        return Vec::new();
    }
    u.sort_by(f64::total_cmp);
    let q = |f: f64| u[((u.len() - 1) as f64 * f) as usize];
    let (lo, hi) = (q(0.05) + 1.0, q(0.95) - 1.0);
    (1..).map(|i| f64::from(i) * KNOT_STEP_PCT).take_while(|&k| k < 100.0).filter(|k| (lo..=hi).contains(k)).collect()
}

/// The coefficient that probes the output's sensitivity to the term of coefficient
/// `coefficient`: small, so the simulated output moves by a fraction of a newton.
pub(crate) fn probe(coefficient: usize) -> f64 {
    match coefficient {
        0 | 2 | 9 => 0.02,
        4 => 2e-5,
        10 => 5e-5,
        7 => 1e-7,
        _ => 1e-8,
    }
}

/// A term's family in the selection, which takes one column per family: the two history
/// gains (the thrust's and the throttle's) are one family, since the thrust follows the
/// throttle and the two columns are near collinear over a run. Picked together, they
/// cancel each other in the joint fit: on a heat soak of τ 47 s on 100 s (fresh seed 6703,
/// case 26) a thrust history of 30 s and a throttle history of 5 s started the fit, which
/// ended with neither.
fn family(term: DiscrepancyTerm) -> usize {
    match term.coefficient {
        10 => 4,
        c => c,
    }
}

fn library(problem: &Problem<'_>, history_max_s: f64) -> Vec<Column> {
    let knots = knots(problem);
    let mut out = Vec::new();
    for term in DISCREPANCY_TERMS {
        match term.coefficient {
            0 | 2 => out.extend(knots.iter().map(|&k| Column { term, shape: Some(k), probe: probe(term.coefficient) })),
            4 | 10 => out.extend(HISTORY_S.iter().filter(|&&t| t <= history_max_s).map(|&t| Column {
                term,
                shape: Some(t),
                probe: probe(term.coefficient),
            })),
            _ => out.push(Column { term, shape: None, probe: probe(term.coefficient) }),
        }
    }
    out
}

/// Sensitivity of the simulated output to each column, per run on its grid (NaN where
/// there is no sample).
fn sensitivities(
    problem: &Problem<'_>,
    fixed: &Effects,
    current: &Spec,
    sim: &Sim,
    columns: &[Column],
) -> Vec<Option<Vec<Vec<f64>>>> {
    let mut probe_sim = Sim::new();
    columns
        .iter()
        .map(|c| {
            let mut values = DISCREPANCY_DEFAULTS.to_vec();
            values[c.term.coefficient] = c.probe;
            if let (Some(s), Some(v)) = (c.term.shape, c.shape) {
                values[s] = v;
            }
            let spec = current.with(EffectKind::Discrepancy, values);
            let plant: Plant = spec.plant(fixed)?;
            problem.simulate(&plant, &spec.states, false, &mut probe_sim).ok()?;
            Some(divided_difference(problem, &probe_sim, sim, c.probe))
        })
        .collect()
}

/// Sensitivity of the simulated output to each of the ten parameters of `current`, per
/// run on its grid (NaN where there is no sample); a parameter whose probe diverges is
/// left out.
fn parameter_sensitivities(problem: &Problem<'_>, fixed: &Effects, current: &Spec, sim: &Sim) -> Vec<Vec<Vec<f64>>> {
    let mut probe_sim = Sim::new();
    let given = current.params.to_array();
    (0..given.len())
        .filter_map(|i| {
            let delta = 1e-4 * given[i].abs().max(1e-3);
            let mut params = given;
            params[i] += delta;
            let mut spec = current.clone();
            spec.params = Params::from_array(params);
            let plant = spec.plant(fixed)?;
            problem.simulate(&plant, &spec.states, false, &mut probe_sim).ok()?;
            Some(divided_difference(problem, &probe_sim, sim, delta))
        })
        .collect()
}

/// `(probed − base) / step` per run on its grid, NaN where the run has no sample: the
/// sensitivity of the simulated output to whatever was moved by `step`.
fn divided_difference(problem: &Problem<'_>, probed: &Sim, base: &Sim, step: f64) -> Vec<Vec<f64>> {
    problem
        .runs
        .iter()
        .enumerate()
        .map(|(r, run)| {
            (0..run.y.len())
                .map(|k| if run.y[k].is_finite() { (probed[r][k] - base[r][k]) / step } else { f64::NAN })
                .collect()
        })
        .collect()
}

/// Innovations of `columns` (one vector per run) over `part`, in the order of
/// [`Problem::innovations`].
fn whitened(problem: &Problem<'_>, runs: &[Vec<f64>], part: Part) -> Vec<f64> {
    let mut out = Vec::new();
    problem.whiten_part(runs, part, &mut out);
    out
}

/// Selects discrepancy terms for the residual of `current` (simulated as `sim`).
/// `None` when no term helps on held-out data (or a discrepancy is already there).
pub(crate) fn select(problem: &Problem<'_>, fixed: &Effects, current: &Spec, sim: &Sim) -> Option<Selection> {
    if current.has(EffectKind::Discrepancy) || fixed.get(EffectKind::Discrepancy).is_some() {
        return None;
    }
    let columns = library(problem, current.history_max_s);
    let sens = sensitivities(problem, fixed, current, sim, &columns);
    let residual: Vec<Vec<f64>> = (0..problem.runs.len()).map(|i| problem.residual(i, sim)).collect();
    let (r_cal, r_val) =
        (whitened(problem, &residual, Part::Calibration), whitened(problem, &residual, Part::Validation));
    // The ten parameters' sensitivities first when the hypothesis refits them (the fit that
    // follows frees them, so the selection does too), then the columns of the library
    // usable: simulated, and as long as the residual (no divergence).
    let (mut cal, mut val) = (Vec::new(), Vec::new());
    if current.refit {
        for s in parameter_sensitivities(problem, fixed, current, sim) {
            let (sc, sv) = (whitened(problem, &s, Part::Calibration), whitened(problem, &s, Part::Validation));
            if sc.len() == r_cal.len() && sv.len() == r_val.len() && sc.iter().chain(&sv).all(|x| x.is_finite()) {
                cal.push(sc);
                val.push(sv);
            }
        }
    }
    let nuisance: Vec<usize> = (0..cal.len()).collect();
    let mut usable = Vec::new();
    for (c, s) in sens.iter().enumerate() {
        let Some(s) = s else { continue };
        let (sc, sv) = (whitened(problem, s, Part::Calibration), whitened(problem, s, Part::Validation));
        if sc.len() == r_cal.len() && sv.len() == r_val.len() {
            usable.push(c);
            cal.push(sc);
            val.push(sv);
        }
    }
    if usable.is_empty() {
        return None;
    }
    let m = nuisance.len();
    let p = cal.len();
    // Library column of entry `a` (entries `m..`).
    let column = |a: usize| columns[usable[a - m]];
    let dot = |x: &[f64], y: &[f64]| -> f64 { x.iter().zip(y).map(|(a, b)| a * b).sum() };
    let gram = DMatrix::from_fn(p, p, |a, b| dot(&cal[a], &cal[b]));
    let rhs = DVector::from_fn(p, |a, _| dot(&cal[a], &r_cal));
    let n_val = r_val.len() as f64;
    let score = |sse: f64, k: usize| n_val * (sse / n_val).ln() + k as f64 * n_val.ln();

    let solve = |active: &[usize]| -> Option<DVector<f64>> {
        let k = active.len();
        let a = DMatrix::from_fn(k, k, |i, j| gram[(active[i], active[j])] * if i == j { 1.0 + 1e-10 } else { 1.0 });
        let b = DVector::from_fn(k, |i, _| rhs[active[i]]);
        a.cholesky().map(|c| c.solve(&b))
    };
    let val_sse = |active: &[usize], theta: &DVector<f64>| -> f64 {
        (0..r_val.len())
            .map(|row| {
                let pred: f64 = active.iter().zip(theta.iter()).map(|(&a, t)| val[a][row] * t).sum();
                (r_val[row] - pred).powi(2)
            })
            .sum()
    };
    let base = if m == 0 {
        score(r_val.iter().map(|x| x * x).sum(), 0)
    } else {
        score(val_sse(&nuisance, &solve(&nuisance)?), 0)
    };
    let mut active: Vec<usize> = Vec::new();
    let mut best: Option<(f64, Vec<usize>)> = None;
    while active.len() < MAX_TERMS {
        let family_used = |a: usize| active.iter().any(|&b| family(column(b).term) == family(column(a).term));
        let step = (m..p)
            .filter(|&a| !family_used(a))
            .filter_map(|a| {
                let mut trial = nuisance.clone();
                trial.extend(active.iter().copied().chain([a]));
                let theta = solve(&trial)?;
                let fitted: f64 = trial.iter().zip(theta.iter()).map(|(&i, t)| rhs[i] * t).sum();
                Some((fitted, a, trial, theta))
            })
            .max_by(|x, y| x.0.total_cmp(&y.0));
        let Some((_, a, trial, theta)) = step else { break };
        active.push(a);
        let k: usize = active.iter().map(|&a| column(a).cost()).sum();
        let s = score(val_sse(&trial, &theta), k);
        if best.as_ref().is_none_or(|(b, _)| s < *b) {
            best = Some((s, active.clone()));
        }
    }
    let (s, chosen) = best?;
    if s >= base {
        return None;
    }
    // The fit starts from the chosen columns' own least squares (the parameters, if they
    // are refitted, move in the fit itself).
    let theta = solve(&chosen)?;
    let mut values = DISCREPANCY_DEFAULTS.to_vec();
    let mut free = Vec::new();
    let mut scale = vec![1.0; values.len()];
    let mut labels = Vec::new();
    for (&a, &coefficient) in chosen.iter().zip(theta.iter()) {
        let c = column(a);
        let rms = (cal[a].iter().map(|x| x * x).sum::<f64>() / cal[a].len().max(1) as f64).sqrt();
        values[c.term.coefficient] = coefficient;
        scale[c.term.coefficient] = if rms > 0.0 { 1.0 / rms } else { c.probe };
        free.push(c.term.coefficient);
        if let (Some(i), Some(v)) = (c.term.shape, c.shape) {
            values[i] = v;
            scale[i] = if i == 5 || i == 11 { 0.3 * v } else { KNOT_STEP_PCT };
            free.push(i);
        }
        labels.push(c.label());
    }
    free.sort_unstable();
    Some(Selection { values, free, scale, columns: labels })
}

/// The discrepancy `values` with their history gain moved to the other history, the
/// thrust's to the throttle's or back, at the same time constant and for about the same
/// change of gain over the recording (the coefficient times the mean thrust over the mean
/// throttle map, or the inverse): `(from, to, factor, values)`, the indexes of the two gains
/// and the factor between them; `None` without a history term.
pub(crate) fn history_swapped(
    problem: &Problem<'_>,
    params: &Params,
    values: &[f64],
) -> Option<(usize, usize, f64, Vec<f64>)> {
    let (thrust, throttle): (Vec<f64>, Vec<f64>) = problem
        .runs
        .iter()
        .flat_map(|r| r.y.iter().zip(&r.u))
        .filter(|(y, u)| y.is_finite() && u.is_finite())
        .map(|(&y, &u)| (y, params.v(u)))
        .unzip();
    let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len().max(1) as f64;
    let (thrust_n, v) = (mean(&thrust), mean(&throttle));
    if !(thrust_n.abs() > 1e-9 && v.abs() > 1e-9) {
        return None;
    }
    let (from, to, factor) = if values[4] != 0.0 {
        (4, 10, thrust_n / v)
    } else if values[10] != 0.0 {
        (10, 4, v / thrust_n)
    } else {
        return None;
    };
    let mut swapped = values.to_vec();
    swapped[to] = values[from] * factor;
    swapped[to + 1] = values[from + 1];
    swapped[from] = DISCREPANCY_DEFAULTS[from];
    swapped[from + 1] = DISCREPANCY_DEFAULTS[from + 1];
    Some((from, to, factor, swapped))
}

/// `free` and `scale` of a discrepancy fit moved with [`history_swapped`]'s `from` → `to`.
pub(crate) fn history_free_swapped(from: usize, to: usize, factor: f64, free: &mut [usize], scale: &mut [f64]) {
    for i in free.iter_mut() {
        if *i == from || *i == from + 1 {
            *i = *i - from + to;
        }
    }
    free.sort_unstable();
    if scale.len() > to.max(from) + 1 {
        scale[to] = scale[from] * factor;
        scale[to + 1] = scale[from + 1];
    }
}

/// `selection` with its history gain moved to the other history ([`history_swapped`]);
/// `None` when it has no history term. The two columns are near collinear, so which one the
/// selection took can turn on the noise, and a history started at a time constant far from
/// its own can end on the edge of its range, where it is dropped: when the first fit loses
/// its history, the fit runs again from this one ([`crate::diagnose`]'s `try_discrepancy`).
pub(crate) fn other_history(problem: &Problem<'_>, params: &Params, selection: &Selection) -> Option<Selection> {
    let (from, to, factor, values) = history_swapped(problem, params, &selection.values)?;
    let mut twin = Selection { values, ..selection.clone() };
    history_free_swapped(from, to, factor, &mut twin.free, &mut twin.scale);
    let (key, shape) = (DISCREPANCY_KEYS[from], DISCREPANCY_KEYS[from + 1]);
    for label in &mut twin.columns {
        if label.starts_with(key) {
            *label = label.replacen(key, DISCREPANCY_KEYS[to], 1).replacen(shape, DISCREPANCY_KEYS[to + 1], 1);
        }
    }
    Some(twin)
}

/// The term of a fitted discrepancy that does nothing: its shape on the edge of the range
/// a fit may explore (a time constant gone to its bound is a constant), or its coefficient
/// within two standard errors of zero; the least significant such term.
pub(crate) fn idle_term(fit: &Fit) -> Option<DiscrepancyTerm> {
    let values = fit.spec.values(EffectKind::Discrepancy)?;
    let errors = fit.stderr.iter().find(|(k, _)| *k == EffectKind::Discrepancy).map(|(_, e)| e.as_slice())?;
    DISCREPANCY_TERMS
        .iter()
        .copied()
        .filter(|t| fit.spec.discrepancy_free.contains(&t.coefficient))
        .filter_map(|t| {
            let z = values[t.coefficient].abs() / errors[t.coefficient];
            let edge = t.shape.is_some_and(|i| {
                let (lo, hi) = fit.spec.value_bounds(EffectKind::Discrepancy, i);
                let tolerance = 1e-3 * fit.spec.discrepancy_scale.get(i).copied().unwrap_or(1.0);
                values[i] - lo <= tolerance || hi - values[i] <= tolerance
            });
            (edge || z.is_nan() || z < 2.0).then_some((if edge { 0.0 } else { z }, t))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, t)| t)
}

/// `spec` without `term` (its coefficient 0, no longer fitted); `None` when it was the
/// last term.
pub(crate) fn without_term(spec: &Spec, term: DiscrepancyTerm) -> Option<Spec> {
    let mut values = spec.values(EffectKind::Discrepancy)?.to_vec();
    values[term.coefficient] = 0.0;
    let mut next = spec.with(EffectKind::Discrepancy, values);
    next.discrepancy_free.retain(|&i| i != term.coefficient && Some(i) != term.shape);
    (!next.discrepancy_free.is_empty()).then_some(next)
}
