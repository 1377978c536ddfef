//! The ten parameters in the state of an extended Kalman filter (docs/model/README.md).
//!
//! State `[T, Ṫ, K_T, …, B_UU]` (12), parameters as random walks, measurement
//! `y = T`. Each pass runs the filter over the calibration data starting from
//! the previous pass's parameters; passes repeat until the free-run validation
//! error stops improving, and the best pass is kept.
//!
//! Prediction integrates the model with one classic RK4 step per sample (the
//! simulated engine's integrator to within `O(Δt⁵)`), so the parameters are
//! those of the continuous model that validation simulates. The Jacobian is the
//! study's discretisation `T⁺ = T + Ṫ·Δt + T̈·Δt²/2`, `Ṫ⁺ = Ṫ + T̈·Δt`.
//!
//! The covariance is kept in blocks (state 2×2, cross 2×10, parameters 10×10):
//! the transition is the identity on the parameters, so a step costs a few
//! hundred multiplications instead of two 12×12 products.

use jetbench_model::{Params, STEP_S};
use nalgebra::{SMatrix, SVector};
use serde::Serialize;

use crate::excite::sensitivities;
use crate::series::Series;
use crate::validate::{self, NoiseFloor, Score};
use crate::IdentError;

type P10 = SMatrix<f64, 10, 10>;
type X2P = SMatrix<f64, 2, 10>;
type V10 = SVector<f64, 10>;

/// Tuning of the identification filter; `None` means "set from the data".
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct EkfOptions {
    /// Measurement noise variance R, N². Default: the estimated noise variance.
    pub measurement_var_n2: Option<f64>,
    /// Standard deviation of unmodelled thrust acceleration, N/s². Default: 8·σ per
    /// second squared, with σ the noise standard deviation in N (a noisier bench
    /// trusts the model less).
    pub accel_noise_n_per_s2: Option<f64>,
    /// Initial standard deviation of each parameter, relative to its scale.
    pub p0_relative: f64,
    /// Random-walk standard deviation of each parameter per sample, relative to its scale.
    pub walk_relative: f64,
    /// Most passes over the calibration data.
    pub max_passes: usize,
}

impl Default for EkfOptions {
    fn default() -> Self {
        EkfOptions {
            measurement_var_n2: None,
            accel_noise_n_per_s2: None,
            p0_relative: 0.1,
            walk_relative: 1e-5,
            max_passes: 20,
        }
    }
}

/// One pass over the calibration data.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Pass {
    /// Its number, from 1.
    pub pass: usize,
    /// Free-run validation score after the pass; `None` if the model diverged.
    pub validation: Option<Score>,
}

/// The result of the filter identification.
#[derive(Clone, Debug, PartialEq)]
pub struct EkfFit {
    /// Parameters of the best pass.
    pub params: Params,
    /// Every pass run, in order, with its validation score.
    pub passes: Vec<Pass>,
    /// The tuning actually used (defaults resolved): the measurement variance, N².
    pub measurement_var_n2: f64,
    /// The process noise used: unmodelled acceleration, N/s².
    pub accel_noise_n_per_s2: f64,
}

/// Runs passes from `start` until validation on `validation` stops improving.
/// `progress` is told about each pass as it ends.
pub fn fit(
    calibration: &[Series],
    validation: &[Series],
    start: Params,
    noise: NoiseFloor,
    options: &EkfOptions,
    mut progress: impl FnMut(&Pass),
) -> Result<EkfFit, IdentError> {
    let r = options.measurement_var_n2.unwrap_or(noise.sigma_n.powi(2)).max(1e-6);
    let sigma_a = options.accel_noise_n_per_s2.unwrap_or(8.0 * r.sqrt());
    if !(r.is_finite() && sigma_a.is_finite() && sigma_a > 0.0) {
        return Err(IdentError::Options(format!("EKF: R = {r} N², accel noise = {sigma_a} N/s² must be positive")));
    }
    let scales = param_scales(calibration, &start);
    let score = |p: &Params| validate::simulate(p, validation).score(validation);
    let mut best = (start, score(&start));
    let mut params = start;
    let mut passes = Vec::new();
    let mut worse_in_a_row = 0;
    for pass in 1..=options.max_passes.max(1) {
        let filter = Filter { r, sigma_a, scales, options: *options };
        params = match filter.pass(calibration, params) {
            Some(p) => p,
            None => break, // the filter blew up: keep the best pass so far
        };
        let validation = score(&params);
        let report = Pass { pass, validation };
        progress(&report);
        passes.push(report);
        let better = match (validation, best.1) {
            (Some(now), Some(was)) => now.mae_n < was.mae_n,
            (Some(_), None) => true,
            _ => false,
        };
        if better {
            // Improvements below 0.1 % count as converged.
            let converged = best.1.is_some_and(|was| validation.is_some_and(|now| now.mae_n > 0.999 * was.mae_n));
            best = (params, validation);
            worse_in_a_row = 0;
            if converged {
                break;
            }
        } else {
            worse_in_a_row += 1;
            if worse_in_a_row >= 2 {
                break;
            }
        }
    }
    Ok(EkfFit { params: best.0, passes, measurement_var_n2: r, accel_noise_n_per_s2: sigma_a })
}

/// The natural size of each parameter on this data: the coefficient that would
/// make its term alone as large as the typical acceleration, or the starting
/// value if that is larger.
fn param_scales(data: &[Series], start: &Params) -> V10 {
    let mut sum_sq = V10::zeros();
    let mut n = 0.0f64;
    for s in data {
        for run in s.runs() {
            let y = &s.thrust_n[run.clone()];
            let u = &s.u_pct[run];
            for k in 1..y.len().saturating_sub(1) {
                let d = (y[k + 1] - y[k - 1]) / (2.0 * STEP_S);
                let phi = V10::from(sensitivities(start, y[k], d.clamp(-500.0, 500.0), u[k]));
                sum_sq += phi.component_mul(&phi);
                n += 1.0;
            }
        }
    }
    // Typical thrust acceleration of such engines: tens of N/s².
    const TYPICAL_ACCEL: f64 = 50.0;
    let start = V10::from(start.to_array());
    V10::from_fn(|i, _| {
        let rms = (sum_sq[i] / n.max(1.0)).sqrt();
        let natural = if rms > 0.0 { TYPICAL_ACCEL / rms } else { 1.0 };
        start[i].abs().max(0.05 * natural)
    })
}

struct Filter {
    r: f64,
    sigma_a: f64,
    scales: V10,
    options: EkfOptions,
}

impl Filter {
    /// One pass over every run; `None` if the state became non-finite.
    fn pass(&self, data: &[Series], start: Params) -> Option<Params> {
        let dt = STEP_S;
        let mut p = V10::from(start.to_array());
        let p0 = V10::from_fn(|i, _| (self.options.p0_relative * self.scales[i]).powi(2));
        let walk = V10::from_fn(|i, _| (self.options.walk_relative * self.scales[i]).powi(2));
        let mut ppp = P10::from_diagonal(&p0);
        // Process noise of [T, Ṫ] from white acceleration held over a step.
        let qa = self.sigma_a * self.sigma_a;
        let qx = SMatrix::<f64, 2, 2>::new(
            qa * dt.powi(4) / 4.0,
            qa * dt.powi(3) / 2.0,
            qa * dt.powi(3) / 2.0,
            qa * dt * dt,
        );
        for s in data {
            for run in s.runs() {
                let y = &s.thrust_n[run.clone()];
                let u = &s.u_pct[run];
                if y.len() < 3 {
                    continue;
                }
                let start_state = validate::initial_state(y);
                let mut x = SVector::<f64, 2>::new(start_state.thrust_n, start_state.thrust_rate_n_per_s);
                let mut pxx = SMatrix::<f64, 2, 2>::new(self.r, 0.0, 0.0, 100.0);
                let mut pxp = X2P::zeros();
                for k in 0..y.len() {
                    if k > 0 {
                        // Predict over [k − 1, k) with u[k − 1] held.
                        let params = Params::from_array(p.into());
                        let (t, d, uk) = (x[0], x[1], u[k - 1]);
                        let partials = params.accel_partials(t, d, uk);
                        let a_p = V10::from(sensitivities(&params, t, d, uk));
                        let next = rk4(&params, t, d, uk, dt);
                        let a = SMatrix::<f64, 2, 2>::new(
                            1.0 + partials.d_thrust_per_s2 * dt * dt / 2.0,
                            dt + partials.d_rate_per_s * dt * dt / 2.0,
                            partials.d_thrust_per_s2 * dt,
                            1.0 + partials.d_rate_per_s * dt,
                        );
                        let b = X2P::from_rows(&[(a_p * (dt * dt / 2.0)).transpose(), (a_p * dt).transpose()]);
                        let b_ppp = b * ppp;
                        let a_pxp = a * pxp;
                        pxx = a * pxx * a.transpose()
                            + a_pxp * b.transpose()
                            + b * pxp.transpose() * a.transpose()
                            + b_ppp * b.transpose()
                            + qx;
                        pxp = a_pxp + b_ppp;
                        ppp += P10::from_diagonal(&walk);
                        x = SVector::<f64, 2>::new(next.0, next.1);
                    }
                    // Update with y[k] = T.
                    let s_inv = 1.0 / (pxx[(0, 0)] + self.r);
                    let innovation = y[k] - x[0];
                    let kx = pxx.column(0) * s_inv;
                    let kp: V10 = pxp.row(0).transpose() * s_inv;
                    let pxx_row = pxx.row(0).into_owned();
                    let pxp_row = pxp.row(0).into_owned();
                    x += kx * innovation;
                    p += kp * innovation;
                    pxx -= kx * pxx_row;
                    pxp -= kx * pxp_row;
                    ppp -= kp * pxp_row;
                    if !(x[0].is_finite() && x[1].is_finite() && p.iter().all(|v| v.is_finite())) {
                        return None;
                    }
                }
                ppp = (ppp + ppp.transpose()) * 0.5;
            }
        }
        Some(Params::from_array(p.into()))
    }
}

/// One RK4 step of `[Ṫ, T̈]` with the throttle held.
fn rk4(p: &Params, t: f64, d: f64, u: f64, h: f64) -> (f64, f64) {
    let f = |t: f64, d: f64| (d, p.accel(t, d, u));
    let k1 = f(t, d);
    let k2 = f(t + 0.5 * h * k1.0, d + 0.5 * h * k1.1);
    let k3 = f(t + 0.5 * h * k2.0, d + 0.5 * h * k2.1);
    let k4 = f(t + h * k3.0, d + h * k3.1);
    (t + h / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0), d + h / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1))
}
