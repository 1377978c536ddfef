//! The ten parameters by linear least squares on Savitzky–Golay derivatives.
//!
//! `T̈ = f(T, Ṫ) + g(T, Ṫ)·v(u)` is linear in nine parameters once `B_UU` is fixed,
//! so `B_UU` is found by a one-dimensional search over the residual of the
//! nine-parameter linear fit (variable projection). The Gram matrix of the twelve
//! expanded regressors `[T, T², Ṫ, Ṫ², T·Ṫ, 1, u, u², T·u, T·u², Ṫ·u, Ṫ·u²]` is built
//! once; every candidate `B_UU` is then a 9×9 solve.
//!
//! Two things keep the estimate unbiased on noisy, step-rich data:
//! - The Savitzky–Golay second derivative at `t_k` is a weighted average of `T̈`
//!   around `t_k` (its Peano kernel). The regressors are averaged with the very
//!   same kernel, the throttle exactly over the intervals it was held, so a step
//!   in `u` is seen on both sides of the equation alike.
//! - Thrust and rate in the regressors are smoothed first, so their noise is small
//!   against their range (errors in the regressors bias least squares).

use jetbench_model::{Params, STEP_S};
use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use serde::Serialize;

use crate::spd::SpdSolver;

use crate::series::Series;
use crate::IdentError;

/// Options of the least-squares fit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LsOptions {
    /// Savitzky–Golay window, samples (odd).
    pub window: usize,
    /// Savitzky–Golay polynomial order.
    pub order: usize,
}

impl Default for LsOptions {
    fn default() -> Self {
        LsOptions { window: 101, order: 3 }
    }
}

/// The result of a least-squares fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LsFit {
    /// The ten coefficients fitted.
    pub params: Params,
    /// RMS of the acceleration residual, N/s².
    pub residual_rms_n_per_s2: f64,
    /// Equations (samples) used.
    pub samples: usize,
}

type Gram = SMatrix<f64, 12, 12>;
type Vec12 = SVector<f64, 12>;

/// Normal equations of the twelve expanded regressors, from cross products of
/// the two independent halves of the data (see the module docs): the noise of one
/// half never multiplies itself, so it adds no bias.
#[derive(Clone, Debug)]
struct Normal {
    gram: Gram,
    rhs: Vec12,
    yy: f64,
    n: usize,
}

impl Normal {
    fn new() -> Self {
        Normal { gram: Gram::zeros(), rhs: Vec12::zeros(), yy: 0.0, n: 0 }
    }

    /// Adds the equations of one time point read off the even (`a`) and odd (`b`) samples.
    fn add(&mut self, a: &Equation, b: &Equation) {
        let cross = a.row * b.row.transpose();
        self.gram += cross + cross.transpose();
        self.rhs += a.row * b.target + b.row * a.target;
        self.yy += 2.0 * a.target * b.target;
        self.n += 2;
    }

    /// The nine-parameter solution for `b = B_UU`, and its residual sum of squares.
    fn solve(&self, b: f64) -> Option<(SVector<f64, 9>, f64)> {
        // Columns of M map [K_T..c, B_U, B_T, B_D] to the twelve expanded coefficients.
        let mut m = SMatrix::<f64, 12, 9>::zeros();
        for i in 0..6 {
            m[(i, i)] = 1.0;
        }
        for (j, (lin, quad)) in [(6, 7), (8, 9), (10, 11)].into_iter().enumerate() {
            m[(lin, 6 + j)] = 1.0;
            m[(quad, 6 + j)] = b;
        }
        let a = m.transpose() * self.gram * m;
        let r = m.transpose() * self.rhs;
        // The regressors differ by orders of magnitude: the solver scales to a unit diagonal.
        let solver = SpdSolver::new(DMatrix::from_iterator(9, 9, a.iter().copied()))?;
        let theta = SVector::<f64, 9>::from_iterator(
            solver.solve(&DVector::from_iterator(9, r.iter().copied())).iter().copied(),
        );
        let sse = self.yy - 2.0 * theta.dot(&r) + (theta.transpose() * a * theta)[(0, 0)];
        theta.iter().all(|x| x.is_finite()).then_some((theta, sse))
    }
}

/// Fits the ten parameters to every contiguous run of `data`.
pub fn fit(data: &[Series], options: &LsOptions) -> Result<LsFit, IdentError> {
    if options.window.is_multiple_of(2) || options.window < 4 * (options.order + 1) || options.order < 2 {
        return Err(IdentError::Options(format!(
            "least squares: window {} must be odd and at least 4·(order + 1), order {} at least 2",
            options.window, options.order
        )));
    }
    let half_span = options.window / 2;
    let half = Half::new(half_span, options.order)
        .ok_or_else(|| IdentError::Options(format!("least squares: window {} too short", options.window)))?;
    let mut normal = Normal::new();
    let (mut a, mut b) = (Equation { row: Vec12::zeros(), target: 0.0 }, Equation { row: Vec12::zeros(), target: 0.0 });
    for s in data {
        for run in s.runs() {
            let (y, u) = (&s.thrust_n[run.clone()], &s.u_pct[run]);
            if y.len() <= 4 * half_span + 1 {
                continue;
            }
            let even = smooth(&half, y, 0, half_span);
            let odd = smooth(&half, y, 1, half_span);
            for k in 2 * half_span..y.len() - 2 * half_span {
                equation(&half, &even, u, 0, k, &mut a);
                equation(&half, &odd, u, 1, k, &mut b);
                normal.add(&a, &b);
            }
        }
    }
    if normal.n < 100 {
        return Err(IdentError::TooLittleData(format!(
            "least squares needs contiguous runs of more than {} samples; found {} usable equations",
            4 * half_span + 1,
            normal.n
        )));
    }
    let b_uu = search_b_uu(&normal).ok_or_else(|| IdentError::Singular("least squares".into()))?;
    let (theta, sse) = normal.solve(b_uu).ok_or_else(|| IdentError::Singular("least squares".into()))?;
    let mut p = [0.0; 10];
    p[..9].copy_from_slice(theta.as_slice());
    p[9] = b_uu;
    Ok(LsFit {
        params: Params::from_array(p),
        residual_rms_n_per_s2: (sse.max(0.0) / normal.n as f64).sqrt(),
        samples: normal.n,
    })
}

/// `B_UU` minimising the residual: a coarse scan of the plausible range, then a
/// golden-section refinement around the best point.
fn search_b_uu(normal: &Normal) -> Option<f64> {
    let sse = |b: f64| normal.solve(b).map_or(f64::INFINITY, |(_, s)| s);
    // v(u) = u + B_UU·u² must stay monotonic over the throttle range: |B_UU| < 1/200.
    let (lo, hi, steps) = (-0.005, 0.05, 220);
    let grid = (0..=steps).map(|i| lo + (hi - lo) * i as f64 / steps as f64);
    let (best, best_sse) = grid.map(|b| (b, sse(b))).min_by(|a, b| a.1.total_cmp(&b.1))?;
    if !best_sse.is_finite() {
        return None;
    }
    let h = (hi - lo) / steps as f64;
    let (mut a, mut b) = (best - h, best + h);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (sse(c), sse(d));
    for _ in 0..60 {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = sse(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = sse(d);
        }
    }
    Some((a + b) / 2.0)
}

/// Local polynomial (Savitzky–Golay) kernels over a set of sample offsets: value,
/// rate and acceleration at offset 0, and the averaging weights that make the
/// regressors consistent with the acceleration kernel.
struct Kernel {
    /// Sample offsets used (all of one parity).
    offsets: Vec<isize>,
    value: Vec<f64>,
    rate: Vec<f64>,
    accel: Vec<f64>,
    /// Leftmost integer offset of the averaging weights.
    left: isize,
    /// Weights of smooth regressors at integer offsets `left..`.
    knots: Vec<f64>,
    /// Weights of the held throttle over `[left + i, left + i + 1)`.
    intervals: Vec<f64>,
}

impl Kernel {
    /// Least-squares polynomial of `order` through `offsets` (unit spacing),
    /// differentiated at 0.
    fn new(offsets: Vec<isize>, order: usize) -> Option<Kernel> {
        let scale = offsets.iter().map(|o| o.unsigned_abs()).max()?.max(1) as f64;
        let v = DMatrix::from_fn(offsets.len(), order + 1, |r, c| (offsets[r] as f64 / scale).powi(c as i32));
        // Rows of (VᵀV)⁻¹Vᵀ: the coefficients of 1, x, x² as weights of the samples.
        let pinv = (v.transpose() * &v).try_inverse()? * v.transpose();
        let row = |c: usize, factor: f64| -> Vec<f64> { pinv.row(c).iter().map(|w| w * factor).collect() };
        let (value, rate, accel) = (row(0, 1.0), row(1, 1.0 / scale), row(2, 2.0 / (scale * scale)));
        // Peano kernel of the acceleration weights: Σ_j h_j T(j) = ∫ T̈(s)·K(s) ds with
        // K(s) = Σ_{j > s} h_j (j − s), piecewise linear between sample offsets.
        let (left, right) = (*offsets.first()?, *offsets.last()?);
        let knots: Vec<f64> = (left..=right)
            .map(|s| offsets.iter().zip(&accel).filter(|(j, _)| **j > s).map(|(j, h)| h * (j - s) as f64).sum())
            .collect();
        let intervals = knots.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
        Some(Kernel { offsets, value, rate, accel, left, knots, intervals })
    }

    fn apply(weights: &[f64], offsets: &[isize], y: &[f64], i: usize) -> f64 {
        weights.iter().zip(offsets).map(|(w, o)| w * y[(i as isize + o) as usize]).sum()
    }
}

/// The centred Savitzky–Golay acceleration weights over `window` samples and
/// their Peano kernel at each sample (the weights with which any smooth
/// regressor must be averaged to match the acceleration estimate).
pub(crate) fn centred_kernel(window: usize, order: usize) -> Option<(Vec<f64>, Vec<f64>)> {
    let h = (window / 2) as isize;
    let k = Kernel::new((-h..=h).collect(), order)?;
    Some((k.accel, k.knots))
}

/// Kernels that read a time point off the samples of one parity only.
struct Half {
    /// For time points of the same parity as the samples.
    on: Kernel,
    /// For time points between them.
    off: Kernel,
}

impl Half {
    fn new(half: usize, order: usize) -> Option<Half> {
        let h = (half / 2 * 2) as isize;
        Some(Half {
            on: Kernel::new((-h..=h).step_by(2).collect(), order)?,
            off: Kernel::new((-(h - 1)..=(h - 1)).step_by(2).collect(), order)?,
        })
    }
}

/// Regressors and target of one time point from the samples of one parity.
struct Equation {
    row: Vec12,
    target: f64,
}

/// Thrust, rate and acceleration at every time point, from the samples of parity `p`.
fn smooth(half: &Half, y: &[f64], p: usize, reach: usize) -> [Vec<f64>; 3] {
    let n = y.len();
    let [mut value, mut rate, mut accel] = [vec![f64::NAN; n], vec![f64::NAN; n], vec![f64::NAN; n]];
    for (i, ((v, r), a)) in value.iter_mut().zip(&mut rate).zip(&mut accel).enumerate().take(n - reach).skip(reach) {
        let k = if i % 2 == p { &half.on } else { &half.off };
        *v = Kernel::apply(&k.value, &k.offsets, y, i);
        *r = Kernel::apply(&k.rate, &k.offsets, y, i) / STEP_S;
        *a = Kernel::apply(&k.accel, &k.offsets, y, i) / (STEP_S * STEP_S);
    }
    [value, rate, accel]
}

fn equation(half: &Half, states: &[Vec<f64>; 3], u: &[f64], p: usize, k: usize, eq: &mut Equation) {
    let kernel = if k % 2 == p { &half.on } else { &half.off };
    let (t, d) = (&states[0], &states[1]);
    eq.row.fill(0.0);
    for (i, &w) in kernel.knots.iter().enumerate() {
        let j = (k as isize + kernel.left + i as isize) as usize;
        let terms = [t[j], t[j] * t[j], d[j], d[j] * d[j], t[j] * d[j], 1.0];
        for (r, x) in eq.row.iter_mut().zip(terms) {
            *r += w * x;
        }
    }
    for (i, &w) in kernel.intervals.iter().enumerate() {
        let j = (k as isize + kernel.left + i as isize) as usize;
        // Over [j, j + 1) the throttle is u[j]; the state factor is the interval's mean.
        let (tm, dm) = (0.5 * (t[j] + t[j + 1]), 0.5 * (d[j] + d[j + 1]));
        let (uj, uu) = (u[j], u[j] * u[j]);
        eq.row[6] += w * uj;
        eq.row[7] += w * uu;
        eq.row[8] += w * tm * uj;
        eq.row[9] += w * tm * uu;
        eq.row[10] += w * dm * uj;
        eq.row[11] += w * dm * uu;
    }
    eq.target = states[2][k];
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::{synth, validate};
    use jetbench_model::Preset;

    #[test]
    fn recovers_the_plant_without_noise() {
        for preset in [Preset::P100Diesel, Preset::P220Kerosene] {
            let truth = preset.params();
            let s = synth::record(&truth, &synth::test_profile(20_000, 9), 0.0, 0).unwrap();
            let fit = fit(std::slice::from_ref(&s), &LsOptions::default()).unwrap();
            let score = validate::simulate(&fit.params, std::slice::from_ref(&s)).score(&[s]).unwrap();
            assert!(score.mae_n < 0.2, "{preset:?}: {:?} -> {score:?}", fit.params);
        }
    }
}
