//! A generic sparse model of what the catalogue may not name: the residual regressed
//! on a library of candidate terms by sequentially thresholded least squares.
//!
//! The terms are built from the model's own noise-free simulation (its thrust, rate
//! and acceleration), the throttle and time, so they carry no measurement noise and
//! the regression is not biased by errors in its variables. Each term reads as
//! physics: `dT/dt` is a timing error (the coefficient is a lead in seconds), `T` a
//! gain error, `sign(dT/dt)` a band that follows the direction of change, `t·T` a
//! gain that drifts over the run, `T_slow` a bias that follows thrust history.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use jetbench_model::STEP_S;

use super::fit::{Part, Problem, Sim};

/// Terms of the library, with the unit of their coefficient.
const TERMS: [(&str, &str); 10] = [
    ("1", "N"),
    ("T", "1"),
    ("T^2", "1/N"),
    ("dT/dt", "s"),
    ("d2T/dt2", "s^2"),
    ("sign(dT/dt)", "N"),
    ("u", "N/%"),
    ("t", "N/min"),
    ("t*T", "1/min"),
    ("T_slow", "1"),
];
/// Time constant of the slow-thrust term, s.
const SLOW_S: f64 = 30.0;
/// Rate at which `sign(dT/dt)` is half way to ±1, N/s.
const SIGN_SCALE_N_PER_S: f64 = 2.0;

/// One term kept by the sparse regression.
#[derive(Clone, Debug, Serialize)]
pub struct Term {
    pub term: &'static str,
    pub coefficient: f64,
    /// Unit of the coefficient.
    pub unit: &'static str,
    /// RMS of its contribution to the residual, N.
    pub rms_n: f64,
}

/// The sparse discrepancy model of one residual.
#[derive(Clone, Debug, Serialize)]
pub struct Discrepancy {
    /// Terms kept, largest contribution first; empty when nothing stands out.
    pub terms: Vec<Term>,
    /// Validation MAE of the model alone, N.
    pub mae_val_before_n: f64,
    /// Validation MAE with the discrepancy added to the model's output, N.
    pub mae_val_after_n: f64,
}

impl Discrepancy {
    /// `r ≈ 0.081·dT/dt − 1.20·sign(dT/dt)`.
    pub fn equation(&self) -> String {
        if self.terms.is_empty() {
            return "r ≈ 0 (no term stands out)".to_owned();
        }
        let parts: Vec<String> = self.terms.iter().map(|t| format!("{:+.4}·{}", t.coefficient, t.term)).collect();
        format!("r ≈ {}", parts.join(" ").trim_start_matches('+'))
    }
}

/// Library rows for series `i`, aligned with `rows` (all rows of its runs).
fn library(problem: &Problem<'_>, sim: &Sim, i: usize, rows: &[usize]) -> Vec<[f64; TERMS.len()]> {
    let s = &problem.data[i];
    let mut out = Vec::with_capacity(rows.len());
    for piece in rows.chunk_by(|a, b| b == &(a + 1)) {
        let y: Vec<f64> = piece.iter().map(|&k| sim[i][k]).collect();
        let n = y.len();
        let diff = |x: &[f64], j: usize| {
            let (a, b) = (j.saturating_sub(1), (j + 1).min(n - 1));
            if b > a {
                (x[b] - x[a]) / ((b - a) as f64 * STEP_S)
            } else {
                0.0
            }
        };
        let rate: Vec<f64> = (0..n).map(|j| diff(&y, j)).collect();
        let alpha = 1.0 - (-STEP_S / SLOW_S).exp();
        let mut slow = y.first().copied().unwrap_or(0.0);
        for (j, &k) in piece.iter().enumerate() {
            slow += (y[j] - slow) * alpha;
            let t_min = s.t_s[k] / 60.0;
            out.push([
                1.0,
                y[j],
                y[j] * y[j],
                rate[j],
                diff(&rate, j),
                (rate[j] / SIGN_SCALE_N_PER_S).tanh(),
                s.u_pct[k],
                t_min,
                t_min * y[j],
                slow,
            ]);
        }
    }
    out
}

/// Fits the sparse discrepancy model of `measured − sim` on the calibration rows and
/// scores it on the validation rows. `threshold_n`: a term is kept only when its
/// contribution has at least this RMS.
pub(crate) fn fit(problem: &Problem<'_>, sim: &Sim, threshold_n: f64) -> Discrepancy {
    let p = TERMS.len();
    let (mut rows_cal, mut r_cal) = (Vec::new(), Vec::new());
    let (mut rows_val, mut r_val) = (Vec::new(), Vec::new());
    for i in 0..problem.data.len() {
        let rows: Vec<usize> = problem.rows(i, Part::All).collect();
        let lib = library(problem, sim, i, &rows);
        for (&k, theta) in rows.iter().zip(lib) {
            let r = problem.data[i].thrust_n[k] - sim[i][k];
            if k < problem.cut[i] {
                rows_cal.push(theta);
                r_cal.push(r);
            } else {
                rows_val.push(theta);
                r_val.push(r);
            }
        }
    }
    let n = rows_cal.len().max(1) as f64;
    // Column scales: the RMS of each term (its contribution per unit coefficient).
    let scale: Vec<f64> =
        (0..p).map(|j| (rows_cal.iter().map(|row| row[j] * row[j]).sum::<f64>() / n).sqrt().max(1e-12)).collect();
    let mut gram = DMatrix::<f64>::zeros(p, p);
    let mut rhs = DVector::<f64>::zeros(p);
    for (row, &r) in rows_cal.iter().zip(&r_cal) {
        for a in 0..p {
            let xa = row[a] / scale[a];
            rhs[a] += xa * r;
            for b in a..p {
                gram[(a, b)] += xa * row[b] / scale[b];
            }
        }
    }
    for a in 0..p {
        for b in 0..a {
            gram[(a, b)] = gram[(b, a)];
        }
    }
    gram /= n;
    rhs /= n;
    let mut active: Vec<usize> = (0..p).collect();
    let mut w = vec![0.0; p];
    for _ in 0..20 {
        if active.is_empty() {
            break;
        }
        let m = active.len();
        let sub = DMatrix::from_fn(m, m, |a, b| gram[(active[a], active[b])] + if a == b { 1e-9 } else { 0.0 });
        let sub_rhs = DVector::from_fn(m, |a, _| rhs[active[a]]);
        let Some(sol) = sub.cholesky().map(|c| c.solve(&sub_rhs)) else { break };
        w.fill(0.0);
        for (a, &j) in active.iter().enumerate() {
            w[j] = sol[a];
        }
        // The contribution of a term is its scaled coefficient (N RMS); the constant
        // is judged the same way.
        let kept: Vec<usize> = active.iter().copied().filter(|&j| w[j].abs() >= threshold_n).collect();
        if kept.len() == active.len() {
            break;
        }
        active = kept;
    }
    for (j, wj) in w.iter_mut().enumerate() {
        if !active.contains(&j) {
            *wj = 0.0;
        }
    }
    let predict = |row: &[f64; TERMS.len()]| (0..p).map(|j| w[j] * row[j] / scale[j]).sum::<f64>();
    let mae = |rows: &[[f64; TERMS.len()]], r: &[f64], corrected: bool| {
        rows.iter().zip(r).map(|(row, &ri)| (ri - if corrected { predict(row) } else { 0.0 }).abs()).sum::<f64>()
            / r.len().max(1) as f64
    };
    let mut terms: Vec<Term> = active
        .iter()
        .map(|&j| Term { term: TERMS[j].0, coefficient: w[j] / scale[j], unit: TERMS[j].1, rms_n: w[j].abs() })
        .collect();
    terms.sort_by(|a, b| b.rms_n.total_cmp(&a.rms_n));
    Discrepancy {
        terms,
        mae_val_before_n: mae(&rows_val, &r_val, false),
        mae_val_after_n: mae(&rows_val, &r_val, true),
    }
}
