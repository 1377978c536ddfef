//! Mismatch discovery: where a model and a recording disagree, which physics the
//! model leaves out, the model with it added, and the proof on held-out data.
//!
//! 1. **Locate.** The model is simulated from the recorded throttle and its residual
//!    analysed ([`residual::Analysis`]): whiteness, correlation with throttle changes,
//!    dependence on the direction of change and the operating point, drift over the
//!    run, spectrum, and the time windows where it is systematic.
//! 2. **Name.** Every effect of the catalogue ([`EffectKind`]) is a hypothesis: it is
//!    added to the model, its parameters fitted on the calibration part of each file
//!    (output error, from a coarse grid then Levenberg–Marquardt), and the extended
//!    model judged on the validation part by
//!    `N_v·ln(SSE_v/N_v) + k·ln(N_v)` (a likelihood on data the fit never saw, with a
//!    BIC penalty per parameter). A sparse regression of the residual on a library of
//!    terms ([`discrepancy`]) reports what the catalogue may not name.
//! 3. **Model.** The best hypothesis is kept when it beats the current model on that
//!    score and lowers the validation MAE by a practical margin; then the search
//!    repeats with every kept effect refitted jointly, until nothing passes. A model
//!    that explains the recording gets nothing added.
//! 4. **Show.** Validation MAE and fit before and after, whiteness before and after,
//!    and a verdict in words.

pub mod discrepancy;
mod fit;
pub mod residual;

use std::collections::BTreeMap;

use jetbench_model::{EffectKind, Effects, ModelFile, Plant};
use serde::Serialize;

use crate::series::Series;
use crate::validate::{noise_floor, NoiseFloor};
use crate::IdentError;
use discrepancy::Discrepancy;
use fit::{Part, Problem, Sim};
use residual::Analysis;

/// Settings of a diagnosis.
#[derive(Clone, Debug)]
pub struct Options {
    /// Fraction at the end of each file held out for validation.
    pub holdout: f64,
    /// Most effects added.
    pub max_effects: usize,
    /// Smallest validation-MAE improvement worth an effect, as a fraction of the noise
    /// floor: below it an effect is statistically visible but not worth modelling.
    pub min_gain: f64,
    /// Hypotheses tried (default: the whole catalogue).
    pub candidates: Vec<EffectKind>,
    /// A discrepancy term is reported when its contribution has at least this RMS, N.
    pub discrepancy_threshold_n: f64,
    /// Two hypotheses whose scores differ by less than this are reported as hard to
    /// tell apart (log-likelihood units: 10 is a likelihood ratio of about 150).
    pub ambiguity: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            holdout: 0.3,
            max_effects: 3,
            min_gain: 0.01,
            candidates: EffectKind::ALL.to_vec(),
            discrepancy_threshold_n: 0.15,
            ambiguity: 10.0,
        }
    }
}

/// One hypothesis tried in one round.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    pub name: &'static str,
    /// Fitted parameters of this effect.
    pub params: BTreeMap<&'static str, f64>,
    /// Their standard errors.
    pub uncertainty: BTreeMap<&'static str, f64>,
    /// Validation MAE of the model with it (and every effect kept so far), N.
    pub mae_val_n: f64,
    /// Score improvement over the current model (positive: better, penalty included);
    /// `None` when the extended model diverged.
    pub score_gain: Option<f64>,
}

/// One round of the search.
#[derive(Clone, Debug, Serialize)]
pub struct Round {
    /// Validation MAE of the model the round starts from, N.
    pub mae_val_n: f64,
    /// Every hypothesis, best first.
    pub candidates: Vec<Candidate>,
    /// The one kept, if any.
    pub accepted: Option<&'static str>,
}

/// Why an effect was named.
#[derive(Clone, Debug, Serialize)]
pub struct Evidence {
    /// In words, for the bench engineer.
    pub summary: String,
    /// Validation MAE before and after adding it, N.
    pub mae_val_before_n: f64,
    pub mae_val_after_n: f64,
    /// Score improvement on held-out data (penalty included).
    pub score_gain: f64,
    /// The next-best hypothesis of that round and its score gain.
    pub runner_up: Option<(&'static str, f64)>,
    /// True when the runner-up is within [`Options::ambiguity`] of it.
    pub ambiguous: bool,
    /// What the residual showed before it was added.
    pub residual: Vec<String>,
}

/// An effect the model left out, as modelled.
#[derive(Clone, Debug, Serialize)]
pub struct FoundEffect {
    pub name: &'static str,
    pub params: BTreeMap<&'static str, f64>,
    /// Standard errors of the parameters.
    pub uncertainty: BTreeMap<&'static str, f64>,
    pub evidence: Evidence,
}

/// The result of [`diagnose`].
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    /// What the model left out, in the order found.
    pub effects: Vec<FoundEffect>,
    /// Validation MAE of the given model, N.
    pub mae_before_n: f64,
    /// Validation MAE of the improved model, N.
    pub mae_after_n: f64,
    /// Noise floor: the MAE of the noise alone, N.
    pub noise_floor_n: f64,
    /// Validation fit % before and after.
    pub fit_before_pct: f64,
    pub fit_after_pct: f64,
    /// What to do, in words.
    pub verdict: String,
    /// Samples fitted on and judged on.
    pub calibration_samples: usize,
    pub validation_samples: usize,
    /// The residual of the given model, and of the improved one.
    pub before: Analysis,
    pub after: Analysis,
    /// Sparse discrepancy models of both residuals.
    pub discrepancy_before: Discrepancy,
    pub discrepancy_after: Discrepancy,
    /// Every hypothesis tried.
    pub rounds: Vec<Round>,
    /// Noise estimate.
    pub noise: NoiseFloor,
    /// The improved model (the given one with the effects added).
    #[serde(skip)]
    pub improved: ModelFile,
    /// Simulated measured thrust of the given and the improved model, per file.
    #[serde(skip)]
    pub sim_before: Vec<Vec<f64>>,
    #[serde(skip)]
    pub sim_after: Vec<Vec<f64>>,
    /// First validation row of each file.
    #[serde(skip)]
    pub cut: Vec<usize>,
}

/// A model scored on the validation rows.
struct Scored {
    free: Vec<(EffectKind, Vec<f64>)>,
    stderr: Vec<(EffectKind, Vec<f64>)>,
    sim: Sim,
    sse_val: f64,
    mae_val: f64,
}

impl Scored {
    fn params(&self) -> usize {
        self.free.iter().map(|(_, v)| v.len()).sum()
    }
}

/// Finds what `model` leaves out of `data` (recordings with measured thrust).
pub fn diagnose(
    model: &ModelFile,
    data: &[Series],
    options: &Options,
    progress: &mut dyn FnMut(&str),
) -> Result<Diagnosis, IdentError> {
    if !(options.holdout > 0.05 && options.holdout < 0.95) {
        return Err(IdentError::Options(format!("--holdout {} must be in (0.05, 0.95)", options.holdout)));
    }
    if data.iter().any(|s| !s.has_thrust()) {
        return Err(IdentError::Options("every recording needs measured thrust (a thrust_n column)".into()));
    }
    let noise = noise_floor(data)
        .ok_or_else(|| IdentError::TooLittleData("too few samples to estimate the noise floor".into()))?;
    let nominal = model.plant();
    let problem = Problem::new(data, &nominal, options.holdout)?;
    let fixed = model.effects.clone();
    let params = model.model;

    progress("simulating the model over the recording");
    let mut sim = Sim::new();
    if let Err((i, at)) = problem.simulate(&nominal, false, &mut sim) {
        return Err(IdentError::Failed(format!(
            "the model diverges on the recorded input of {} at t = {at:.2} s, so it cannot be compared with the \
             recording; identify a model that is valid over this throttle range first (jetbench identify)",
            data[i].name
        )));
    }
    let before = Scored {
        free: Vec::new(),
        stderr: Vec::new(),
        sse_val: problem.sse(&sim, Part::Validation),
        mae_val: problem.mae(&sim, Part::Validation),
        sim,
    };
    progress("analysing the residual");
    let analysis_before = residual::analyse(&problem, &before.sim, noise.sigma_n);
    let discrepancy_before = discrepancy::fit(&problem, &before.sim, options.discrepancy_threshold_n);

    let n_val = problem.n_val as f64;
    let score = |s: &Scored| n_val * (s.sse_val / n_val).ln() + s.params() as f64 * n_val.ln();
    let mut current = before;
    let mut rounds = Vec::new();
    let mut found: Vec<(EffectKind, Evidence)> = Vec::new();
    let mut residual_now = analysis_before.findings.clone();
    while found.len() < options.max_effects {
        let tried: Vec<EffectKind> = options
            .candidates
            .iter()
            .copied()
            .filter(|k| fixed.get(*k).is_none() && !current.free.iter().any(|(c, _)| c == k))
            .collect();
        if tried.is_empty() {
            break;
        }
        let mut results: Vec<(EffectKind, Option<Scored>)> = Vec::new();
        for (i, &kind) in tried.iter().enumerate() {
            progress(&format!("round {}: trying {kind} ({}/{})", rounds.len() + 1, i + 1, tried.len()));
            results.push((kind, try_hypothesis(&problem, model, &current.free, kind)));
        }
        let base = score(&current);
        let mut candidates: Vec<Candidate> = results
            .iter()
            .map(|(kind, s)| {
                let own = |list: &[(EffectKind, Vec<f64>)]| -> BTreeMap<&'static str, f64> {
                    list.iter()
                        .find(|(k, _)| k == kind)
                        .map(|(_, v)| kind.keys().iter().copied().zip(v.iter().copied()).collect())
                        .unwrap_or_default()
                };
                Candidate {
                    name: kind.name(),
                    params: s.as_ref().map(|s| own(&s.free)).unwrap_or_default(),
                    uncertainty: s.as_ref().map(|s| own(&s.stderr)).unwrap_or_default(),
                    mae_val_n: s.as_ref().map_or(f64::NAN, |s| s.mae_val),
                    score_gain: s.as_ref().map(|s| base - score(s)),
                }
            })
            .collect();
        candidates.sort_by(|a, b| {
            b.score_gain.unwrap_or(f64::NEG_INFINITY).total_cmp(&a.score_gain.unwrap_or(f64::NEG_INFINITY))
        });
        let best = candidates.first().cloned();
        let runner_up = candidates.get(1).and_then(|c| c.score_gain.map(|g| (c.name, g)));
        let accept = best.as_ref().and_then(|b| {
            let gain = b.score_gain?;
            (gain > 0.0 && current.mae_val - b.mae_val_n >= options.min_gain * noise.mae_n).then_some((b.name, gain))
        });
        rounds.push(Round { mae_val_n: current.mae_val, candidates, accepted: accept.map(|a| a.0) });
        let Some((name, gain)) = accept else { break };
        let Some((kind, Some(next))) = results.into_iter().find(|(k, _)| k.name() == name) else { break };
        let evidence = Evidence {
            summary: String::new(),
            mae_val_before_n: current.mae_val,
            mae_val_after_n: next.mae_val,
            score_gain: gain,
            ambiguous: runner_up.is_some_and(|(_, g)| gain - g < options.ambiguity),
            runner_up,
            residual: residual_now,
        };
        found.push((kind, evidence));
        current = next;
        residual_now = residual::analyse(&problem, &current.sim, noise.sigma_n).findings;
    }

    progress("analysing the improved model");
    let analysis_after = residual::analyse(&problem, &current.sim, noise.sigma_n);
    let discrepancy_after = discrepancy::fit(&problem, &current.sim, options.discrepancy_threshold_n);
    let mut improved_effects = fixed.clone();
    let mut effects = Vec::new();
    for (kind, mut evidence) in found {
        let values = current.free.iter().find(|(k, _)| *k == kind).map(|(_, v)| v.clone()).unwrap_or_default();
        let errors = current.stderr.iter().find(|(k, _)| *k == kind).map(|(_, v)| v.clone()).unwrap_or_default();
        if let Ok(e) = jetbench_model::Effect::new(kind, &values) {
            improved_effects = improved_effects.with(e);
        }
        evidence.summary = explain(kind, &values, &errors, &analysis_before);
        effects.push(FoundEffect {
            name: kind.name(),
            params: kind.keys().iter().copied().zip(values.iter().copied()).collect(),
            uncertainty: kind.keys().iter().copied().zip(errors.iter().copied()).collect(),
            evidence,
        });
    }
    let fit_pct =
        |sim: &Sim| crate::validate::score(problem.pairs(sim, Part::Validation)).map_or(f64::NAN, |s| s.fit_pct);
    let mut diagnosis = Diagnosis {
        mae_before_n: rounds.first().map_or(current.mae_val, |r| r.mae_val_n),
        mae_after_n: current.mae_val,
        noise_floor_n: noise.mae_n,
        fit_before_pct: f64::NAN,
        fit_after_pct: fit_pct(&current.sim),
        verdict: String::new(),
        calibration_samples: problem.n_cal,
        validation_samples: problem.n_val,
        effects,
        before: analysis_before,
        after: analysis_after,
        discrepancy_before,
        discrepancy_after,
        rounds,
        noise,
        improved: ModelFile { model: params, effects: improved_effects },
        sim_before: Vec::new(),
        sim_after: current.sim,
        cut: problem.cut.clone(),
    };
    let mut sim_before = Sim::new();
    if problem.simulate(&nominal, false, &mut sim_before).is_ok() {
        diagnosis.fit_before_pct = fit_pct(&sim_before);
    }
    diagnosis.sim_before = sim_before;
    diagnosis.verdict = verdict(&diagnosis);
    Ok(diagnosis)
}

/// Fits `kind` together with the effects kept so far; `None` when it diverges everywhere.
fn try_hypothesis(
    problem: &Problem<'_>,
    model: &ModelFile,
    kept: &[(EffectKind, Vec<f64>)],
    kind: EffectKind,
) -> Option<Scored> {
    let with = |values: &[f64]| -> Option<Plant> {
        let mut effects: Effects = model.effects.clone();
        for (k, v) in kept.iter().chain(std::iter::once(&(kind, values.to_vec()))) {
            effects = effects.with(jetbench_model::Effect::new(*k, v).ok()?);
        }
        Some(Plant::new(model.model, effects))
    };
    let mut sim = Sim::new();
    let start = fit::start_grid(kind)
        .into_iter()
        .filter_map(|g| {
            let plant = with(&g)?;
            problem.simulate(&plant, true, &mut sim).ok()?;
            Some((problem.sse(&sim, Part::Calibration), g))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))?
        .1;
    let mut free = kept.to_vec();
    free.push((kind, start));
    let fitted = fit::fit(problem, model.model, &model.effects, &free)?;
    let free: Vec<(EffectKind, Vec<f64>)> = free
        .iter()
        .map(|(k, _)| (*k, fitted.effects.get(*k).map(|e| e.values().to_vec()).unwrap_or_default()))
        .collect();
    let plant = Plant::new(model.model, fitted.effects.clone());
    problem.simulate(&plant, false, &mut sim).ok()?;
    Some(Scored {
        free,
        stderr: fitted.stderr,
        sse_val: problem.sse(&sim, Part::Validation),
        mae_val: problem.mae(&sim, Part::Validation),
        sim,
    })
}

/// `0.081 ± 0.006`, with as many decimals as the uncertainty needs.
fn pm(value: f64, error: f64) -> String {
    let decimals = if error.is_finite() && error > 0.0 { (-error.log10().floor()).clamp(0.0, 6.0) as usize } else { 3 };
    if error.is_finite() {
        format!("{value:.decimals$} ± {error:.decimals$}")
    } else {
        format!("{value:.decimals$}")
    }
}

/// One sentence per effect: what the residual showed, the physics, the fitted values.
fn explain(kind: EffectKind, v: &[f64], e: &[f64], before: &Analysis) -> String {
    let get = |i: usize| (v.get(i).copied().unwrap_or(f64::NAN), e.get(i).copied().unwrap_or(f64::NAN));
    let direction = |class: &str| before.by_direction.iter().find(|c| c.class == class).map_or(0.0, |c| c.mean_n);
    match kind {
        EffectKind::InputDelay => {
            let (d, de) = get(0);
            format!(
                "Residual follows the throttle {:.0} ms later, rising ({:+.2} N) and falling ({:+.2} N) alike: input \
                 delay left out. Modelled: {} s.",
                d * 1000.0,
                direction("rising"),
                direction("falling"),
                pm(d, de)
            )
        }
        EffectKind::ActuatorLag => {
            let (t, te) = get(0);
            format!(
                "Residual is largest right after fast throttle changes and smeared in time, unlike a pure delay: \
                 actuator (fuel-pump) lag left out. Modelled: time constant {} s.",
                pm(t, te)
            )
        }
        EffectKind::RateLimit => {
            let ((up, upe), (down, downe)) = (get(0), get(1));
            format!(
                "Residual only on large fast throttle changes, its sign following the direction of change: the \
                 ECU's rate limit left out. Modelled: up {} %/s, down {} %/s.",
                pm(up, upe),
                pm(down, downe)
            )
        }
        EffectKind::SensorDrift => {
            let ((g, ge), (t, te)) = (get(0), get(1));
            format!(
                "Slow offset that follows the thrust history (it lingers at idle after high thrust): the force \
                 sensor drifts as it heats. Modelled: bias gain {} of thrust, time constant {} s.",
                pm(g, ge),
                pm(t, te)
            )
        }
        EffectKind::GainDrift => {
            let (p, pe) = get(0);
            format!(
                "The same throttle gives {} thrust as the run goes on (residual slope {:+.3} N/min): gain drift \
                 left out. Modelled: {} %/min.",
                if p >= 0.0 { "less" } else { "more" },
                before.drift.slope_n_per_min,
                pm(p * 100.0, pe * 100.0)
            )
        }
        EffectKind::BearingFriction => {
            let (f, fe) = get(0);
            format!(
                "Measured force trails the thrust by a constant band whose sign follows the direction of change \
                 (rising {:+.2} N, falling {:+.2} N): bearing friction left out. Modelled: play band ± {} N.",
                direction("rising"),
                direction("falling"),
                pm(f, fe)
            )
        }
    }
}

fn verdict(d: &Diagnosis) -> String {
    let floor = d.noise_floor_n;
    let after = &d.after.whiteness;
    let before = &d.before.whiteness;
    let closing = if d.mae_after_n <= 1.10 * floor {
        "at the noise floor"
    } else {
        "still above the noise floor: something the catalogue does not hold remains"
    };
    if d.effects.is_empty() {
        let best = d.rounds.first().and_then(|r| r.candidates.first());
        let nothing = if before.white {
            format!(
                "Nothing left out: the residual is white (Ljung–Box p = {:.2}) and no effect in the catalogue \
                 improves the held-out fit",
                before.p_value
            )
        } else {
            format!(
                "No effect in the catalogue improves the held-out fit enough to be worth modelling, though the \
                 residual is not white (Ljung–Box p = {:.1e}); see the discrepancy terms",
                before.p_value
            )
        };
        let best = best
            .map_or(String::new(), |c| format!(" (best candidate {}: validation MAE {:.3} N)", c.name, c.mae_val_n));
        return format!(
            "{nothing}{best}. Validation MAE {:.2} N against a noise floor of {:.2} N: {}.",
            d.mae_before_n,
            floor,
            if d.mae_before_n <= 1.10 * floor { "the model explains the recording" } else { closing }
        );
    }
    let mut text: Vec<String> = d.effects.iter().map(|e| e.evidence.summary.clone()).collect();
    for e in d.effects.iter().filter(|e| e.evidence.ambiguous) {
        if let Some((other, _)) = e.evidence.runner_up {
            text.push(format!("({} and {other} fit almost equally well at this noise level.)", e.name));
        }
    }
    text.push(format!(
        "Validation MAE {:.2} N → {:.2} N (noise floor {:.2} N), {closing}; residual whiteness Ljung–Box p {:.1e} → {:.2}.",
        d.mae_before_n, d.mae_after_n, floor, before.p_value, after.p_value
    ));
    text.join(" ")
}
