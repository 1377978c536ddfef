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
//! The probes' sizes are what matters at a 100 Hz bench, independent of any recording (see
//! [`probes`]).

use jetbench_model::{EffectKind, Effects, STEP_S};
use serde::Serialize;

use super::fit::Spec;
use super::problem::{Part, Problem, Sim};

/// Matched-filter statistic above which the residual carries a probe's shape: about one in
/// 30 000 under noise alone, for each of the couple of dozen probes.
pub const SHAPE_Z: f64 = 4.0;

/// One class of effect at the size that matters: whether this recording would show it.
#[derive(Clone, Debug, Serialize)]
pub struct Detectability {
    /// The class (a catalogue name, or `periodic` for a force at its own period).
    pub effect: &'static str,
    /// The probe: its values by key.
    pub probe: Vec<(&'static str, f64)>,
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
/// - a periodic force of 1 N at a period of 30 s.
fn probes() -> Vec<(EffectKind, Vec<f64>, bool)> {
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
    out
}

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
        _ => "a longer, richer campaign (jetbench excite)",
    }
}

fn describe(kind: EffectKind, v: &[f64]) -> String {
    match kind {
        EffectKind::InputDelay => format!("a delay of {:.0} ms", v[0] * 1000.0),
        EffectKind::ActuatorLag => format!("a lag of {:.0} ms", v[0] * 1000.0),
        EffectKind::RateLimit => format!("a rate limit of {:.0} %/s", v[0]),
        EffectKind::SensorDrift => format!("a sensor drift of {:.0} % of thrust (τ {:.0} s)", v[0] * 100.0, v[1]),
        EffectKind::GainDrift => format!("a gain drift of {:.1} %/min", v[0] * 100.0),
        EffectKind::BearingFriction => format!("a friction band of {:.1} N", v[0]),
        EffectKind::StandResonance => format!("a stand resonance at {:.1} Hz (ζ {:.2})", v[0], v[1]),
        EffectKind::Discrepancy => "a discrepancy".to_owned(),
    }
}

/// Energy and matched-filter statistic of a reading difference `delta` (grid vectors per run)
/// against the `residual` over the held-out samples where both have an innovation.
fn measure(problem: &Problem<'_>, delta: &[Vec<f64>], residual: &[Vec<f64>], s2: f64) -> (f64, f64) {
    let (mut e, mut dot) = (0.0, 0.0);
    for (i, run) in problem.runs.iter().enumerate() {
        // Where the recording has no sample, neither has the effect's reading.
        let masked: Vec<f64> =
            delta[i].iter().zip(&run.y).map(|(d, y)| if y.is_finite() { *d } else { f64::NAN }).collect();
        let (wd, wr) = (problem.whiten(i, &masked), problem.whiten(i, &residual[i]));
        for (j, (a, b)) in wd.iter().zip(&wr).enumerate() {
            if a.is_finite() && b.is_finite() && run.in_part(j * run.stride, Part::Validation) {
                e += a * a;
                dot += a * b;
            }
        }
    }
    if s2 <= 0.0 || e <= 0.0 {
        return (0.0, 0.0);
    }
    (e / s2, dot / (s2.sqrt() * e.sqrt()))
}

/// Every probe on the model found (`spec`, simulated as `sim`): whether this recording would
/// show it, and whether its residual carries its shape.
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
    let mut out = Vec::new();
    let mut with = Sim::new();
    for (kind, values, proportional) in probes() {
        if spec.has(kind) || fixed.get(kind).is_some() {
            continue;
        }
        let probe = spec.with(kind, values.clone());
        let Some(plant) = probe.plant(fixed) else { continue };
        if problem.simulate(&plant, &spec.states, false, &mut with).is_err() {
            continue;
        }
        let delta: Vec<Vec<f64>> =
            with.iter().zip(sim).map(|(a, b)| a.iter().zip(b).map(|(x, y)| x - y).collect()).collect();
        let (energy, shape_z) = measure(problem, &delta, &residual, s2);
        let threshold = strong_evidence + kind.keys().len() as f64 * ln_n;
        out.push(Detectability {
            effect: kind.name(),
            probe: kind.keys().iter().copied().zip(values.iter().copied()).collect(),
            size: describe(kind, &values),
            energy,
            threshold,
            would_show: energy >= threshold,
            shape_z,
            smallest: (proportional && energy > 0.0).then(|| values[0] * (threshold / energy).sqrt()),
            experiment: experiment_for(kind.name()),
        });
    }
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
        let (e, z) = measure(problem, &delta, &residual, s2);
        energy = energy.min(e);
        shape_z = shape_z.max(z.abs());
    }
    let threshold = strong_evidence + 3.0 * ln_n;
    out.push(Detectability {
        effect: super::rivals::PERIODIC,
        probe: vec![("amplitude_n", 1.0), ("period_s", period_s)],
        size: format!("a periodic force of 1 N at {period_s:.0} s"),
        energy,
        threshold,
        would_show: energy >= threshold,
        shape_z,
        smallest: (energy > 0.0 && energy.is_finite()).then(|| (threshold / energy).sqrt()),
        experiment: experiment_for(super::rivals::PERIODIC),
    });
    out
}

/// True when every probe would show and none is in the residual: `none` may stand.
pub fn excluded(probes: &[Detectability]) -> bool {
    !probes.is_empty() && probes.iter().all(|p| p.would_show && p.shape_z < SHAPE_Z)
}
