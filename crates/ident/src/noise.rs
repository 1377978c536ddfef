//! Sensor noise as an autoregressive process, estimated from a recording alone.
//!
//! A force sensor's noise is rarely white: its electronics filter it, the frame
//! shakes. Modelled as AR(p), `e_k = φ₁·e_(k−1) + … + φ_p·e_(k−p) + w_k` with white
//! innovations `w` of variance `σ_w²`, it is what whiteness tests, the noise floor
//! and the scores of a diagnosis must account for, or coloured noise is called
//! physics.
//!
//! The model is estimated without any engine model ([`estimate`]): second differences
//! of the measured thrust remove the engine's signal (at 100 Hz `T̈·Δt²` is a few
//! hundredths of a newton, the noise's second difference newtons), and the AR
//! parameters maximise the exact Gaussian likelihood of those contrasts over windows
//! of 32 samples (restricted maximum likelihood: whatever constant and slope the
//! signal has in a window cancels). The order (0 to 6) is chosen by BIC, so white
//! noise stays AR(0). The noise's whole variance, and with it the noise floor,
//! follows from the model: `σ_e² = σ_w²·Σψ_j²` with `ψ` its impulse response.
//!
//! ```
//! use jetbench_ident::noise::{estimate, ArModel};
//!
//! // AR(1) noise of variance 7 N² on a slow ramp.
//! let model = ArModel::new(vec![0.6], 1.0).with_marginal_var(7.0);
//! let noise = model.generate(20_000, 3);
//! let y: Vec<f64> = noise.iter().enumerate().map(|(k, e)| 0.01 * k as f64 + e).collect();
//! let found = estimate(&[y]).unwrap();
//! assert_eq!(found.model.order(), 1);
//! assert!((found.model.phi[0] - 0.6).abs() < 0.03);
//! assert!((found.model.marginal_var() - 7.0).abs() < 0.7);
//! ```

use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

/// Largest AR order tried.
pub const MAX_ORDER: usize = 6;
/// Samples per likelihood window.
const WINDOW: usize = 32;
/// Shortest window used (the tail of a stretch between gaps).
const MIN_WINDOW: usize = 8;
/// Partial autocorrelations are kept inside ±this, so the model stays stationary.
const MAX_PACF: f64 = 0.995;

/// An AR(p) noise model.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ArModel {
    /// `φ₁ … φ_p` (empty: white noise).
    pub phi: Vec<f64>,
    /// Variance of the white innovations `w`, N².
    pub innovation_var: f64,
}

impl ArModel {
    /// `e_k = φ₁·e_(k−1) + … + φ_p·e_(k−p) + w_k` with `w` white of variance
    /// `innovation_var`, N².
    pub fn new(phi: Vec<f64>, innovation_var: f64) -> Self {
        Self { phi, innovation_var }
    }

    /// White noise of variance `var`.
    pub fn white(var: f64) -> Self {
        Self { phi: Vec::new(), innovation_var: var }
    }

    /// The AR order `p`.
    pub fn order(&self) -> usize {
        self.phi.len()
    }

    /// True when the process is stationary (every partial autocorrelation inside ±1).
    pub fn is_stationary(&self) -> bool {
        self.phi.iter().all(|p| p.is_finite()) && to_pacf(&self.phi).iter().all(|k| k.abs() < 1.0)
    }

    /// `Σψ_j²`: the noise variance per unit of innovation variance.
    pub fn variance_gain(&self) -> f64 {
        impulse_response(&self.phi).iter().map(|x| x * x).sum()
    }

    /// The variance of the noise itself, N².
    pub fn marginal_var(&self) -> f64 {
        self.innovation_var * self.variance_gain()
    }

    /// The same model scaled to noise variance `var`.
    pub fn with_marginal_var(self, var: f64) -> Self {
        let gain = self.variance_gain();
        Self { innovation_var: var / gain, ..self }
    }

    /// Autocorrelation of the noise at lags `0..lags`.
    pub fn autocorrelation(&self, lags: usize) -> Vec<f64> {
        let psi = impulse_response(&self.phi);
        let gamma0: f64 = psi.iter().map(|x| x * x).sum();
        (0..lags).map(|l| psi.iter().zip(psi.iter().skip(l)).map(|(a, b)| a * b).sum::<f64>() / gamma0).collect()
    }

    /// The innovation of `r[k]` given `r[k−1..k−p]`: `r_k − Σφ_i·r_(k−i)`. `None` when
    /// any of them is missing (NaN) or before the start.
    pub fn innovation(&self, r: &[f64], k: usize) -> Option<f64> {
        if k < self.phi.len() || !r[k].is_finite() {
            return None;
        }
        let mut w = r[k];
        for (i, phi) in self.phi.iter().enumerate() {
            let past = r[k - 1 - i];
            if !past.is_finite() {
                return None;
            }
            w -= phi * past;
        }
        Some(w)
    }

    /// `n` samples of the process, started in its stationary state, from `seed`.
    pub fn generate(&self, n: usize, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let Ok(normal) = Normal::new(0.0, self.innovation_var.max(0.0).sqrt()) else { return vec![0.0; n] };
        let burn = if self.phi.is_empty() { 0 } else { 2000 };
        let mut past = vec![0.0; self.phi.len()];
        let mut out = Vec::with_capacity(n);
        for k in 0..n + burn {
            let mut e = normal.sample(&mut rng);
            for (i, phi) in self.phi.iter().enumerate() {
                e += phi * past[i];
            }
            if !past.is_empty() {
                past.rotate_right(1);
                past[0] = e;
            }
            if k >= burn {
                out.push(e);
            }
        }
        out
    }

    /// `"white"`, or `"AR(2): φ = 0.61, −0.12"`.
    pub fn describe(&self) -> String {
        if self.phi.is_empty() {
            return "white".to_owned();
        }
        let phi: Vec<String> = self.phi.iter().map(|p| format!("{p:.3}")).collect();
        format!("AR({}): φ = {}", self.phi.len(), phi.join(", "))
    }
}

/// Impulse response `ψ` of `1/(1 − Σφ_i q^−i)`, until it has died out.
fn impulse_response(phi: &[f64]) -> Vec<f64> {
    let mut psi = vec![1.0];
    if phi.is_empty() {
        return psi;
    }
    let mut quiet = 0;
    while psi.len() < 50_000 && quiet < phi.len() {
        let k = psi.len();
        let next: f64 = phi.iter().enumerate().filter(|(i, _)| *i < k).map(|(i, p)| p * psi[k - 1 - i]).sum();
        quiet = if next.abs() < 1e-9 { quiet + 1 } else { 0 };
        psi.push(next);
    }
    psi
}

/// AR coefficients from partial autocorrelations (Levinson's step-up recursion): any
/// `|κ_i| < 1` gives a stationary model.
fn from_pacf(kappa: &[f64]) -> Vec<f64> {
    let mut phi: Vec<f64> = Vec::with_capacity(kappa.len());
    for &k in kappa {
        let previous = phi.clone();
        for (i, p) in phi.iter_mut().enumerate() {
            *p = previous[i] - k * previous[previous.len() - 1 - i];
        }
        phi.push(k);
    }
    phi
}

/// The noise model of a recording, as [`estimate`] found it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NoiseEstimate {
    /// The AR model fitted to the noise (its order, 0 to 6, chosen by BIC).
    pub model: ArModel,
    /// Standard deviation of the noise, N.
    pub sigma_n: f64,
    /// Mean absolute value of the noise (Gaussian), N: the best validation MAE a model
    /// can reach.
    pub mae_n: f64,
    /// Second-difference contrasts the likelihood used.
    pub contrasts: usize,
    /// BIC of every order tried, AR(0) first.
    pub bic: Vec<f64>,
}

/// Estimates the noise of the thrust in `stretches` (each a run on the 10 ms grid,
/// NaN where a sample is missing or an outlier), with no engine model. `None` when
/// there are too few windows.
pub fn estimate(stretches: &[Vec<f64>]) -> Option<NoiseEstimate> {
    let windows = contrast_windows(stretches);
    let contrasts: usize = windows.iter().map(Vec::len).sum();
    if contrasts < 200 {
        return None;
    }
    let mut best: Option<(f64, ArModel)> = None;
    let mut bic = Vec::new();
    let n = contrasts as f64;
    for order in 0..=MAX_ORDER {
        let objective = |x: &[f64]| -> f64 {
            let kappa: Vec<f64> = x.iter().map(|v| MAX_PACF * v.tanh()).collect();
            restricted_likelihood(&windows, &from_pacf(&kappa)).map_or(f64::INFINITY, |(ll, _)| -ll)
        };
        let start = best.as_ref().map_or_else(Vec::new, |(_, m)| pacf_start(&m.phi, order));
        let x = if order == 0 { Vec::new() } else { nelder_mead(&objective, &start, 0.3, 400) };
        let kappa: Vec<f64> = x.iter().map(|v| MAX_PACF * v.tanh()).collect();
        let phi = from_pacf(&kappa);
        let Some((ll, var)) = restricted_likelihood(&windows, &phi) else { continue };
        let b = -2.0 * ll + (order + 1) as f64 * n.ln();
        bic.push(b);
        if best.as_ref().is_none_or(|(bb, _)| b < *bb) {
            best = Some((b, ArModel::new(phi, var)));
        }
    }
    let (_, model) = best?;
    let sigma_n = model.marginal_var().sqrt();
    Some(NoiseEstimate { sigma_n, mae_n: sigma_n * (2.0 / std::f64::consts::PI).sqrt(), model, contrasts, bic })
}

/// The noise's mean absolute value over the held-out part of `stretches` (each from index
/// `held_out_from[i]` on), N, for noise of standard deviation `sigma_n` over the whole.
///
/// `σ·√(2/π)` is that floor only when the noise's scale is the same everywhere. A force
/// sensor's noise often grows with thrust (the frame shakes more), and then the held-out part
/// has its own scale, and the mean absolute value of a varying scale is below `√(2/π)` times
/// its root mean square. Second differences carry the noise's scale sample by sample (the
/// engine's own part of them is hundredths of a newton) and, Gaussian or AR, the same ratio of
/// mean absolute value to root mean square as the noise: so the floor is `σ` times the held-out
/// part's mean `|Δ²y|` over the whole's root mean square `Δ²y`. Under constant-scale noise it is
/// `σ·√(2/π)` within the sampling error of the held-out mean (under 1 % for a few thousand
/// samples). `None` with fewer than 200 held-out contrasts.
pub fn held_out_floor(sigma_n: f64, stretches: &[Vec<f64>], held_out_from: &[usize]) -> Option<f64> {
    let (mut squares, mut all) = (0.0, 0usize);
    let (mut absolute, mut held_out) = (0.0, 0usize);
    for (y, &from) in stretches.iter().zip(held_out_from) {
        for (k, t) in y.windows(3).enumerate() {
            let d = t[2] - 2.0 * t[1] + t[0];
            if !d.is_finite() {
                continue;
            }
            squares += d * d;
            all += 1;
            if k >= from {
                absolute += d.abs();
                held_out += 1;
            }
        }
    }
    (held_out >= 200 && squares > 0.0).then(|| sigma_n * (absolute / held_out as f64) / (squares / all as f64).sqrt())
}

/// Most AR order [`fit_to_series`] tries.
pub const MAX_RESIDUAL_ORDER: usize = 12;

/// An AR model of a series that is all noise (a residual nothing explains): Yule–Walker
/// (Levinson–Durbin) on its autocovariance, pairs with a missing sample (NaN) left out,
/// the order (0 to [`MAX_RESIDUAL_ORDER`]) by BIC. Unlike [`estimate`] it sees the noise's
/// slow parts too, but it calls whatever the series holds noise. `None` with too few
/// samples.
pub fn fit_to_series(series: &[Vec<f64>]) -> Option<ArModel> {
    let n: usize = series.iter().map(|x| x.iter().filter(|v| v.is_finite()).count()).sum();
    if n < 200 {
        return None;
    }
    let mean = series.iter().flatten().filter(|v| v.is_finite()).sum::<f64>() / n as f64;
    let gamma: Vec<f64> = (0..=MAX_RESIDUAL_ORDER)
        .map(|lag| {
            let (mut sum, mut pairs) = (0.0, 0usize);
            for x in series {
                for (a, b) in x.iter().zip(x.iter().skip(lag)) {
                    if a.is_finite() && b.is_finite() {
                        sum += (a - mean) * (b - mean);
                        pairs += 1;
                    }
                }
            }
            sum / pairs.max(1) as f64
        })
        .collect();
    if gamma[0].is_nan() || gamma[0] <= 0.0 {
        return Some(ArModel::white(gamma[0].max(1e-12)));
    }
    // Levinson–Durbin: every order at once, each with its innovation variance.
    let (mut phi, mut var) = (Vec::new(), gamma[0]);
    let mut best = (n as f64 * var.ln(), ArModel::white(var));
    for p in 1..=MAX_RESIDUAL_ORDER {
        let k = (gamma[p] - phi.iter().enumerate().map(|(i, f)| f * gamma[p - 1 - i]).sum::<f64>()) / var;
        if k.is_nan() || k.abs() >= 1.0 {
            break;
        }
        let previous = phi.clone();
        for (i, f) in phi.iter_mut().enumerate() {
            *f = previous[i] - k * previous[previous.len() - 1 - i];
        }
        phi.push(k);
        var *= 1.0 - k * k;
        let bic = n as f64 * var.ln() + p as f64 * (n as f64).ln();
        if bic < best.0 {
            best = (bic, ArModel::new(phi.clone(), var));
        }
    }
    Some(best.1)
}

/// A starting point in the (atanh-scaled) PACF space of order `order` that extends
/// the lower-order fit `phi` with a zero.
fn pacf_start(phi: &[f64], order: usize) -> Vec<f64> {
    let mut kappa = to_pacf(phi);
    kappa.resize(order, 0.0);
    kappa.iter().map(|k| (k / MAX_PACF).clamp(-0.999, 0.999).atanh()).collect()
}

/// Partial autocorrelations of AR coefficients (Levinson's step-down recursion).
fn to_pacf(phi: &[f64]) -> Vec<f64> {
    let mut a = phi.to_vec();
    let mut kappa = vec![0.0; a.len()];
    while let Some(&k) = a.last() {
        let p = a.len();
        kappa[p - 1] = k;
        if k.abs() >= 1.0 {
            break;
        }
        let previous = a.clone();
        a.truncate(p - 1);
        for (i, x) in a.iter_mut().enumerate() {
            *x = (previous[i] + k * previous[p - 2 - i]) / (1.0 - k * k);
        }
    }
    kappa
}

/// Second-difference contrasts of every window of up to [`WINDOW`] consecutive
/// finite samples.
fn contrast_windows(stretches: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let mut out = Vec::new();
    for y in stretches {
        for piece in y.split(|v| !v.is_finite()) {
            for w in piece.chunks(WINDOW) {
                if w.len() >= MIN_WINDOW {
                    out.push(w.windows(3).map(|t| t[2] - 2.0 * t[1] + t[0]).collect());
                }
            }
        }
    }
    out
}

/// Log-likelihood of the contrasts under AR coefficients `phi` with the innovation
/// variance at its maximum, and that variance.
fn restricted_likelihood(windows: &[Vec<f64>], phi: &[f64]) -> Option<(f64, f64)> {
    let psi = impulse_response(phi);
    let gamma = |lag: usize| -> f64 { psi.iter().zip(psi.iter().skip(lag)).map(|(a, b)| a * b).sum() };
    let max_len = windows.iter().map(Vec::len).max()?;
    let g: Vec<f64> = (0..max_len + 2).map(gamma).collect();
    let at = |l: i64| g[l.unsigned_abs() as usize];
    // Covariance of the second differences per unit innovation variance.
    let c: Vec<f64> =
        (0..max_len as i64).map(|l| 6.0 * at(l) - 4.0 * (at(l - 1) + at(l + 1)) + at(l - 2) + at(l + 2)).collect();
    // Per window length: the covariance's factor, its log-determinant, and two vectors of
    // that length reused for every window (the contrasts, and their solve).
    type Factor = (nalgebra::Cholesky<f64, nalgebra::Dyn>, f64, DVector<f64>, DVector<f64>);
    let mut by_len: Vec<Option<Factor>> = vec![None; max_len + 1];
    let (mut quad, mut logdet, mut n) = (0.0, 0.0, 0usize);
    for z in windows {
        let m = z.len();
        if by_len[m].is_none() {
            let cov = DMatrix::from_fn(m, m, |i, j| c[i.abs_diff(j)]);
            let chol = cov.cholesky()?;
            let ld = 2.0 * chol.l_dirty().diagonal().iter().map(|d| d.ln()).sum::<f64>();
            by_len[m] = Some((chol, ld, DVector::zeros(m), DVector::zeros(m)));
        }
        let (chol, ld, v, solved) = by_len[m].as_mut()?;
        v.copy_from_slice(z);
        solved.copy_from(v);
        chol.solve_mut(solved);
        quad += v.dot(solved);
        logdet += *ld;
        n += m;
    }
    // A noise-free recording (simulated with no noise) has no variance to take a log of.
    let var = (quad / n as f64).max(1e-12);
    if !var.is_finite() {
        return None;
    }
    Some((-0.5 * (n as f64 * var.ln() + logdet + n as f64), var))
}

/// Minimises `f` from `start` by Nelder–Mead with initial steps `step`.
pub(crate) fn nelder_mead(f: &dyn Fn(&[f64]) -> f64, start: &[f64], step: f64, evaluations: usize) -> Vec<f64> {
    let n = start.len();
    if n == 0 {
        return Vec::new();
    }
    let mut simplex: Vec<(Vec<f64>, f64)> = (0..=n)
        .map(|i| {
            let mut x = start.to_vec();
            if i > 0 {
                x[i - 1] += step;
            }
            let fx = f(&x);
            (x, fx)
        })
        .collect();
    let mut used = n + 1;
    while used < evaluations {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        let spread = simplex[n].1 - simplex[0].1;
        if spread.abs() < 1e-9 * simplex[0].1.abs().max(1.0) {
            break;
        }
        let centroid: Vec<f64> =
            (0..n).map(|j| simplex[..n].iter().map(|(x, _)| x[j]).sum::<f64>() / n as f64).collect();
        let towards = |t: f64| -> Vec<f64> {
            centroid.iter().zip(&simplex[n].0).map(|(c, w)| c + t * (w - c)).collect::<Vec<f64>>()
        };
        let reflected = towards(-1.0);
        let fr = f(&reflected);
        used += 1;
        if fr < simplex[0].1 {
            let expanded = towards(-2.0);
            let fe = f(&expanded);
            used += 1;
            simplex[n] = if fe < fr { (expanded, fe) } else { (reflected, fr) };
        } else if fr < simplex[n - 1].1 {
            simplex[n] = (reflected, fr);
        } else {
            let contracted = towards(0.5);
            let fc = f(&contracted);
            used += 1;
            if fc < simplex[n].1 {
                simplex[n] = (contracted, fc);
            } else {
                let best = simplex[0].0.clone();
                for (x, fx) in simplex.iter_mut().skip(1) {
                    *x = x.iter().zip(&best).map(|(a, b)| b + 0.5 * (a - b)).collect();
                    *fx = f(x);
                    used += 1;
                }
            }
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    simplex.swap_remove(0).0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp_plus(noise: &[f64]) -> Vec<f64> {
        noise.iter().enumerate().map(|(k, e)| 20.0 + 30.0 * (k as f64 * 0.003).sin() + e).collect()
    }

    #[test]
    fn white_noise_stays_white_and_its_floor_is_the_gaussian_one() {
        let y = ramp_plus(&ArModel::white(7.0).generate(30_000, 1));
        let found = estimate(&[y]).unwrap();
        assert_eq!(found.model.order(), 0, "{:?}", found.bic);
        assert!((found.sigma_n - 7f64.sqrt()).abs() < 0.03 * 7f64.sqrt(), "{}", found.sigma_n);
    }

    #[test]
    fn the_held_out_floor_is_the_mean_absolute_noise_there() {
        let held_out_mae =
            |e: &[f64], from: usize| e[from..].iter().map(|v| v.abs()).sum::<f64>() / (e.len() - from) as f64;
        let from = 20_000;
        // Constant scale, white and coloured: the Gaussian floor.
        for truth in [ArModel::white(7.0), ArModel::new(vec![0.6], 1.0).with_marginal_var(7.0)] {
            let e = truth.generate(30_000, 11);
            let found = estimate(&[ramp_plus(&e)]).unwrap();
            let floor = held_out_floor(found.sigma_n, &[ramp_plus(&e)], &[from]).unwrap();
            assert!((floor / found.mae_n - 1.0).abs() < 0.02, "{floor} against {}", found.mae_n);
            assert!((floor / held_out_mae(&e, from) - 1.0).abs() < 0.03, "{floor}");
        }
        // A scale that grows with thrust, low over the held-out part: the Gaussian floor of the
        // whole is far above what the held-out part can reach, the held-out floor is not.
        let e: Vec<f64> = ArModel::white(1.0)
            .generate(30_000, 12)
            .iter()
            .enumerate()
            .map(|(k, w)| w * if k < from { 0.6 + 0.8 * ((k / 500) % 2) as f64 } else { 0.7 })
            .collect();
        let y = ramp_plus(&e);
        let found = estimate(std::slice::from_ref(&y)).unwrap();
        let floor = held_out_floor(found.sigma_n, &[y], &[from]).unwrap();
        let truth = held_out_mae(&e, from);
        assert!(found.mae_n > 1.25 * truth, "the whole's floor {} against {truth}", found.mae_n);
        assert!((floor / truth - 1.0).abs() < 0.03, "{floor} against {truth}");
        assert_eq!(held_out_floor(1.0, &[vec![0.0; 100]], &[0]), None, "too few contrasts");
    }

    #[test]
    fn coloured_noise_is_found_with_its_whole_variance() {
        for (phi, var) in [(vec![0.7], 7.0), (vec![1.2, -0.45], 9.0), (vec![0.3], 7.0)] {
            let truth = ArModel::new(phi.clone(), 1.0).with_marginal_var(var);
            let mut y = ramp_plus(&truth.generate(30_000, 5));
            // Lost samples and an outlier removed: gaps in the stretch.
            for k in (0..y.len()).step_by(97) {
                y[k] = f64::NAN;
            }
            let found = estimate(&[y]).unwrap();
            assert_eq!(found.model.order(), phi.len(), "{phi:?}: {:?}", found.model);
            for (a, b) in found.model.phi.iter().zip(&phi) {
                assert!((a - b).abs() < 0.05, "{phi:?}: {:?}", found.model.phi);
            }
            assert!((found.model.marginal_var() - var).abs() < 0.08 * var, "{phi:?}: {}", found.model.marginal_var());
        }
    }

    #[test]
    fn a_residual_that_is_all_noise_gets_its_whole_model() {
        // White noise plus a slow wander: second differences miss the wander, the
        // series' own autocovariance does not.
        let slow = ArModel::new(vec![0.97], 1.0).with_marginal_var(2.0).generate(30_000, 8);
        let fast = ArModel::white(5.0).generate(30_000, 9);
        let e: Vec<f64> = slow.iter().zip(&fast).map(|(a, b)| a + b).collect();
        let model = fit_to_series(&[e]).unwrap();
        assert!((model.marginal_var() - 7.0).abs() < 0.7, "{model:?}: {}", model.marginal_var());
        assert!(!model.phi.is_empty());
        let white = fit_to_series(&[ArModel::white(7.0).generate(30_000, 10)]).unwrap();
        assert_eq!(white.order(), 0, "{white:?}");
    }

    #[test]
    fn pacf_round_trips_and_innovations_whiten() {
        let phi = vec![0.9, -0.2, 0.05];
        let back = from_pacf(&to_pacf(&phi));
        assert!(phi.iter().zip(&back).all(|(a, b)| (a - b).abs() < 1e-12), "{back:?}");
        let model = ArModel::new(vec![0.8], 1.0);
        let e = model.generate(20_000, 2);
        let w: Vec<f64> = (0..e.len()).filter_map(|k| model.innovation(&e, k)).collect();
        let lag1 = w.windows(2).map(|p| p[0] * p[1]).sum::<f64>() / w.iter().map(|x| x * x).sum::<f64>();
        assert!(lag1.abs() < 0.03, "{lag1}");
        assert_eq!(model.innovation(&[1.0, f64::NAN, 2.0], 2), None);
        assert!((model.autocorrelation(3)[2] - 0.64).abs() < 1e-9);
    }
}
