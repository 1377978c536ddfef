//! Validation by free-run simulation, and the noise floor it is judged against.
//!
//! A model is validated the way it will be used: started from the measured state
//! at the beginning of each contiguous run of held-out data and simulated from
//! the recorded throttle alone, with no measurement correcting it. Its error then
//! includes the measurement noise, so the best any model can do is the noise floor:
//! the mean absolute value of the noise, estimated from the data itself.

use crate::SavitzkyGolay;
use jetbench_model::{
    rk4_step, Effects, Params, Plant, SlowStart, State, DIVERGENCE_RATE_N_PER_S, DIVERGENCE_THRUST_N, STEP_S, SUBSTEPS,
};
use serde::Serialize;

use crate::series::Series;

/// Savitzky–Golay window (samples) used to read the initial state off the data.
pub const STATE_WINDOW: usize = 31;
/// Savitzky–Golay polynomial order used to read the initial state off the data.
pub const STATE_ORDER: usize = 3;

/// Something that can be simulated from a throttle sequence.
pub trait Dynamics {
    /// Simulated thrust at each sample: `out[0]` is `initial`, `out[k + 1]` follows
    /// from `out[k]` with `u_pct[k]` held for [`STEP_S`]. On divergence the
    /// remaining samples are NaN and the time of divergence (s from the run start)
    /// is returned.
    fn free_run(&self, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64>;

    /// [`Dynamics::free_run`] of a run that starts `t0_s` seconds into the recording,
    /// for models that depend on time (a gain that drifts over the run).
    fn free_run_at(&self, t0_s: f64, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        let _ = t0_s;
        self.free_run(initial, u_pct, out)
    }
}

impl Dynamics for Plant {
    fn free_run(&self, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        Plant::free_run(self, 0.0, initial, u_pct, out)
    }

    fn free_run_at(&self, t0_s: f64, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        Plant::free_run(self, t0_s, initial, u_pct, out)
    }
}

/// A plant whose slow states (a sensor drift's bias, a thrust history) start at `slow`
/// rather than settled: what an initial-state fit runs when those starts are known.
#[derive(Clone, Copy, Debug)]
pub struct Started<'a> {
    /// The plant.
    pub plant: &'a Plant,
    /// Where its slow states start.
    pub slow: SlowStart,
}

impl Dynamics for Started<'_> {
    fn free_run(&self, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        self.free_run_at(0.0, initial, u_pct, out)
    }

    fn free_run_at(&self, t0_s: f64, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        self.plant.free_run_from(SUBSTEPS, t0_s, initial, self.slow, u_pct, out)
    }
}

impl Dynamics for Params {
    /// The ten-parameter engine: a plant without effects, which is [`jetbench_model::Engine`]
    /// bit for bit.
    fn free_run(&self, initial: State, u_pct: &[f64], out: &mut Vec<f64>) -> Option<f64> {
        Plant::new(*self, Effects::none()).free_run(0.0, initial, u_pct, out)
    }
}

/// Free run of any `T̈ = a(T, Ṫ, u)` with the integrator of the simulated engine
/// (classic RK4 at 1 kHz, throttle held over each 10 ms step).
pub fn free_run_fn(
    accel: impl Fn(f64, f64, f64) -> f64,
    initial: State,
    u_pct: &[f64],
    out: &mut Vec<f64>,
) -> Option<f64> {
    let h = STEP_S / SUBSTEPS as f64;
    let (mut t, mut d) = (initial.thrust_n, initial.thrust_rate_n_per_s);
    out.clear();
    out.push(t);
    for (k, &u) in u_pct.iter().enumerate().take(u_pct.len().saturating_sub(1)) {
        for _ in 0..SUBSTEPS {
            (t, d) = rk4_step(t, d, h, |t, d| accel(t, d, u));
        }
        if !(t.is_finite() && d.is_finite() && t.abs() <= DIVERGENCE_THRUST_N && d.abs() <= DIVERGENCE_RATE_N_PER_S) {
            out.resize(u_pct.len(), f64::NAN);
            return Some((k + 1) as f64 * STEP_S);
        }
        out.push(t);
    }
    None
}

/// A plant free-run over the throttle of a recording or a profile, as `jetbench
/// simulate` does it: from the state fitted to the first 2 s of measured thrust, or at
/// rest at the first throttle (effects included) when there is none.
#[derive(Clone, Debug, PartialEq)]
pub struct InputRun {
    /// Simulated measured thrust per row (NaN after a divergence), N.
    pub thrust_n: Vec<f64>,
    /// Where the model diverged, s from the first row.
    pub diverged_at_s: Option<f64>,
}

/// Runs `plant` over `input`'s throttle (one run: the throttle is held over gaps).
pub fn simulate_input(plant: &Plant, input: &Series) -> InputRun {
    let t0_s = input.t_s.first().copied().unwrap_or(0.0);
    let initial = if input.has_thrust() {
        fit_initial_state_at(plant, t0_s, &input.thrust_n, &input.u_pct)
    } else {
        State { thrust_n: plant.rest_thrust_n(input.u_pct.first().copied().unwrap_or(0.0)), thrust_rate_n_per_s: 0.0 }
    };
    let mut thrust_n = Vec::new();
    let diverged_at_s = plant.free_run(t0_s, initial, &input.u_pct, &mut thrust_n);
    InputRun { thrust_n, diverged_at_s }
}

/// Writes `time_s,throttle_pct,thrust_n[,measured_n]` of a simulation over `input`, up
/// to a divergence.
pub fn write_simulation_csv<W: std::io::Write>(mut out: W, input: &Series, thrust_n: &[f64]) -> std::io::Result<()> {
    let measured = input.has_thrust();
    writeln!(out, "time_s,throttle_pct,thrust_n{}", if measured { ",measured_n" } else { "" })?;
    for (k, simulated) in thrust_n.iter().enumerate().take_while(|(_, t)| !t.is_nan()) {
        write!(out, "{:?},{:?},{:?}", input.t_s[k], input.u_pct[k], simulated)?;
        if measured {
            write!(out, ",{:?}", input.thrust_n[k])?;
        }
        writeln!(out)?;
    }
    out.flush()
}

/// The measurement noise, estimated from the data.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct NoiseFloor {
    /// Standard deviation of the noise, N.
    pub sigma_n: f64,
    /// Mean absolute value of the noise, N: the best validation MAE a model can reach.
    pub mae_n: f64,
}

/// Estimates the noise from second differences, which remove a smooth signal
/// (at 100 Hz the engine's own `T̈·Δt²` is a few hundredths of a newton) and
/// multiply white noise variance by 6. The median absolute value makes steps and
/// outliers harmless. Gaussian noise is assumed for `mae = σ·√(2/π)`.
pub fn noise_floor(data: &[Series]) -> Option<NoiseFloor> {
    let mut d2: Vec<f64> = Vec::new();
    for s in data {
        for run in s.runs() {
            let y = &s.thrust_n[run];
            d2.extend(y.windows(3).map(|w| (w[2] - 2.0 * w[1] + w[0]).abs()));
        }
    }
    if d2.len() < 10 {
        return None;
    }
    let mid = d2.len() / 2;
    let (_, median, _) = d2.select_nth_unstable_by(mid, f64::total_cmp);
    // MAD of a zero-mean normal is 0.6745 σ.
    let sigma_n = *median / 0.674_489_750_196_081_7 / 6f64.sqrt();
    Some(NoiseFloor { sigma_n, mae_n: sigma_n * (2.0 / std::f64::consts::PI).sqrt() })
}

/// Thrust and thrust rate at the start of `y`, read off a local polynomial fit.
/// Noisy at the edge (a rate error of tens of N/s is common at σ = 2.6 N); see
/// [`fit_initial_state`] for the state a free run should start from. A missing
/// sample (NaN) in the window falls back to the first sample, at rest.
pub fn initial_state(y: &[f64]) -> State {
    let window = STATE_WINDOW.min(if y.len() % 2 == 1 { y.len() } else { y.len().saturating_sub(1) });
    if y[..window].iter().any(|v| !v.is_finite()) {
        let thrust_n = y.iter().copied().find(|v| v.is_finite()).unwrap_or(0.0);
        return State { thrust_n, thrust_rate_n_per_s: 0.0 };
    }
    let fit = SavitzkyGolay::new(window, STATE_ORDER.min(window.saturating_sub(2)))
        .ok()
        .and_then(|sg| Some((sg.apply(&y[..window], 0, STEP_S).ok()?, sg.apply(&y[..window], 1, STEP_S).ok()?)));
    match fit {
        Some((t, d)) => State { thrust_n: t[0], thrust_rate_n_per_s: d[0] },
        None => State { thrust_n: y.first().copied().unwrap_or(0.0), thrust_rate_n_per_s: 0.0 },
    }
}

/// Samples over which the initial state of a free run is fitted (2 s).
pub const INITIAL_FIT_SAMPLES: usize = 200;

/// The initial state that best explains the first [`INITIAL_FIT_SAMPLES`] of `y`
/// under `model` (Gauss–Newton on `[T₀, Ṫ₀]`, started from [`initial_state`]).
///
/// Output-error validation must not blame the model for a bad starting point: at
/// low thrust the engine's slow mode carries a starting error for seconds. The
/// fit uses the first two seconds only, the same way for every model.
pub fn fit_initial_state(model: &dyn Dynamics, y: &[f64], u: &[f64]) -> State {
    fit_initial_state_at(model, 0.0, y, u)
}

/// [`fit_initial_state`] of a run that starts `t0_s` seconds into the recording.
/// Samples of `y` that are NaN (lost or rejected) are left out of the fit.
pub fn fit_initial_state_at(model: &dyn Dynamics, t0_s: f64, y: &[f64], u: &[f64]) -> State {
    let n = y.len().min(u.len()).min(INITIAL_FIT_SAMPLES);
    let edge = initial_state(y);
    if n < 10 {
        return edge;
    }
    let (mut base, mut dt_run, mut dd_run) = (Vec::new(), Vec::new(), Vec::new());
    let sse =
        |sim: &[f64]| -> f64 { sim.iter().zip(y).filter(|(_, m)| m.is_finite()).map(|(s, m)| (s - m).powi(2)).sum() };
    // Three starts: the local polynomial's; at rest at the first samples' mean (the
    // polynomial's rate at the edge can be tens of N/s off, enough to make a model that
    // is stiff in Ṫ (K_DD > 0) run away); and that rest moved by what the model reads on
    // top of the thrust at the start (a sensor bias it starts with), so that what it
    // reads, not the engine, sits at the first samples' mean. Without the third, a model
    // that starts with a bias of 12 N had both starts 12 N high, and from the better one the
    // fit ended at a start that rang for two seconds (−114 N/s) with five times the sum of
    // squares of the right one: the residual of a drift fitted exactly was then not white.
    let first: Vec<f64> = y[..n].iter().copied().filter(|v| v.is_finite()).take(10).collect();
    let rest = State { thrust_n: first.iter().sum::<f64>() / first.len().max(1) as f64, thrust_rate_n_per_s: 0.0 };
    let read_over = if model.free_run_at(t0_s, rest, &u[..1.min(n)], &mut base).is_none() {
        base.first().map_or(0.0, |r| r - rest.thrust_n)
    } else {
        0.0
    };
    // Only a model that reads something on top of its thrust has a third start to try.
    let read_rest = (read_over != 0.0).then_some(State { thrust_n: rest.thrust_n - read_over, ..rest });
    // And at rest at the mean of every sample fitted: where a reading that holds (a frame in
    // its bearings' play) sits, which the first ten samples of coloured noise can miss by
    // more than the play lets the thrust pull it back.
    let all: Vec<f64> = y[..n].iter().copied().filter(|v| v.is_finite()).collect();
    let rest_all = (!all.is_empty())
        .then(|| State { thrust_n: all.iter().sum::<f64>() / all.len() as f64, thrust_rate_n_per_s: 0.0 });
    let mut best: Option<(f64, State)> = None;
    for start in [edge, rest].into_iter().chain(rest_all).chain(read_rest) {
        if model.free_run_at(t0_s, start, &u[..n], &mut base).is_none() {
            let e = sse(&base);
            if best.is_none_or(|(b, _)| e < b) {
                best = Some((e, start));
            }
        }
    }
    let Some((_, mut x)) = best else { return rest };
    for _ in 0..4 {
        if model.free_run_at(t0_s, x, &u[..n], &mut base).is_some() {
            return x;
        }
        let (ht, hd) = (0.1, 1.0);
        let bumped_t = State { thrust_n: x.thrust_n + ht, ..x };
        let bumped_d = State { thrust_rate_n_per_s: x.thrust_rate_n_per_s + hd, ..x };
        if model.free_run_at(t0_s, bumped_t, &u[..n], &mut dt_run).is_some()
            || model.free_run_at(t0_s, bumped_d, &u[..n], &mut dd_run).is_some()
        {
            return x;
        }
        // Normal equations of the 2-parameter linearised problem.
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for k in (0..n).filter(|&k| y[k].is_finite()) {
            let (j1, j2) = ((dt_run[k] - base[k]) / ht, (dd_run[k] - base[k]) / hd);
            let r = y[k] - base[k];
            a11 += j1 * j1;
            a12 += j1 * j2;
            a22 += j2 * j2;
            b1 += j1 * r;
            b2 += j2 * r;
        }
        let det = a11 * a22 - a12 * a12;
        if det.is_nan() {
            return x;
        }
        // Where one of the two moves nothing the sensor reads, the step is along the other
        // alone: a frame held in its bearings' play reads where it starts whatever the
        // engine's starting rate, and giving up there left the start where the first ten
        // samples put it, a couple of newtons off the first two seconds' mean for the
        // seconds until the throttle moved.
        let next = if det > 1e-9 * a11 * a22 && det > 1e-12 {
            State {
                thrust_n: x.thrust_n + (a22 * b1 - a12 * b2) / det,
                thrust_rate_n_per_s: x.thrust_rate_n_per_s + (a11 * b2 - a12 * b1) / det,
            }
        } else if a11 >= a22 && a11 > 1e-12 {
            State { thrust_n: x.thrust_n + b1 / a11, ..x }
        } else if a22 > 1e-12 {
            State { thrust_rate_n_per_s: x.thrust_rate_n_per_s + b2 / a22, ..x }
        } else {
            return x;
        };
        // The step, halved while it does worse (a start that leaves the play band is pulled
        // back by it, which the linearised step does not see).
        let mut trial = Vec::new();
        let base_sse = sse(&base);
        let mut step = 1.0;
        let taken = loop {
            let at = State {
                thrust_n: x.thrust_n + step * (next.thrust_n - x.thrust_n),
                thrust_rate_n_per_s: x.thrust_rate_n_per_s + step * (next.thrust_rate_n_per_s - x.thrust_rate_n_per_s),
            };
            if model.free_run_at(t0_s, at, &u[..n], &mut trial).is_none() && sse(&trial) <= base_sse {
                break Some(at);
            }
            if step < 0.1 {
                break None;
            }
            step *= 0.5;
        };
        let Some(next) = taken else { return x };
        x = next;
    }
    x
}

/// How well simulated thrust matches measured thrust.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Score {
    /// Mean absolute error, N.
    pub mae_n: f64,
    /// Root mean square error, N.
    pub rmse_n: f64,
    /// `100·(1 − ‖y − ŷ‖ / ‖y − ȳ‖)`, %.
    pub fit_pct: f64,
    /// Samples compared.
    pub samples: usize,
}

/// A model simulated over data.
#[derive(Clone, Debug, Default)]
pub struct Simulation {
    /// Simulated thrust, one vector per series (NaN after a divergence).
    pub thrust_n: Vec<Vec<f64>>,
    /// Where the model diverged: (series name, time s), if it did.
    pub diverged: Option<(String, f64)>,
}

impl Simulation {
    /// Error against the measured thrust; `None` when the model diverged.
    pub fn score(&self, data: &[Series]) -> Option<Score> {
        if self.diverged.is_some() {
            return None;
        }
        score(data.iter().zip(&self.thrust_n).flat_map(|(s, sim)| s.thrust_n.iter().copied().zip(sim.iter().copied())))
    }
}

/// MAE, RMSE and fit % over (measured, simulated) pairs.
pub fn score(pairs: impl Iterator<Item = (f64, f64)> + Clone) -> Option<Score> {
    let (mut n, mut sum_y) = (0usize, 0.0);
    for (y, _) in pairs.clone() {
        n += 1;
        sum_y += y;
    }
    if n == 0 {
        return None;
    }
    let mean = sum_y / n as f64;
    let (mut abs, mut sq, mut var) = (0.0, 0.0, 0.0);
    for (y, s) in pairs {
        abs += (y - s).abs();
        sq += (y - s).powi(2);
        var += (y - mean).powi(2);
    }
    let fit_pct = if var > 0.0 { 100.0 * (1.0 - (sq / var).sqrt()) } else { f64::NAN };
    Some(Score { mae_n: abs / n as f64, rmse_n: (sq / n as f64).sqrt(), fit_pct, samples: n })
}

/// Simulates `model` over every contiguous run of every series, each run started
/// from the state measured at its beginning.
pub fn simulate(model: &dyn Dynamics, data: &[Series]) -> Simulation {
    let mut result = Simulation::default();
    let mut buffer = Vec::new();
    for s in data {
        let mut sim = vec![f64::NAN; s.len()];
        for run in s.runs() {
            let start = run.start;
            let initial = fit_initial_state_at(model, s.t_s[start], &s.thrust_n[run.clone()], &s.u_pct[run.clone()]);
            if let Some(at) = model.free_run_at(s.t_s[start], initial, &s.u_pct[run.clone()], &mut buffer) {
                if result.diverged.is_none() {
                    result.diverged = Some((s.name.clone(), s.t_s[start] + at));
                }
            }
            sim[run].copy_from_slice(&buffer);
        }
        result.thrust_n.push(sim);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth;
    use jetbench_model::Preset;

    #[test]
    fn noise_floor_recovers_the_noise_of_a_recording() {
        let profile = synth::test_profile(6000, 3);
        for (var, preset) in [(7.0, Preset::P100Diesel), (9.0, Preset::P220Kerosene), (1.0, Preset::P100Diesel)] {
            let s = synth::record(&preset.params(), &profile, var, 11).unwrap();
            let floor = noise_floor(&[s]).unwrap();
            let sigma: f64 = f64::sqrt(var);
            assert!((floor.sigma_n - sigma).abs() < 0.03 * sigma, "{var}: {floor:?}");
        }
    }

    #[test]
    fn the_true_model_scores_at_the_noise_floor() {
        let p = Preset::P100Diesel.params();
        let s = synth::record(&p, &synth::test_profile(6000, 5), 7.0, 2).unwrap();
        let sim = simulate(&p, std::slice::from_ref(&s));
        let score = sim.score(std::slice::from_ref(&s)).unwrap();
        let floor = noise_floor(std::slice::from_ref(&s)).unwrap();
        assert!((score.mae_n - floor.mae_n).abs() < 0.05 * floor.mae_n, "{score:?} vs {floor:?}");
        assert!(score.fit_pct > 80.0, "{score:?}");
    }

    /// A model that starts with a sensor bias reads that bias on top of its thrust from the
    /// first sample: its start is fitted where what it reads sits at the first samples (a
    /// P220 engine at rest at 92 % throttle, 206 N, a 12 N bias, AR(1) noise). Started only
    /// from the local polynomial and from the first samples' mean as its thrust, the fit
    /// ended, on seed 22, at a start that rang for two seconds (−111 N/s) with seven times
    /// the sum of squares of the truth's.
    #[test]
    fn a_start_is_fitted_under_the_bias_the_model_reads() {
        use jetbench_model::{Effect, EffectKind};
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let params = Preset::P220Kerosene.params();
        let u = vec![92.0; INITIAL_FIT_SAMPLES];
        let mut settle = Vec::new();
        assert!(params.free_run(State::default(), &vec![92.0; 6000], &mut settle).is_none());
        let rest = State { thrust_n: settle[settle.len() - 1], thrust_rate_n_per_s: 0.0 };
        let (gain, tau_s, bias_n) = (0.06, 40.0, 12.0);
        let drift = Effect::new(EffectKind::SensorDrift, &[gain, tau_s]).unwrap();
        let plant = Plant::new(params, Effects::new([drift]).unwrap());
        let model = Started { plant: &plant, slow: SlowStart { bias_n, ..SlowStart::SETTLED } };
        // AR(1) noise, φ 0.42: the local polynomial's rate at the edge is tens of N/s off.
        let noise = Normal::new(0.0, 2.3).unwrap();
        for seed in 0..100 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let mut e = 0.0;
            let y: Vec<f64> = (0..u.len())
                .map(|k| {
                    let t = k as f64 * STEP_S;
                    e = 0.42 * e + noise.sample(&mut rng);
                    rest.thrust_n + gain * rest.thrust_n + (bias_n - gain * rest.thrust_n) * (-t / tau_s).exp() + e
                })
                .collect();
            let start = fit_initial_state_at(&model, 0.0, &y, &u);
            // The fitted start explains the first two seconds at least as well as the truth's.
            let sse = |x: State| {
                let mut out = Vec::new();
                assert!(model.free_run(x, &u, &mut out).is_none());
                out.iter().zip(&y).map(|(s, m)| (s - m).powi(2)).sum::<f64>()
            };
            assert!(
                sse(start) <= sse(rest) + 1e-6,
                "seed {seed}: {start:?} {} against {rest:?} {}",
                sse(start),
                sse(rest)
            );
        }
    }

    /// A frame held in its bearings' play reads where it starts, whatever the engine's
    /// starting rate: the rate moves nothing the fit sees. The start must still come to the
    /// first two seconds' reading along the thrust alone. It used to stay where the first
    /// ten samples put it (a campaign case of a 2.9 N band under coloured noise started 1.7 N
    /// high, and held there for the 6 s until the throttle moved).
    #[test]
    fn a_start_inside_the_play_band_is_fitted_to_the_first_seconds() {
        use jetbench_model::{Effect, EffectKind};
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let params = Preset::P220Kerosene.params();
        let u = vec![47.0; INITIAL_FIT_SAMPLES];
        let mut settle = Vec::new();
        assert!(params.free_run(State::default(), &vec![47.0; 6000], &mut settle).is_none());
        let rest_n = settle[settle.len() - 1];
        let play = Effect::new(EffectKind::BearingFriction, &[2.9]).unwrap();
        let plant = Plant::new(params, Effects::new([play]).unwrap());
        let model = Started { plant: &plant, slow: SlowStart::SETTLED };
        // The frame 0.8 N above the thrust, inside the band: it reads there from the start.
        let truth = State { thrust_n: rest_n + 0.8, thrust_rate_n_per_s: 0.0 };
        let noise = Normal::new(0.0, 2.1).unwrap();
        let sse = |x: State, y: &[f64]| {
            let mut out = Vec::new();
            assert!(model.free_run(x, &u, &mut out).is_none());
            out.iter().zip(y).map(|(s, m)| (s - m).powi(2)).sum::<f64>()
        };
        for seed in 0..100 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let mut e = 0.0;
            let y: Vec<f64> = u
                .iter()
                .map(|_| {
                    e = 0.44 * e + noise.sample(&mut rng);
                    truth.thrust_n + e
                })
                .collect();
            let start = fit_initial_state_at(&model, 0.0, &y, &u);
            assert!(
                sse(start, &y) <= sse(truth, &y) + 1e-6,
                "seed {seed}: {start:?} {} against {truth:?} {}",
                sse(start, &y),
                sse(truth, &y)
            );
        }
    }

    #[test]
    fn generic_integrator_matches_the_engine() {
        let p = Preset::P100Diesel.params();
        let u: Vec<f64> = (0..500).map(|k| if k < 100 { 30.0 } else { 90.0 }).collect();
        let initial = State { thrust_n: 5.0, thrust_rate_n_per_s: 0.0 };
        let (mut a, mut b) = (Vec::new(), Vec::new());
        assert!(p.free_run(initial, &u, &mut a).is_none());
        assert!(free_run_fn(|t, d, u| p.accel(t, d, u), initial, &u, &mut b).is_none());
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-9, "{x} {y}");
        }
    }

    #[test]
    fn divergence_is_reported_not_nan_scored() {
        let p = Preset::P100Ekf.params();
        let u: Vec<f64> = (0..600).map(|k| if k < 100 { 70.0 } else { 100.0 }).collect();
        let s = Series {
            name: "d".into(),
            t_s: (0..600).map(|k| k as f64 * STEP_S).collect(),
            thrust_n: vec![60.0; 600],
            u_pct: u,
        };
        let sim = simulate(&p, std::slice::from_ref(&s));
        let (_, at) = sim.diverged.clone().unwrap();
        assert!(at > 1.0 && at < 6.0, "{at}");
        assert!(sim.score(std::slice::from_ref(&s)).is_none());
    }
}
