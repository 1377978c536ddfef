//! Mismatch discovery: where a model and a recording disagree, whether the model's
//! parameters are off or physics is missing, the model with it added, and the proof
//! on held-out data.
//!
//! ```no_run
//! use jetbench_ident::diagnose::{diagnose, Cause, Options};
//! use jetbench_ident::series::Series;
//! use jetbench_model::resolve_model;
//!
//! let model = resolve_model("p100-diesel")?;
//! let (run, note) = Series::load_any_rate("run.csv".as_ref(), true)?;
//! let d = diagnose(&model, &[run], &Options::default(), &mut |_| {})?;
//! if d.cause == Cause::MissingPhysics {
//!     println!("{}", d.verdict);
//!     d.improved.save("improved.toml".as_ref())?;
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! 1. **Prepare.** The recordings go on the model's 10 ms grid: short gaps are
//!    simulated through with the throttle held (the second after one in which the
//!    throttle stepped left out), spikes are rejected against a robust
//!    scale and counted, and the sensor noise is modelled as an AR process from the
//!    data alone ([`problem`], [`crate::noise`]).
//! 2. **Locate.** The model is simulated from the recorded throttle and its residual
//!    analysed against the noise model ([`residual::Analysis`]).
//! 3. **Name.** Three kinds of hypothesis compete, each fitted on the calibration part
//!    of every file (output error, prewhitened by the noise model) and judged on the
//!    held-out part by `N·ln(SSE_w/N) + k·ln N` (a likelihood on data the fit never
//!    saw, with a BIC penalty per fitted parameter):
//!    - each effect of the catalogue ([`EffectKind::CATALOGUE`]), with its physical
//!      range and sign: a fit outside it is evidence, never a claim;
//!    - re-identification: the ten parameters refitted;
//!    - the sparse discrepancy ([`discrepancy`]): named terms for physics outside the
//!      catalogue.
//! 4. **Model.** Each round keeps the best hypothesis that wins on held-out data by a
//!    practical margin; when a refit explains the residual as well as the best effect
//!    (within [`Options::ambiguity`] of its likelihood), the parameters are blamed, not
//!    physics. Later rounds fit everything kept jointly (effects with the ten
//!    parameters when both are needed). At the end every part kept must still earn its
//!    place: one whose removal does not worsen the held-out score goes.
//! 5. **Show.** The cause (none, parameters, missing physics, unexplained), validation
//!    MAE and fit before and after, whiteness under the noise model before and after,
//!    and a verdict in words ([`report`]).

/// The experiment that separates a diagnosis's rivals (`jetbench excite --discriminate`).
pub mod design;
/// Whether a recording could have shown each class of effect at the size that matters:
/// what `none` and `parameters` must earn.
pub mod detect;
pub(crate) mod discrepancy;
mod fit;
/// The recordings on the model's 10 ms grid, their noise model and the calibration and
/// held-out parts every hypothesis is fitted and judged on.
pub mod problem;
/// The verdict in words, the JSON contract and the plots of a diagnosis.
pub mod report;
/// What a model's residual shows against the noise model: whiteness, correlation with the
/// throttle, drift, spectrum, a periodic part.
pub mod residual;
/// Rival explanations weighed on block-bootstrap resamples of the held-out data, and
/// whether one dominates the others.
pub mod rivals;

use std::cell::RefCell;
use std::collections::BTreeMap;

use jetbench_model::{Effect, EffectKind, ModelFile, Params, STEP_S};
use serde::Serialize;

use crate::series::Series;
use crate::IdentError;
use fit::{Fit, Spec};
use problem::{DataReport, Part, Problem, Sim, SimCache};
use residual::Analysis;
use rivals::{Entry, Rival};

/// Settings of a diagnosis.
#[derive(Clone, Debug)]
pub struct Options {
    /// Fraction at the end of each file held out for validation.
    pub holdout: f64,
    /// Most effects added.
    pub max_effects: usize,
    /// Smallest validation-MAE improvement worth modelling, as a fraction of the noise
    /// floor: below it a hypothesis is statistically visible but not worth a claim...
    pub min_gain: f64,
    /// ... unless its held-out score gain is at least this (score units: 40 is a
    /// likelihood ratio of e²⁰), evidence no chance alignment of noise gives.
    pub strong_evidence: f64,
    /// Effects tried (default: the catalogue and the discrepancy).
    pub candidates: Vec<EffectKind>,
    /// Try re-identifying the ten parameters.
    pub refit: bool,
    /// Score units (`N·ln(SSE/N)`, twice a log-likelihood) within which two hypotheses
    /// explain the held-out data equally well: 10 is a likelihood ratio of e⁵ ≈ 150.
    pub ambiguity: f64,
    /// Physics is preferred to a refit only when it fits the held-out data better by more
    /// than `ambiguity` and by this many standard errors of the paired difference. With
    /// parameters the only thing off, a flexible hypothesis (the discrepancy) can beat the
    /// refit by 10-15 units under coloured noise, but not by two standard errors.
    pub significance_z: f64,
    /// Notes from loading the recordings (another sampling rate, ...), passed on to the report.
    pub notes: Vec<String>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            holdout: 0.3,
            max_effects: 3,
            min_gain: 0.01,
            strong_evidence: 40.0,
            // An acceleration schedule is structure `identify` chooses, not a hypothesis.
            candidates: EffectKind::ALL.into_iter().filter(|k| *k != EffectKind::AccelSchedule).collect(),
            refit: true,
            ambiguity: 10.0,
            significance_z: 2.0,
            notes: Vec::new(),
        }
    }
}

/// What the diagnosis blames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Cause {
    /// The model explains the recording: the residual is noise.
    None,
    /// The ten parameters are off; re-identify (no physics is missing). Claimed only when
    /// the refitted model's residual is noise and this recording would have shown every
    /// class of effect beside the refit ([`detect`]).
    Parameters,
    /// Physics is missing (named, or modelled by the discrepancy); the parameters may
    /// have been refitted too.
    MissingPhysics,
    /// Something systematic remains that no hypothesis explains on held-out data.
    Unexplained,
    /// Two or more explanations of different kinds fit the held-out data about equally
    /// well: `rivals` lists them with their weights and what would tell them apart.
    Ambiguous,
    /// Too little held-out data to tell any explanation from another: nothing claimed.
    InsufficientData,
}

/// The name of the re-identification hypothesis in rounds.
pub const REFIT: &str = "refit";

/// One hypothesis tried in one round.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    /// An effect's name, or [`REFIT`].
    pub name: &'static str,
    /// The effect fitted together with it, in a round of pairs (two effects that each fit
    /// the held-out data worse than none alone, where one hides the other).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub with: Option<&'static str>,
    /// Fitted parameters of this hypothesis (the effect's, or the ten).
    pub params: BTreeMap<&'static str, f64>,
    /// Their standard errors.
    pub uncertainty: BTreeMap<&'static str, f64>,
    /// Validation MAE of the model with it (and everything kept so far), N.
    pub mae_val_n: f64,
    /// Score improvement over the current model (positive: better, penalty included);
    /// `None` when the extended model diverged.
    pub score_gain: Option<f64>,
    /// The same without the penalty: how much better it explains the held-out data.
    pub fit_gain: Option<f64>,
    /// Parameters fitted.
    pub parameters: usize,
    /// Why it cannot be a claim (outside its physical range, or an effect whose size is
    /// within two standard errors of zero), if so.
    pub unphysical: Option<String>,
    /// What else there is to say (the discrepancy's terms, a divergence).
    pub note: Option<String>,
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
    /// Why, in a few words.
    pub reason: String,
    /// Which search: `physics` (effects alone), `parameters` (the ten refitted, effects on
    /// top) or `choice` (between the two).
    pub phase: &'static str,
}

/// Why a part of the improved model is there.
#[derive(Clone, Debug, Serialize)]
pub struct Evidence {
    /// In words, for the bench engineer.
    pub summary: String,
    /// Validation MAE before adding it, N.
    pub mae_val_before_n: f64,
    /// Validation MAE after adding it, N.
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
    /// The effect's catalogue name (`input_delay`, ...) or `discrepancy`.
    pub name: &'static str,
    /// Fitted parameters (a discrepancy's: its terms, each with its shape key).
    pub params: BTreeMap<&'static str, f64>,
    /// Standard errors of the parameters.
    pub uncertainty: BTreeMap<&'static str, f64>,
    /// Why it is there: the held-out gain and what the residual showed.
    pub evidence: Evidence,
}

/// The ten parameters re-identified (all, or the few that are off).
#[derive(Clone, Debug, Serialize)]
pub struct Refit {
    /// The ten parameters, by name (`K_T`, ..., `B_UU`), in the model file's units: refitted,
    /// or as given where a sparse refit left them.
    pub params: BTreeMap<&'static str, f64>,
    /// The parameters refitted: all ten, or the few a sparse refit moved.
    pub refitted: Vec<&'static str>,
    /// Their standard errors on the calibration part, same units.
    pub uncertainty: BTreeMap<&'static str, f64>,
    /// Change from the given model, %.
    pub change_pct: BTreeMap<&'static str, f64>,
    /// Why the refit is there: the held-out gain and what the residual showed.
    pub evidence: Evidence,
}

impl Refit {
    /// The refit in words: "a refit of the ten parameters", or of the few it moved.
    pub fn what(&self) -> String {
        match self.refitted.len() {
            10 => "a refit of the ten parameters".to_owned(),
            _ => format!("a refit of {}", report::sparse_refit(&self.refitted)),
        }
    }
}

/// How far the ten parameters could be from the given ones with this recording unable to
/// tell, beside what is claimed on them (physics on the given parameters, or `none`). A claim
/// on the given parameters says they are right only so far: 200 s of a P220 showed an input
/// delay beside a `c` 7.7 % off no better refitted than as given (a campaign's case), and a
/// claim that did not say how far the recording bounds the parameters read as if they were
/// exact.
#[derive(Clone, Debug, Serialize)]
pub struct ParameterRanges {
    /// Per parameter (`K_T`, ..., `B_UU`, the model file's units), `[low, high]`: where a refit
    /// of the ten beside the same physics puts it, `z` of its standard errors either side, from
    /// the recording alone (the refit's prior left out); `null` for no bound (the recording does
    /// not determine the parameter to within its own size).
    pub range: BTreeMap<&'static str, [Option<f64>; 2]>,
    /// Standard errors either side: the ten at once at 99 % (3.29, Bonferroni over ten).
    pub z: f64,
    /// In words, the widest ranges first.
    pub summary: String,
}

/// Standard errors either side of [`ParameterRanges`]: a two-sided 0.1 % level per parameter,
/// 1 % for the ten together.
const RANGE_Z: f64 = 3.29;

/// Where one run of the improved model starts its slow first-order states: fitted with the
/// hypothesis (a recording starts some time after the tare and after the engine started, so
/// a drift's bias and a soak's thrust history are still on their way), `None` where the
/// improved model has no such state.
#[derive(Clone, Debug, Serialize)]
pub struct SlowStartFound {
    /// The recording (its index among those given).
    pub recording: usize,
    /// Time of the run's first sample in that recording, s.
    pub from_s: f64,
    /// The sensor drift's bias at that sample, N (a sensor drift found).
    pub sensor_bias_n: Option<f64>,
    /// The thrust history's offset from the thrust at that sample, N (a discrepancy with a
    /// thrust-history term found).
    pub history_offset_n: Option<f64>,
    /// Where the stand's frame sat in the bearings' play band at that sample, as a fraction
    /// of the band (−1: at its bottom, trailing a rise; +1: at its top), bearing friction
    /// found.
    pub play_position: Option<f64>,
}

/// The result of [`diagnose`].
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    /// What is blamed.
    pub cause: Cause,
    /// Physics the model left out, in the order found (none for `parameters`).
    pub effects: Vec<FoundEffect>,
    /// The re-identified parameters, when the given ones were off.
    pub refit: Option<Refit>,
    /// Physics claimed on the given parameters although a refit with the same physics fits
    /// the held-out data better, by less than blames the parameters: what the refit gained.
    /// The physics is needed either way; whether the parameters are off as well, the
    /// recording cannot tell, and this says so.
    pub parameters_open: Option<String>,
    /// Claimed on the given parameters (physics without a refit, or `none`), with nothing
    /// left open about them: how far each could be off with this recording unable to tell.
    pub parameter_ranges: Option<ParameterRanges>,
    /// Validation MAE of the given model, N.
    pub mae_before_n: f64,
    /// Validation MAE of the improved model, N.
    pub mae_after_n: f64,
    /// Noise floor: the MAE of the noise alone, N (from its model, coloured or not).
    pub noise_floor_n: f64,
    /// Validation fit % of the given model (100 % is a perfect fit, 0 % the mean).
    pub fit_before_pct: f64,
    /// Validation fit % of the improved model.
    pub fit_after_pct: f64,
    /// What to do, in words.
    pub verdict: String,
    /// Samples every hypothesis is fitted on (the calibration part).
    pub calibration_samples: usize,
    /// Samples every hypothesis is judged on (the held-out part).
    pub validation_samples: usize,
    /// The sensor noise and what the data needed: outliers removed, gaps.
    pub noise: DataReport,
    /// The residual of the given model against the noise model.
    pub before: Analysis,
    /// The residual of the improved model against the noise model.
    pub after: Analysis,
    /// Every hypothesis tried.
    pub rounds: Vec<Round>,
    /// Parts dropped at the end (the held-out score did not need them, or their size is
    /// within two standard errors of zero), and why the claim is not the search's pick
    /// when it is not.
    pub dropped: Vec<String>,
    /// Every explanation kept as a rival, best first, with its weight (the share of
    /// block-bootstrap resamples of the held-out data it wins) and what tells it apart
    /// from the search's explanation; a claimed cause lists its rivals too.
    pub rivals: Vec<Rival>,
    /// Held-out data, s.
    pub held_out_s: f64,
    /// Held-out data a claim needs, s ([`rivals::MIN_BLOCKS`] independent blocks).
    pub needed_s: f64,
    /// True when the search's explanation beats every rival of another kind in at least
    /// 95 % of resamples and by more than a tie.
    pub dominant: bool,
    /// When the search's explanation does not dominate but every explanation in play holds
    /// the effects claimed (`effects`): what each explanation in play holds beside them, with
    /// its weight. The claim is of those effects; whether any of these parts is there too,
    /// the recording cannot tell (see [`report::cause`]). Empty otherwise.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub undecided: Vec<rivals::OpenPart>,
    /// The effects every explanation in play holds, and what each holds beside them (see
    /// [`rivals::Rivals::settled`]).
    #[serde(skip)]
    pub(crate) in_play: (Vec<&'static str>, Vec<rivals::OpenPart>),
    /// When the held-out part alone left the claim short of one and the rivals were weighed
    /// both ways round (each fitted on either part and judged on the other): the claim's
    /// weight on the held-out part alone.
    pub weighed_both_ways: Option<f64>,
    /// When no explanation is claimed although one wins at least 95 % of the resamples of the
    /// held-out data: why that one is not claimed, in words (the rival it does not dominate
    /// and by how much its lead falls short, or the bar of a claim it fails).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub short_of_claim: Option<String>,
    /// Each class of effect at the size that matters, whether this recording would show it
    /// beside the model found (beside the refit, when the parameters were refitted) and
    /// whether the residual carries its shape (see [`detect`]): what `none` and `parameters`
    /// must earn, and, beside physics found, what could hide next to it.
    pub detectability: Vec<detect::Detectability>,
    /// A slow periodic part left in the residual of the improved model, if any.
    pub periodic: Option<residual::Periodic>,
    /// The sine the periodic rival fitted to the calibration part of the improved model's
    /// residual (a rival, not a finding: see `rivals`).
    pub periodic_rival: Option<residual::Periodic>,
    /// Where each run of the improved model starts its slow states, when it has them: they
    /// are fitted per run and charged as parameters (see [`problem::RunStart`]).
    pub starts: Vec<SlowStartFound>,
    /// The improved model (refitted parameters, effects added).
    #[serde(skip)]
    pub improved: ModelFile,
    /// Simulated measured thrust of the given model, per file and row, N.
    #[serde(skip)]
    pub sim_before: Vec<Vec<f64>>,
    /// Simulated measured thrust of the improved model, per file and row, N.
    #[serde(skip)]
    pub sim_after: Vec<Vec<f64>>,
    /// First validation row of each file.
    #[serde(skip)]
    pub cut: Vec<usize>,
}

/// A hypothesis fitted and scored on the validation samples.
#[derive(Clone, Debug)]
struct Scored {
    fit: Fit,
    sim: Sim,
    sse_val: f64,
    n_val: usize,
    mae_val: f64,
}

impl Scored {
    fn score(&self) -> f64 {
        rivals::score(self.sse_val, self.n_val as f64, self.fit.spec.free_count(), 0.0)
    }

    /// `N·ln(SSE/N)` alone: the fit without its penalty.
    fn misfit(&self) -> f64 {
        let n = self.n_val as f64;
        n * (self.sse_val / n).ln()
    }

    /// What stops it being a claim: an effect outside its physical range, or a value
    /// the fit left on the edge of its range. A value held, not fitted (a rate limit's
    /// direction with no limit), is no finding and is not judged.
    fn unphysical(&self) -> Option<String> {
        let spec = &self.fit.spec;
        let problems: Vec<String> = spec
            .effects
            .iter()
            .filter_map(|(kind, v)| {
                let judged: Vec<f64> = v
                    .iter()
                    .enumerate()
                    .map(|(i, &x)| if spec.is_held(*kind, i) { kind.physical()[i].1 } else { x })
                    .collect();
                Some(format!("{kind}: {}", Effect::new(*kind, &judged).ok()?.unphysical()?))
            })
            .chain(self.fit.spec.at_bound())
            .collect();
        (!problems.is_empty()).then(|| problems.join("; "))
    }

    /// What stops it being a claim although it is physical: an effect whose size the data
    /// cannot tell from zero ([`fit::idle_effects`]).
    fn unsupported(&self) -> Option<String> {
        let idle: Vec<String> = fit::idle_effects(&self.fit)
            .into_iter()
            .map(|(kind, key, value, error)| {
                format!("{kind}: {key} = {value:.4} ± {error:.4}, within two standard errors of zero")
            })
            .collect();
        (!idle.is_empty()).then(|| idle.join("; "))
    }

    /// Why it cannot be claimed: [`Scored::unphysical`], else [`Scored::unsupported`].
    fn not_a_claim(&self) -> Option<String> {
        self.unphysical().or_else(|| self.unsupported())
    }
}

/// The search's state, with everything it needs.
struct Search<'p, 'a> {
    problem: &'p Problem<'a>,
    model: &'p ModelFile,
    options: &'p Options,
    floor_n: f64,
    /// Every explanation fitted, for the rivals.
    pool: RefCell<Vec<Entry>>,
    /// The engine path of the last hypothesis scored: rivals that differ from it on the
    /// sensor side alone are scored without stepping the engine again.
    cache: RefCell<SimCache>,
    /// The explanations fitted the other way round (see [`weigh_rivals`]), by their parts:
    /// `None` where that fit failed.
    back: RefCell<BTreeMap<Label, Option<Entry>>>,
    /// The best of the sparse refits without effects ([`sparse_refit_rivals`]), once fitted:
    /// the same whichever explanation asks.
    sparse_alone: RefCell<Option<Option<Scored>>>,
}

/// An explanation's parts: its effects' names, sorted, and whether the ten parameters are
/// refitted.
type Label = (Vec<&'static str>, bool);

impl<'p, 'a> Search<'p, 'a> {
    /// A search over `problem`, nothing fitted yet; the floor is the problem's noise floor.
    fn new(problem: &'p Problem<'a>, model: &'p ModelFile, options: &'p Options) -> Self {
        Self {
            problem,
            model,
            options,
            floor_n: problem.noise.mae_n,
            pool: RefCell::new(Vec::new()),
            cache: RefCell::new(SimCache::default()),
            back: RefCell::default(),
            sparse_alone: RefCell::default(),
        }
    }

    fn evaluate(&self, fit: Fit) -> Option<Scored> {
        let plant = fit.spec.plant(&self.model.effects)?;
        let mut sim = Sim::new();
        self.problem.simulate_reusing(&plant, &fit.spec.states, false, &mut self.cache.borrow_mut(), &mut sim).ok()?;
        let (sse_val, n_val) = self.problem.sse(&sim, Part::Validation);
        let mae_val = self.problem.mae(&sim, Part::Validation);
        let scored =
            (sse_val.is_finite() && mae_val.is_finite()).then_some(Scored { fit, sim, sse_val, n_val, mae_val })?;
        self.pool.borrow_mut().push(self.entry(&scored));
        Some(scored)
    }

    /// The pool's best physical fit of `label` judged on `rows` held-out samples, by its
    /// held-out score.
    fn pooled(&self, label: &Label, rows: usize) -> Option<Entry> {
        self.best_pooled(label, rows, |e| e.score, |e| e.fit.is_some())
    }

    /// The pool's physical entry of `label` judged on `rows` held-out samples that `keep`
    /// admits, lowest by `rank` (a rival jetbench cannot model has no fit: `keep` asks for
    /// one where it is needed).
    fn best_pooled(
        &self,
        label: &Label,
        rows: usize,
        rank: impl Fn(&Entry) -> f64,
        keep: impl Fn(&Entry) -> bool,
    ) -> Option<Entry> {
        self.pool
            .borrow()
            .iter()
            .filter(|e| e.label() == *label && !e.unphysical && e.score.is_finite() && e.w2.len() == rows)
            .filter(|e| keep(e))
            .min_by(|a, b| rank(a).total_cmp(&rank(b)))
            .cloned()
    }

    /// The rivals' view of a scored hypothesis: its parts and held-out innovations.
    fn entry(&self, s: &Scored) -> Entry {
        let mut w = Vec::new();
        self.problem.innovations(&s.sim, Part::Validation, &mut w);
        let kinds: Vec<EffectKind> = s.fit.spec.effects.iter().map(|(k, _)| *k).collect();
        let mut entry = rivals::entry(
            &kinds,
            s.fit.spec.refit,
            &w,
            s.fit.spec.free_count(),
            s.fit.spec.prior_cost(),
            s.mae_val,
            s.unphysical().is_some(),
        );
        entry.idle = fit::idle_effects(&s.fit).into_iter().map(|(k, ..)| k.name()).collect();
        entry.refit_only = s.fit.spec.refit_only.clone();
        // Its fitted values: what a rival is rebuilt from, and how a discrepancy's terms are
        // compared between the explanations in play.
        entry.fit = Some(s.fit.clone());
        entry
    }

    /// How many standard errors `b` fits the held-out data worse than `a` (a paired test
    /// of two non-nested models, Vuong's): the per-sample difference of squared
    /// innovations, summed, over its standard error. Positive: `a` is better.
    /// How many standard errors `a` fits the held-out data better than `b` by (paired,
    /// per sample), `b` charged `extra` score units on top (spread over the samples).
    fn paired_z(&self, a: &Scored, b: &Scored, extra: f64) -> f64 {
        let (mut wa, mut wb) = (Vec::new(), Vec::new());
        self.problem.innovations(&a.sim, Part::Validation, &mut wa);
        self.problem.innovations(&b.sim, Part::Validation, &mut wb);
        if wa.len() != wb.len() || wa.len() < 2 {
            return 0.0;
        }
        let d: Vec<f64> = wa.iter().zip(&wb).map(|(x, y)| y * y - x * x).collect();
        let n = d.len() as f64;
        // A score unit (of `N·ln(SSE/N)`) is `SSE/N` of squared innovation.
        let mean = (d.iter().sum::<f64>() + extra * b.sse_val / b.n_val as f64) / n;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        if var > 0.0 {
            mean * n.sqrt() / var.sqrt()
        } else {
            0.0
        }
    }

    /// `scored` with each run's initial state fitted anew under it (the same model, a
    /// better start; the slow states' fitted starts kept), when that simulates.
    fn restart(&self, scored: Scored) -> Scored {
        let Some(plant) = scored.fit.spec.plant(&self.model.effects) else { return scored };
        let mut fit = scored.fit.clone();
        fit.spec.states = self.problem.restarted(&plant, &fit.spec.states);
        self.evaluate(fit).unwrap_or(scored)
    }

    /// `spec`, a part `added` to a hypothesis, fitted ([`Search::fit`]), and fitted again
    /// without the rate limit kept before when the fit took that limit to no limit both ways
    /// ([`fit::no_limit_left`]): the part added took its place. A rate limit that is the part
    /// added is left on its edge, for the judge to refuse.
    fn fit_adding(&self, spec: &Spec, added: EffectKind) -> Option<Scored> {
        let scored = self.fit(spec)?;
        match fit::no_limit_left(&scored.fit.spec).filter(|_| added != EffectKind::RateLimit) {
            Some(rest) => self.fit(&rest).or(Some(scored)),
            None => Some(scored),
        }
    }

    /// `spec` fitted ([`Search::fit_with_starts`]), and fitted again with its rate limit
    /// one-sided when the fit took one direction to no limit ([`fit::one_sided`]).
    fn fit(&self, spec: &Spec) -> Option<Scored> {
        let scored = self.fit_with_starts(spec)?;
        match fit::one_sided(&scored.fit.spec) {
            Some(one) => self.fit_with_starts(&one).or(Some(scored)),
            None => Some(scored),
        }
    }

    /// `spec` fitted on the calibration part and scored. A hypothesis with a sensor drift is
    /// fitted twice: the engine's start it grew from was fitted to the first samples with the
    /// whole reading on the engine, where part of it is the bias the drift has built up since
    /// the tare. The first fit finds that bias; the engine's start is fitted anew under it, and
    /// the second fit starts from both. Fitted once, the engine's start held the bias and the
    /// drift's time constant bent to make up for it (80 s fitted at 68 ± 1.4 s on a recording
    /// whose reading the model reproduced to 0.0001 N, and the residual not white). A start
    /// that hardly moves is not fitted for again.
    ///
    /// A refit of the ten parameters is fitted twice the same way: its start was fitted under
    /// the parameters as given, and where the throttle moves in the first seconds the refitted
    /// engine does not answer it as they do.
    fn fit_with_starts(&self, spec: &Spec) -> Option<Scored> {
        let first = fit::fit(self.problem, &self.model.effects, spec)?;
        if !spec.fits_bias_start() && !spec.refit {
            return self.evaluate(first);
        }
        let Some(plant) = first.spec.plant(&self.model.effects) else { return self.evaluate(first) };
        let mut again = first.spec.clone();
        again.states = self.problem.restarted(&plant, &again.states);
        // A start that moves by less than a tenth of the noise's σ changes no fit: the
        // hypothesis grew from one whose start already held the bias.
        let moved = again
            .states
            .iter()
            .zip(&first.spec.states)
            .any(|(a, b)| (a.state.thrust_n - b.state.thrust_n).abs() > 0.1 * self.problem.noise.sigma_n);
        if !moved {
            return self.evaluate(first);
        }
        match fit::fit(self.problem, &self.model.effects, &again).and_then(|f| self.evaluate(f)) {
            Some(second) => Some(second),
            None => self.evaluate(first),
        }
    }

    /// A catalogue effect added to `current`: the best of a coarse grid, then a joint fit.
    ///
    /// An effect of the throttle path (a delay, a rate limit, a lag) changes what the engine
    /// does in the first seconds, which its start was fitted to: each point of its grid starts
    /// from the engine state fitted anew under it. Held at the start fitted without it, a
    /// delay of 216 ms behind a throttle that ramps from the first row (a fresh campaign's
    /// case) met a start falling at 35 N/s, bent to 196 ms (ten standard errors off) to make
    /// up for it, and left a residual only a discrepancy beside it could take.
    fn try_effect(&self, current: &Spec, kind: EffectKind, peak_hz: Option<f64>) -> Option<Scored> {
        // Only the effects the user lets the search try (`--only`), wherever it tries them:
        // a look-alike fitted in a kept effect's place is tried too, and may be claimed.
        if !self.options.candidates.contains(&kind) {
            return None;
        }
        // A sensor-side effect's grid runs on one engine path (see [`SimCache`]).
        let mut cache = SimCache::default();
        let joins = kind == EffectKind::SensorDrift && !current.has(kind);
        let on_path = matches!(kind, EffectKind::InputDelay | EffectKind::RateLimit | EffectKind::ActuatorLag);
        let mut grid: Vec<(f64, Spec)> = fit::start_grid(kind, peak_hz)
            .into_iter()
            .filter_map(|g| {
                let mut spec = current.with(kind, g);
                if on_path {
                    spec.states = self.problem.restarted(&spec.plant(&self.model.effects)?, &spec.states);
                }
                let spec = if joins { self.agreeing_starts(spec, &mut cache) } else { spec };
                Some((fit::calibration_sse(self.problem, &self.model.effects, &spec, &mut cache)?, spec))
            })
            .collect();
        grid.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (_, best) = grid.first()?;
        if kind != EffectKind::SensorDrift {
            return self.fit_adding(best, kind);
        }
        // A drift's fit stops where the basin of its start ends: a fast drift that stands in
        // for a misfit at the start, or a slow one that follows the thrust, and along a flat
        // valley in between. Beside a delay, a drift of τ 40 s fitted from the grid's best
        // start (τ 250 s) stopped at 51.5 s, from one at 15 s at 48.8 s, the better fit of the
        // calibration part. The fit runs from the best start and from the best whose time
        // constant is more than three times away, and keeps the better fit of the
        // calibration part.
        let tau = |s: &Spec| s.values(kind).map_or(f64::NAN, |v| v[1]);
        let far = grid.iter().map(|(_, s)| s).find(|s| !(1.0 / 3.0..=3.0).contains(&(tau(s) / tau(best))));
        std::iter::once(best)
            .chain(far)
            .filter_map(|start| {
                let scored = self.fit_adding(start, kind)?;
                let sse = fit::calibration_sse(self.problem, &self.model.effects, &scored.fit.spec, &mut cache)?;
                Some((sse, scored))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, scored)| scored)
    }

    /// `spec` with each run's engine start and sensor-bias start fitted to agree, when a
    /// sensor drift joins a hypothesis without one. The engine's start it grew from was
    /// fitted to the first samples with the whole reading on the engine; the bias the drift
    /// had built up since the tare is in it. A drift fitted from there finds no bias at the
    /// start and bends its time constant to build one up fast instead: a drift of 3 % and τ
    /// 20 s on a 150 s recording (a fresh campaign's case) was fitted at τ 4 s, outside the
    /// physical range, and a discrepancy on the engine was claimed in its place. The bias
    /// start is fitted under the engine start, the engine start anew under that bias, twice:
    /// every point of the start grid, and so the fit, starts from a pair that agrees.
    fn agreeing_starts(&self, mut spec: Spec, cache: &mut SimCache) -> Spec {
        for _ in 0..2 {
            spec = fit::with_bias_starts(self.problem, &self.model.effects, spec, cache);
            let Some(plant) = spec.plant(&self.model.effects) else { break };
            spec.states = self.problem.restarted(&plant, &spec.states);
        }
        spec
    }

    /// `kind` added to the effects of `current` as [`Search::try_effect`] does, and fitted
    /// the other way round when that joint fit pushes an effect already there out of its
    /// physical range or onto the edge of its fit: `kind` alone first, then each effect of
    /// `current` on top from its own start grid. An effect kept in an earlier round was
    /// fitted without `kind` and may have bent to stand in for it; started from that bent
    /// value, the joint fit can trade the two into a degenerate corner. A sensor drift kept
    /// first at 1.45 % and τ 49 s (the truth 2.5 % and 30 s, beside a gain drift of 1.2
    /// %/min) went to τ 1000 s, the edge, when the gain drift was added to it. The better
    /// scored of the two is the candidate, with a note when it is the other order. Not with
    /// the ten parameters refitted or with a discrepancy (their fits move many values).
    fn try_beside(&self, current: &Spec, kind: EffectKind, peak_hz: Option<f64>) -> (Option<Scored>, Option<String>) {
        let joint = self.try_effect(current, kind, peak_hz);
        self.other_way_round(current, kind, peak_hz, joint, false)
    }

    /// [`Search::try_beside`] given the joint fit. With `claims_only` (a pair, whose joint
    /// fit has been claimed as it is since pairs were tried), a joint fit that could be a
    /// claim is kept, and the other way round replaces it only when it could be one.
    fn other_way_round(
        &self,
        current: &Spec,
        kind: EffectKind,
        peak_hz: Option<f64>,
        joint: Option<Scored>,
        claims_only: bool,
    ) -> (Option<Scored>, Option<String>) {
        let claim = |s: &Scored| s.not_a_claim().is_none();
        let pushed = |s: &Scored| {
            let spec = &s.fit.spec;
            spec.on_edge().any(|(k, ..)| k != kind)
                || spec
                    .effects
                    .iter()
                    .any(|(k, v)| *k != kind && Effect::new(*k, v).ok().and_then(|e| e.unphysical()).is_some())
        };
        if current.effects.is_empty()
            || current.refit
            || current.has(EffectKind::Discrepancy)
            || !joint.as_ref().is_some_and(pushed)
            || (claims_only && joint.as_ref().is_some_and(claim))
        {
            return (joint, None);
        }
        let mut bare = current.clone();
        bare.effects.clear();
        let other = current.effects.iter().fold(self.try_effect(&bare, kind, peak_hz), |built, (k, _)| {
            built.and_then(|b| self.try_effect(&b.fit.spec, *k, peak_hz))
        });
        match (joint, other) {
            (Some(joint), Some(other)) if joint.score() <= other.score() => (Some(joint), None),
            (joint, Some(other)) if claims_only && !claim(&other) => (joint, None),
            (joint, None) => (joint, None),
            (_, Some(other)) => {
                (Some(other), Some(format!("fitted the other way round: {kind} first, the effects kept on top")))
            }
        }
    }

    /// The discrepancy's terms selected for the residual of `current`, fitted jointly; a
    /// term the fit leaves degenerate (its knot or time constant on the edge of its range)
    /// or not significant (its coefficient within two standard errors of zero) is dropped
    /// and the rest refitted, so that one idle term does not sink the others.
    ///
    /// A selection with a history gain whose fit loses the history (dropped, or stopped at
    /// the edge of its time constants) is fitted a second time with that gain on the other
    /// history ([`discrepancy::other_history`]), and the better scored of the two is kept
    /// (with the ten parameters as given).
    fn try_discrepancy(&self, current: &Scored) -> Option<(Scored, Vec<String>)> {
        if !self.options.candidates.contains(&EffectKind::Discrepancy) {
            return None;
        }
        let selection = discrepancy::select(self.problem, &self.model.effects, &current.fit.spec, &current.sim)?;
        let twin = discrepancy::other_history(self.problem, &current.fit.spec.params, &selection);
        let fit = |selection: discrepancy::Selection| -> Option<(Scored, Vec<String>)> {
            let mut spec = current.fit.spec.with(EffectKind::Discrepancy, selection.values);
            spec.discrepancy_free = selection.free;
            spec.discrepancy_scale = selection.scale;
            let mut fitted = self.fit_adding(&spec, EffectKind::Discrepancy)?;
            while let Some(idle) = discrepancy::idle_term(&fitted.fit) {
                let Some(without) = discrepancy::without_term(&fitted.fit.spec, idle) else { break };
                fitted = self.fit(&without)?;
            }
            Some((fitted, selection.columns))
        };
        let first = fit(selection);
        let kept = |s: &Scored| {
            let spec = &s.fit.spec;
            spec.values(EffectKind::Discrepancy)
                .is_some_and(|v| history_taus(v).next().is_some() && !history_at_its_edge(v, spec))
        };
        // (Not beside a refit of the ten parameters: each fit there moves 12-18 values, and on
        // 600 s the second took two seconds of a case's thirty.)
        let refit = current.fit.spec.refit;
        let Some(twin) = twin.filter(|_| !refit && !first.as_ref().is_some_and(|(s, _)| kept(s))) else {
            return first;
        };
        match (first, fit(twin)) {
            (Some(a), Some(b)) => Some(if b.0.score() < a.0.score() { b } else { a }),
            (a, b) => a.or(b),
        }
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
    let nominal = model.plant();
    progress("putting the recordings on the 10 ms grid, rejecting outliers, modelling the noise");
    let mut problem = Problem::new(data, &nominal, options.holdout)?;
    problem.report.notes.extend(options.notes.iter().cloned());
    let floor_n = problem.noise.mae_n;

    progress("simulating the model over the recording");
    let mut given = Spec::new(model.model, problem.given_states());
    given.history_max_s = problem.longest_run_s() / 3.0;
    let search = Search::new(&problem, model, options);
    let before = search.fit(&given).ok_or_else(|| diverged(&problem, &nominal, data))?;
    progress("analysing the residual");
    let analysis_before = residual::analyse(&problem, &before.sim);

    let Path { current, rounds, mut kept, alternative } = search_both(&search, &before, &analysis_before, progress);
    // What physics alone found, when the refit was chosen over it: a rival whatever pruning does.
    let physics_found = alternative.as_ref().map(|(physics, _)| physics.fit.spec.clone());
    let mut dropped = Vec::new();
    progress("checking that everything kept is needed");
    let mut current = prune(&search, current, &mut kept, &mut dropped);
    if let Some((physics, mut physics_kept)) = alternative.filter(|_| !current.fit.spec.refit) {
        // The refit went: the effects it was chosen with were picked beside it. Physics
        // alone, as the physics search found it, may name them better.
        let mut physics_dropped = Vec::new();
        let physics = prune(&search, physics, &mut physics_kept, &mut physics_dropped);
        if physics.score() <= current.score() {
            dropped.push(format!(
                "the refit search's effects without the refit score no better than the physics search's ({:+.1}): \
                 those are kept",
                current.score() - physics.score()
            ));
            dropped.extend(physics_dropped);
            (current, kept) = (physics, physics_kept);
        }
    }

    progress("fitting the close runners-up in place of each effect kept");
    swap_rivals(&search, &current, &rounds);
    progress("refitting a few parameters at a time, rivals of a discrepancy");
    if let Some(sparse) = sparse_refit_rivals(&search, &before, &current) {
        // "The parameters are off" found: the few that are off say it with fewer parameters
        // to pay for, when the held-out score agrees.
        if current.fit.spec.refit && current.fit.spec.effects.is_empty() && sparse.score() < current.score() {
            current = sparse;
        }
    }
    progress("trying play in the throttle path, a rival outside the catalogue");
    throttle_play_rivals(&search, &current);
    progress("trying a soak slower than the recording settles, a rival of what is kept beside a history");
    for spec in std::iter::once(&current.fit.spec).chain(physics_found.as_ref()) {
        slow_history_rivals(&search, spec, &rounds);
        history_edge_rivals(&search, spec);
        other_history_rival(&search, spec);
    }
    progress("trying a periodic disturbance, a rival that is no engine physics");
    let sine = periodic_rivals(&search, &before, &current);
    progress("weighing the rival explanations on resampled held-out data");
    let mut weighed = weigh_rivals(&search, &current, progress);
    if idle_rivals(&search, &current, &weighed) {
        weighed = weigh_rivals(&search, &current, progress);
    }
    let mut parameters_open = None;
    // A rival dominates every other explanation where the search's own pick does not: the
    // greedy order of the search is no evidence, the held-out data are. Each of its parts has
    // its look-alikes fitted in its place first: those were fitted for the search's pick, not
    // for it. (A lag and a sensor drift on 150 s, the `lag+sensor-drift-150s-p100` scenario:
    // the search arrived at a refit and an input delay; the drift in the refit's place, beside
    // the delay, led and was claimed with no lag in the delay's place weighed. Fitted, the lag
    // beside the drift leads.) A few parameters that are off are the look-alikes of a
    // discrepancy's static terms. When the look-alikes take the lead from it, the search's pick
    // is weighed anew against the grown pool and the new leader is tried the same way, a few
    // times at most.
    // Why the last leader tried was not claimed, by its label.
    let mut declined: Option<(Label, String)> = None;
    for _ in 0..LEADERS_TRIED {
        let claim = match lead(&search, &before, &current, &weighed) {
            Ok(claim) => claim,
            Err(why) => {
                declined = why.zip(weighed.leader.clone()).map(|(why, label)| (label, why));
                break;
            }
        };
        swap_rivals(&search, &claim.0, &rounds);
        sparse_refit_rivals(&search, &before, &claim.0);
        other_history_rival(&search, &claim.0.fit.spec);
        let again = weigh_rivals(&search, &claim.0, progress);
        if again.dominant {
            let name = |spec: &Spec| {
                report::label(&spec.effects.iter().map(|(k, _)| k.name()).collect::<Vec<_>>(), spec.refit)
            };
            let weight = again.rivals.iter().find(|r| r.tells_apart.is_empty()).map_or(0.0, |r| r.weight);
            dropped.push(format!(
                "the search arrived at {}, but {} beats it and every other explanation on resampled held-out data \
                 (weight {:.0} %): that one is claimed",
                name(&current.fit.spec),
                name(&claim.0.fit.spec),
                100.0 * weight
            ));
            (current, kept, weighed) = (claim.0, claim.1, again);
            parameters_open = claim.2;
            break;
        }
        let anew = weigh_rivals(&search, &current, progress);
        let same = anew.leader == weighed.leader;
        weighed = anew;
        if same {
            break;
        }
    }
    let short_of_claim = short_of_a_claim(&search, &current, &weighed, declined);
    if parameters_open.is_none() {
        parameters_open = refit_beside(&search, &current);
    }
    let mut parameter_ranges = None;
    if parameters_open.is_none() && !current.fit.spec.refit && search.options.refit {
        progress("bounding the parameters beside what is found");
        (parameter_ranges, parameters_open) = parameters_bounded(&search, &current);
    }
    progress("analysing the improved model");
    // What the explanation leaves is judged under the noise as its own second differences show
    // it: the recording's took in a little of a fast engine's transients (see
    // `Problem::with_colour_from`).
    let recoloured = problem.with_colour_from(&current.sim);
    let analysis_after = residual::analyse(recoloured.as_ref().unwrap_or(&problem), &current.sim);
    let improved = ModelFile {
        model: current.fit.spec.params,
        effects: current.fit.spec.effects_over(&model.effects).unwrap_or_else(|| model.effects.clone()),
    };
    let fit_pct =
        |sim: &Sim| crate::validate::score(problem.pairs(sim, Part::Validation)).map_or(f64::NAN, |s| s.fit_pct);
    let (mut effects, refit) = report::found(&current.fit, model, kept, &analysis_before);
    if let Some(note) = history_twin(&search, &current) {
        for e in effects.iter_mut().filter(|e| e.name == EffectKind::Discrepancy.name()) {
            e.evidence.summary = format!("{} {note}", e.evidence.summary);
        }
    }
    // Nothing explains the residual on held-out data and yet it is not white: it may be
    // noise with slow parts the second differences do not see. The residual is then the
    // best estimate of the noise; modelled on it, the case is noise only if no pattern is
    // left (tied to the throttle, the operating point, the direction of change, time).
    let (mut analysis_before, mut analysis_after, mut noise, mut floor_n) =
        (analysis_before, analysis_after, problem.report.clone(), floor_n);
    if let Some(r) = &recoloured {
        noise.notes.push(format!(
            "the residual after is judged under the noise as its own second differences show it ({}); the \
             recording's second differences, which carry the engine's fast transients too, gave {}",
            r.ar().describe(),
            problem.ar().describe()
        ));
    }
    if effects.is_empty() && refit.is_none() && !analysis_after.whiteness.white {
        if let Some(refined) = problem.with_noise_from(&current.sim) {
            let again = residual::analyse(&refined, &current.sim);
            if !again.systematic() {
                (analysis_before, analysis_after) = (residual::analyse(&refined, &before.sim), again);
                (noise, floor_n) = (refined.report.clone(), refined.noise.mae_n);
            }
        }
    }
    let no_effect = effects.is_empty();
    let mut d = Diagnosis {
        cause: Cause::None,
        effects,
        refit,
        parameters_open,
        parameter_ranges,
        mae_before_n: before.mae_val,
        mae_after_n: current.mae_val,
        noise_floor_n: floor_n,
        fit_before_pct: fit_pct(&before.sim),
        fit_after_pct: fit_pct(&current.sim),
        verdict: String::new(),
        calibration_samples: problem.n_cal,
        validation_samples: problem.n_val,
        noise,
        before: analysis_before,
        after: analysis_after,
        rounds,
        dropped,
        rivals: weighed.rivals,
        held_out_s: weighed.held_out_s,
        needed_s: weighed.needed_s,
        dominant: weighed.dominant,
        undecided: Vec::new(),
        in_play: (weighed.settled, weighed.open),
        weighed_both_ways: weighed.both_ways,
        short_of_claim,
        // "Nothing is missing" and "only the parameters are off" are claims alike: both need
        // every class of effect to have been detectable (beside the refit, for the latter).
        // Beside physics found, the same probes say what could hide next to it (a lag that
        // smooths the throttle so much that a stand resonance never rings).
        detectability: {
            progress(if no_effect {
                "asking whether this recording could have shown each class of effect"
            } else {
                "asking what could hide beside the physics found"
            });
            detect::probe_all(&problem, &model.effects, &current.fit.spec, &current.sim, options.strong_evidence)
        },
        periodic: residual::periodic(&problem, &current.sim),
        periodic_rival: sine.map(|s| residual::Periodic {
            period_s: s.period_s,
            amplitude_n: s.amplitude_n(),
            share: s.share,
        }),
        starts: problem
            .runs
            .iter()
            .zip(&current.fit.spec.states)
            .filter(|_| {
                let spec = &current.fit.spec;
                spec.fits_bias_start() || spec.fits_history_start() || spec.fits_play_start()
            })
            .map(|(run, start)| SlowStartFound {
                recording: run.series,
                from_s: run.t0_s,
                sensor_bias_n: current.fit.spec.fits_bias_start().then_some(start.slow.bias_n),
                history_offset_n: current.fit.spec.fits_history_start().then_some(start.slow.history_offset_n),
                play_position: current.fit.spec.fits_play_start().then_some(start.slow.play_position),
            })
            .collect(),
        improved,
        sim_before: problem.per_row(&before.sim),
        sim_after: problem.per_row(&current.sim),
        cut: problem.cut.clone(),
    };
    d.cause = report::cause(&d);
    if d.cause == Cause::MissingPhysics && !d.dominant {
        // A claim of what every explanation in play holds; the rest stays open.
        let (settled, open) = std::mem::take(&mut d.in_play);
        d.effects.retain(|e| settled.contains(&e.name));
        sizes_in_play(&mut d);
        if open.iter().any(|o| !o.refit) {
            d.refit = None;
        }
        // A refit among what is undecided leaves the parameters open: no range clears them.
        if open.iter().any(|o| o.refit) {
            d.parameter_ranges = None;
        }
        d.undecided = open;
    }
    d.verdict = report::verdict(&d);
    Ok(d)
}

/// The sizes a claim of what every explanation in play holds reports are the search's fit's.
/// An explanation in play may hold a claimed effect at another size: then its size is not
/// settled, and each such effect says so, naming the best-weighed explanation in play that
/// sizes it otherwise (beyond two standard errors and a tenth of its value).
///
/// Fresh seed 7919, case 143: a rate limit and a sensor drift of 4.1 % (τ 119 s), the
/// parameters exact. The limit and the drift were claimed, sized by the search's fit beside
/// a refit (the drift 1.2 %, τ 26 s), while the limit and the drift on the given
/// parameters, which led every resample, held the drift at its true size.
fn sizes_in_play(d: &mut Diagnosis) {
    for e in &mut d.effects {
        let differs = |other: &BTreeMap<&'static str, f64>| {
            e.params.iter().any(|(key, &value)| {
                let Some(&theirs) = other.get(key) else { return false };
                let gap = (value - theirs).abs();
                let error = e.uncertainty.get(key).copied().filter(|s| s.is_finite()).unwrap_or(0.0);
                gap > 2.0 * error && gap > 0.1 * value.abs().max(theirs.abs())
            })
        };
        let other = d
            .rivals
            .iter()
            .filter(|r| !r.dominated)
            .filter_map(|r| Some((r, r.fitted.as_ref()?.effects.iter().find(|x| x.name == e.name)?)))
            .filter(|(_, x)| differs(&x.params))
            .max_by(|a, b| a.0.weight.total_cmp(&b.0.weight));
        if let Some((r, x)) = other {
            let values: Vec<String> =
                x.params.iter().map(|(k, v)| format!("{k} = {}", report::significant(*v))).collect();
            e.evidence.summary = format!(
                "{} Its size is not settled: {} (weight {:.0} %), also in play, holds it at {}.",
                e.evidence.summary,
                report::label(&r.effects, r.refit),
                100.0 * r.weight,
                values.join(", ")
            );
        }
    }
}

/// Each rival of `weighed` that holds an effect at a size its fit cannot tell from zero,
/// fitted without it: the same physics with fewer parameters to pay for, weighed in its own
/// right. True when one was fitted.
///
/// A fresh campaign's case (100 s of a P100 with an input delay of 67 ms, its `K_TD` 8 % and
/// `c` 6 % off) led with the delay beside a refit of `K_TD` and `c` and a gain drift of 0.09 ±
/// 0.13 %/min: the drift was no part of it, and without the drift it had not been fitted.
fn idle_rivals(search: &Search<'_, '_>, current: &Scored, weighed: &rivals::Rivals) -> bool {
    let rows = search.entry(current).w2.len();
    let mut fitted = false;
    for r in weighed.rivals.iter().filter(|r| !r.idle.is_empty() && !r.dominated) {
        let label: Label = (r.effects.clone(), r.refit);
        let Some(spec) = search.pooled(&label, rows).and_then(|e| e.fit).map(|f| f.spec) else { continue };
        let mut without = spec;
        for kind in r.idle.iter().filter_map(|name| name.parse::<EffectKind>().ok()) {
            without = without.without(kind);
        }
        if without.effects.len() < r.effects.len() && search.fit(&without).is_some() {
            fitted = true;
        }
    }
    fitted
}

/// The rivals of `current` weighed on the held-out data ([`rivals::weigh`]), and weighed
/// again both ways round when that leaves the best-weighed explanation short of a claim.
///
/// The held-out part is a third of the data or less, and two explanations of other parts
/// (a delay against a lag) differ on it only at a few throttle steps: the leader wins 80–95
/// % of the resamples and leads by a few units, short of a claim, on recordings whose
/// calibration part holds twice as many steps that could tell. Each explanation in play is
/// then fitted again the other way round, on the held-out part, and judged on the
/// calibration part ([`Problem::reversed`]); the weights are drawn anew over both judged
/// parts together ([`rivals::both_ways`]), every sample judging a fit it played no part in.
/// The result replaces the first weighing only when it claims, and only what each way
/// round supports on its own: the explanation it claims must be the best-weighed one on the
/// held-out data, and must fit better than every rival in each of the two judged parts.
/// Never for an explanation without physics (`none` and `parameters` keep the held-out
/// test alone), nor when a rival in play (not dominated on the held-out data) is one
/// jetbench cannot fit (throttle play, a periodic force), an explanation does not simulate
/// fitted the other way round, or the claim's fit that way leaves its physical range.
fn weigh_rivals(search: &Search<'_, '_>, current: &Scored, progress: &mut dyn FnMut(&str)) -> rivals::Rivals {
    let chosen = search.entry(current);
    let once = rivals::weigh(&search.pool.borrow(), &chosen);
    let top = match once.rivals.iter().max_by(|a, b| a.weight.total_cmp(&b.weight)) {
        // A rival that leads on the held-out part alone is claimed without this ([`lead`]).
        Some(top)
            if !once.dominant && once.leader.is_none() && once.held_out_s >= once.needed_s && top.weight >= 0.5 =>
        {
            top
        }
        _ => return once,
    };
    // A rival jetbench cannot fit the other way round (throttle play, a periodic force, ...)
    // blocks the second weighing while it is in play; one the held-out data already rule out
    // does not. The same rule holds for the rivals of the claim weighed below.
    let blocks = |r: &Rival| r.unmodelled() && !r.dominated;
    if top.effects.is_empty() || once.rivals.iter().any(blocks) {
        return once;
    }
    let claimant: Label = (top.effects.clone(), top.refit);
    // The explanations in play, each as the first weighing fitted it (its entry and fit): the
    // best-weighed one and every rival it does not already dominate on the held-out data.
    let (in_play, ruled_out) = {
        let find = |label: &Label| -> Option<(Entry, Spec)> {
            if *label == chosen.label() {
                return Some((chosen.clone(), current.fit.spec.clone()));
            }
            let e = search.pooled(label, chosen.w2.len())?;
            let spec = e.fit.as_ref()?.spec.clone();
            Some((e, spec))
        };
        let Some(lead) = find(&claimant) else { return once };
        let by_lead =
            if claimant == chosen.label() { once.clone() } else { rivals::weigh(&search.pool.borrow(), &lead.0) };
        let mut in_play = vec![lead];
        let mut ruled_out = Vec::new();
        for r in by_lead.rivals.into_iter().filter(|r| (r.effects.clone(), r.refit) != claimant) {
            if r.dominated || r.unmodelled() {
                ruled_out.push(r);
                continue;
            }
            match find(&(r.effects.clone(), r.refit)) {
                Some(found) => in_play.push(found),
                None => return once,
            }
        }
        (in_play, ruled_out)
    };
    if in_play.len() < 2 || ruled_out.iter().any(blocks) {
        return once;
    }
    // A slow state (a sensor drift's bias, a heat soak's thrust history) settles over tens of
    // seconds, and the held-out part alone hardly determines it: an explanation that has one
    // where a rival has none would be judged the other way round by a poor fit of that state,
    // not by what it explains (a heat soak on 100 s, fitted on its last 30 s, predicted the
    // first 70 s 85 units worse, and a gain drift was claimed in its place). The second
    // weighing only compares explanations whose slow states agree.
    let slow = |spec: &Spec| (spec.fits_bias_start(), spec.fits_history_start());
    if in_play.iter().any(|(_, spec)| slow(spec) != slow(&in_play[0].1)) {
        return once;
    }
    // Nor a resonance in the place of a delay or a lag when its frequency is seen only through
    // its low-frequency lag: fitted on the short part, it would be judged by how poorly that
    // part pins its frequency, not by what it explains ([`rivals::LAG_LOOK_ALIKES`]). One
    // whose ringing pins its frequency is weighed both ways like any rival.
    let kinds = |spec: &Spec| spec.effects.iter().map(|(k, _)| *k).collect::<Vec<EffectKind>>();
    let lag_only = |(entry, spec): &(Entry, Spec)| {
        let Some(f) = spec.values(EffectKind::StandResonance).map(|v| v[0]) else { return false };
        let se = entry.fit.as_ref().and_then(|fit| fit.stderr.iter().find(|(k, _)| *k == EffectKind::StandResonance));
        !se.and_then(|(_, se)| se.first()).is_some_and(|se| *se <= rivals::PINNED_FREQUENCY * f)
    };
    let unpinned = in_play.iter().any(|e| {
        rivals::lag_look_alikes(&kinds(&e.1), &kinds(&in_play[0].1)) && (lag_only(e) || lag_only(&in_play[0]))
    });
    if unpinned {
        return once;
    }
    progress("fitting each explanation in play the other way round: on the held-out part, judged on the rest");
    let reversed = search.problem.reversed();
    let back = Search::new(&reversed, search.model, search.options);
    let mut crossed = Vec::with_capacity(in_play.len());
    let mut backs = Vec::with_capacity(in_play.len());
    for (entry, spec) in &in_play {
        // A rival fitted out of its physical range on the held-out part is judged with that
        // fit (it can only fit better so, and the claim must beat it all the same); the
        // claim itself must stay in range.
        match fitted_back(search, &back, &entry.label(), spec) {
            Some(judged) if !(judged.unphysical && backs.is_empty()) => {
                crossed.push(rivals::both_ways(entry, &judged));
                backs.push(judged);
            }
            _ => return once,
        }
    }
    let mut both = rivals::weigh(&crossed, &crossed[0]);
    let ahead_each_way = (1..in_play.len())
        .all(|j| rivals::compared(&in_play[0].0, &in_play[j].0) > 0.0 && rivals::compared(&backs[0], &backs[j]) > 0.0);
    if !both.dominant || !ahead_each_way {
        return once;
    }
    // Judged on the part it was not fitted on, an explanation whose value the data pin sharply
    // (a delay shifts every step) pays for that value's estimation noise more than a smooth
    // look-alike does (a lag), and can lose to it each way round while fitting every part
    // better wherever it is fitted. A delay of 73 ms on 200 s (a fresh campaign's case) was
    // fitted at 77.5 ms on one part and shorter on the other, noise each time, and a lag of
    // 77 ms was claimed; with the truth's delay the recording favours the delay by 5 units.
    // So the claim must also fit better in sample: each explanation fitted on each part and
    // judged on that part, its parameters charged.
    let in_sample = |(entry, spec): &(Entry, Spec), back: &Entry| -> Option<f64> {
        let fixed = &search.model.effects;
        let cal = fit::calibration_sse(search.problem, fixed, spec, &mut SimCache::default())?;
        let held = fit::calibration_sse(&reversed, fixed, &back.fit.as_ref()?.spec, &mut SimCache::default())?;
        let n = (entry.w2.len() + back.w2.len()) as f64;
        let score = rivals::score(cal + held, n, entry.free, 0.5 * (entry.prior + back.prior));
        score.is_finite().then_some(score)
    };
    let scores: Vec<Option<f64>> = in_play.iter().zip(&backs).map(|(once, back)| in_sample(once, back)).collect();
    let fits_best_in_sample = scores[0].is_some_and(|claim| scores[1..].iter().all(|s| s.is_none_or(|s| claim < s)));
    if !fits_best_in_sample {
        return once;
    }
    if claimant != chosen.label() {
        // The search arrived elsewhere: the best-weighed explanation leads, and is claimed
        // when it clears the search's own bars and is weighed again as the claim.
        return rivals::Rivals { leader: Some(claimant), ..once };
    }
    both.rivals.extend(ruled_out);
    (both.held_out_s, both.needed_s, both.both_ways) = (once.held_out_s, once.needed_s, Some(top.weight));
    both
}

/// Why the explanation that wins at least `1 − RIVAL_WIN_SHARE` of the resamples is not
/// claimed, when the search's explanation does not dominate: a weight of 100 % beside "the
/// recording cannot tell these apart" reads as a contradiction unless the verdict says what
/// the weight does not show. A lead the same in every block wins every resample however
/// small it is, and a claim needs a lead as large as [`rivals::DISTINCT`] (or a [`rivals::TIE`]
/// between nested explanations), or the bars [`lead`] applies (`declined`, with the label it
/// was declined for). `None` when no explanation wins that often, or the reason is not one of
/// these.
fn short_of_a_claim(
    search: &Search<'_, '_>,
    current: &Scored,
    weighed: &rivals::Rivals,
    declined: Option<(Label, String)>,
) -> Option<String> {
    if weighed.dominant {
        return None;
    }
    let top = weighed.rivals.iter().max_by(|a, b| a.weight.total_cmp(&b.weight))?;
    if top.weight < 1.0 - rivals::RIVAL_WIN_SHARE {
        return None;
    }
    let label: Label = (top.effects.clone(), top.refit);
    let chosen = search.entry(current);
    let closest = if label == chosen.label() {
        weighed.closest.clone()
    } else {
        // Its held-out innovations are all the weighing needs: a rival jetbench weighs but
        // cannot model (a zero shift of the sensor) has no fit, and may be the favourite.
        let entry = search.best_pooled(&label, chosen.w2.len(), |e| e.score, |_| true)?;
        rivals::weigh(&search.pool.borrow(), &entry).closest
    };
    let why = match closest {
        Some(c) if c.beats_share >= rivals::RIVAL_WIN_SHARE => {
            format!("{} fits better in {:.0} % of them", report::label(&c.label.0, c.label.1), 100.0 * c.beats_share)
        }
        Some(c) => {
            let rival = report::label(&c.label.0, c.label.1);
            // Between explanations of other parts the lead is the lesser of those on fit and score.
            let on = if c.on_score {
                "score, parameters charged"
            } else {
                "fit (the lesser of its leads on fit and on score)"
            };
            if c.lead <= 0.0 {
                format!("over all the held-out data {rival} is {:.1} units of {on} ahead of it", -c.lead)
            } else if c.on_score {
                format!(
                    "its lead over {rival} is consistent but small: {:.1} units of held-out {on}, where a claim needs \
                     more than {:.0}",
                    c.lead, c.needed
                )
            } else {
                // Units and ratios each compared with their own kind: a lead of 8 units (a ratio
                // of 55) short of a bar of 10 units (a ratio of 148) must not read as 55 against 10.
                format!(
                    "its lead over {rival} is consistent but small: {:.1} units of held-out {on}, a likelihood ratio \
                     of {:.0}, where a claim needs more than {:.0} units (a ratio of {:.0})",
                    c.lead,
                    (0.5 * c.lead).exp(),
                    c.needed,
                    (0.5 * c.needed).exp()
                )
            }
        }
        None => declined.filter(|(l, _)| *l == label)?.1,
    };
    Some(format!(
        "{} wins {:.0} % of the resamples but is not claimed: {why}",
        report::label(&label.0, label.1),
        100.0 * top.weight
    ))
}

/// Physics claimed on the given parameters where a refit beside the same physics fits the
/// held-out data better, its prior paid, by less than the search blames the parameters for:
/// what it gained, said beside the claim (`Diagnosis::parameters_open`). The physics is
/// claimed; that the parameters are right is not. A lag claimed on a P220 whose K_D was 11 %
/// off (a campaign's case, 300 s) took up the damping the parameters lacked, 0.53 s against
/// the engine's 0.50 s, and a refit beside it fitted the held-out data 7 units better: the
/// claim said nothing of the parameters, as if they were right. `None` when the claim refits
/// them, holds no physics, or no refit beside the same physics fits better.
fn refit_beside(search: &Search<'_, '_>, current: &Scored) -> Option<String> {
    if current.fit.spec.refit || current.fit.spec.effects.is_empty() {
        return None;
    }
    let chosen = search.entry(current);
    let refitted =
        search.best_pooled(&(chosen.effects.clone(), true), chosen.w2.len(), Entry::fit, |e| e.fit.is_some())?;
    let gain = chosen.fit() - refitted.fit();
    let which = match &refitted.refit_only {
        Some(only) => only.iter().filter_map(|&i| Params::NAMES.get(i).copied()).collect::<Vec<_>>().join(", "),
        None => "the ten parameters".to_owned(),
    };
    (gain > 0.0).then(|| {
        format!(
            "a refit of {which} beside the same physics fits the held-out data {gain:.1} units of N·ln(SSE/N) \
             better (its prior paid), not by enough to blame the parameters: whether they are off as well, this \
             recording cannot tell (re-identify them on a second recording of other steps, jetbench identify)"
        )
    })
}

/// How far the parameters could be from the given ones beside `current`, claimed on them
/// ([`ParameterRanges`]): the ten refitted beside the same physics (the pool's best such
/// refit, or one fitted now), each within [`RANGE_Z`] of its standard errors from the
/// recording alone. Where a given value lies outside its range, the recording does not clear
/// the parameters, and that is said instead (the second value, for
/// `Diagnosis::parameters_open`).
fn parameters_bounded(search: &Search<'_, '_>, current: &Scored) -> (Option<ParameterRanges>, Option<String>) {
    let chosen = search.entry(current);
    let all_ten = |e: &Entry| {
        e.refit_only.is_none() && e.fit.as_ref().is_some_and(|f| f.param_stderr_data.iter().any(|s| s.is_finite()))
    };
    let pooled =
        search.best_pooled(&(chosen.effects.clone(), true), chosen.w2.len(), Entry::fit, all_ten).and_then(|e| e.fit);
    let refit = pooled.or_else(|| {
        let mut spec = current.fit.spec.clone();
        (spec.refit, spec.refit_only) = (true, None);
        search.fit(&spec).filter(|s| s.unphysical().is_none()).map(|s| s.fit)
    });
    let Some(refit) = refit else { return (None, None) };
    let (centre, given) = (refit.spec.params.to_array(), current.fit.spec.params.to_array());
    let mut range = BTreeMap::new();
    let (mut outside, mut widths) = (Vec::new(), Vec::new());
    for (i, name) in Params::NAMES.iter().enumerate() {
        let half = RANGE_Z * refit.param_stderr_data[i];
        // A range wider than the parameter's own size bounds nothing.
        let bounded = half.is_finite() && half < given[i].abs().max(1e-9);
        let (lo, hi) = (centre[i] - half, centre[i] + half);
        range.insert(*name, if bounded { [Some(lo), Some(hi)] } else { [None, None] });
        widths.push((if bounded { half / given[i].abs().max(1e-9) } else { f64::INFINITY }, *name));
        if bounded && !(lo..=hi).contains(&given[i]) {
            outside.push(format!(
                "{name} as given ({}) lies outside {}..{}",
                report::significant(given[i]),
                report::significant(lo),
                report::significant(hi)
            ));
        }
    }
    if !outside.is_empty() {
        let open = format!(
            "beside the same physics, a refit of the ten puts {} ({RANGE_Z} standard errors either side, from this \
             recording): the parameters may be off as well (re-identify them on a second recording of other steps, \
             jetbench identify)",
            outside.join(", ")
        );
        return (None, Some(open));
    }
    widths.sort_by(|a, b| b.0.total_cmp(&a.0));
    let loose: Vec<String> = widths
        .iter()
        .filter(|(w, _)| w.is_finite() && *w >= 0.02)
        .map(|(w, n)| format!("{n} to ±{:.0} %", 100.0 * w))
        .collect();
    let alone: Vec<&str> = widths.iter().filter(|(w, _)| w.is_infinite()).map(|(_, n)| *n).collect();
    let mut said = Vec::new();
    if !loose.is_empty() {
        said.push(loose.join(", "));
    }
    if !alone.is_empty() {
        said.push(format!(
            "{} not one by one (the recording holds what they do together, not each alone)",
            alone.join(", ")
        ));
    }
    let summary = if said.is_empty() {
        "This recording bounds each of the ten parameters to within 2 % of the value given.".to_owned()
    } else {
        format!(
            "The parameters as given agree with this recording, which bounds them only so far: {} ({RANGE_Z} standard \
             errors of a refit beside the same physics). Errors within that do not show here; a recording of wider \
             and faster steps narrows them (jetbench excite).",
            said.join("; ")
        )
    };
    (Some(ParameterRanges { range, z: RANGE_Z, summary }), None)
}

/// The explanation `label` (fitted as `spec` on the calibration part) fitted by `back` (the
/// search on the parts the other way round) from where `spec` ended, its entry judged on
/// the calibration part; kept per label in `search`.
fn fitted_back(search: &Search<'_, '_>, back: &Search<'_, '_>, label: &Label, spec: &Spec) -> Option<Entry> {
    if let Some(done) = search.back.borrow().get(label) {
        return done.clone();
    }
    // With its fit: what it fits in sample (see [`weigh_rivals`]).
    let entry = back.fit(spec).map(|s| back.entry(&s)).filter(|e| e.score.is_finite());
    search.back.borrow_mut().insert(label.clone(), entry.clone());
    entry
}

/// The rival that leads (see [`rivals::leader`]), fitted, with what it keeps. `Err` when
/// no rival leads or the leader is not one the model can hold, with the bar below it fails
/// when it fails one (for the verdict: see [`short_of_a_claim`]).
///
/// A leader must also clear the bars the search's own pick cleared, so that only the greedy
/// order of the search stops deciding, never the evidence a claim needs:
/// - every part it has beyond an explanation without that part is admitted as the search
///   admits a part ([`rivals::earns`]: a practical MAE gain or strong evidence);
/// - physics with the given parameters must fit the held-out data better than the best
///   refit of the ten parameters, as in the search's choice between the two
///   ([`rivals::fits_better`]): a discrepancy that fits no better than a refit is no
///   evidence of missing physics. Unless the best refit holds the same physics, and that
///   physics earns its place beside the refit alone as the search admits a part: then the
///   physics is needed whether the parameters are off or not, and is claimed, with what
///   the refit gained said beside it (the third value): the parameters are neither
///   cleared nor blamed.
fn lead(
    search: &Search<'_, '_>,
    before: &Scored,
    current: &Scored,
    weighed: &rivals::Rivals,
) -> Result<(Scored, Vec<Kept>, Option<String>), Option<String>> {
    let (effects, refit) = weighed.leader.clone().ok_or(None)?;
    let options = search.options;
    let chosen = search.entry(current);
    let pool = search.pool.borrow();
    let best = |effects: &[&'static str], refit: bool| -> Option<&Entry> {
        if chosen.effects == effects && chosen.refit == refit {
            return Some(&chosen);
        }
        pool.iter()
            .filter(|e| e.effects == effects && e.refit == refit && !e.unphysical && e.score.is_finite())
            .min_by(|a, b| a.score.total_cmp(&b.score))
    };
    let leader = best(&effects, refit).ok_or(None)?;
    let min_gain_n = options.min_gain * search.floor_n;
    let mut open = None;
    let mut smaller: Vec<(Vec<&'static str>, bool)> = effects
        .iter()
        .filter(|e| !chosen.effects.contains(e))
        .map(|x| (effects.iter().copied().filter(|e| e != x).collect(), refit))
        .collect();
    if refit && !chosen.refit {
        smaller.push((effects.clone(), false));
    }
    for (parts, r) in &smaller {
        if let Some(without) = best(parts, *r) {
            if !rivals::earns(leader, without, options.strong_evidence, min_gain_n) {
                let part = effects.iter().find(|e| !parts.contains(e)).map_or("the refit", |e| *e);
                return Err(Some(format!(
                    "beside {}, its {part} gains {:.1} units of held-out score and {:.0} mN of validation MAE, where \
                     a part must gain {:.0} units or {:.0} mN to be admitted",
                    report::label(parts, *r),
                    without.score - leader.score,
                    1e3 * (without.mae_val_n - leader.mae_val_n),
                    options.strong_evidence,
                    1e3 * min_gain_n
                )));
            }
        }
    }
    if !refit {
        let refitted = pool
            .iter()
            .chain(std::iter::once(&chosen))
            .filter(|e| e.refit && !e.unphysical && e.score.is_finite() && e.w2.len() == leader.w2.len())
            .min_by(|a, b| {
                (a.score - a.free as f64 * (a.w2.len() as f64).ln())
                    .total_cmp(&(b.score - b.free as f64 * (b.w2.len() as f64).ln()))
            });
        if let Some(r) = refitted {
            if !rivals::fits_better(leader, r, options.ambiguity, options.significance_z) {
                let alone = best(&[], true).ok_or(None)?;
                if leader.effects.is_empty()
                    || r.effects != leader.effects
                    || !rivals::earns(r, alone, options.strong_evidence, min_gain_n)
                {
                    let (ahead, z) = rivals::refit_lead(leader, r).unwrap_or((f64::NAN, f64::NAN));
                    return Err(Some(format!(
                        "it fits the held-out data {ahead:.1} units of N·ln(SSE/N) better than {} (its prior paid), \
                         {z:.1} standard errors of the paired difference, where physics is blamed rather than the \
                         parameters only {:.0} units and {:.0} standard errors ahead",
                        report::label(&r.effects, true),
                        options.ambiguity,
                        options.significance_z
                    )));
                }
                open = Some(format!(
                    "a refit of the ten parameters with the same physics fits the held-out data {:.1} units of \
                     N·ln(SSE/N) better (its prior paid), not by the {:.0} units and {:.0} standard errors that blame \
                     the parameters; the physics is needed with the parameters refitted too (it gains {:.1} units of \
                     score over the refit alone): whether the parameters are off as well, this recording cannot tell \
                     (re-identify them on a second recording of other steps, jetbench identify)",
                    leader.fit() - r.fit(),
                    options.ambiguity,
                    options.significance_z,
                    alone.score - r.score
                ));
            }
        }
    }
    let fit = leader.fit.clone().ok_or(None)?;
    drop(pool);
    let scored = search.evaluate(fit).ok_or(None)?;
    if let Some(idle) = scored.unsupported() {
        return Err(Some(format!("fitted again as the claim, {idle}")));
    }
    let evidence = |name: &str| Evidence {
        summary: String::new(),
        mae_val_before_n: before.mae_val,
        mae_val_after_n: scored.mae_val,
        score_gain: before.score() - scored.score(),
        runner_up: None,
        ambiguous: false,
        residual: vec![format!(
            "{name}: part of the explanation that dominates every rival on resampled held-out data, where the \
             search's own pick did not"
        )],
    };
    let mut kept = Vec::new();
    if refit {
        kept.push(Kept { name: REFIT, evidence: evidence(REFIT) });
    }
    for (kind, _) in &scored.fit.spec.effects {
        kept.push(Kept { name: kind.name(), evidence: evidence(kind.name()) });
    }
    Ok((scored, kept, open))
}

fn diverged(problem: &Problem<'_>, nominal: &jetbench_model::Plant, data: &[Series]) -> IdentError {
    let mut sim = Sim::new();
    let (i, at) = problem.simulate(nominal, &problem.given_states(), false, &mut sim).err().unwrap_or((0, f64::NAN));
    IdentError::Failed(format!(
        "the model diverges on the recorded input of {} at t = {at:.2} s, so it cannot be compared with the \
         recording; identify a model that is valid over this throttle range first (jetbench identify)",
        data.get(i).map_or("the recording", |s| s.name.as_str())
    ))
}

/// A part kept: the round's evidence, and what it was.
pub(crate) struct Kept {
    pub name: &'static str,
    pub evidence: Evidence,
}

/// The result of one forward search.
struct Path {
    current: Scored,
    rounds: Vec<Round>,
    kept: Vec<Kept>,
    /// The physics search's result, when the refit search was chosen over it: if pruning
    /// later drops the refit, the two are physics alone and compete again on score.
    alternative: Option<(Scored, Vec<Kept>)>,
}

/// Both searches, and the choice between them: physics alone, against the ten
/// parameters refitted with physics on top. The refit wins when it explains the
/// held-out data as well (within [`Options::ambiguity`] of the misfit), so physics
/// is claimed only when re-identifying the parameters cannot do without it.
fn search_both(search: &Search<'_, '_>, before: &Scored, analysis: &Analysis, progress: &mut dyn FnMut(&str)) -> Path {
    let options = search.options;
    let physics = forward(search, before.clone(), analysis, &options.candidates, "physics", Vec::new(), progress);
    if !options.refit {
        return physics;
    }
    progress("refitting the ten parameters");
    let mut spec = before.fit.spec.clone();
    spec.refit = true;
    let refit = search.fit(&spec);
    let tried = vec![(REFIT, refit, None)];
    let (accepted, mut reason, candidates) = decide(search, before, &tried, "parameters");
    // When physics is claimed, the refit competes even if it does not pay for its ten
    // parameters alone: a claim must explain the data better than re-identifying would.
    let competes = accepted.is_none() && !physics.kept.is_empty();
    if competes {
        reason = format!("{reason}; the refit still competes with the physics found, on fit");
    }
    let mut rounds = physics.rounds;
    rounds.push(Round { mae_val_n: before.mae_val, candidates, accepted, reason, phase: "parameters" });
    let Some((_, Some(refit), _)) = tried.into_iter().next().filter(|_| accepted.is_some() || competes) else {
        return Path { rounds, ..physics };
    };
    // Effects worth trying on top of the refit: those that helped in any round of the
    // physics search, and those it kept (an effect may pay only once another is in: a
    // friction fitted at nothing beside the gain error it hides behind; a gain drift
    // that lost the first round to a discrepancy standing in for parameters that are off,
    // and paid once the discrepancy was in).
    let helped: Vec<EffectKind> = options
        .candidates
        .iter()
        .copied()
        .filter(|k| {
            physics.kept.iter().any(|kept| kept.name == k.name())
                || rounds
                    .iter()
                    .filter(|r| r.phase == "physics")
                    .any(|r| r.candidates.iter().any(|c| c.name == k.name() && c.score_gain.is_some_and(|g| g > 0.0)))
        })
        .collect();
    let first = Kept { name: REFIT, evidence: evidence(before, &refit, None, options, analysis.findings.clone()) };
    let refit = search.restart(refit);
    let after_refit = residual::analyse(search.problem, &refit.sim);
    let both = forward(search, refit, &after_refit, &helped, "parameters", vec![first], progress);
    rounds.extend(both.rounds);
    // Physics wins only when it fits the held-out data better by more than the ambiguity
    // and by a significant paired difference; otherwise the refit explains as well. The
    // refit is judged with what its prior charged it on the calibration part: parameters
    // far from the given ones must explain the data the better for it (a few per cent off
    // costs nothing; 30 % off in four parameters, about 36 units).
    let prior = both.current.fit.spec.prior_cost() - physics.current.fit.spec.prior_cost();
    let margin = both.current.misfit() + prior - physics.current.misfit();
    let z = search.paired_z(&physics.current, &both.current, prior);
    let choose_refit = !(margin > options.ambiguity && z >= options.significance_z);
    let named: Vec<&str> = physics.kept.iter().map(|k| k.name).collect();
    let reason = if choose_refit {
        format!(
            "the refitted parameters explain the held-out data as well as the physics found ({}): misfit {margin:+.1} \
             against it, {z:.1} standard errors of the paired difference; blame the parameters first",
            if named.is_empty() { "nothing".to_owned() } else { named.join(", ") }
        )
    } else {
        format!(
            "physics alone explains the held-out data better than any refit: misfit {margin:.1} lower, {z:.1} \
             standard errors of the paired difference"
        )
    };
    let (chosen, kept, alternative) = if choose_refit {
        (both.current, both.kept, Some((physics.current, physics.kept)))
    } else {
        (physics.current, physics.kept, None)
    };
    rounds.push(Round { mae_val_n: chosen.mae_val, candidates: Vec::new(), accepted: None, reason, phase: "choice" });
    Path { current: chosen, rounds, kept, alternative }
}

fn evidence(
    current: &Scored,
    next: &Scored,
    runner_up: Option<(&'static str, f64)>,
    options: &Options,
    residual: Vec<String>,
) -> Evidence {
    let gain = current.score() - next.score();
    Evidence {
        summary: String::new(),
        mae_val_before_n: current.mae_val,
        mae_val_after_n: next.mae_val,
        score_gain: gain,
        ambiguous: runner_up.is_some_and(|(_, g)| gain - g < options.ambiguity),
        runner_up,
        residual,
    }
}

/// A forward search from `current`: round after round, the best of `kinds` that earns
/// its place, fitted jointly with everything kept.
fn forward(
    search: &Search<'_, '_>,
    mut current: Scored,
    analysis: &Analysis,
    kinds: &[EffectKind],
    phase: &'static str,
    mut kept: Vec<Kept>,
    progress: &mut dyn FnMut(&str),
) -> Path {
    let options = search.options;
    let mut rounds = Vec::new();
    let mut residual_now = analysis.findings.clone();
    let peak = |a: &Analysis| Some(a.spectrum.peak_hz).filter(|_| a.spectrum.peak_ratio > 3.0);
    let mut peak_hz = peak(analysis);
    let mut white = analysis.whiteness.white;
    while current.fit.spec.effects.len() < options.max_effects {
        let mut tried: Vec<Tried> = Vec::new();
        let round = rounds.len() + 1;
        for &kind in kinds.iter().filter(|k| **k != EffectKind::Discrepancy) {
            if current.fit.spec.has(kind) || search.model.effects.get(kind).is_some() {
                continue;
            }
            progress(&format!("{phase} round {round}: trying {kind}"));
            let (scored, note) = search.try_beside(&current.fit.spec, kind, peak_hz);
            tried.push((kind.name(), scored, note));
        }
        if kinds.contains(&EffectKind::Discrepancy) && !current.fit.spec.has(EffectKind::Discrepancy) {
            progress(&format!("{phase} round {round}: selecting discrepancy terms"));
            match search.try_discrepancy(&current) {
                Some((s, columns)) => tried.push((EffectKind::Discrepancy.name(), Some(s), Some(columns.join(", ")))),
                None => tried.push((
                    EffectKind::Discrepancy.name(),
                    None,
                    Some("no term of the library improves the held-out fit".into()),
                )),
            }
        }
        if tried.is_empty() {
            break;
        }
        let (single, mut reason, candidates) = decide(search, &current, &tried, phase);
        let pairs = if white || current.fit.spec.effects.len() + 2 > options.max_effects {
            Vec::new()
        } else {
            pairs(search, &current, &tried, peak_hz, &mut |kind, with| {
                progress(&format!("{phase} round {round}: trying {kind} with {with}"));
            })
        };
        let (pair, pair_reason, pair_candidates) = decide(search, &current, &pairs, phase);
        let gain = |tried: &[Tried], name: Option<&str>| {
            tried
                .iter()
                .find(|(n, _, _)| Some(*n) == name)
                .and_then(|(_, s, _)| s.as_ref())
                .map_or(f64::NEG_INFINITY, |s| current.score() - s.score())
        };
        let by_pair = pair.is_some() && gain(&pairs, pair) > gain(&tried, single);
        if by_pair && single.is_some() {
            reason = format!("{reason}, but a pair of effects fitted together wins by more (the next round)");
        }
        let accepted = if by_pair { None } else { single };
        let mut runner_up = runner_up_of(&candidates, accepted);
        rounds.push(Round { mae_val_n: current.mae_val, candidates, accepted, reason, phase });
        if !pairs.is_empty() {
            let reason = match pair_candidates.iter().find(|c| pair == Some(c.name)) {
                Some(c) if by_pair => format!(
                    "{} and {} fitted together win on held-out data, where each alone fits it worse than the model \
                     without it",
                    c.with.unwrap_or_default(),
                    c.name
                ),
                Some(c) => format!(
                    "{} and {} fitted together improve the held-out fit, but by less than {} alone",
                    c.with.unwrap_or_default(),
                    c.name,
                    single.unwrap_or_default()
                ),
                None => format!(
                    "no pair of the effects the calibration part wants explains the held-out data: {pair_reason}"
                ),
            };
            let kept_pair = pair.filter(|_| by_pair);
            if by_pair {
                // The runner-up of a pair: the next pair, or the best single effect.
                runner_up = runner_up_of(&pair_candidates, kept_pair)
                    .into_iter()
                    .chain(runner_up)
                    .max_by(|a, b| a.1.total_cmp(&b.1));
            }
            rounds.push(Round {
                mae_val_n: current.mae_val,
                candidates: pair_candidates,
                accepted: kept_pair,
                reason,
                phase,
            });
        }
        let (accepted, tried) = if by_pair { (pair, pairs) } else { (single, tried) };
        let Some(name) = accepted else { break };
        let Some((_, Some(next), _)) = tried.into_iter().find(|(n, _, _)| *n == name) else { break };
        let evidence = evidence(&current, &next, runner_up, options, residual_now);
        if let Some(with) = joined(&current.fit.spec, &next.fit.spec, name) {
            kept.push(Kept { name: with.name(), evidence: evidence.clone() });
        }
        kept.push(Kept { name, evidence });
        current = search.restart(next);
        // A rate limit the part just added took to no limit both ways is gone from the
        // hypothesis ([`fit::no_limit_left`]), and from what was kept.
        if !current.fit.spec.has(EffectKind::RateLimit) {
            kept.retain(|k| k.name != EffectKind::RateLimit.name());
        }
        let analysis = residual::analyse(search.problem, &current.sim);
        peak_hz = peak(&analysis);
        white = analysis.whiteness.white;
        residual_now = analysis.findings;
    }
    Path { current, rounds, kept, alternative: None }
}

/// The best candidate of a round other than the one kept that could be a claim, and its
/// score gain.
fn runner_up_of(candidates: &[Candidate], accepted: Option<&'static str>) -> Option<(&'static str, f64)> {
    candidates
        .iter()
        .filter(|c| Some(c.name) != accepted && c.unphysical.is_none())
        .find_map(|c| c.score_gain.map(|g| (c.name, g)))
}

/// The effect `next` adds to `current` beside `name`: the other half of a pair.
fn joined(current: &Spec, next: &Spec, name: &str) -> Option<EffectKind> {
    next.effects.iter().map(|(k, _)| *k).find(|k| k.name() != name && !current.has(*k))
}

/// Most effects a round of pairs joins to the one the calibration part wants most.
const PAIR_PARTNERS: usize = 2;

/// Pairs of effects that hide each other. A forward search adds one effect at a time, and
/// each must fit the held-out data better than the model without it. Two effects can each
/// fail that and explain the recording together: a force sensor that reads high as it
/// warms and an engine that loses thrust as the run goes on pull the reading opposite
/// ways, and either alone, fitted to the calibration part, bends to imitate the other's
/// share there and misses the held-out part by more than the model as given (a drift of 2 %
/// at τ 25 s with a gain drift of 1.1 %/min on 150 s: −421 and −896 score units alone).
/// When the residual is not white and two or more effects of a round are contradicted
/// (each fits the calibration part better by at least [`Options::strong_evidence`], and
/// the held-out part worse than the model without it), the one whose fit gains most on
/// the calibration part is fitted together with each of the next [`PAIR_PARTNERS`], each
/// pair from its own grid start beside the first's fit, and the other way round when that
/// pushes the first to an edge and is no claim ([`Search::other_way_round`]): a sensor drift fitted alone at τ
/// 49 s (the truth 116 s, beside a gain drift of 0.94 %/min) went to τ 1000 s when the
/// drift was added to it, and the pair was no claim. A pair is judged as one candidate
/// would be, charged for both effects' parameters, and kept in place of the round's best
/// single effect only when it wins by more.
fn pairs(
    search: &Search<'_, '_>,
    current: &Scored,
    tried: &[Tried],
    peak_hz: Option<f64>,
    progress: &mut dyn FnMut(EffectKind, EffectKind),
) -> Vec<Tried> {
    let calibration_misfit = |s: &Scored| {
        let (sse, n) = search.problem.sse(&s.sim, Part::Calibration);
        n as f64 * (sse / n.max(1) as f64).ln()
    };
    let base = calibration_misfit(current);
    let mut wanted: Vec<(EffectKind, &Scored, f64)> = tried
        .iter()
        .filter_map(|(name, s, _)| {
            let kind = name.parse::<EffectKind>().ok().filter(|k| *k != EffectKind::Discrepancy)?;
            let s = s.as_ref().filter(|s| s.score() > current.score())?;
            Some((kind, s, base - calibration_misfit(s)))
        })
        .filter(|(_, _, gain)| *gain >= search.options.strong_evidence)
        .collect();
    if wanted.len() < 2 {
        return Vec::new();
    }
    wanted.sort_by(|a, b| b.2.total_cmp(&a.2));
    let Some(((first, first_fit, _), partners)) = wanted.split_first() else { return Vec::new() };
    partners
        .iter()
        .take(PAIR_PARTNERS)
        .map(|&(kind, _, _)| {
            progress(kind, *first);
            let joint = search.try_effect(&first_fit.fit.spec, kind, peak_hz);
            let (scored, note) = search.other_way_round(&first_fit.fit.spec, kind, peak_hz, joint, true);
            (kind.name(), scored, note)
        })
        .collect()
}

/// A hypothesis tried in a round: its name, its fit (`None`: it diverged) and a note.
type Tried = (&'static str, Option<Scored>, Option<String>);

/// Which hypothesis of a round is kept, why, and every candidate for the report.
fn decide(
    search: &Search<'_, '_>,
    current: &Scored,
    tried: &[Tried],
    phase: &'static str,
) -> (Option<&'static str>, String, Vec<Candidate>) {
    let options = search.options;
    let base = current.score();
    let base_misfit = current.misfit();
    let mut candidates: Vec<Candidate> = tried
        .iter()
        .map(|(name, s, note)| {
            let (params, uncertainty) = s.as_ref().map(|s| report::own_params(&s.fit, name)).unwrap_or_default();
            Candidate {
                name,
                with: s.as_ref().and_then(|s| joined(&current.fit.spec, &s.fit.spec, name)).map(EffectKind::name),
                params,
                uncertainty,
                mae_val_n: s.as_ref().map_or(f64::NAN, |s| s.mae_val),
                score_gain: s.as_ref().map(|s| base - s.score()),
                fit_gain: s.as_ref().map(|s| base_misfit - s.misfit()),
                parameters: s.as_ref().map_or(0, |s| s.fit.spec.free_count() - current.fit.spec.free_count()),
                unphysical: s.as_ref().and_then(Scored::not_a_claim),
                note: note.clone().or_else(|| s.is_none().then(|| "the model diverges".to_owned())),
            }
        })
        .collect();
    candidates.sort_by(|a, b| {
        b.score_gain.unwrap_or(f64::NEG_INFINITY).total_cmp(&a.score_gain.unwrap_or(f64::NEG_INFINITY))
    });
    let admissible = |c: &&Candidate| {
        c.score_gain.is_some_and(|g| g > 0.0)
            && c.unphysical.is_none()
            && (current.mae_val - c.mae_val_n >= options.min_gain * search.floor_n
                || c.score_gain.is_some_and(|g| g >= options.strong_evidence))
    };
    let (accepted, reason) = match candidates.iter().find(admissible) {
        Some(c) if phase == "parameters" && c.name == REFIT => {
            (Some(c.name), "refitting the ten parameters improves the held-out fit".to_owned())
        }
        Some(c) => (Some(c.name), format!("{} wins on held-out data", c.name)),
        None => {
            let why = candidates
                .iter()
                .find(|c| c.score_gain.is_some_and(|g| g > 0.0) && c.unphysical.is_some())
                .map_or("no hypothesis improves the held-out fit enough".to_owned(), |c| {
                    format!(
                        "{} would improve the fit only outside its physical range or at a size the data cannot \
                         tell from none ({}): evidence, not a claim",
                        c.name,
                        c.unphysical.as_deref().unwrap_or("")
                    )
                });
            (None, why)
        }
    };
    (accepted, reason, candidates)
}

/// Drops every kept effect whose size the data cannot tell from zero, then every kept part
/// whose removal does not worsen the held-out score (the whole model refitted without it),
/// one at a time, until each is needed.
fn prune(search: &Search<'_, '_>, mut current: Scored, kept: &mut Vec<Kept>, dropped: &mut Vec<String>) -> Scored {
    // An effect whose size the data cannot tell from zero goes first, whatever the score
    // says: it is no physics found. A refit or a joint fit can leave one behind that was
    // significant when it was admitted.
    while let Some((kind, key, value, error)) = fit::idle_effects(&current.fit).into_iter().next() {
        let Some(i) = kept.iter().position(|p| p.name == kind.name()) else { break };
        let Some(without) = search.fit(&current.fit.spec.without(kind)) else { break };
        kept.remove(i);
        dropped.push(format!(
            "{kind}: its size ({key} = {value:.4} ± {error:.4}) is within two standard errors of zero once the rest \
             is fitted with it: the data cannot tell it from none ({:+.1} on the held-out score without it)",
            current.score() - without.score()
        ));
        current = without;
    }
    while kept.len() > 1 {
        let base = current.score();
        let mut best: Option<(usize, Scored)> = None;
        for (i, part) in kept.iter().enumerate() {
            let spec = if part.name == REFIT {
                let mut s = current.fit.spec.clone();
                s.refit = false;
                s.params = search.model.model;
                s
            } else {
                match part.name.parse::<EffectKind>() {
                    Ok(kind) => current.fit.spec.without(kind),
                    Err(_) => continue,
                }
            };
            let Some(without) = search.fit(&spec) else { continue };
            if without.unphysical().is_some() || without.score() > base {
                continue;
            }
            if best.as_ref().is_none_or(|(_, b)| without.score() < b.score()) {
                best = Some((i, without));
            }
        }
        let Some((i, without)) = best else { break };
        let part = kept.remove(i);
        dropped.push(format!(
            "{}: the held-out score is no worse without it ({:+.1}) once the rest is refitted",
            part.name,
            base - without.score()
        ));
        current = without;
    }
    current
}

/// The parameter values of `params` by name.
pub(crate) fn named(params: &Params) -> BTreeMap<&'static str, f64> {
    Params::NAMES.iter().copied().zip(params.to_array()).collect()
}

/// A few parameters that are off, as a rival of a discrepancy's static terms: sparse refits,
/// the others and no effect as given. A static term is parameters in another form (an input
/// gain in T·Ṫ and the state's K_TD, a throttle-map hinge and B_UU), and a refit of all ten,
/// charged for the parameters the data do not ask to move, fits the held-out data worse than
/// one term: K_TD 11 % off on 150 s was claimed as the iRonCub input-gain term B_TD, 17 units
/// of fit ahead of the ten refitted; B_U 10 % low with B_T 11 % high on 100 s was claimed as
/// B_TT. Every parameter alone and the most promising pairs are fitted, and for more the
/// refit of all ten pared one parameter at a time, the one it moved least (in its own standard
/// errors) going first, down to three. Pairs are fitted outright because parameters that are
/// off together imitate each other in part: on that case B_U and B_T were each alone a poor
/// fit, adding one parameter at a time picked B_UU, K_TT and K_T, and paring the ten dropped
/// B_T at four; the pair itself fits as well as the B_TT term. Which pairs: the refit of all
/// ten says, to first order, what each of the 45 would leave ([`fit::Fit::refit_cost`]), and
/// the [`PAIRS_SCREENED`] cheapest are fitted (all 45 when that refit fails). Every fit
/// joins the weighing as `refit`; the best stands for the parameters. A discrepancy of the
/// thrust-history gain alone has a state of its own, as a drift has, and gets no such rival: a
/// constant parameter imitates it only as far as the recording is short, as it does a gain
/// drift.
///
/// A discrepancy (of any terms) or a gain drift found beside other effects is fitted the same
/// way in their company too: the other effects kept, the few parameters in the place of the
/// discrepancy and the drift. Without that, parameters that are off beside an effect had only a
/// refit of all ten beside it, or a few with no effect, as rivals, and were claimed as the
/// effect and a discrepancy (a campaign's case: a friction band of 1.5 N with B_U 9 % low and
/// K_TD 6 % high on 150 s, claimed as the friction and a hinged throttle map with B_TT). A
/// thrust-history gain much faster than the holds is a static term on them, and a drift of a
/// fraction of a per cent over the run a gain: 1.16 N of friction with K_T, K_D and B_U 5-9 %
/// off on 600 s (fresh seed 7607, case 85) was claimed as the friction beside a history gain of
/// τ 10 s or a gain drift of 0.08 %/min, the parameters not said.
fn sparse_refit_rivals(search: &Search<'_, '_>, before: &Scored, current: &Scored) -> Option<Scored> {
    if !search.options.refit {
        return None;
    }
    let history = [4, 5]; // gain_history_per_n and its time constant, in DISCREPANCY_KEYS
    let spec = &current.fit.spec;
    let has_static = spec.has(EffectKind::Discrepancy) && spec.discrepancy_free.iter().any(|i| !history.contains(i));
    // What a few parameters can stand in for beside other effects: a discrepancy of any terms
    // (a thrust-history gain faster than the holds is a static term on them) and a gain drift.
    let stand_in = |k: &EffectKind| matches!(k, EffectKind::Discrepancy | EffectKind::GainDrift);
    let others = spec.effects.iter().filter(|(k, _)| !stand_in(k)).count();
    let beside = (others > 0 && others < spec.effects.len())
        .then(|| spec.without(EffectKind::Discrepancy).without(EffectKind::GainDrift));
    let refit = |subset: Vec<usize>, from: &Spec| {
        let mut spec = from.clone();
        spec.refit = true;
        spec.refit_only = (subset.len() < Params::NAMES.len()).then_some(subset);
        search.fit(&spec)
    };
    if let Some(beside) = &beside {
        // Joins the weighing; "the parameters are off" alone is still stood for by the best
        // without effects.
        let mut company = None;
        pared_refits(&refit, beside, &mut company);
    }
    // Without effects: a static discrepancy, or a refit found (it stands for "the parameters
    // are off"; the few that are off stand for it better than all ten, which pay for every
    // parameter the data do not ask to move).
    if !(has_static || spec.refit) {
        return None;
    }
    // The best on held-out score of the sparse refits without effects, fitted once.
    if let Some(done) = search.sparse_alone.borrow().as_ref() {
        return done.clone();
    }
    let mut best = None;
    pared_refits(&refit, &before.fit.spec, &mut best);
    *search.sparse_alone.borrow_mut() = Some(best.clone());
    best
}

/// Sparse refits from `from` (see [`sparse_refit_rivals`]): every parameter alone and every
/// pair, then the refit of all ten pared one parameter at a time down to three; the best on
/// held-out score into `best`.
fn pared_refits(refit: &dyn Fn(Vec<usize>, &Spec) -> Option<Scored>, from: &Spec, best: &mut Option<Scored>) {
    let mut keep = |fitted: Option<Scored>| {
        if let Some(s) = fitted.filter(|s| best.as_ref().is_none_or(|b| s.score() < b.score())) {
            *best = Some(s);
        }
    };
    let mut subset: Vec<usize> = (0..Params::NAMES.len()).collect();
    let all = refit(subset.clone(), from);
    // Every parameter alone; the pairs screened by what the refit of all ten says each would
    // cost to first order, the cheapest fitted (all of them without that refit).
    let mut pairs: Vec<(f64, Vec<usize>)> = Vec::new();
    for i in 0..Params::NAMES.len() {
        for j in i..Params::NAMES.len() {
            if i == j {
                keep(refit(vec![i], from));
                continue;
            }
            let cost = all.as_ref().and_then(|a| a.fit.refit_cost(&[i, j])).unwrap_or(0.0);
            pairs.push((cost, vec![i, j]));
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (_, pair) in pairs.into_iter().take(if all.is_some() { PAIRS_SCREENED } else { usize::MAX }) {
        keep(refit(pair, from));
    }
    let Some(mut pared) = all else { return };
    while subset.len() > 3 {
        let (params, given) = (pared.fit.spec.params.to_array(), pared.fit.spec.given.to_array());
        let moved = |i: usize| ((params[i] - given[i]) / pared.fit.param_stderr[i]).abs();
        let Some(least) = subset.iter().copied().min_by(|&a, &b| moved(a).total_cmp(&moved(b))) else { break };
        subset.retain(|&i| i != least);
        // From the values the wider refit found, the pared parameter back as given.
        let mut start = pared.fit.spec.clone();
        let mut values = start.params.to_array();
        values[least] = given[least];
        start.params = Params::from_array(values);
        match refit(subset.clone(), &start) {
            Some(next) => {
                keep(Some(next.clone()));
                pared = next;
            }
            None => break,
        }
    }
}

/// Play (backlash) in the throttle path, outside the catalogue and the discrepancy's
/// library: the engine follows a throttle that moves only once the command has taken up
/// the play. It acts before the engine's dynamics, where bearing friction (its sensor-side
/// look-alike) acts on the reading, so it is weighed as a rival of whatever the search
/// found: the model found, with the play and without its sensor-side effects, at a few
/// widths (whichever fits best stands for it). The discrepancy's terms imitate play in part
/// (a map that shifts after a reversal, a spool-down that differs from the spool-up), fitted
/// beside the friction in its place; the play is not refitted with them, so where the model
/// found holds a discrepancy the play is also tried in place of both. It is never claimed,
/// only kept as a rival.
fn throttle_play_rivals(search: &Search<'_, '_>, current: &Scored) {
    let mut engine_side = current.fit.spec.clone();
    engine_side.effects.retain(|(k, _)| rivals::side_of(k.name()) != "sensor");
    let mut bases = vec![engine_side.clone()];
    if engine_side.has(EffectKind::Discrepancy) {
        bases.push(engine_side.without(EffectKind::Discrepancy));
    }
    let mut best: Option<Entry> = None;
    for spec in &bases {
        let Some(plant) = spec.plant(&search.model.effects) else { continue };
        for width in [0.5, 1.0, 1.5, 2.0, 3.0] {
            let mut problem = search.problem.clone();
            for run in &mut problem.runs {
                let mut held = run.u.first().copied().unwrap_or(0.0);
                for u in &mut run.u {
                    held = held.clamp(*u - width, *u + width);
                    *u = held;
                }
            }
            let states = problem.restarted(&plant, &spec.states);
            let Some(mut entry) = unclaimable_entry(&problem, &plant, spec, &states, 1, rivals::THROTTLE_PLAY) else {
                continue;
            };
            entry.values = rivals::RivalValues::of_spec(spec).map(|v| v.with_throttle_play(width));
            if best.as_ref().is_none_or(|b| entry.score < b.score) {
                best = Some(entry);
            }
        }
    }
    search.pool.borrow_mut().extend(best);
}

/// A soak slower than the recording settles, as a rival of a gain drift. A fit explores a
/// history time constant up to a third of the longest run (a longer one is seen only as a
/// ramp), so a soak slower than that is fitted as a faster history plus a gain drift for the
/// rest: a fuel soak of τ 64 s on 150 s (fresh seed 6133, case 146) was claimed as a history
/// of τ 32 s and a gain drift of 1.2 ± 0.4 %/min, the drift false. Or the history stops at that
/// edge, barred from the claim, and the drift alone is claimed: a heat soak of τ 72 s on 300 s
/// (fresh seed 3719, case 230) fitted better as a history at the edge (+535.8) than as the gain
/// drift claimed (+531.9); such a history is a runner-up of the drift like any other (within
/// [`rivals::WINDOW`] of it in the round that took the drift), barred by the edge alone. The
/// rival is the model found with the drift's place taken by the history, free to any time
/// constant; it is weighed under its own name and never claimed, for the reason a history
/// time constant is held to a third of the run: so slow a history is a ramp, and a ramp is what
/// a gain drift is.
fn slow_history_rivals(search: &Search<'_, '_>, spec: &Spec, rounds: &[Round]) {
    if !spec.has(EffectKind::GainDrift) {
        return;
    }
    let slow = match spec.values(EffectKind::Discrepancy) {
        Some(v) if history_taus(v).next().is_some() => spec.without(EffectKind::GainDrift),
        Some(_) => return,
        None if history_runner_up(rounds, spec) => {
            match history_at_edge(search, &spec.without(EffectKind::GainDrift)) {
                Some(edge) => edge,
                None => return,
            }
        }
        None => return,
    };
    freed_history_rival(search, slow);
}

/// `slow`, its discrepancy's history freed of the longest time constant a fit explores,
/// fitted and put in the pool as the unclaimable `slow_history` rival. A rival is as strong as
/// its best form: the history is started at that edge and twice as slow, on its own history
/// and on the other one (the thrust's for the throttle's, or back), and the fit that predicts
/// the held-out data best stands for all of them (the weighing keeps one entry per
/// explanation). A heat soak of τ 72 s on 150 s (fresh seed 7243, case 97) was found among the
/// runners-up on the throttle's history; freed from twice the edge, it fitted the held-out part
/// 10.1 units behind the gain drift claimed, and the drift was claimed alone. On the thrust's
/// history, the truth's, it is 5.7 units behind the drift, within what tells two explanations
/// of other parts apart, and the case is `ambiguous` between the drift and the soak.
fn freed_history_rival(search: &Search<'_, '_>, mut slow: Spec) {
    let Some(values) = slow.values(EffectKind::Discrepancy).map(<[f64]>::to_vec) else { return };
    let taus: Vec<usize> = history_taus(&values).map(|(i, _)| i).collect();
    slow.history_max_s = f64::INFINITY;
    let mut forms = Vec::new();
    for stretch in [1.0, 2.0] {
        let mut v = values.clone();
        for &i in &taus {
            v[i] *= stretch;
        }
        let form = slow.with(EffectKind::Discrepancy, v);
        // The other history, when there is one history to move.
        let other = (taus.len() == 1).then(|| on_other_history(search.problem, &form)).flatten();
        forms.push((form, 0));
        forms.extend(other.map(|o| (o, 0)));
    }
    // The history held at slower time constants, its gain fitted. A time constant longer than
    // the calibration part settles is fitted there by where the part ends, not by what the
    // engine does after: a fuel soak of τ 68 s on 100 s (fresh seed 7829, case 71), freed,
    // was fitted at τ 56 s on the first 70 s and predicted the held-out 30 s 13 units worse
    // than a gain drift, which was claimed, while the truth predicted them as well as the drift.
    // Each held time constant is charged as a value fitted, as it is chosen among a few.
    for stretch in [1.5, 2.0, 3.0] {
        let mut v = values.clone();
        for &i in &taus {
            v[i] *= stretch;
        }
        let mut form = slow.with(EffectKind::Discrepancy, v);
        form.discrepancy_free.retain(|i| !taus.contains(i));
        forms.push((form, taus.len()));
    }
    let best = forms
        .iter()
        .filter_map(|(spec, held)| {
            let fit = fit::fit(search.problem, &search.model.effects, spec)?;
            let plant = fit.spec.plant(&search.model.effects)?;
            let mut entry =
                unclaimable_entry(search.problem, &plant, &fit.spec, &fit.spec.states, *held, rivals::SLOW_HISTORY)?;
            // Never claimed, but simulated like any model: the designed experiment rebuilds
            // it from these values.
            entry.values = rivals::RivalValues::of(&fit);
            Some(entry)
        })
        .min_by(|a, b| a.fit().total_cmp(&b.fit()));
    search.pool.borrow_mut().extend(best);
}

/// A soak slower than the recording settles, as a rival of an effect kept beside a thrust
/// history: taken away, it leaves the history at the longest time constant a fit explores,
/// where no claim can be made, so the effect may be no physics of its own but what lets the
/// history off that edge. A heat soak of τ 47 s on 100 s (fresh seed 6703, case 26) fitted as
/// a history alone stopped at the edge, 33 s; bearing friction, kept first as a stand-in for the
/// soak, shrank to a band of 0.15 ± 0.05 N once the history joined it, and held the history at
/// 31 s: the friction was claimed, and the pruning could not drop it, since without it the
/// history is at the edge again. The rival is the model found with that effect taken away and
/// the history free to any time constant, weighed under its own name and never claimed, as in
/// [`slow_history_rivals`].
fn history_edge_rivals(search: &Search<'_, '_>, spec: &Spec) {
    if spec.values(EffectKind::Discrepancy).is_none_or(|v| history_taus(v).next().is_none()) {
        return;
    }
    let beside: Vec<EffectKind> = spec
        .effects
        .iter()
        .map(|(k, _)| *k)
        .filter(|k| !matches!(k, EffectKind::Discrepancy | EffectKind::GainDrift))
        .collect();
    for kind in beside {
        let Some(without) = search.fit(&spec.without(kind)) else { continue };
        if without.fit.spec.values(EffectKind::Discrepancy).is_some_and(|v| history_at_its_edge(v, spec)) {
            freed_history_rival(search, without.fit.spec);
        }
    }
}

/// True when the round that took the gain drift of `spec` (in its phase: physics alone, or
/// beside the refit) found a discrepancy whose history stopped at the longest time constant a
/// fit explores within [`rivals::WINDOW`] of the drift. Beside a refit, the round of physics
/// alone that took the drift counts too: a refit takes part of what a soak does, and the soak's
/// history beside it, held at the edge, can fall further behind the drift than alone. A fuel
/// soak of τ 54 s on 150 s (a fresh campaign's case) led the drift by 1218 units alone, its
/// history at the edge; beside the refit it was 101 units behind, and the drift with the refit
/// was claimed with no slow history weighed.
fn history_runner_up(rounds: &[Round], spec: &Spec) -> bool {
    let phase = if spec.refit { "parameters" } else { "physics" };
    rounds
        .iter()
        .filter(|r| r.phase == phase || r.phase == "physics")
        .filter(|r| r.accepted == Some(EffectKind::GainDrift.name()))
        .any(|round| history_leads_at_edge(round, spec))
}

/// [`history_runner_up`] for one round that took the drift.
fn history_leads_at_edge(round: &Round, spec: &Spec) -> bool {
    let gain = |name: &str| round.candidates.iter().find(|c| c.name == name).and_then(|c| c.score_gain);
    let (Some(drift), Some(history)) = (gain(EffectKind::GainDrift.name()), gain(EffectKind::Discrepancy.name()))
    else {
        return false;
    };
    let keys = &jetbench_model::discrepancy::DISCREPANCY_KEYS;
    let at_edge = round
        .candidates
        .iter()
        .filter(|c| c.name == EffectKind::Discrepancy.name())
        .flat_map(|c| [keys[5], keys[11]].into_iter().filter_map(|key| c.params.get(key)))
        .any(|&tau| at_history_edge(tau, spec));
    at_edge && drift - history <= rivals::WINDOW
}

/// True when a history time constant `tau` sits on the longest one a fit of `spec` explores.
fn at_history_edge(tau: f64, spec: &Spec) -> bool {
    tau >= spec.history_max_s * (1.0 - 1e-3)
}

/// The histories a discrepancy's `values` use, each as the index of its time constant and
/// its value: the thrust history's (a heat soak) when its gain is not 0, the throttle
/// history's (a fuel soak) when its gain is not 0.
fn history_taus(values: &[f64]) -> impl Iterator<Item = (usize, f64)> + '_ {
    HISTORY_GAINS.into_iter().filter(|&gain| values[gain] != 0.0).map(|gain| (gain + 1, values[gain + 1]))
}

/// True when a history of the discrepancy `values` sits on the longest time constant a fit
/// of `spec` explores.
fn history_at_its_edge(values: &[f64], spec: &Spec) -> bool {
    history_taus(values).any(|(_, tau)| at_history_edge(tau, spec))
}

/// The best-scored discrepancy of the pool fitted on `base` (its effects and its refit) with a
/// history (the thrust's or the throttle's) stopped at the longest time constant a fit explores.
fn history_at_edge(search: &Search<'_, '_>, base: &Spec) -> Option<Spec> {
    let kinds = |s: &Spec| -> Vec<EffectKind> { s.effects.iter().map(|(k, _)| *k).collect() };
    let pool = search.pool.borrow();
    pool.iter()
        .filter(|e| e.score.is_finite())
        .filter_map(|e| Some((e.score, &e.fit.as_ref()?.spec)))
        .filter(|(_, s)| {
            s.values(EffectKind::Discrepancy).is_some_and(|v| history_at_its_edge(v, s))
                && s.refit == base.refit
                && s.refit_only == base.refit_only
                && kinds(&s.without(EffectKind::Discrepancy)) == kinds(base)
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, s)| s.clone())
}

/// The rivals' view of an explanation the model cannot hold: `spec` on `plant`, simulated over
/// `problem` from `states`, named `label` beside its effects, with `extra` parameters on top of
/// the spec's own. It carries no fit, so it is weighed and never claimed.
fn unclaimable_entry(
    problem: &Problem<'_>,
    plant: &jetbench_model::Plant,
    spec: &Spec,
    states: &[problem::RunStart],
    extra: usize,
    label: &'static str,
) -> Option<Entry> {
    let mut sim = Sim::new();
    problem.simulate(plant, states, false, &mut sim).ok()?;
    let mut w = Vec::new();
    problem.innovations(&sim, Part::Validation, &mut w);
    let entry = named_entry(spec, &w, extra, problem.mae(&sim, Part::Validation), false, label);
    entry.score.is_finite().then_some(entry)
}

/// The rivals' entry of `spec` with something the model cannot hold beside it, named `label`:
/// `w` its held-out innovations, `extra` the parameters it adds to the spec's own, `mae` its
/// held-out MAE.
fn named_entry(spec: &Spec, w: &[f64], extra: usize, mae: f64, unphysical: bool, label: &'static str) -> Entry {
    let kinds: Vec<EffectKind> = spec.effects.iter().map(|(k, _)| *k).collect();
    let mut entry = rivals::entry(&kinds, spec.refit, w, spec.free_count() + extra, spec.prior_cost(), mae, unphysical);
    entry.effects.push(label);
    entry.effects.sort_unstable();
    entry
}

/// A slow periodic force on the stand (or a sensor's thermal cycle) as a rival: a sine fitted
/// to the calibration part of the residual, carried over the held-out part, on top of the
/// model as given and of the model found. Something that repeats at its own period is no
/// engine physics; a term of the model is claimed only when it explains the held-out data
/// better than the sine does (see [`report::cause`]). Returns the sine on the model found,
/// when it is weighed.
///
/// The sine is fitted with a constant beside it, and a constant alone is no periodic force:
/// the sine is weighed only where it earns its two parameters on the held-out data against
/// the same rival with the constant alone. Where it does not on the model as given, the
/// rival is that constant, a zero shift of the sensor since the tare ([`offset_rival`]); on
/// the model found, the constant beside it (friction found beside a sensor drift of 1.4 %
/// that the search did not add: with a constant beside it, the friction fits the held-out
/// part 23 units better, and the friction alone is not claimed). A sensor drift whose bias had
/// nearly settled by the held-out part was left `unexplained` on a fresh draw of 300 cases
/// (three of its six misses of a drift alone): the calibration part's mean residual carried
/// the settled bias, the "periodic" rival held it with a sine of 0.1-0.8 % of the residual's
/// variance, and tied with the drift. The constant alone fitted the held-out part 15-30
/// units better than that sine.
fn periodic_rivals(search: &Search<'_, '_>, before: &Scored, current: &Scored) -> Option<residual::Sine> {
    let problem = search.problem;
    let longest_cal = problem.runs.iter().map(|r| r.cut.min(r.y.len())).max().unwrap_or(0) as f64 * STEP_S;
    let mut found = None;
    let bases: &[&Scored] = if current.fit.spec == before.fit.spec { &[before] } else { &[before, current] };
    for (i, base) in bases.iter().enumerate() {
        let mut calibration = Vec::new();
        let residuals: Vec<Vec<f64>> = (0..problem.runs.len()).map(|r| problem.residual(r, &base.sim)).collect();
        for (run, r) in problem.runs.iter().zip(&residuals) {
            calibration.extend(
                r.iter()
                    .enumerate()
                    .take(run.cut)
                    .filter(|(_, v)| v.is_finite())
                    .map(|(k, v)| (run.t0_s + k as f64 * STEP_S, *v)),
            );
        }
        let Some(sine) = residual::fit_sine(&calibration, longest_cal) else { continue };
        let spec = &base.fit.spec;
        // What the model and `remove` (a function of time) leave, as a rival's entry.
        let leaves = |remove: &dyn Fn(f64) -> f64, extra: usize, name: &'static str| {
            let left: Vec<Vec<f64>> = problem
                .runs
                .iter()
                .zip(&residuals)
                .map(|(run, r)| r.iter().enumerate().map(|(k, v)| v - remove(run.t0_s + k as f64 * STEP_S)).collect())
                .collect();
            let mut w = Vec::new();
            problem.whiten_part(&left, Part::Validation, &mut w);
            let (mut sum, mut n) = (0.0, 0usize);
            for (run, r) in problem.runs.iter().zip(&left) {
                for v in r.iter().skip(run.cut).filter(|v| v.is_finite()) {
                    sum += v.abs();
                    n += 1;
                }
            }
            named_entry(spec, &w, extra, sum / n.max(1) as f64, base.unphysical().is_some(), name)
        };
        let periodic = leaves(&|t| sine.at(t), 3, rivals::PERIODIC);
        let mut constant = leaves(&|_| sine.mean, 1, rivals::SENSOR_OFFSET);
        constant.values = rivals::RivalValues::of_spec(spec).map(|v| v.with_reading_offset(sine.mean));
        if periodic.score < constant.score {
            if periodic.score.is_finite() {
                search.pool.borrow_mut().push(periodic);
            }
            if i == bases.len() - 1 {
                found = Some(sine);
            }
        } else if i == 0 {
            if let Some(offset) = offset_rival(search, before, current, sine.mean) {
                search.pool.borrow_mut().push(offset);
            }
        } else if constant.score.is_finite() {
            // The model found with a zero shift beside it: where the constant fits the held-out
            // data better, something slow is left that the model found does not hold.
            search.pool.borrow_mut().push(constant);
        }
    }
    found
}

/// A zero shift of the sensor as a rival: the model as given (`before`) with a constant added
/// to what is read, the reading a fixed amount off the thrust since the tare. The constant
/// starts from `guess` (the calibration part's mean residual) and is fitted on the
/// calibration part with the engine's start fitted anew under it (a start fitted to readings
/// that are off by the shift would take it up in the first seconds). Returned when it is a
/// rival of the model found: it fits the calibration part, its parameter charged, within the
/// margin the weighing gives explanations of other parts ([`rivals::DISTINCT`], or
/// [`rivals::TIE`] when the model found is the model as given) of what the model found fits
/// there.
///
/// The constant is fitted on the calibration part, so on the held-out part it predicts
/// whatever bias had settled by then, as well as a sensor drift does: judged there alone, a
/// drift whose bias builds up through the calibration part ties with a constant. The
/// calibration part tells them apart, and a constant that fits it worse is no explanation of
/// the recording. One that fits it as well (a zero shift at the tare, a drift settled before
/// the recording began) is weighed beside the rest.
fn offset_rival(search: &Search<'_, '_>, before: &Scored, current: &Scored, guess: f64) -> Option<Entry> {
    let spec = &before.fit.spec;
    let plant = spec.plant(&search.model.effects)?;
    let mut shifted = search.problem.clone();
    let (mut offset, mut sim, mut cache) = (0.0, Sim::new(), SimCache::default());
    let mut step = guess;
    for _ in 0..4 {
        offset += step;
        for (run, given) in shifted.runs.iter_mut().zip(&search.problem.runs) {
            run.y.iter_mut().zip(&given.y).for_each(|(y, g)| *y = g - offset);
        }
        let states = shifted.restarted(&plant, &spec.states);
        shifted.simulate_reusing(&plant, &states, false, &mut cache, &mut sim).ok()?;
        let (sum, n) = (0..shifted.runs.len())
            .flat_map(|r| shifted.residual(r, &sim).into_iter().take(shifted.runs[r].cut))
            .filter(|v| v.is_finite())
            .fold((0.0, 0usize), |(a, n), v| (a + v, n + 1));
        step = sum / n.max(1) as f64;
        if step.abs() < 1e-3 * shifted.noise.sigma_n {
            break;
        }
    }
    let mut w = Vec::new();
    shifted.innovations(&sim, Part::Validation, &mut w);
    let mut entry = named_entry(spec, &w, 1, shifted.mae(&sim, Part::Validation), false, rivals::SENSOR_OFFSET);
    entry.values = rivals::RivalValues::of_spec(spec).map(|v| v.with_reading_offset(offset));
    let free = entry.free;
    let (sse, n) = shifted.sse(&sim, Part::Calibration);
    let found =
        fit::calibration_sse(search.problem, &search.model.effects, &current.fit.spec, &mut SimCache::default())?;
    let n = n as f64;
    let margin = if current.fit.spec == *spec { rivals::TIE } else { rivals::DISTINCT };
    let (found_spec, constant) = (&current.fit.spec, rivals::score(sse, n, free, spec.prior_cost()));
    let behind = constant - rivals::score(found, n, found_spec.free_count(), found_spec.prior_cost());
    (entry.score.is_finite() && n > 0.0 && behind < margin).then_some(entry)
}

/// When the model found holds a discrepancy with a history gain, the same model with the
/// gain on the other history (the thrust's for the throttle's or back, [`discrepancy::history_swapped`])
/// fitted, and what that says in words: within [`rivals::DISTINCT`] of the model found, the
/// recording cannot tell a soak that follows the thrust from one that follows the throttle
/// (the two histories are one explanation to the weighing, which goes by parts); further
/// apart, which fits better. `None` without a history. The heat-soak scenario
/// (`heat-soak-p100`), found on the thrust's history, fits 10.2 units better on the
/// throttle's: the mechanism behind a soak is not what this weighs, only the fit.
fn history_twin(search: &Search<'_, '_>, current: &Scored) -> Option<String> {
    let spec = &current.fit.spec;
    let twin = on_other_history(search.problem, spec)?;
    let behind = search.fit(&twin)?.score() - current.score();
    let on_thrust = spec.values(EffectKind::Discrepancy).is_some_and(|v| v[HISTORY_GAINS[0]] != 0.0);
    let (found, other) =
        if on_thrust { ("the thrust's", "the throttle's") } else { ("the throttle's", "the thrust's") };
    Some(if behind.abs() < rivals::DISTINCT {
        format!(
            "Whether the gain follows {found} history or {other}, this recording cannot tell: on {other} history the \
             model scores {behind:+.1} on the held-out data against this one (long holds at a middle and at a high \
             throttle tell them apart: a soak of the engine's heat takes gain with the thrust held, one of the fuel's \
             with the throttle)."
        )
    } else if behind > 0.0 {
        format!(
            "On {other} history the model scores {behind:+.1} on the held-out data against this one: {found} history \
             fits better."
        )
    } else {
        format!(
            "On {other} history the model scores {behind:+.1} on the held-out data against this one: {other} history \
             fits better, though the search, from its starts, settled on {found}."
        )
    })
}

/// The discrepancy's history swapped for the other one (the thrust's for the throttle's, or
/// back) with the gain drift beside it taken away, fitted as a rival of the model found: a
/// drift can make up for a soak written on the wrong history. A heat soak of τ 58 s on 300 s (a
/// fresh campaign's case) was found on the throttle's history beside a gain drift of 0.4 %/min,
/// and both were claimed; the soak on the thrust's history alone was never fitted, so the drift
/// was never weighed against it (fitted, it scores 0.2 units behind the claim, and the case is
/// `ambiguous`). Nested in the model found, the rival holds the drift to the bar a part must
/// clear. Only where the model holds both a history and a gain drift; for the search's pick
/// and for a leader claimed in its place.
fn other_history_rival(search: &Search<'_, '_>, spec: &Spec) {
    let Some(values) = spec.values(EffectKind::Discrepancy) else { return };
    if !spec.has(EffectKind::GainDrift) || history_taus(values).next().is_none() {
        return;
    }
    let Some(twin) = on_other_history(search.problem, &spec.without(EffectKind::GainDrift)) else { return };
    // Fitted and scored, it joins the pool the weighing draws on.
    let _ = search.fit(&twin);
}

/// `spec` with its discrepancy's history gain moved to the other history, the thrust's for
/// the throttle's or back ([`discrepancy::history_swapped`]), its free values and their scales
/// moved along; `None` without a history.
fn on_other_history(problem: &Problem<'_>, spec: &Spec) -> Option<Spec> {
    let values = spec.values(EffectKind::Discrepancy)?;
    let (from, to, factor, swapped) = discrepancy::history_swapped(problem, &spec.params, values)?;
    let mut twin = spec.with(EffectKind::Discrepancy, swapped);
    discrepancy::history_free_swapped(from, to, factor, &mut twin.discrepancy_free, &mut twin.discrepancy_scale);
    Some(twin)
}

/// How many leading rivals, one after another, may be tried as the claim in place of the
/// search's pick (each with its own look-alikes fitted first).
const LEADERS_TRIED: usize = 3;

/// Pairs of parameters refitted outright among the 45 ([`pared_refits`]): those a refit of
/// all ten says, to first order, would leave the least misfit. The rest go unfitted; a pair
/// the screen puts last is one whose two parameters cannot carry what the ten moved.
pub(crate) const PAIRS_SCREENED: usize = 10;

/// The indexes of the discrepancy's history gains among its values: the thrust history's
/// (`gain_history_per_n`) and the throttle history's (`gain_throttle_history_per_pct`).
const HISTORY_GAINS: [usize; 2] = [4, 10];

/// Runners-up of each catalogue effect kept, fitted in its place with the rest of the
/// model found: the round that accepted an effect compared the others only on top of what
/// was kept before it, so an explanation such as "a delay and a gain drift" against "a lag
/// and a gain drift" would never be fitted, and the weighing could not see it. Each physical
/// candidate of that round within [`rivals::WINDOW`] score units of the effect kept is fitted
/// in its place and joins the pool (it is a rival, never a claim by itself).
///
/// Each look-alike of an effect kept ([`rivals::LOOK_ALIKES`]: a delay for a lag, a sensor
/// drift for a soak, ...) is fitted in its place whatever the round said: a claim of several
/// parts is only as sure as each part's lead over the same explanation with its look-alike in
/// its place, and that explanation must be in the weighing for the claim to be judged against
/// it. Where the claim has other parts (and keeps the given parameters), the swapped
/// explanation is also built afresh (the look-alike first, then each other part from its own
/// start grid), so that the rest of the model, fitted beside the part it replaces, does not
/// hold it in a poor local fit.
///
/// When the explanation refits the ten parameters, its physics on the given parameters is
/// fitted too, with its own runners-up and look-alikes: a search that took the refit before
/// the physics it needed never fits those, and the truth can be among them. A lag with a
/// sensor drift on 150 s was claimed as the lag, a thrust-history discrepancy in the drift's
/// place, and a refit (K_T +9 %, three standard errors, the parameters exact), while the
/// lag with the drift on the given parameters, never fitted, predicted the held-out data
/// better (validation MAE 1.991 N against 1.998 N, a white residual). Each effect a refit can
/// stand in for ([`rivals::REFIT_LOOK_ALIKES`]) is fitted in the refit's place as well: a
/// sensor drift of 1.1 % (τ 43 s) beside friction was claimed as the friction and a refit
/// (fresh seed 2851, case 145), the truth's MAE 2.168 N against the claim's 2.176 N, the drift
/// never fitted beside the friction on the given parameters.
fn swap_rivals(search: &Search<'_, '_>, current: &Scored, rounds: &[Round]) {
    swaps_of(search, &current.fit.spec, rounds);
    if current.fit.spec.refit {
        let mut physics = current.fit.spec.clone();
        physics.refit = false;
        physics.params = physics.given;
        // (Each run's start fitted anew: the refit's was fitted under other parameters.)
        if let Some(fitted) = search.fit(&physics).map(|s| search.restart(s)) {
            swaps_of(search, &fitted.fit.spec, rounds);
            // The refit in place of the slow effects it can stand in for: a sensor drift
            // settled early in the run reads as a gain the parameters can take.
            let rest: Vec<EffectKind> = fitted.fit.spec.effects.iter().map(|(k, _)| *k).collect();
            for kind in rivals::REFIT_LOOK_ALIKES.into_iter().filter(|k| !rest.contains(k)) {
                let _ = search.try_effect(&fitted.fit.spec, kind, None);
                if !rest.is_empty() && !rest.contains(&EffectKind::Discrepancy) {
                    afresh(search, &fitted.fit.spec, kind, &rest);
                }
            }
            // A slow part the refit shared its work with, fitted again on the given parameters
            // from its own start grid: beside the refit it took only what the parameters left,
            // and started from there it stays in that basin. A rate limit with a sensor drift
            // of 4.1 % (τ 119 s) on 150 s (fresh seed 7919, case 143) was claimed as the limit,
            // a drift of 1.2 % (τ 26 s) and a refit ("the parameters were off too", none of
            // them moved by three standard errors; they were exact): the drift on the given
            // parameters, fitted from the refit's values, stayed at τ 26 s, and the truth
            // was never weighed.
            for kind in rivals::REFIT_LOOK_ALIKES.into_iter().filter(|k| rest.contains(k)) {
                let _ = search.try_effect(&fitted.fit.spec.without(kind), kind, None);
            }
        }
    }
}

/// The catalogue effects the round that accepted `kind` found within [`rivals::WINDOW`] of it,
/// other than `kind`, each with whether its fit there was physical.
fn runners_up(rounds: &[Round], kind: EffectKind) -> Vec<(EffectKind, bool)> {
    let Some(round) = rounds.iter().rev().find(|r| r.accepted == Some(kind.name())) else { return Vec::new() };
    let Some(gain) = round.candidates.iter().find(|c| c.name == kind.name()).and_then(|c| c.score_gain) else {
        return Vec::new();
    };
    round
        .candidates
        .iter()
        .filter(|c| c.score_gain.is_some_and(|g| gain - g <= rivals::WINDOW))
        .filter_map(|c| Some((c.name.parse::<EffectKind>().ok()?, c.unphysical.is_none())))
        .filter(|(other, _)| *other != kind && *other != EffectKind::Discrepancy)
        .collect()
}

/// The runners-up and look-alikes of each effect of `spec`, fitted in its place (see
/// [`swap_rivals`]).
fn swaps_of(search: &Search<'_, '_>, spec: &Spec, rounds: &[Round]) {
    for (kind, _) in spec.effects.iter().filter(|(k, _)| *k != EffectKind::Discrepancy) {
        let without = spec.without(*kind);
        for (other, physical) in runners_up(rounds, *kind) {
            let alike = rivals::look_alikes(*kind).any(|k| k == other);
            if physical && !alike && !spec.has(other) {
                let _ = search.try_effect(&without, other, None);
            }
        }
    }
    let kinds: Vec<EffectKind> = spec.effects.iter().map(|(k, _)| *k).collect();
    for &kind in &kinds {
        let without = spec.without(kind);
        for other in rivals::look_alikes(kind).filter(|o| !spec.has(*o)) {
            if other == EffectKind::Discrepancy {
                // A soak stands in on either history: the one the selection did not take is
                // fitted too. One whose history stops at the longest time constant a fit
                // explores is weighed freed of it ([`freed_history_rival`]): a heat soak of
                // τ 63 s on 200 s (fresh seed 7583, case 31), on the thrust's history in a gain
                // drift's place, stopped at that edge (67 s) 4.5 units behind the drift; it
                // was barred, and the drift was claimed.
                let found = search.fit(&without).and_then(|base| search.try_discrepancy(&base)).map(|(d, _)| d);
                let twin = found.as_ref().and_then(|d| on_other_history(search.problem, &d.fit.spec));
                let twin = twin.and_then(|t| search.fit(&t));
                // Freed once, from the better of the two at the edge: it tries both histories.
                let at_edge = found.into_iter().chain(twin).filter(|soak| {
                    let spec = &soak.fit.spec;
                    spec.values(EffectKind::Discrepancy).is_some_and(|v| history_at_its_edge(v, spec))
                });
                if let Some(soak) = at_edge.min_by(|a, b| a.score().total_cmp(&b.score())) {
                    freed_history_rival(search, soak.fit.spec);
                }
                continue;
            }
            if let Some(swapped) = search.try_effect(&without, other, None) {
                // A runner-up of the part replaced may be the rest of the truth beside its
                // look-alike, though it fitted nothing physical alone: a lag of 82 ms with a
                // stand ringing at 3 Hz (ζ 0.03) passed for a delay of 81 ms at the truth's
                // MAE (fresh seed 3719, case 9), the resonance alone fitted as an overdamped
                // one (ζ 0.93) and, beside the delay, gone to 32 Hz.
                for (partner, _) in runners_up(rounds, kind) {
                    if partner != other && !swapped.fit.spec.has(partner) {
                        let _ = search.try_effect(&swapped.fit.spec, partner, None);
                    }
                }
            }
            if kind == EffectKind::Discrepancy {
                // A history gain of the discrepancy (the thrust's or the throttle's) alone
                // replaced by the sensor drift, its other terms (a throttle map's slope, ...)
                // kept: engine side against sensor side for the slow part only.
                let histories = jetbench_model::discrepancy::DISCREPANCY_TERMS.iter().copied().filter(|t| {
                    HISTORY_GAINS.contains(&t.coefficient) && spec.discrepancy_free.contains(&t.coefficient)
                });
                for partial in histories.filter_map(|t| discrepancy::without_term(spec, t)) {
                    if search.try_effect(&partial, other, None).is_some() {
                        if let Some(last) = search.pool.borrow_mut().last_mut() {
                            last.swapped = true;
                        }
                    }
                }
            }
            let rest: Vec<EffectKind> = kinds.iter().copied().filter(|k| *k != kind).collect();
            if rest.is_empty() || rest.contains(&EffectKind::Discrepancy) || spec.refit {
                // (With the ten parameters refitted each fit moves 11-16 values: the swap
                // above, started from the model found, is the one that fits in the time.)
                continue;
            }
            afresh(search, spec, other, &rest);
        }
    }
}

/// `first` alone on the parameters of `spec` (none of its effects), then each of `rest` on
/// top from its own start grid: an explanation built so that the parts fitted beside the one
/// it replaces do not hold it in a poor local fit.
fn afresh(search: &Search<'_, '_>, spec: &Spec, first: EffectKind, rest: &[EffectKind]) {
    let mut bare = spec.clone();
    bare.effects.clear();
    bare.discrepancy_free.clear();
    let Some(mut built) = search.try_effect(&bare, first, None) else { return };
    for &k in rest {
        match search.try_effect(&built.fit.spec, k, None) {
            Some(next) => built = next,
            None => break,
        }
    }
}
