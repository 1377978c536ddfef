//! Structure chosen by the data: the ten parameters extended by the terms of the
//! discrepancy library ([`jetbench_model::discrepancy`]) and the throttle-path effect of
//! the catalogue or the acceleration schedule that held-out data pays for.
//!
//! The terms are the ones a diagnosis knows: input gain in `T²`, `Ṫ²` and `T·Ṫ`
//! (`B_TT`, `B_DD`, `B_TD`, the iRonCub group's later jet model) and hinges in the
//! throttle map (`map_below`, `map_above`, at the diagnosis's knots: every 5 % within the
//! recorded throttle's range, `diagnose::discrepancy::knots`). The criterion is the
//! diagnosis's own, on the same data ([`crate::diagnose::problem::Problem`]: the
//! recordings on the 10 ms grid, spikes left out, the sensor noise modelled and the
//! residual prewhitened), so both commands choose structure alike:
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
//! real simulations.
//!
//! Then the way in and the pace: an input delay, an actuator lag (first order) and a rate
//! limit (the catalogue's effects on the way in, which the model's throttle path runs),
//! and an acceleration schedule (the thrust rate bounded by a power of the thrust, the
//! ECU's fuel schedule pacing the spool) are each fitted, with the ten parameters and the
//! terms kept, on the simulation error from the best of a few starting values, and the one
//! that pays most against what was kept, by the same score and bar, is added (at most
//! one). Every part must then still earn its place.
//!
//! The extended model is written only when it stays bounded over the
//! throttle range: a rest point at every throttle of a 2.5 % grid that a staircase and
//! full steps both ways reach.

use jetbench_model::discrepancy::{DISCREPANCY_DEFAULTS, DISCREPANCY_KEYS, DISCREPANCY_TERMS};
use jetbench_model::{
    Effect, EffectKind, Effects, ModelFile, Params, Plant, State, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT,
};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use crate::diagnose::discrepancy;
use crate::diagnose::problem::{Part, Problem, Sim};
use crate::series::Series;
use crate::spd::SpdSolver;

/// Most terms added (the diagnosis's discrepancy takes as many).
pub const MAX_TERMS: usize = 4;
/// Gauss–Newton iterations of each fit on the simulation error.
const ITERATIONS: usize = 3;
/// Gauss–Newton iterations of a fit that moves an acceleration schedule's four values,
/// whose starting grid is coarse.
const SCHEDULE_ITERATIONS: usize = 8;

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
    /// The recorded throttle's range, %.
    range: (f64, f64),
}

/// Most values of an effect tried as structure (an acceleration schedule's four).
const PATH_VALUES: usize = 4;

/// A candidate model: the ten parameters, the discrepancy's values and one effect tried
/// as structure with its values (a schedule has four, a rate limit two, the others one).
#[derive(Clone, Debug, PartialEq)]
struct Candidate {
    params: [f64; 10],
    disc: [f64; DISCREPANCY_KEYS.len()],
    path: Option<(EffectKind, [f64; PATH_VALUES])>,
}

impl Candidate {
    /// Adds `delta` to value `index`: the ten parameters (0–9), the discrepancy (10–18),
    /// the effect tried as structure (19–22; kept within what a fit may explore).
    fn add(&mut self, index: usize, delta: f64) {
        match index {
            0..10 => self.params[index] += delta,
            10..19 => self.disc[index - 10] += delta,
            _ => {
                if let Some((kind, values)) = &mut self.path {
                    let (lo, hi) = path_range(*kind, index - 19);
                    values[index - 19] = (values[index - 19] + delta).clamp(lo, hi);
                }
            }
        }
    }

    fn plant(&self) -> Option<Plant> {
        let p = Params::from_array(self.params);
        p.validate().ok()?;
        let mut effects = Vec::new();
        if let Some((kind, values)) = &self.path {
            effects.push(Effect::new(*kind, &values[..kind.keys().len()]).ok()?);
        }
        // A knot or a time constant moved from its default with no term using it is no
        // discrepancy: a model file would hold an empty `[effects.discrepancy]` table.
        if DISCREPANCY_TERMS.iter().any(|term| self.disc[term.coefficient] != 0.0) {
            effects.push(Effect::new(EffectKind::Discrepancy, &self.disc).ok()?);
        }
        Some(Plant::new(p, Effects::new(effects).ok()?))
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
    /// parameters (0–9), discrepancy (10–18) or effect tried as structure (19–22), whitened over
    /// calibration and validation.
    fn column(&self, c: &Candidate, sim: &Sim, index: usize, delta: f64) -> Option<(Vec<f64>, Vec<f64>)> {
        let mut probe = c.clone();
        probe.add(index, delta);
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
    /// the values `free` (0–8: the discrepancy's; 9–12: the effect tried as structure),
    /// from `start`; the best candidate seen by calibration error, with its simulation.
    fn fit(&self, start: &Candidate, free: &[usize]) -> Option<(Candidate, Sim)> {
        let mut current = start.clone();
        let mut sim = self.simulate(&current)?;
        let cal_sse = |sim: &Sim| self.problem.sse(sim, Part::Calibration).0;
        let mut best_sse = cal_sse(&sim);
        let schedule = matches!(start.path, Some((EffectKind::AccelSchedule, _))) && free.iter().any(|&j| j >= 9);
        'iterations: for _ in 0..if schedule { SCHEDULE_ITERATIONS } else { ITERATIONS } {
            let (r_cal, _) = self.residuals(&sim);
            let mut cols = Vec::new();
            let mut index = Vec::new();
            let mut probes = Vec::new();
            for i in 0..10 {
                probes.push((i, Self::param_delta(&current.params, i)));
            }
            for &j in free {
                let d = match (j, current.path) {
                    (0..9, _) => discrepancy::probe(j),
                    (_, Some((kind, values))) => path_delta(kind, j - 9, values[j - 9]),
                    (_, None) => return None,
                };
                probes.push((10 + j, d));
            }
            for (i, d) in probes {
                // A model sped up for a schedule is stiff: a probe that diverges is tried the
                // other way, and if that diverges too the fit keeps the best it has.
                let column = match self.column(&current, &sim, i, d) {
                    None if schedule => self.column(&current, &sim, i, -d),
                    column => column,
                };
                match column {
                    Some((cal, _)) => cols.push(cal),
                    None if schedule => break 'iterations,
                    None => return None,
                }
                index.push(i);
            }
            if cols.iter().any(|c| c.len() != r_cal.len()) {
                return None;
            }
            let all: Vec<usize> = (0..cols.len()).collect();
            let theta = solve(&cols, &r_cal, &all, 0.0)?;
            // Halve the step until the calibration error falls; a schedule's fit then damps
            // the step instead (Levenberg–Marquardt): where the schedule binds, the error is
            // not smooth in its values and the plain step can point nowhere useful.
            let damped: &[f64] = if schedule { &[0.01, 0.1, 1.0, 10.0] } else { &[] };
            let tries = (0..6)
                .map(|h| (theta.clone(), 0.5f64.powi(h)))
                .chain(damped.iter().filter_map(|&lambda| Some((solve(&cols, &r_cal, &all, lambda)?, 1.0))));
            let mut improved = false;
            for (theta, step) in tries {
                let mut next = current.clone();
                for (&i, t) in index.iter().zip(theta.iter()) {
                    next.add(i, step * t);
                }
                // A schedule's fit stays where the ten parameters rest stably (see [`rests_stably`]).
                if schedule && !rests_stably(&next.params, self.range.0, self.range.1) {
                    continue;
                }
                if let Some(s) = self.simulate(&next) {
                    let e = cal_sse(&s);
                    if e.is_finite() && e < best_sse {
                        (current, sim, best_sse, improved) = (next, s, e, true);
                        break;
                    }
                }
            }
            if !improved {
                break;
            }
        }
        Some((current, sim))
    }
}

/// Least squares of `r` on the columns `active` (Gram matrix scaled to a unit diagonal),
/// damped by `lambda` times the Gram matrix's diagonal (Marquardt's; 0: none).
fn solve(cols: &[Vec<f64>], r: &[f64], active: &[usize], lambda: f64) -> Option<DVector<f64>> {
    let m = active.len();
    let dot = |x: &[f64], y: &[f64]| -> f64 { x.iter().zip(y).map(|(a, b)| a * b).sum() };
    let gram = DMatrix::from_fn(m, m, |i, j| {
        let g = dot(&cols[active[i]], &cols[active[j]]);
        if i == j {
            g * (1.0 + lambda)
        } else {
            g
        }
    });
    let rhs = DVector::from_fn(m, |i, _| dot(&cols[active[i]], r));
    let theta = SpdSolver::new(gram)?.solve(&rhs);
    theta.iter().all(|t| t.is_finite()).then_some(theta)
}

/// Why the model of `plant` is not bounded over `lo..=hi` % (None: it is): the
/// staircase up and down a 2.5 % grid (3 s per level) and full steps both ways (20 s
/// each) from rest at `lo` must stay finite and end each level near its rest point, and the
/// sines of [`crate::identify::sine_checks`] must stay within the engine's range.
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
    for (label, throttle) in crate::identify::sine_checks(lo, hi) {
        let mut engine = plant.at_equilibrium(throttle[0]);
        for &u in &throttle {
            match engine.step(u).map(|s| s.state.thrust_n) {
                Ok(thrust_n) if thrust_n.is_finite() && thrust_n.abs() < 2.0 * top.abs() + 10.0 => {}
                _ => return Some(format!("it runs away on a sine of {label}")),
            }
        }
    }
    None
}

/// Chooses the terms the data pays for, starting from the bounded ten-parameter model
/// `base` identified on `calibration` (`validation` its held-out tail).
///
/// `Err` says why no search could be made (held-out files that are not the recordings'
/// tails, too little data, the base model diverging on the data).
/// `schedule` lets the search try an acceleration schedule beside the throttle-path effects.
pub fn choose(
    calibration: &[Series],
    validation: &[Series],
    base: Params,
    schedule: bool,
) -> Result<Structure, String> {
    let (data, holdout) = rejoin(calibration, validation).ok_or_else(|| {
        "the held-out data is not the tail of the calibration recordings (separate validation files)".to_owned()
    })?;
    let base_plant = Plant::new(base, Effects::none());
    let problem = Problem::new(&data, &base_plant, holdout).map_err(|e| e.to_string())?;
    let settings = crate::diagnose::Options::default();
    let floor_n = problem.noise.mae_n;
    let recorded = problem.runs.iter().flat_map(|r| r.u.iter().copied()).filter(|u| u.is_finite());
    let (range_lo, range_hi) =
        recorded.fold((THROTTLE_MIN_PCT, THROTTLE_MAX_PCT), |(lo, hi), u| (lo.min(u), hi.max(u)));
    let search = Search { states: problem.given_states(), problem: &problem, n_val: 0.0, range: (range_lo, range_hi) };
    let start = Candidate { params: base.to_array(), disc: DISCREPANCY_DEFAULTS, path: None };
    let sim0 = search.simulate(&start).ok_or("the ten-parameter model diverges on the data")?;
    let (r_cal, r_val) = search.residuals(&sim0);
    let search = Search { n_val: r_val.len() as f64, ..search };
    if r_val.len() < 500 {
        return Err(format!("{} held-out samples; the search needs 500", r_val.len()));
    }

    // The library: the diagnosis's knots, within the recorded throttle's range.
    let knots = discrepancy::knots(&problem);
    let mut library = Vec::new();
    for term in DISCREPANCY_TERMS {
        match (term.coefficient, term.shape) {
            (0 | 2, Some(s)) => library.extend(knots.iter().map(|&k| Column {
                coefficient: term.coefficient,
                shape: Some((s, k)),
                probe: discrepancy::probe(term.coefficient),
            })),
            (6..=8, None) => library.push(Column {
                coefficient: term.coefficient,
                shape: None,
                probe: discrepancy::probe(term.coefficient),
            }),
            // The thrust-history gain is a slow, time-varying effect, not engine structure.
            _ => {}
        }
    }

    // Sensitivities: the ten parameters first, then the library.
    let (mut cal, mut val, mut usable) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..10 {
        // A probe that leaves a stiff model's stable range is tried the other way.
        let d = Search::param_delta(&start.params, i);
        let (c, v) = search
            .column(&start, &sim0, i, d)
            .or_else(|| search.column(&start, &sim0, i, -d))
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
    let refit_theta = solve(&cal, &r_cal, &params, 0.0).ok_or("the parameters' sensitivities are singular")?;
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
                let theta = solve(&cal, &r_cal, &cols, 0.0)?;
                let explained: f64 = cols.iter().zip(theta.iter()).map(|(&c, t)| dot(&cal[c], &r_cal) * t).sum();
                Some((explained, a))
            })
            .max_by(|x, y| x.0.total_cmp(&y.0));
        let Some((_, a)) = step else { break };
        active.push(a);
        let mut cols = params.clone();
        cols.extend(active.iter().map(|&b| 10 + b));
        let Some(theta) = solve(&cal, &r_cal, &cols, 0.0) else { break };
        let k: usize = active.iter().map(|&b| library[usable[b]].cost()).sum();
        let s = search.score(predicted_sse(&cols, &theta), k);
        if best.as_ref().is_none_or(|(b, _)| s < *b) {
            best = Some((s, active.clone()));
        }
    }

    // The refit alone, fitted on the simulation error and judged for real.
    let (refit, refit_sim) = search.fit(&start, &[]).ok_or("the ten parameters' refit diverges")?;
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
    // The diagnosis's admission bar, for a gain of `gain` score units and `mae_gain` N.
    let pays = |gain: f64, mae_gain: f64| {
        gain > 0.0 && (mae_gain >= settings.min_gain * floor_n || gain >= settings.strong_evidence)
    };
    let mut notes = Vec::new();

    // 1. The discrepancy's terms: the best prefix of the linearised search, fitted on the
    // simulation error, each term kept only while it earns its place.
    let mut kept: Option<Fitted> = None;
    match best {
        Some((s, chosen)) if s < linear_refit => {
            // Start from the linearised solution.
            let mut start_ext = start.clone();
            for &a in &chosen {
                if let Some((i, v)) = library[usable[a]].shape {
                    start_ext.disc[i] = v;
                }
            }
            let mut cols = params.clone();
            cols.extend(chosen.iter().map(|&b| 10 + b));
            if let Some(theta) = solve(&cal, &r_cal, &cols, 0.0) {
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
            let terms = chosen.iter().map(|&a| Term::Library(library[usable[a]])).collect();
            match search.fit_terms(&start_ext, terms) {
                Ok(fitted) => {
                    let gain = refit_score - fitted.score(&search);
                    if pays(gain, refit_judged.mae_n - fitted.judged.mae_n) && fitted.earned.iter().all(|&e| e > 0.0) {
                        kept = Some(fitted);
                    } else {
                        notes.push(format!(
                            "{} does not pay on held-out data against the ten parameters refitted: {gain:+.1} score \
                             units (penalty included), MAE {:.3} → {:.3} N",
                            names(&fitted.terms),
                            refit_judged.mae_n,
                            fitted.judged.mae_n
                        ));
                    }
                }
                Err(why) => notes.push(why),
            }
        }
        _ => notes.push(format!(
            "no term of the library pays for its ln N = {:.1} score units per parameter on held-out data ({} \
             columns tried)",
            structure.penalty_per_parameter,
            usable.len()
        )),
    }

    // 2. The way in and the pace: each effect of the catalogue on the way in, and an
    // acceleration schedule, fitted with what was kept, kept when it pays against that.
    let base = kept.clone().unwrap_or_else(|| Fitted {
        terms: Vec::new(),
        model: refit.clone(),
        judged: refit_judged,
        earned: Vec::new(),
    });
    let base_score = base.score(&search);
    let mut tried = Vec::new();
    let mut best_path: Option<Fitted> = None;
    for kind in PATH_EFFECTS.into_iter().filter(|&k| schedule || k != EffectKind::AccelSchedule) {
        let mut terms = base.terms.clone();
        terms.push(Term::Path(kind));
        // A schedule is fitted from its three best starts, and only a bounded fit counts: a
        // sped-up model can leave its rest points behind.
        let (fits, bounded_only) = if kind == EffectKind::AccelSchedule { (3, true) } else { (1, false) };
        let fitted = search
            .path_starts_ranked(&base.model, kind)
            .iter()
            .take(fits)
            .filter_map(|start| search.fit_judged(start, terms.clone()))
            .filter(|f| {
                !bounded_only
                    || (rests_stably(&f.model.params, range_lo, range_hi)
                        && f.model
                            .model_file()
                            .is_some_and(|m| unbounded_over(&m.plant(), range_lo, range_hi).is_none()))
            })
            .min_by(|a, b| a.score(&search).total_cmp(&b.score(&search)));
        let Some(fitted) = fitted else {
            tried.push(format!(
                "{} {}",
                kind.name(),
                if bounded_only { "diverges or is not bounded" } else { "diverges" }
            ));
            continue;
        };
        let gain = base_score - fitted.score(&search);
        tried.push(format!("{} {gain:+.1}", kind.name()));
        if pays(gain, base.judged.mae_n - fitted.judged.mae_n)
            && best_path.as_ref().is_none_or(|b| fitted.score(&search) < b.score(&search))
        {
            best_path = Some(fitted);
        }
    }
    let what = if schedule { "no throttle-path effect or acceleration schedule" } else { "no throttle-path effect" };
    let path_note = format!("{what} pays against it ({})", tried.join(", "));
    // Every part must still earn its place beside the path effect; without a path effect
    // that keeps its place, the library's terms stand alone, if any were kept.
    let with_path = best_path
        .and_then(|path| search.fit_terms(&path.model, path.terms).ok())
        .filter(|fitted| fitted.terms.iter().any(|t| matches!(t, Term::Path(_))));
    let Some(fitted) = with_path.or(kept) else {
        notes.push(path_note);
        structure.verdict = format!("{}: the ten parameters suffice", notes.join("; "));
        return Ok(structure);
    };

    let labels = fitted.labels();
    let ext_score = fitted.score(&search);
    structure.extended_score = Some(ext_score);
    structure.extended_mae_n = Some(fitted.judged.mae_n);
    let gain = refit_score - ext_score;
    if !(pays(gain, refit_judged.mae_n - fitted.judged.mae_n) && fitted.earned.iter().all(|&e| e > 0.0)) {
        structure.verdict = format!(
            "{labels} does not pay on held-out data against the ten parameters refitted: {gain:+.1} score units \
             (penalty included), MAE {:.3} → {:.3} N",
            refit_judged.mae_n, fitted.judged.mae_n
        );
        return Ok(structure);
    }
    let Some(file) = fitted.model.model_file() else {
        structure.verdict = format!("{labels}: the fitted values leave the effects' bounds");
        return Ok(structure);
    };
    let paced = matches!(fitted.model.path, Some((EffectKind::AccelSchedule, _)));
    if paced && !rests_stably(&fitted.model.params, range_lo, range_hi) {
        structure.verdict = format!(
            "{labels} pays on held-out data ({gain:+.1} score units) but, paced by the schedule, the ten parameters \
             lose a stable rest point within {range_lo:.0}–{range_hi:.0} %; the ten-parameter model is kept"
        );
        return Ok(structure);
    }
    if let Some(why) = unbounded_over(&file.plant(), range_lo, range_hi) {
        structure.verdict = format!(
            "{labels} pays on held-out data ({gain:+.1} score units) but the extended model is not bounded over \
             {range_lo:.0}–{range_hi:.0} %: {why}; the ten-parameter model is kept"
        );
        return Ok(structure);
    }
    for (t, &held_out_gain) in fitted.terms.iter().zip(&fitted.earned) {
        structure.chosen.push(ChosenTerm {
            label: t.label(&fitted.model),
            key: t.key(),
            value: t.value(&fitted.model),
            parameters: t.cost(),
            held_out_gain,
        });
    }
    structure.verdict = format!(
        "the ten parameters extended by {labels}: held-out score {gain:+.1} units against the ten parameters \
         refitted (penalty ln N = {:.1} per parameter included), MAE {:.3} → {:.3} N, bounded over \
         {range_lo:.0}–{range_hi:.0} %",
        structure.penalty_per_parameter, refit_judged.mae_n, fitted.judged.mae_n
    );
    structure.model = Some(file);
    Ok(structure)
}

/// The effects tried as structure: what happens to the throttle before the engine
/// follows it (the catalogue's delay, lag and rate limit: the model's
/// [`jetbench_model::ThrottlePath`]), and how fast the engine may move (an acceleration
/// schedule).
const PATH_EFFECTS: [EffectKind; 4] =
    [EffectKind::InputDelay, EffectKind::ActuatorLag, EffectKind::RateLimit, EffectKind::AccelSchedule];

/// Where a fit of an effect tried as structure may start: a delay or a lag at four
/// sizes; a rate limit the same both ways at four rates; a schedule the same both ways at
/// three rates at 100 N, growing with the thrust to the power 1, 1.5 or 2, from a 5 N offset.
fn path_starts(kind: EffectKind) -> Vec<[f64; PATH_VALUES]> {
    let one = |values: &[f64]| values.iter().map(|&v| [v, v, 0.0, 0.0]).collect();
    match kind {
        EffectKind::InputDelay => one(&[0.02, 0.05, 0.1, 0.2]),
        EffectKind::ActuatorLag => one(&[0.03, 0.08, 0.2, 0.5]),
        EffectKind::AccelSchedule => [150.0, 500.0, 1500.0]
            .into_iter()
            .flat_map(|rate| [1.0, 1.5, 2.0].map(|exponent| [rate, rate, exponent, 5.0]))
            .collect(),
        _ => one(&[30.0, 60.0, 120.0, 250.0]),
    }
}

/// The range a fit of value `index` of an effect tried as structure may explore (the
/// diagnosis's for the catalogue; a schedule's physical range).
fn path_range(kind: EffectKind, index: usize) -> (f64, f64) {
    match kind {
        EffectKind::InputDelay => (0.0, 1.0),
        EffectKind::ActuatorLag => (0.002, 3.0),
        EffectKind::AccelSchedule => kind.physical()[index.min(PATH_VALUES - 1)],
        _ => (1.0, 2000.0),
    }
}

/// The probe of value `index`, `v`, of an effect tried as structure: 2 ms of delay or
/// lag, 2 % of a rate, 0.02 of a schedule's exponent, 0.5 N of its offset, pointing away
/// from the edge of its range.
fn path_delta(kind: EffectKind, index: usize, v: f64) -> f64 {
    let d = match (kind, index) {
        (EffectKind::InputDelay | EffectKind::ActuatorLag, _) => 0.002,
        (EffectKind::AccelSchedule, 2) => 0.02,
        (EffectKind::AccelSchedule, 3) => 0.5,
        _ => (0.02 * v).max(0.5),
    };
    if v + d > path_range(kind, index).1 {
        -d
    } else {
        d
    }
}

/// Half the window of the local slopes [`envelope_schedule`] reads, samples (0.1 s).
const ENVELOPE_HALF: usize = 10;
/// Thrust bands of [`envelope_schedule`].
const ENVELOPE_BANDS: usize = 8;
/// Offsets [`envelope_schedule`] tries, N.
const ENVELOPE_OFFSETS_N: [f64; 7] = [0.0, 2.0, 5.0, 10.0, 20.0, 40.0, 80.0];

/// A schedule read off the calibration data: in each of [`ENVELOPE_BANDS`] bands of
/// thrust (equal counts), the fastest the measured thrust rose and fell (the 98th
/// percentile of its slope over 0.2 s), and a power law of `T + offset_n` through both,
/// the exponent and offset shared, fitted in logarithms. `None` when the data never moves
/// both ways in every band. A start for the fit, not a fit: where the data never met the
/// schedule, the envelope is the campaign's pace, not the engine's.
fn envelope_schedule(problem: &Problem<'_>) -> Option<[f64; PATH_VALUES]> {
    let mut slopes: Vec<(f64, f64)> = Vec::new();
    for run in &problem.runs {
        let y = &run.y;
        for k in ENVELOPE_HALF..y.len().saturating_sub(ENVELOPE_HALF) {
            if !run.in_part(k, Part::Calibration) {
                continue;
            }
            let (mut n, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (j, &v) in y.iter().enumerate().take(k + ENVELOPE_HALF + 1).skip(k - ENVELOPE_HALF) {
                if v.is_finite() {
                    let x = (j as f64 - k as f64) * jetbench_model::STEP_S;
                    (n, sx, sy, sxx, sxy) = (n + 1.0, sx + x, sy + v, sxx + x * x, sxy + x * v);
                }
            }
            let det = n * sxx - sx * sx;
            if n >= (ENVELOPE_HALF + 1) as f64 && det > 0.0 {
                slopes.push((sy / n, (n * sxy - sx * sy) / det));
            }
        }
    }
    if slopes.len() < 100 * ENVELOPE_BANDS {
        return None;
    }
    slopes.sort_by(|a, b| a.0.total_cmp(&b.0));
    let quantile = |mut v: Vec<f64>| -> f64 {
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * 0.98) as usize]
    };
    let per_band = slopes.len() / ENVELOPE_BANDS;
    let mut bands = Vec::new();
    for band in slopes.chunks(per_band).take(ENVELOPE_BANDS) {
        let thrust = band.iter().map(|s| s.0).sum::<f64>() / band.len() as f64;
        let up = quantile(band.iter().map(|s| s.1).collect());
        let down = quantile(band.iter().map(|s| -s.1).collect());
        if !(up > 0.0 && down > 0.0) {
            return None;
        }
        bands.push((thrust, up.ln(), down.ln()));
    }
    // ln rate = a + p·ln((T + offset)/100 N), a per direction; least squares per offset.
    let mut best: Option<(f64, [f64; PATH_VALUES])> = None;
    for offset in ENVELOPE_OFFSETS_N {
        if bands.iter().any(|b| b.0 + offset <= 1.0) {
            continue;
        }
        let x: Vec<f64> = bands.iter().map(|b| ((b.0 + offset) / jetbench_model::SCHEDULE_REFERENCE_N).ln()).collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let up: Vec<f64> = bands.iter().map(|b| b.1).collect();
        let down: Vec<f64> = bands.iter().map(|b| b.2).collect();
        let (mx, mu, md) = (mean(&x), mean(&up), mean(&down));
        let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
        if sxx <= 0.0 {
            continue;
        }
        let sxy: f64 = x.iter().zip(up.iter().zip(&down)).map(|(v, (a, b))| (v - mx) * (a - mu + b - md)).sum();
        let (lo, hi) = path_range(EffectKind::AccelSchedule, 2);
        let p = (sxy / (2.0 * sxx)).clamp(lo, hi);
        let (a_up, a_down) = (mu - p * mx, md - p * mx);
        let sse: f64 = x
            .iter()
            .zip(up.iter().zip(&down))
            .map(|(v, (a, b))| (a - a_up - p * v).powi(2) + (b - a_down - p * v).powi(2))
            .sum();
        let (rate_lo, rate_hi) = path_range(EffectKind::AccelSchedule, 0);
        let values = [a_up.exp().clamp(rate_lo, rate_hi), a_down.exp().clamp(rate_lo, rate_hi), p, offset];
        if best.is_none_or(|(b, _)| sse < b) {
            best = Some((sse, values));
        }
    }
    best.map(|(_, v)| v)
}

/// True when the ten parameters have a stable rest point at every throttle of a 2.5 % grid
/// over `lo..=hi` %. A schedule bounds the thrust rate, so a model paced by one stays
/// bounded in simulation even where its own rest point is gone or unstable: the rest
/// points are checked on their own.
fn rests_stably(params: &[f64; 10], lo: f64, hi: f64) -> bool {
    let p = Params::from_array(*params);
    let steps = ((hi - lo) / 2.5).ceil().max(1.0) as usize;
    (0..=steps).all(|i| p.stable_equilibrium((lo + 2.5 * i as f64).min(hi)).is_some())
}

/// How many times faster than the model without it a fit with a schedule may start.
const SCHEDULE_SPEED_UPS: [f64; 3] = [1.0, 2.0, 4.0];

/// The ten parameters of a model `speed` times faster, with the same rest points: time
/// scaled by `1/speed`, `T̈ = speed²·(f + g·v)(T, Ṫ/speed)`. Terms in `Ṫ` scale with
/// `speed`, in `Ṫ²` not at all, the rest with `speed²`; `B_UU` shapes the throttle map.
fn sped_up(params: &[f64; 10], speed: f64) -> [f64; 10] {
    let (s1, s2) = (speed, speed * speed);
    let scale = [s2, s2, s1, 1.0, s1, s2, s2, s2, s1, 1.0];
    std::array::from_fn(|i| params[i] * scale[i])
}

/// A part of the structure: a term of the discrepancy library at its knot, or an
/// effect tried as structure.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Term {
    Library(Column),
    Path(EffectKind),
}

impl Term {
    /// Parameters it costs in the penalty.
    fn cost(&self) -> usize {
        match self {
            Term::Library(c) => c.cost(),
            Term::Path(kind) => kind.keys().len(),
        }
    }

    /// The values a fit moves ([`Search::fit`]'s `free`).
    fn free(&self) -> Vec<usize> {
        match self {
            Term::Library(c) => vec![c.coefficient],
            Term::Path(kind) => (0..kind.keys().len()).map(|i| 9 + i).collect(),
        }
    }

    /// `model` without it.
    fn remove(&self, model: &mut Candidate) {
        match self {
            Term::Library(c) => model.disc[c.coefficient] = 0.0,
            Term::Path(_) => model.path = None,
        }
    }

    fn name(&self) -> String {
        match self {
            Term::Library(c) => c.label(),
            Term::Path(kind) => kind.name().to_owned(),
        }
    }

    /// In words with its values in `model`.
    fn label(&self, model: &Candidate) -> String {
        match (self, model.path) {
            (Term::Path(kind), Some((_, values))) => {
                let v: Vec<String> =
                    kind.keys().iter().zip(values).map(|(k, v)| format!("{k} = {}", round3(v))).collect();
                format!("{} ({})", kind.name(), v.join(", "))
            }
            _ => self.name(),
        }
    }

    fn key(&self) -> &'static str {
        match self {
            Term::Library(c) => DISCREPANCY_KEYS[c.coefficient],
            Term::Path(kind) => kind.name(),
        }
    }

    /// Its (first) fitted value in `model`.
    fn value(&self, model: &Candidate) -> f64 {
        match self {
            Term::Library(c) => model.disc[c.coefficient],
            Term::Path(_) => model.path.map_or(f64::NAN, |(_, v)| v[0]),
        }
    }
}

/// `v` to three significant digits, for labels.
fn round3(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(2 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}

fn names(terms: &[Term]) -> String {
    terms.iter().map(Term::name).collect::<Vec<_>>().join(", ")
}

fn free_of(terms: &[Term]) -> Vec<usize> {
    terms.iter().flat_map(Term::free).collect()
}

fn cost_of(terms: &[Term]) -> usize {
    terms.iter().map(Term::cost).sum()
}

/// An extension fitted on the simulation error and judged on held-out data.
#[derive(Clone, Debug)]
struct Fitted {
    terms: Vec<Term>,
    model: Candidate,
    judged: Judged,
    /// What each term earns: how much worse the held-out score is without it, the rest
    /// refitted (score units, penalty included).
    earned: Vec<f64>,
}

impl Fitted {
    fn score(&self, search: &Search<'_, '_>) -> f64 {
        search.score(self.judged.sse, cost_of(&self.terms))
    }

    fn labels(&self) -> String {
        self.terms.iter().map(|t| t.label(&self.model)).collect::<Vec<_>>().join(", ")
    }
}

impl Search<'_, '_> {
    /// `model` with the effect `kind` tried as structure at each of its starting values,
    /// the best by calibration error first. A schedule starts from `model` sped up too
    /// ([`sped_up`]): a model fitted without one has learnt the schedule's pace as slow
    /// dynamics, and a schedule on a model that slow never binds, so a fit from there
    /// would not move it.
    fn path_starts_ranked(&self, model: &Candidate, kind: EffectKind) -> Vec<Candidate> {
        let speeds: &[f64] = if kind == EffectKind::AccelSchedule { &SCHEDULE_SPEED_UPS } else { &[1.0] };
        let mut starts = path_starts(kind);
        if kind == EffectKind::AccelSchedule {
            starts.extend(envelope_schedule(self.problem));
        }
        let mut ranked: Vec<(f64, Candidate)> = starts
            .into_iter()
            .flat_map(|values| speeds.iter().map(move |&speed| (values, speed)))
            .filter_map(|(values, speed)| {
                let mut c = model.clone();
                c.params = sped_up(&c.params, speed);
                c.path = Some((kind, values));
                let sim = self.simulate(&c)?;
                let e = self.problem.sse(&sim, Part::Calibration).0;
                e.is_finite().then_some((e, c))
            })
            .collect();
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
        ranked.into_iter().map(|(_, c)| c).collect()
    }

    /// `terms` fitted from `start` and judged (nothing earned yet).
    fn fit_judged(&self, start: &Candidate, terms: Vec<Term>) -> Option<Fitted> {
        let (model, sim) = self.fit(start, &free_of(&terms))?;
        let judged = self.judge(&sim)?;
        Some(Fitted { terms, model, judged, earned: Vec::new() })
    }

    /// `terms` fitted from `start`; then every term must earn its place: the held-out score
    /// without it (the rest refitted) must be worse, and the term that earns least goes
    /// first, as in a diagnosis. `Err` says which terms diverge.
    fn fit_terms(&self, start: &Candidate, terms: Vec<Term>) -> Result<Fitted, String> {
        let diverges =
            |terms: &[Term]| format!("{} looked worth adding, but the extended model diverges", names(terms));
        let mut fitted = self.fit_judged(start, terms.clone()).ok_or_else(|| diverges(&terms))?;
        loop {
            let score = fitted.score(self);
            fitted.earned = fitted
                .terms
                .iter()
                .map(|t| {
                    let mut without = fitted.model.clone();
                    t.remove(&mut without);
                    let rest: Vec<Term> = fitted.terms.iter().copied().filter(|o| o != t).collect();
                    self.fit(&without, &free_of(&rest))
                        .and_then(|(_, sim)| self.judge(&sim))
                        .map_or(f64::INFINITY, |j| self.score(j.sse, cost_of(&rest)) - score)
                })
                .collect();
            let worst = (0..fitted.terms.len()).min_by(|&a, &b| fitted.earned[a].total_cmp(&fitted.earned[b]));
            match worst {
                Some(w) if fitted.earned[w] <= 0.0 && fitted.terms.len() > 1 => {
                    let mut without = fitted.model.clone();
                    fitted.terms[w].remove(&mut without);
                    let mut rest = fitted.terms.clone();
                    rest.remove(w);
                    fitted = self.fit_judged(&without, rest.clone()).ok_or_else(|| diverges(&rest))?;
                }
                _ => return Ok(fitted),
            }
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use jetbench_model::Preset;

    /// 10–90 % rise time of a step from 30 to 90 % of `params`, s.
    fn rise_s(params: Params) -> f64 {
        let plant = Plant::new(params, Effects::none());
        let (lo, hi) = (plant.rest_thrust_n(30.0), plant.rest_thrust_n(90.0));
        let mut out = Vec::new();
        let initial = State { thrust_n: lo, thrust_rate_n_per_s: 0.0 };
        assert!(plant.free_run(0.0, initial, &[90.0; 1000], &mut out).is_none());
        let at = |f: f64| out.iter().position(|&t| t >= lo + f * (hi - lo)).expect("the step settles") as f64;
        (at(0.9) - at(0.1)) * jetbench_model::STEP_S
    }

    #[test]
    fn a_sped_up_model_keeps_its_rest_points_and_steps_faster() {
        let p = Preset::P100Diesel.params();
        let fast = Params::from_array(sped_up(&p.to_array(), 2.0));
        for u in [25.0, 50.0, 75.0, 100.0] {
            let (a, b) = (p.stable_equilibrium(u).unwrap(), fast.stable_equilibrium(u).unwrap());
            assert!((a - b).abs() < 1e-6 * a.abs().max(1.0), "rest at {u} %: {a} vs {b}");
        }
        let (slow_s, fast_s) = (rise_s(p), rise_s(fast));
        assert!((fast_s / slow_s - 0.5).abs() < 0.03, "rise {slow_s} s → {fast_s} s");
    }

    #[test]
    fn a_knot_moved_with_no_term_on_it_writes_no_discrepancy() {
        let mut c =
            Candidate { params: Preset::P100Diesel.params().to_array(), disc: DISCREPANCY_DEFAULTS, path: None };
        c.disc[1] = 70.0; // knot_below_pct, its term's coefficient still 0
        let plant = c.plant().expect("a valid model");
        assert!(plant.effects.get(EffectKind::Discrepancy).is_none(), "{:?}", plant.effects);
        c.disc[0] = 0.1; // map_below: the term now acts
        let plant = c.plant().expect("a valid model");
        assert!(plant.effects.get(EffectKind::Discrepancy).is_some());
    }

    #[test]
    fn a_model_without_a_stable_rest_point_in_the_range_does_not_rest_stably() {
        let p = Preset::P100Diesel.params().to_array();
        assert!(rests_stably(&p, 25.0, 100.0));
        // K_T and K_D of the other sign: no stable rest point at any throttle.
        let mut unstable = p;
        unstable[0] = -p[0];
        unstable[2] = -p[2];
        assert!(!rests_stably(&unstable, 25.0, 100.0));
    }
}
