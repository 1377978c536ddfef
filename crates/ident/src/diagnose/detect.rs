//! "Nothing is missing" is a claim: before the diagnosis says `none`, it asks, for every class
//! of effect it knows, whether this recording could have shown that effect at the size that
//! matters at the bench, and whether the residual carries its shape anyway.
//!
//! For a probe (an effect at a given size), the model found is simulated with and without it
//! on the recorded throttle; the difference `δ` is what the effect would add to the reading.
//! Prewhitened by the noise model over the held-out part, its energy in units of the
//! innovation variance,
//!
//! ```text
//! E = Σ (A(q)·δ)² / s²,
//! ```
//!
//! is the held-out score gain (twice a log-likelihood) that fitting the effect would bring
//! if it were there: the search keeps an effect only when its gain clears the strong-evidence
//! margin plus its BIC penalty, `T = strong_evidence + k·ln N`. So the effect **would show**
//! when `E ≥ T`; for the classes whose reading grows in proportion to their size (delay, lag,
//! drift, friction, a periodic force, approximately), the smallest size that would show is
//! `size·√(T/E)`. And the residual **carries its shape** when the matched filter
//! `z = Σ (A(q)·r)(A(q)·δ) / (s·√(Σ (A(q)·δ)²))` exceeds [`SHAPE_Z`]: under noise alone `z` is a
//! standard normal draw.
//!
//! `none` stands only when every probe would show and none is in the residual; otherwise the
//! answer is `insufficient_data`, with what could hide and the experiment that would tell.
//! Beside physics that is claimed, the same probes (of the classes the claim does not hold)
//! say in the verdict what could hide next to it: a claim names what the recording shows,
//! not that nothing else is there.
//!
//! `parameters` ("the physics is complete, only the numbers are off") is as strong a claim
//! and gets the same rule, with one difference: ten refitted parameters can mimic part of an
//! effect. So `δ` is first fitted on the calibration part by a linearised refit (the
//! output's prewhitened sensitivities to the ten parameters, with the refit's prior), and
//! only what the refit could not absorb counts, on the held-out part, in `E` and `z`.
//! The probes' sizes are what matters at a 100 Hz bench, independent of any recording (see
//! [`probes`]).

use std::collections::BTreeMap;

use jetbench_model::discrepancy::DISCREPANCY_DEFAULTS;
use jetbench_model::{EffectKind, Effects, STEP_S};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::fit::{Spec, REFIT_PRIOR};
use super::problem::{Part, Problem, Sim};

/// Matched-filter statistic above which the residual carries a probe's shape: about one in
/// 30 000 under noise alone, for each of the couple of dozen probes.
pub const SHAPE_Z: f64 = 4.0;

/// One class of effect at the size that matters: whether this recording would show it.
#[derive(Clone, Debug, Serialize)]
pub struct Detectability {
    /// The class (a catalogue name, or `periodic` for a force at its own period).
    pub effect: &'static str,
    /// The probe: its values by key (an object in the JSON).
    pub probe: BTreeMap<&'static str, f64>,
    /// What it means in words (`a delay of 20 ms`).
    pub size: String,
    /// Energy of its prewhitened reading over the held-out part, innovation variances.
    pub energy: f64,
    /// Energy the search needs to keep it.
    pub threshold: f64,
    /// `energy ≥ threshold`: this recording would show it.
    pub would_show: bool,
    /// Matched-filter statistic of the residual against its shape.
    pub shape_z: f64,
    /// The smallest size of this probe's kind this recording would show (proportional
    /// classes only), in the probe's first key.
    pub smallest: Option<f64>,
    /// What would show it, when this recording does not.
    pub experiment: &'static str,
    /// When it would not show: every effect of this class whose values lie in these ranges
    /// (by key, `[low, high]`, `None` for no bound) is no more visible here than the probe,
    /// so it could hide too (see [`could_hide`]). `None` when the probe would show.
    pub could_hide: Option<BTreeMap<&'static str, [Option<f64>; 2]>>,
    /// A stand resonance at another damping than the size that matters (ζ 0.1), listed because
    /// the probe at ζ 0.1 would show and this one would not: it says what could hide beside a
    /// claim, and does not count for `none` or `parameters`, which ask for the size that matters.
    pub disclosure_only: bool,
}

/// Dampings at which a hidden stand-resonance probe is measured again, to bound the dampings
/// that could hide with it (the catalogue's range is 0.005-0.3). The steps are small where a
/// resonance's reading changes fastest with ζ (it grows about as ζ² below the resonance), so
/// that the bound between two of them ([`hidden_dampings`]) is not much above either.
const DAMPINGS: [f64; 13] = [0.005, 0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.125, 0.15, 0.175, 0.2, 0.25, 0.3];

/// The range of [`DAMPINGS`] (first and last index) around `home` over which a resonance is
/// no more visible than `threshold`, from the energies measured at each damping.
///
/// At one frequency each spectral component of the reading a resonance adds,
/// `|H(jω) − 1|²·|T(jω)|²`, is monotonic in ζ² (a ratio of two functions linear in ζ²), so
/// anywhere between two measured dampings `a < b` it is at most the larger of its values at
/// `a` and `b`, and the energy at most `E(a) + E(b)`. A stretch between two neighbouring
/// dampings could hide when some pair of measured dampings around it (not only its own two
/// ends) sums below the threshold, and no damping measured between them would show (which
/// the bound says cannot happen: a recording where it does is not trusted with the bound);
/// the range grows from `home` over such stretches.
fn hidden_dampings(energies: &[f64], home: usize, threshold: f64) -> (usize, usize) {
    let bracket =
        |i: usize, j: usize| energies[i] + energies[j] < threshold && energies[i..=j].iter().all(|e| *e < threshold);
    let covered = |k: usize| (0..=k).any(|i| (k + 1..energies.len()).any(|j| bracket(i, j)));
    let (mut lo, mut hi) = (home, home);
    while lo > 0 && covered(lo - 1) {
        lo -= 1;
    }
    while hi + 1 < energies.len() && covered(hi) {
        hi += 1;
    }
    (lo, hi)
}

/// The values of a hidden probe's class that are no more visible than the probe, per key.
///
/// For every class but the resonance, the reading an effect adds grows with one size in one
/// direction, the others held: a longer delay or lag, a larger drift gain, gain drift,
/// friction band or periodic amplitude, a lower rate limit, a deeper soak all add more.
/// Values on the less visible side of the probe could hide. A time constant or a period is
/// not ordered that way (a slower drift is smaller at first and larger later): it is
/// pinned to the probe's value.
///
/// The resonance is handled in [`probe_all`]: its damping is not ordered (a light damping
/// rings more after a step, a heavy one lags more behind a ramp), so the dampings that could
/// hide are measured, and its frequency is bounded by the probes above it.
fn could_hide(kind: EffectKind, v: &[f64]) -> BTreeMap<&'static str, [Option<f64>; 2]> {
    let up_to = |x: f64| [Some(0.0), Some(x)];
    let at = |x: f64| [Some(x), Some(x)];
    match kind {
        EffectKind::InputDelay => BTreeMap::from([("delay_s", up_to(v[0]))]),
        EffectKind::ActuatorLag => BTreeMap::from([("time_constant_s", up_to(v[0]))]),
        EffectKind::RateLimit => {
            BTreeMap::from([("up_pct_per_s", [Some(v[0]), None]), ("down_pct_per_s", [Some(v[1]), None])])
        }
        EffectKind::SensorDrift => BTreeMap::from([("gain", up_to(v[0])), ("time_constant_s", at(v[1]))]),
        EffectKind::GainDrift => BTreeMap::from([("per_minute", up_to(v[0]))]),
        EffectKind::BearingFriction => BTreeMap::from([("force_n", up_to(v[0]))]),
        EffectKind::StandResonance => BTreeMap::from([("frequency_hz", at(v[0])), ("damping_ratio", at(v[1]))]),
        EffectKind::Discrepancy => {
            BTreeMap::from([("gain_history_per_n", [Some(v[4]), Some(0.0)]), ("history_time_constant_s", at(v[5]))])
        }
    }
}

/// The probes: each class at the size that matters at a 100 Hz thrust bench.
///
/// - a delay of 20 ms (two control cycles: a controller's phase budget at its bandwidth);
/// - a lag of 50 ms (five cycles);
/// - a rate limit of 100 %/s (a 10 % step that takes 0.1 s);
/// - a sensor drift of 2 % of thrust with a 60 s time constant;
/// - a gain drift of 0.5 %/min (5 % over a ten-minute run);
/// - a friction band of 0.5 N;
/// - a stand resonance at 0.5–8 Hz with damping 0.1 (the band the engine's thrust has power
///   in; above it the engine cannot ring the stand);
/// - a periodic force of 1 N at a period of 30 s;
/// - an engine gain that follows the thrust history (a heat soak, the discrepancy
///   library's history term): 2 % less thrust per throttle after a long hold at full thrust
///   (`full_thrust_n`, the model's highest thrust over the recording), time constant 60 s.
fn probes(full_thrust_n: f64) -> Vec<(EffectKind, Vec<f64>, bool)> {
    let mut soak = DISCREPANCY_DEFAULTS.to_vec();
    soak[4] = -SOAK_LOSS / full_thrust_n.max(1.0);
    soak[5] = 60.0;
    let mut out = vec![
        (EffectKind::InputDelay, vec![0.02], true),
        (EffectKind::ActuatorLag, vec![0.05], true),
        (EffectKind::RateLimit, vec![100.0, 100.0], false),
        (EffectKind::SensorDrift, vec![0.02, 60.0], true),
        (EffectKind::GainDrift, vec![0.005], true),
        (EffectKind::BearingFriction, vec![0.5], true),
    ];
    for f in [0.5, 1.0, 2.0, 3.0, 5.0, 8.0] {
        out.push((EffectKind::StandResonance, vec![f, 0.1], false));
    }
    out.push((EffectKind::Discrepancy, soak, true));
    out
}

/// The class name of the thrust-history gain probe (a heat or fuel soak).
pub const GAIN_HISTORY: &str = "gain_history";
/// Its size: the share of the engine's gain lost after a long hold at full thrust.
const SOAK_LOSS: f64 = 0.02;

fn experiment_for(effect: &str) -> &'static str {
    match effect {
        "input_delay" | "actuator_lag" => {
            "throttle steps of 10-30 % both ways, each held a few seconds (jetbench excite): a delay or a lag \
             shows at every step"
        }
        "rate_limit" => "large fast steps (30 % and more, in one cycle): a rate limit binds only on those",
        "sensor_drift" => {
            "a long high-thrust hold (a minute or more) followed by an idle hold: a drifting sensor decays there \
             with its time constant"
        }
        "gain_drift" => "a longer run (ten minutes or more) with the same steps early and late",
        "bearing_friction" => "many small reversals of the throttle: friction shifts the reading after each",
        "stand_resonance" => "sharp throttle steps (in one cycle): a resonance rings after them",
        "periodic" => "constant-throttle holds of several periods: a periodic force is still there",
        GAIN_HISTORY => {
            "the same throttle steps before and after a long full-thrust hold (a minute or more), then after an idle \
             hold: a soaked engine gives less thrust after the hold and recovers at idle, where parameters that are \
             off act the same throughout"
        }
        _ => "a longer, richer campaign (jetbench excite)",
    }
}

fn describe(kind: EffectKind, v: &[f64], full_thrust_n: f64) -> String {
    match kind {
        EffectKind::InputDelay => format!("a delay of {:.0} ms", v[0] * 1000.0),
        EffectKind::ActuatorLag => format!("a lag of {:.0} ms", v[0] * 1000.0),
        EffectKind::RateLimit => format!("a rate limit of {:.0} %/s", v[0]),
        EffectKind::SensorDrift => format!("a sensor drift of {:.0} % of thrust (τ {:.0} s)", v[0] * 100.0, v[1]),
        EffectKind::GainDrift => format!("a gain drift of {:.1} %/min", v[0] * 100.0),
        EffectKind::BearingFriction => format!("a friction band of {:.1} N", v[0]),
        EffectKind::StandResonance => format!("a stand resonance at {:.1} Hz (ζ {:.2})", v[0], v[1]),
        EffectKind::Discrepancy => format!(
            "an engine gain following the thrust history of {:.1} % at {:.0} N (τ {:.0} s, a heat soak)",
            -100.0 * v[4] * full_thrust_n,
            full_thrust_n,
            v[5]
        ),
    }
}

/// Prewhitened values of grid vectors (each one vector per run, NaN where there is no
/// sample) at the samples of `part` where every one of them has an innovation, in a fixed
/// order: `out[v]` belongs to `vectors[v]`.
fn aligned(problem: &Problem<'_>, vectors: &[&[Vec<f64>]], part: Part) -> Vec<Vec<f64>> {
    let mut out = vec![Vec::new(); vectors.len()];
    for (i, run) in problem.runs.iter().enumerate() {
        // Where the recording has no sample, neither has an effect's reading.
        let white: Vec<Vec<f64>> = vectors
            .iter()
            .map(|v| {
                let masked: Vec<f64> =
                    v[i].iter().zip(&run.y).map(|(d, y)| if y.is_finite() { *d } else { f64::NAN }).collect();
                problem.whiten(i, &masked)
            })
            .collect();
        let len = white.iter().map(Vec::len).min().unwrap_or(0);
        for j in (0..len).filter(|j| run.in_part(j * run.stride, part)) {
            if white.iter().all(|w| w[j].is_finite()) {
                for (o, w) in out.iter_mut().zip(&white) {
                    o.push(w[j]);
                }
            }
        }
    }
    out
}

/// What a refit of the ten parameters absorbs of an effect: the model's output
/// sensitivities to each parameter (prewhitened, on the calibration and the held-out part)
/// and the refit's prior. An effect the refitted parameters can mimic on the calibration
/// part leaves, on the held-out part, only what they could not: that is what would tell
/// it from "the parameters are off".
struct Refit {
    /// Sensitivity of the reading to each of the ten parameters, per unit of the parameter,
    /// as grid vectors per run.
    columns: Vec<Vec<Vec<f64>>>,
    /// The prior's weight on each parameter, in innovation variances per unit².
    prior: Vec<f64>,
}

impl Refit {
    fn new(problem: &Problem<'_>, fixed: &Effects, spec: &Spec, sim: &Sim, s2: f64) -> Option<Self> {
        let mut columns = Vec::with_capacity(10);
        let mut prior = Vec::with_capacity(10);
        let mut moved = Sim::new();
        for i in 0..10 {
            let unit = spec.param_unit(i);
            let h = 1e-3 * unit;
            let mut a = spec.params.to_array();
            a[i] += h;
            let mut next = spec.clone();
            next.params = jetbench_model::Params::from_array(a);
            let plant = next.plant(fixed)?;
            let column: Vec<Vec<f64>> = if problem.simulate(&plant, &spec.states, false, &mut moved).is_ok() {
                moved.iter().zip(sim).map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y) / h).collect()).collect()
            } else {
                // The model diverges just beside the point: that direction absorbs nothing.
                sim.iter().map(|run| vec![0.0; run.len()]).collect()
            };
            columns.push(column);
            prior.push(s2 / (REFIT_PRIOR * unit).powi(2));
        }
        Some(Self { columns, prior })
    }

    /// `delta`'s held-out part once the refit has absorbed what it can of it on the
    /// calibration part (a linearised fit with the refit's prior), and the residual's
    /// held-out part on the same samples.
    fn remainder(&self, problem: &Problem<'_>, delta: &[Vec<f64>], residual: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
        let mut vectors: Vec<&[Vec<f64>]> = vec![delta, residual];
        vectors.extend(self.columns.iter().map(Vec::as_slice));
        let cal = aligned(problem, &vectors, Part::Calibration);
        let mut val = aligned(problem, &vectors, Part::Validation);
        let k = self.columns.len();
        let mut a = DMatrix::<f64>::zeros(k, k);
        let mut b = DVector::<f64>::zeros(k);
        for p in 0..k {
            b[p] = cal[2 + p].iter().zip(&cal[0]).map(|(x, d)| x * d).sum();
            for q in p..k {
                let v: f64 = cal[2 + p].iter().zip(&cal[2 + q]).map(|(x, y)| x * y).sum();
                a[(p, q)] = v;
                a[(q, p)] = v;
            }
            a[(p, p)] += self.prior[p];
        }
        let theta = a.cholesky().map_or_else(|| DVector::zeros(k), |c| c.solve(&b));
        let mut left = std::mem::take(&mut val[0]);
        for (p, t) in theta.iter().enumerate() {
            for (l, x) in left.iter_mut().zip(&val[2 + p]) {
                *l -= t * x;
            }
        }
        (left, std::mem::take(&mut val[1]))
    }
}

/// Energy (innovation variances) and matched-filter statistic of a prewhitened reading
/// difference `wd` against the prewhitened residual `wr` on the same samples.
fn measure(wd: &[f64], wr: &[f64], s2: f64) -> (f64, f64) {
    let e: f64 = wd.iter().map(|a| a * a).sum();
    let dot: f64 = wd.iter().zip(wr).map(|(a, b)| a * b).sum();
    if s2 <= 0.0 || e <= 0.0 {
        return (0.0, 0.0);
    }
    (e / s2, dot / (s2.sqrt() * e.sqrt()))
}

/// Every probe on the model found (`spec`, simulated as `sim`): whether this recording would
/// show it, and whether its residual carries its shape. When the model found refits the ten
/// parameters, a probe is measured by what the refit could not absorb of it (a linearised
/// refit on the calibration part, with its prior): "the parameters are off" is claimed only
/// when every class of effect would have shown beside a refit.
pub(crate) fn probe_all(
    problem: &Problem<'_>,
    fixed: &Effects,
    spec: &Spec,
    sim: &Sim,
    strong_evidence: f64,
) -> Vec<Detectability> {
    let residual: Vec<Vec<f64>> = (0..problem.runs.len()).map(|i| problem.residual(i, sim)).collect();
    let mut w = Vec::new();
    problem.whiten_part(&residual, Part::Validation, &mut w);
    let n = w.len();
    if n < 2 {
        return Vec::new();
    }
    let s2 = w.iter().map(|x| x * x).sum::<f64>() / n as f64;
    let ln_n = (n as f64).ln();
    let refit = if spec.refit { Refit::new(problem, fixed, spec, sim, s2) } else { None };
    let held_out = |delta: &[Vec<f64>]| -> (f64, f64) {
        let (wd, wr) = match &refit {
            Some(r) => r.remainder(problem, delta, &residual),
            None => {
                let mut both = aligned(problem, &[delta, residual.as_slice()], Part::Validation);
                let wr = both.pop().unwrap_or_default();
                (both.pop().unwrap_or_default(), wr)
            }
        };
        measure(&wd, &wr, s2)
    };
    let full_thrust = sim.iter().flatten().copied().filter(|v| v.is_finite()).fold(0.0f64, f64::max);
    let mut with = Sim::new();
    // Energy and matched-filter statistic of one probe on the model found.
    let mut probe = |kind: EffectKind, values: &[f64]| -> Option<(f64, f64)> {
        let plant = spec.with(kind, values.to_vec()).plant(fixed)?;
        problem.simulate(&plant, &spec.states, false, &mut with).ok()?;
        let delta: Vec<Vec<f64>> =
            with.iter().zip(sim).map(|(a, b)| a.iter().zip(b).map(|(x, y)| x - y).collect()).collect();
        Some(held_out(&delta))
    };
    let mut out = Vec::new();
    for (kind, values, proportional) in probes(full_thrust) {
        if spec.has(kind) || fixed.get(kind).is_some() {
            continue;
        }
        let Some((energy, shape_z)) = probe(kind, &values) else { continue };
        let (effect, free, first) = if kind == EffectKind::Discrepancy {
            // The thrust-history gain: its coefficient and its time constant.
            (GAIN_HISTORY, 2, values[4])
        } else {
            (kind.name(), kind.keys().len(), values[0])
        };
        let threshold = strong_evidence + free as f64 * ln_n;
        let would_show = energy >= threshold;
        let mut hide = (!would_show).then(|| could_hide(kind, &values));
        // A resonance is measured at every damping of [`DAMPINGS`]: its damping is not
        // ordered, so the probe at ζ 0.1 says nothing of a lighter or heavier one.
        let dampings: Vec<(f64, f64)> = if kind == EffectKind::StandResonance {
            DAMPINGS
                .iter()
                .map(|&z| {
                    if (z - values[1]).abs() < 1e-12 {
                        (energy, shape_z)
                    } else {
                        probe(kind, &[values[0], z]).unwrap_or((f64::INFINITY, 0.0))
                    }
                })
                .collect()
        } else {
            Vec::new()
        };
        let energies: Vec<f64> = dampings.iter().map(|d| d.0).collect();
        if let (Some(region), EffectKind::StandResonance) = (hide.as_mut(), kind) {
            // The dampings that could hide at this frequency (see [`hidden_dampings`]).
            let home = DAMPINGS.iter().position(|&z| (z - values[1]).abs() < 1e-12).unwrap_or(0);
            let (lo, hi) = hidden_dampings(&energies, home, threshold);
            region.insert("damping_ratio", [Some(DAMPINGS[lo]), Some(DAMPINGS[hi])]);
        }
        out.push(Detectability {
            effect,
            probe: if kind == EffectKind::Discrepancy {
                BTreeMap::from([("gain_history_per_n", values[4]), ("history_time_constant_s", values[5])])
            } else {
                kind.keys().iter().copied().zip(values.iter().copied()).collect()
            },
            size: describe(kind, &values, full_thrust),
            energy,
            threshold,
            would_show,
            shape_z,
            smallest: (proportional && energy > 0.0).then(|| first * (threshold / energy).sqrt()),
            experiment: experiment_for(effect),
            could_hide: hide,
            disclosure_only: false,
        });
        // The probe at ζ 0.1 would show, but a lighter or heavier resonance at this frequency
        // may not (a lightly damped one adds little below its frequency when the engine's
        // thrust has no power near it): the least visible damping measured, with the range
        // around it that could hide, is disclosed beside a claim.
        let least = (0..energies.len()).min_by(|a, b| energies[*a].total_cmp(&energies[*b]));
        // Only beside physics found: `none` and `parameters` ask for the size that matters.
        let beside_physics = !spec.effects.is_empty();
        if let Some(home) = least.filter(|&h| beside_physics && would_show && energies[h] < threshold) {
            let (lo, hi) = hidden_dampings(&energies, home, threshold);
            let at = [values[0], DAMPINGS[home]];
            let mut region = could_hide(kind, &at);
            region.insert("damping_ratio", [Some(DAMPINGS[lo]), Some(DAMPINGS[hi])]);
            out.push(Detectability {
                effect,
                probe: kind.keys().iter().copied().zip(at).collect(),
                size: describe(kind, &at, full_thrust),
                energy: energies[home],
                threshold,
                would_show: false,
                shape_z: dampings[home].1,
                smallest: None,
                experiment: experiment_for(effect),
                could_hide: Some(region),
                disclosure_only: true,
            });
        }
    }
    resonance_bands(&mut out);
    // A periodic force of 1 N at a period of 30 s (a sine and a cosine: its phase is free).
    let period_s = 30.0;
    let (mut energy, mut shape_z) = (f64::INFINITY, 0.0f64);
    for phase in [0.0, std::f64::consts::FRAC_PI_2] {
        let delta: Vec<Vec<f64>> = problem
            .runs
            .iter()
            .map(|run| {
                (0..run.y.len())
                    .map(|k| (std::f64::consts::TAU * (run.t0_s + k as f64 * STEP_S) / period_s + phase).sin())
                    .collect()
            })
            .collect();
        let (e, z) = held_out(&delta);
        energy = energy.min(e);
        shape_z = shape_z.max(z.abs());
    }
    let threshold = strong_evidence + 3.0 * ln_n;
    out.push(Detectability {
        effect: super::rivals::PERIODIC,
        probe: BTreeMap::from([("amplitude_n", 1.0), ("period_s", period_s)]),
        size: format!("a periodic force of 1 N at {period_s:.0} s"),
        energy,
        threshold,
        would_show: energy >= threshold,
        shape_z,
        smallest: (energy > 0.0 && energy.is_finite()).then(|| (threshold / energy).sqrt()),
        experiment: experiment_for(super::rivals::PERIODIC),
        could_hide: (energy < threshold)
            .then(|| BTreeMap::from([("amplitude_n", [Some(0.0), Some(1.0)]), ("period_s", [Some(period_s); 2])])),
        disclosure_only: false,
    });
    out
}

/// The frequencies that could hide, for each hidden stand-resonance probe: from its own up to
/// the next probe frequency when a probe there is hidden too (at ζ 0.1, or at the least
/// visible damping where ζ 0.1 shows; over the dampings both hide at), or its own alone. Between two probe frequencies a resonance picks up the thrust's power near
/// its own frequency, which varies smoothly with frequency (throttle steps through the
/// engine's low-pass): one there is no more visible than at the two probes beside it, both
/// measured hidden. Above the highest probe nothing is said.
fn resonance_bands(out: &mut [Detectability]) {
    let dampings = |p: &Detectability| match p.could_hide.as_ref().and_then(|r| r.get("damping_ratio")) {
        Some([Some(lo), Some(hi)]) => Some((*lo, *hi)),
        _ => None,
    };
    let resonance = |p: &&Detectability| p.effect == "stand_resonance";
    let mut frequencies: Vec<f64> =
        out.iter().filter(resonance).filter_map(|p| p.probe.get("frequency_hz").copied()).collect();
    frequencies.sort_by(f64::total_cmp);
    // Every hidden resonance probe (at ζ 0.1, or at the damping least visible where that one
    // shows): its index, frequency and dampings that could hide.
    let hidden: Vec<(usize, f64, f64, f64)> = out
        .iter()
        .enumerate()
        .filter(|(_, p)| resonance(p))
        .filter_map(|(i, p)| {
            let (lo, hi) = dampings(p)?;
            Some((i, *p.probe.get("frequency_hz")?, lo, hi))
        })
        .collect();
    for &(i, f, lo, hi) in &hidden {
        let Some(next) = frequencies.iter().copied().find(|&g| g > f) else { continue };
        // The widest overlap with a hidden probe at the next frequency.
        let band = hidden
            .iter()
            .filter(|h| h.1 == next)
            .map(|h| (lo.max(h.2), hi.min(h.3)))
            .filter(|(a, b)| a <= b)
            .max_by(|a, b| (a.1 - a.0).total_cmp(&(b.1 - b.0)));
        let (Some((a, b)), Some(region)) = (band, out[i].could_hide.as_mut()) else { continue };
        region.insert("frequency_hz", [Some(f), Some(next)]);
        region.insert("damping_ratio", [Some(a), Some(b)]);
    }
}

/// True when every probe would show and none is in the residual: `none` may stand.
pub fn excluded(probes: &[Detectability]) -> bool {
    let at_size = || probes.iter().filter(|p| !p.disclosure_only);
    at_size().next().is_some() && at_size().all(|p| p.would_show && p.shape_z < SHAPE_Z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidden_dampings_use_any_bracket_around_a_stretch() {
        // Neighbours 2 and 3 sum to 53, above the threshold of 50, but the dampings 0 and 3
        // around that stretch sum to 30: between them every component is at most the larger
        // of its two values, so the stretch could hide.
        assert_eq!(hidden_dampings(&[5.0, 10.0, 28.0, 25.0, 60.0], 3, 50.0), (0, 3));
        // A damping measured visible stops the range, whatever a bracket around it says.
        assert_eq!(hidden_dampings(&[5.0, 60.0, 5.0], 0, 50.0), (0, 0));
        assert_eq!(hidden_dampings(&[5.0, 30.0, 30.0], 0, 50.0), (0, 2));
    }

    fn resonance(frequency_hz: f64, damping: f64, hide: Option<(f64, f64)>) -> Detectability {
        Detectability {
            effect: "stand_resonance",
            probe: BTreeMap::from([("frequency_hz", frequency_hz), ("damping_ratio", damping)]),
            size: String::new(),
            energy: 0.0,
            threshold: 1.0,
            would_show: hide.is_none(),
            shape_z: 0.0,
            smallest: None,
            experiment: "",
            could_hide: hide.map(|(lo, hi)| {
                BTreeMap::from([("frequency_hz", [Some(frequency_hz); 2]), ("damping_ratio", [Some(lo), Some(hi)])])
            }),
            disclosure_only: damping != 0.1,
        }
    }

    #[test]
    fn a_light_resonance_hidden_where_the_probe_shows_joins_the_band_above() {
        // At 2 Hz the probe at ζ 0.1 shows, but ζ 0.005-0.035 hides; at 3 Hz ζ 0.005-0.1 hides.
        let mut out = vec![
            resonance(2.0, 0.1, None),
            resonance(2.0, 0.02, Some((0.005, 0.035))),
            resonance(3.0, 0.1, Some((0.005, 0.1))),
            resonance(5.0, 0.1, None),
        ];
        resonance_bands(&mut out);
        let region = |p: &Detectability| p.could_hide.clone().unwrap_or_default();
        assert_eq!(region(&out[1])["frequency_hz"], [Some(2.0), Some(3.0)]);
        assert_eq!(region(&out[1])["damping_ratio"], [Some(0.005), Some(0.035)]);
        // Nothing hides at 5 Hz: 3 Hz stands for itself alone.
        assert_eq!(region(&out[2])["frequency_hz"], [Some(3.0), Some(3.0)]);
        // The probes at the size that matters decide `none`; the disclosure alone does not.
        assert!(!excluded(&out));
        out.retain(|p| p.would_show || p.disclosure_only);
        assert!(excluded(&out));
    }
}
