//! Structure chosen by the data: the ten parameters extended by the terms of the
//! discrepancy library ([`jetbench_model::discrepancy`]) that held-out data pays for.
//!
//! The terms are the ones a diagnosis knows: input gain in `T²`, `Ṫ²` and `T·Ṫ`
//! (`B_TT`, `B_DD`, `B_TD`, the iRonCub group's later jet model) and hinges in the
//! throttle map (`map_below`, `map_above`, with a knot every 5 % of throttle within the
//! recorded range). The criterion is the diagnosis's own, on the same data
//! ([`crate::diagnose::problem::Problem`]: the recordings on the 10 ms grid, spikes left
//! out, the sensor noise modelled and the residual prewhitened), so both commands
//! choose structure alike:
//!
//! - a model is judged on the held-out samples by `N·ln(SSE/N) + k·ln N`, the
//!   innovations' likelihood with a BIC penalty of `ln N` per fitted parameter (a
//!   coefficient, plus its knot);
//! - a term is kept only when the model with it beats the ten parameters *refitted on
//!   their own*, so it is never credited with what a refit gives, and the gain clears
//!   the diagnosis's admission bar (held-out MAE better by
//!   [`Options::min_gain`](crate::diagnose::Options) of the floor, or
//!   [`strong_evidence`](crate::diagnose::Options) score units).
//!
//! The search linearises the simulated output around the given model (one simulation
//! per parameter and per library column), selects terms greedily on the calibration
//! part (one per family, at most [`MAX_TERMS`]) and scores each prefix on the held-out
//! part, as the diagnosis's discrepancy search does. The chosen prefix and the refit
//! alone are then fitted by Gauss–Newton on the simulation (output) error and judged by
//! real simulations. The extended model is written only when it stays bounded over the
//! throttle range: a rest point at every throttle of a 2.5 % grid that a staircase and
//! full steps both ways reach.

use jetbench_model::discrepancy::{DISCREPANCY_DEFAULTS, DISCREPANCY_KEYS, DISCREPANCY_TERMS};
use jetbench_model::{
    Effect, EffectKind, Effects, ModelFile, Params, Plant, State, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT,
};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use crate::diagnose::problem::{Part, Problem, Sim};
use crate::series::Series;
use crate::spd::SpdSolver;

/// Most terms added (the diagnosis's discrepancy takes as many).
pub const MAX_TERMS: usize = 4;
/// Spacing of the throttle-map knots tried, %.
const KNOT_STEP_PCT: f64 = 5.0;
/// Gauss–Newton iterations of each fit on the simulation error.
const ITERATIONS: usize = 3;

/// One column of the library: a term at one knot.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Column {
    /// Index of the coefficient in the discrepancy's values.
    coefficient: usize,
    /// (index, value) of its knot, for a hinge.
    shape: Option<(usize, f64)>,
    /// Coefficient used to probe the output's sensitivity.
    probe: f64,
}

impl Column {
    /// Parameters it costs in the penalty: the coefficient and its knot.
    fn cost(&self) -> usize {
        1 + usize::from(self.shape.is_some())
    }

    fn label(&self) -> String {
        match self.shape {
            Some((i, v)) => format!("{} ({} = {v})", DISCREPANCY_KEYS[self.coefficient], DISCREPANCY_KEYS[i]),
            None => DISCREPANCY_KEYS[self.coefficient].to_owned(),
        }
    }
}

/// A term kept, and what held-out data says of it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChosenTerm {
    /// The term in words, with its knot (`B_TT`, `map_below (knot_below_pct = 45)`).
    pub label: String,
    /// Its coefficient's key in the model file.
    pub key: &'static str,
    /// The fitted coefficient.
    pub value: f64,
    /// Parameters it costs (coefficient and knot).
    pub parameters: usize,
    /// How much worse the held-out score is without it (the rest refitted), penalty
    /// included, score units: what the term earns beyond its `ln N` per parameter.
    pub held_out_gain: f64,
}

/// What the structure search found.
#[derive(Clone, Debug, Serialize)]
pub struct Structure {
    /// The terms kept, in the order chosen (empty: the ten parameters suffice).
    pub chosen: Vec<ChosenTerm>,
    /// The extended model: the ten parameters refitted with the terms (None: nothing kept).
    #[serde(skip)]
    pub model: Option<ModelFile>,
    /// The penalty per parameter, `ln N` of the held-out innovations (the diagnosis's).
    pub penalty_per_parameter: f64,
    /// Held-out score of the ten parameters refitted alone (k = 0), score units.
    pub refit_score: f64,
    /// Held-out score of the best extension found, penalty included (None: none fitted).
    pub extended_score: Option<f64>,
    /// Held-out MAE of the ten parameters refitted alone and of the extension, N.
    pub refit_mae_n: f64,
    /// Held-out MAE of the extension, N.
    pub extended_mae_n: Option<f64>,
    /// The library's columns tried.
    pub columns_tried: usize,
    /// The decision in one sentence.
    pub verdict: String,
}

/// The recordings the held-out split was cut from, when `validation` is the tail of
/// `calibration` file by file (what [`crate::identify::hold_out`] gives), and the held-out
/// fraction of their duration.
fn rejoin(calibration: &[Series], validation: &[Series]) -> Option<(Vec<Series>, f64)> {
    if calibration.len() != validation.len() || calibration.is_empty() {
        return None;
    }
    let mut joined = Vec::new();
    let (mut held_s, mut total_s) = (0.0, 0.0);
    for (c, v) in calibration.iter().zip(validation) {
        let (c_end, v_start, v_end) = (*c.t_s.last()?, *v.t_s.first()?, *v.t_s.last()?);
        if c.name != v.name || v_start <= c_end {
            return None;
        }
        let mut s = c.clone();
        s.t_s.extend(&v.t_s);
        s.u_pct.extend(&v.u_pct);
        s.thrust_n.extend(&v.thrust_n);
        held_s += v_end - v_start;
        total_s += v_end - c.t_s[0];
        joined.push(s);
    }
    (total_s > 0.0).then_some((joined, held_s / total_s))
}

/// The search over one problem.
struct Search<'p, 'a> {
    problem: &'p Problem<'a>,
    states: Vec<State>,
    n_val: f64,
}

/// A candidate model: the ten parameters and the discrepancy's values.
#[derive(Clone, Debug, PartialEq)]
struct Candidate {
    params: [f64; 10],
    disc: [f64; 9],
}

impl Candidate {
    fn plant(&self) -> Option<Plant> {
        let p = Params::from_array(self.params);
        p.validate().ok()?;
        let effects = if self.disc.iter().zip(DISCREPANCY_DEFAULTS).all(|(a, b)| *a == b) {
            Effects::none()
        } else {
            Effects::new([Effect::new(EffectKind::Discrepancy, &self.disc).ok()?]).ok()?
        };
        Some(Plant::new(p, effects))
    }

    fn model_file(&self) -> Option<ModelFile> {
        let plant = self.plant()?;
        Some(ModelFile { model: plant.params, effects: plant.effects })
    }
}

/// Held-out figures of one simulated candidate.
#[derive(Clone, Copy, Debug)]
struct Judged {
    sse: f64,
    mae_n: f64,
}

impl Search<'_, '_> {
    fn simulate(&self, c: &Candidate) -> Option<Sim> {
        let plant = c.plant()?;
        let mut sim = Sim::new();
        self.problem.simulate(&plant, &self.states, false, &mut sim).ok()?;
        Some(sim)
    }

    fn judge(&self, sim: &Sim) -> Option<Judged> {
        let (sse, _) = self.problem.sse(sim, Part::Validation);
        let mae_n = self.problem.mae(sim, Part::Validation);
        (sse.is_finite() && mae_n.is_finite()).then_some(Judged { sse, mae_n })
    }

    /// The diagnosis's score: `N·ln(SSE/N) + k·ln N` on the held-out innovations.
    fn score(&self, sse: f64, k: usize) -> f64 {
        self.n_val * (sse / self.n_val).ln() + k as f64 * self.n_val.ln()
    }

    fn whitened(&self, runs: &[Vec<f64>], part: Part) -> Vec<f64> {
        let mut out = Vec::new();
        self.problem.whiten_part(runs, part, &mut out);
        out
    }

    /// Sensitivity of the output to a change `delta` of value `index` of the candidate's
    /// parameters (0–9) or discrepancy (10–18), whitened over calibration and validation.
    fn column(&self, c: &Candidate, sim: &Sim, index: usize, delta: f64) -> Option<(Vec<f64>, Vec<f64>)> {
        let mut probe = c.clone();
        if index < 10 {
            probe.params[index] += delta;
        } else {
            probe.disc[index - 10] += delta;
        }
        let moved = self.simulate(&probe)?;
        let per_run: Vec<Vec<f64>> = self
            .problem
            .runs
            .iter()
            .enumerate()
            .map(|(i, run)| {
                (0..run.y.len())
                    .map(|k| if run.y[k].is_finite() { (moved[i][k] - sim[i][k]) / delta } else { f64::NAN })
                    .collect()
            })
            .collect();
        Some((self.whitened(&per_run, Part::Calibration), self.whitened(&per_run, Part::Validation)))
    }

    fn residuals(&self, sim: &Sim) -> (Vec<f64>, Vec<f64>) {
        let r: Vec<Vec<f64>> = (0..self.problem.runs.len()).map(|i| self.problem.residual(i, sim)).collect();
        (self.whitened(&r, Part::Calibration), self.whitened(&r, Part::Validation))
    }

    /// Probe size for parameter `i`.
    fn param_delta(p: &[f64; 10], i: usize) -> f64 {
        1e-4 * p[i].abs().max(1e-3)
    }

    /// Gauss–Newton on the calibration simulation error over the ten parameters and
    /// the discrepancy values `free` (indices into its values), from `start`; the best
    /// candidate seen by calibration error, with its simulation.
    fn fit(&self, start: &Candidate, free: &[usize]) -> Option<(Candidate, Sim)> {
        let mut current = start.clone();
        let mut sim = self.simulate(&current)?;
        let cal_sse = |sim: &Sim| self.problem.sse(sim, Part::Calibration).0;
        let mut best_sse = cal_sse(&sim);
        for _ in 0..ITERATIONS {
            let (r_cal, _) = self.residuals(&sim);
            let mut cols = Vec::new();
            let mut index = Vec::new();
            for i in 0..10 {
                let d = Self::param_delta(&current.params, i);
                let (cal, _) = self.column(&current, &sim, i, d)?;
                cols.push(cal);
                index.push(i);
            }
            for &j in free {
                let d = probe_of(j);
                let (cal, _) = self.column(&current, &sim, 10 + j, d)?;
                cols.push(cal);
                index.push(10 + j);
            }
            if cols.iter().any(|c| c.len() != r_cal.len()) {
                return None;
            }
            let theta = solve(&cols, &r_cal, &(0..cols.len()).collect::<Vec<_>>())?;
            // Halve the step until the calibration error falls.
            let mut step = 1.0;
            let mut improved = false;
            for _ in 0..6 {
                let mut next = current.clone();
                for (&i, t) in index.iter().zip(theta.iter()) {
                    if i < 10 {
                        next.params[i] += step * t;
                    } else {
                        next.disc[i - 10] += step * t;
                    }
                }
                if let Some(s) = self.simulate(&next) {
                    let e = cal_sse(&s);
                    if e.is_finite() && e < best_sse {
                        (current, sim, best_sse, improved) = (next, s, e, true);
                        break;
                    }
                }
                step *= 0.5;
            }
            if !improved {
                break;
            }
        }
        Some((current, sim))
    }
}

/// The probe of discrepancy value `j` (a coefficient): the diagnosis's sizes, a small
/// change of the output.
fn probe_of(j: usize) -> f64 {
    match j {
        0 | 2 => 0.02,
        7 => 1e-7,
        _ => 1e-8,
    }
}

/// Least squares of `r` on the columns `active` (Gram matrix scaled to a unit diagonal).
fn solve(cols: &[Vec<f64>], r: &[f64], active: &[usize]) -> Option<DVector<f64>> {
    let m = active.len();
    let dot = |x: &[f64], y: &[f64]| -> f64 { x.iter().zip(y).map(|(a, b)| a * b).sum() };
    let gram = DMatrix::from_fn(m, m, |i, j| dot(&cols[active[i]], &cols[active[j]]));
    let rhs = DVector::from_fn(m, |i, _| dot(&cols[active[i]], r));
    let theta = SpdSolver::new(gram)?.solve(&rhs);
    theta.iter().all(|t| t.is_finite()).then_some(theta)
}

/// Why the model of `plant` is not bounded over `lo..=hi` % (None: it is): the
/// staircase up and down a 2.5 % grid (3 s per level) and full steps both ways (20 s
/// each) from rest at `lo` must stay finite and end each level near its rest point.
pub fn unbounded_over(plant: &Plant, lo: f64, hi: f64) -> Option<String> {
    let mut levels = Vec::new();
    let mut u = lo;
    while u < hi {
        levels.push(u);
        u += 2.5;
    }
    levels.push(hi);
    let top = levels.iter().map(|&u| plant.rest_thrust_n(u)).fold(f64::NEG_INFINITY, f64::max);
    if !top.is_finite() {
        return Some("no rest point over the throttle range".into());
    }
    let mut engine = plant.at_equilibrium(lo);
    let mut schedule: Vec<(f64, usize)> = levels.iter().map(|&u| (u, 300)).collect();
    schedule.extend(levels.iter().rev().map(|&u| (u, 300)));
    schedule.extend([(hi, 2000), (lo, 2000)]);
    for (u, steps) in schedule {
        let mut thrust_n = 0.0;
        for _ in 0..steps {
            match engine.step(u) {
                Ok(s) => thrust_n = s.state.thrust_n,
                Err(e) => return Some(format!("it diverges at {u} % ({e})")),
            }
            if !(thrust_n.is_finite() && thrust_n > -0.5 * top.abs() - 10.0 && thrust_n < 2.0 * top.abs() + 10.0) {
                return Some(format!("its thrust leaves the engine's range at {u} % ({thrust_n:.1} N)"));
            }
        }
        let rest = plant.rest_thrust_n(u);
        if steps >= 2000 && (thrust_n - rest).abs() > 0.01 * top.abs() + 0.5 {
            return Some(format!("at {u} % it settles at {thrust_n:.1} N, not at its rest point {rest:.1} N"));
        }
    }
    None
}

/// Chooses the terms the data pays for, starting from the bounded ten-parameter model
/// `base` identified on `calibration` (`validation` its held-out tail).
///
/// `Err` says why no search could be made (held-out files that are not the recordings'
/// tails, too little data, the base model diverging on the data).
pub fn choose(calibration: &[Series], validation: &[Series], base: Params) -> Result<Structure, String> {
    let (data, holdout) = rejoin(calibration, validation).ok_or_else(|| {
        "the held-out data is not the tail of the calibration recordings (separate validation files)".to_owned()
    })?;
    let base_plant = Plant::new(base, Effects::none());
    let problem = Problem::new(&data, &base_plant, holdout).map_err(|e| e.to_string())?;
    let settings = crate::diagnose::Options::default();
    let floor_n = problem.noise.mae_n;
    let search = Search { states: problem.given_states(), problem: &problem, n_val: 0.0 };
    let start = Candidate { params: base.to_array(), disc: DISCREPANCY_DEFAULTS };
    let sim0 = search.simulate(&start).ok_or("the ten-parameter model diverges on the data")?;
    let (r_cal, r_val) = search.residuals(&sim0);
    let search = Search { n_val: r_val.len() as f64, ..search };
    if r_val.len() < 500 {
        return Err(format!("{} held-out samples; the search needs 500", r_val.len()));
    }

    // The library: knots within the recorded throttle's 5–95 % quantiles.
    let mut u: Vec<f64> = problem.runs.iter().flat_map(|r| r.u.iter().copied()).collect();
    u.sort_by(f64::total_cmp);
    let q = |f: f64| u.get(((u.len().saturating_sub(1)) as f64 * f) as usize).copied().unwrap_or(50.0);
    let (lo, hi) = (q(0.05) + 1.0, q(0.95) - 1.0);
    let knots: Vec<f64> = (1..=19).map(|i| i as f64 * KNOT_STEP_PCT).filter(|k| (lo..=hi).contains(k)).collect();
    let mut library = Vec::new();
    for term in DISCREPANCY_TERMS {
        match (term.coefficient, term.shape) {
            (0 | 2, Some(s)) => library.extend(knots.iter().map(|&k| Column {
                coefficient: term.coefficient,
                shape: Some((s, k)),
                probe: probe_of(term.coefficient),
            })),
            (6..=8, None) => {
                library.push(Column { coefficient: term.coefficient, shape: None, probe: probe_of(term.coefficient) })
            }
            // The thrust-history gain is a slow, time-varying effect, not engine structure.
            _ => {}
        }
    }

    // Sensitivities: the ten parameters first, then the library.
    let (mut cal, mut val, mut usable) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..10 {
        let (c, v) = search
            .column(&start, &sim0, i, Search::param_delta(&start.params, i))
            .ok_or("a parameter's sensitivity could not be simulated")?;
        cal.push(c);
        val.push(v);
    }
    for (n, col) in library.iter().enumerate() {
        let mut probe = start.clone();
        if let Some((s, k)) = col.shape {
            probe.disc[s] = k;
        }
        let Some((c, v)) = search.column(&probe, &sim0, 10 + col.coefficient, col.probe) else { continue };
        if c.len() == r_cal.len() && v.len() == r_val.len() && c.iter().chain(&v).all(|x| x.is_finite()) {
            cal.push(c);
            val.push(v);
            usable.push(n);
        }
    }
    if cal[..10].iter().any(|c| c.len() != r_cal.len()) {
        return Err("the parameters' sensitivities do not cover the data".into());
    }
    let predicted_sse = |active: &[usize], theta: &DVector<f64>| -> f64 {
        (0..r_val.len())
            .map(|row| {
                let fit: f64 = active.iter().zip(theta.iter()).map(|(&a, t)| val[a][row] * t).sum();
                (r_val[row] - fit).powi(2)
            })
            .sum()
    };
    let params: Vec<usize> = (0..10).collect();
    let refit_theta = solve(&cal, &r_cal, &params).ok_or("the parameters' sensitivities are singular")?;
    let linear_refit = search.score(predicted_sse(&params, &refit_theta), 0);

    // Greedy forward selection on the calibration fit, each prefix scored on held-out data.
    let dot = |x: &[f64], y: &[f64]| -> f64 { x.iter().zip(y).map(|(a, b)| a * b).sum() };
    let mut active: Vec<usize> = Vec::new();
    let mut best: Option<(f64, Vec<usize>)> = None;
    while active.len() < MAX_TERMS {
        let used = |a: usize| active.iter().any(|&b| library[usable[b]].coefficient == library[usable[a]].coefficient);
        let step = (0..usable.len())
            .filter(|&a| !used(a))
            .filter_map(|a| {
                let mut cols = params.clone();
                cols.extend(active.iter().chain([&a]).map(|&b| 10 + b));
                let theta = solve(&cal, &r_cal, &cols)?;
                let explained: f64 = cols.iter().zip(theta.iter()).map(|(&c, t)| dot(&cal[c], &r_cal) * t).sum();
                Some((explained, a))
            })
            .max_by(|x, y| x.0.total_cmp(&y.0));
        let Some((_, a)) = step else { break };
        active.push(a);
        let mut cols = params.clone();
        cols.extend(active.iter().map(|&b| 10 + b));
        let Some(theta) = solve(&cal, &r_cal, &cols) else { break };
        let k: usize = active.iter().map(|&b| library[usable[b]].cost()).sum();
        let s = search.score(predicted_sse(&cols, &theta), k);
        if best.as_ref().is_none_or(|(b, _)| s < *b) {
            best = Some((s, active.clone()));
        }
    }

    // The refit alone, fitted on the simulation error and judged for real.
    let (_, refit_sim) = search.fit(&start, &[]).ok_or("the ten parameters' refit diverges")?;
    let refit_judged = search.judge(&refit_sim).ok_or("the ten parameters' refit diverges on held-out data")?;
    let refit_score = search.score(refit_judged.sse, 0);
    let mut structure = Structure {
        chosen: Vec::new(),
        model: None,
        penalty_per_parameter: search.n_val.ln(),
        refit_score,
        extended_score: None,
        refit_mae_n: refit_judged.mae_n,
        extended_mae_n: None,
        columns_tried: usable.len(),
        verdict: String::new(),
    };
    let chosen = match best {
        Some((s, chosen)) if s < linear_refit => chosen,
        _ => {
            structure.verdict = format!(
                "no term of the library pays for its ln N = {:.1} score units per parameter on held-out data \
                 ({} columns tried): the ten parameters suffice",
                structure.penalty_per_parameter,
                usable.len()
            );
            return Ok(structure);
        }
    };
    let mut columns: Vec<Column> = chosen.iter().map(|&a| library[usable[a]]).collect();
    // Start the extension from the linearised solution, then fit it on the simulation error.
    let mut start_ext = start.clone();
    for c in &columns {
        if let Some((s, v)) = c.shape {
            start_ext.disc[s] = v;
        }
    }
    let mut cols = params.clone();
    cols.extend(chosen.iter().map(|&b| 10 + b));
    if let Some(theta) = solve(&cal, &r_cal, &cols) {
        let mut linear = start_ext.clone();
        for (&c, t) in cols.iter().zip(theta.iter()) {
            if c < 10 {
                linear.params[c] += t;
            } else {
                linear.disc[library[usable[c - 10]].coefficient] += t;
            }
        }
        if linear.plant().is_some() {
            start_ext = linear;
        }
    }
    let free_of = |columns: &[Column]| -> Vec<usize> { columns.iter().map(|c| c.coefficient).collect() };
    let cost_of = |columns: &[Column]| -> usize { columns.iter().map(Column::cost).sum() };
    let label_of = |columns: &[Column]| -> String { columns.iter().map(Column::label).collect::<Vec<_>>().join(", ") };
    let diverges =
        |columns: &[Column]| format!("{} looked worth adding, but the extended model diverges", label_of(columns));
    let Some((mut extended, ext_sim)) = search.fit(&start_ext, &free_of(&columns)) else {
        structure.verdict = diverges(&columns);
        return Ok(structure);
    };
    let Some(mut ext_judged) = search.judge(&ext_sim) else {
        structure.verdict = diverges(&columns);
        return Ok(structure);
    };
    // Every term kept must still earn its place: the held-out score without it (the rest
    // refitted) must be worse; the term that earns least goes first, as in a diagnosis.
    let mut earned: Vec<f64>;
    loop {
        let ext_score = search.score(ext_judged.sse, cost_of(&columns));
        earned = columns
            .iter()
            .map(|c| {
                let mut without = extended.clone();
                without.disc[c.coefficient] = 0.0;
                let rest: Vec<Column> = columns.iter().copied().filter(|o| o != c).collect();
                search
                    .fit(&without, &free_of(&rest))
                    .and_then(|(_, sim)| search.judge(&sim))
                    .map_or(f64::INFINITY, |j| search.score(j.sse, cost_of(&rest)) - ext_score)
            })
            .collect();
        let worst = (0..columns.len()).min_by(|&a, &b| earned[a].total_cmp(&earned[b]));
        match worst {
            Some(w) if earned[w] <= 0.0 && columns.len() > 1 => {
                let mut without = extended.clone();
                without.disc[columns[w].coefficient] = 0.0;
                columns.remove(w);
                let Some((next, judged)) =
                    search.fit(&without, &free_of(&columns)).and_then(|(next, sim)| Some((next, search.judge(&sim)?)))
                else {
                    structure.verdict = diverges(&columns);
                    return Ok(structure);
                };
                (extended, ext_judged) = (next, judged);
            }
            _ => break,
        }
    }
    let labels = label_of(&columns);
    let ext_score = search.score(ext_judged.sse, cost_of(&columns));
    structure.extended_score = Some(ext_score);
    structure.extended_mae_n = Some(ext_judged.mae_n);
    let gain = refit_score - ext_score;
    let mae_gain = refit_judged.mae_n - ext_judged.mae_n;
    let admitted = gain > 0.0
        && earned.iter().all(|&e| e > 0.0)
        && (mae_gain >= settings.min_gain * floor_n || gain >= settings.strong_evidence);
    if !admitted {
        structure.verdict = format!(
            "{labels} does not pay on held-out data against the ten parameters refitted: {gain:+.1} score units \
             (penalty included), MAE {:.3} → {:.3} N",
            refit_judged.mae_n, ext_judged.mae_n
        );
        return Ok(structure);
    }
    let Some(file) = extended.model_file() else {
        structure.verdict = format!("{labels}: the fitted values leave the discrepancy's bounds");
        return Ok(structure);
    };
    let (u_lo, u_hi) = (u.first().copied().unwrap_or(THROTTLE_MIN_PCT), u.last().copied().unwrap_or(100.0));
    let (range_lo, range_hi) = (u_lo.min(THROTTLE_MIN_PCT), u_hi.max(THROTTLE_MAX_PCT));
    if let Some(why) = unbounded_over(&file.plant(), range_lo, range_hi) {
        structure.verdict = format!(
            "{labels} pays on held-out data ({gain:+.1} score units) but the extended model is not bounded over \
             {range_lo:.0}–{range_hi:.0} %: {why}; the ten-parameter model is kept"
        );
        return Ok(structure);
    }
    for (c, held_out_gain) in columns.iter().zip(earned) {
        structure.chosen.push(ChosenTerm {
            label: c.label(),
            key: DISCREPANCY_KEYS[c.coefficient],
            value: extended.disc[c.coefficient],
            parameters: c.cost(),
            held_out_gain,
        });
    }
    structure.verdict = format!(
        "the ten parameters extended by {labels}: held-out score {gain:+.1} units against the ten parameters \
         refitted (penalty ln N = {:.1} per parameter included), MAE {:.3} → {:.3} N, bounded over \
         {range_lo:.0}–{range_hi:.0} %",
        structure.penalty_per_parameter, refit_judged.mae_n, ext_judged.mae_n
    );
    structure.model = Some(file);
    Ok(structure)
}

impl ChosenTerm {
    /// What the term earns, in words.
    pub fn earned_text(&self) -> String {
        let plural = if self.parameters == 1 { "" } else { "s" };
        if self.held_out_gain.is_finite() {
            format!(
                "without it the held-out score is {:.1} units worse ({} parameter{plural}, penalty included)",
                self.held_out_gain, self.parameters
            )
        } else {
            format!("without it the rest, refitted, diverges on the data ({} parameter{plural})", self.parameters)
        }
    }
}

impl Structure {
    /// Comment lines for a model file: which terms were chosen and why.
    pub fn comment(&self) -> String {
        let mut out = format!("# Structure chosen by the data: {}\n", self.verdict);
        for t in &self.chosen {
            out.push_str(&format!("#   {} = {:e}: {}\n", t.label, t.value, t.earned_text()));
        }
        out
    }
}
