//! The ten model coefficients and the algebra on them.

use serde::{Deserialize, Serialize};

use crate::ModelError;

/// Coefficients of `T̈ = f(T, Ṫ) + g(T, Ṫ)·v(u)` (see docs/model/README.md), with thrust `T` in N,
/// its rate `Ṫ` in N/s and the throttle `u` in %.
///
/// ```text
/// f = K_T·T + K_TT·T² + K_D·Ṫ + K_DD·Ṫ² + K_TD·T·Ṫ + c      (N/s²)
/// g = B_U + B_T·T + B_D·Ṫ                                   (N/s² per unit of v)
/// v = u + B_UU·u²
/// ```
///
/// Field names follow the study's notation in files (`K_T`, ..., `c`, ..., `B_UU`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// `K_T` (1/s²): linear thrust term of the drift.
    #[serde(rename = "K_T")]
    pub k_t: f64,
    /// `K_TT` (1/(N·s²)): quadratic thrust term of the drift.
    #[serde(rename = "K_TT")]
    pub k_tt: f64,
    /// `K_D` (1/s): damping.
    #[serde(rename = "K_D")]
    pub k_d: f64,
    /// `K_DD` (s/N): quadratic rate term.
    #[serde(rename = "K_DD")]
    pub k_dd: f64,
    /// `K_TD` (1/(N·s)): thrust-rate cross term.
    #[serde(rename = "K_TD")]
    pub k_td: f64,
    /// `c` (N/s²): constant drift.
    #[serde(rename = "c")]
    pub c: f64,
    /// `B_U`: constant input gain.
    #[serde(rename = "B_U")]
    pub b_u: f64,
    /// `B_T`: input gain growth with thrust.
    #[serde(rename = "B_T")]
    pub b_t: f64,
    /// `B_D`: input gain change with thrust rate.
    #[serde(rename = "B_D")]
    pub b_d: f64,
    /// `B_UU` (1/%): curvature of the throttle map `v(u)`.
    #[serde(rename = "B_UU")]
    pub b_uu: f64,
}

/// A rest point of the model (`Ṫ = 0`) for a constant throttle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Equilibrium {
    /// Thrust at rest, N.
    pub thrust_n: f64,
    /// True when both eigenvalues of the linearisation have negative real part.
    pub stable: bool,
}

/// Partial derivatives of the thrust acceleration `T̈ = f + g·v`, used by the EKF and
/// by the stability test of equilibria.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct AccelPartials {
    /// `∂T̈/∂T`, 1/s².
    pub d_thrust_per_s2: f64,
    /// `∂T̈/∂Ṫ`, 1/s.
    pub d_rate_per_s: f64,
}

impl Params {
    /// Parameter names as written in model files, in the order of [`Params::to_array`].
    pub const NAMES: [&'static str; 10] = ["K_T", "K_TT", "K_D", "K_DD", "K_TD", "c", "B_U", "B_T", "B_D", "B_UU"];

    /// The parameters in [`Params::NAMES`] order, for identification code that works on vectors.
    pub fn to_array(&self) -> [f64; 10] {
        [self.k_t, self.k_tt, self.k_d, self.k_dd, self.k_td, self.c, self.b_u, self.b_t, self.b_d, self.b_uu]
    }

    /// Inverse of [`Params::to_array`].
    pub fn from_array(a: [f64; 10]) -> Self {
        let [k_t, k_tt, k_d, k_dd, k_td, c, b_u, b_t, b_d, b_uu] = a;
        Self { k_t, k_tt, k_d, k_dd, k_td, c, b_u, b_t, b_d, b_uu }
    }

    /// Drift `f(T, Ṫ)`, N/s²: the acceleration the engine has with `v = 0`.
    pub fn f(&self, thrust_n: f64, thrust_rate_n_per_s: f64) -> f64 {
        let t = thrust_n;
        let d = thrust_rate_n_per_s;
        self.k_t * t + self.k_tt * t * t + self.k_d * d + self.k_dd * d * d + self.k_td * t * d + self.c
    }

    /// Input gain `g(T, Ṫ)`: N/s² of acceleration per unit of `v`.
    pub fn g(&self, thrust_n: f64, thrust_rate_n_per_s: f64) -> f64 {
        self.b_u + self.b_t * thrust_n + self.b_d * thrust_rate_n_per_s
    }

    /// Throttle map `v(u) = u + B_UU·u²`.
    pub fn v(&self, throttle_pct: f64) -> f64 {
        throttle_pct + self.b_uu * throttle_pct * throttle_pct
    }

    /// Thrust acceleration `T̈ = f + g·v`, N/s².
    pub fn accel(&self, thrust_n: f64, thrust_rate_n_per_s: f64, throttle_pct: f64) -> f64 {
        self.f(thrust_n, thrust_rate_n_per_s) + self.g(thrust_n, thrust_rate_n_per_s) * self.v(throttle_pct)
    }

    /// Analytic partial derivatives of [`Params::accel`] in `T` and `Ṫ`.
    pub fn accel_partials(&self, thrust_n: f64, thrust_rate_n_per_s: f64, throttle_pct: f64) -> AccelPartials {
        let v = self.v(throttle_pct);
        AccelPartials {
            d_thrust_per_s2: self.k_t + 2.0 * self.k_tt * thrust_n + self.k_td * thrust_rate_n_per_s + self.b_t * v,
            d_rate_per_s: self.k_d + 2.0 * self.k_dd * thrust_rate_n_per_s + self.k_td * thrust_n + self.b_d * v,
        }
    }

    /// Throttle `u` (%) with `u + B_UU·u² = v`: the smallest non-negative root.
    ///
    /// With `B_UU ≥ 0` that root is unique. With `B_UU < 0` (the `p220-ls` set) `v(u)`
    /// rises up to `u* = -1/(2·B_UU)` and falls after it, so a `v` in `[0, v(u*)]` has two
    /// non-negative roots; the one on the rising branch (`u ≤ u*`, the root that tends to
    /// `u = v` as `B_UU → 0`) is returned, so a larger `v` still means more throttle. A
    /// negative `v` then maps to the single positive root beyond `2·u*`.
    ///
    /// `None` when no real non-negative root exists or `v` is not finite. The roots are
    /// computed without cancellation, so tiny `B_UU` is as accurate as `B_UU = 0`.
    pub fn invert_v(&self, v: f64) -> Option<f64> {
        let b = self.b_uu;
        if !v.is_finite() || !b.is_finite() {
            return None;
        }
        if b == 0.0 {
            return (v >= 0.0).then_some(v);
        }
        let disc = 1.0 + 4.0 * b * v;
        if disc < 0.0 {
            return None;
        }
        // √(1 + 4bv); when 4bv overflows, b and v share a sign and √(4bv) is finite.
        let s = if disc.is_finite() { disc.sqrt() } else { 2.0 * b.abs().sqrt() * v.abs().sqrt() };
        // Rising-branch root in the cancellation-free form 2v / (1 + √(1 + 4bv)),
        // arranged so a huge v cannot overflow.
        let rising = v / (0.5 + 0.5 * s);
        if rising.is_finite() && rising >= 0.0 {
            return Some(rising);
        }
        if b < 0.0 {
            let falling = -(1.0 + s) / (2.0 * b);
            if falling.is_finite() && falling >= 0.0 {
                return Some(falling);
            }
        }
        None
    }

    /// Rest points for a constant throttle: the roots in `T` of `f(T, 0) + g(T, 0)·v(u) = 0`,
    /// a quadratic `K_TT·T² + (K_T + B_T·v)·T + (c + B_U·v)` (linear when `K_TT = 0`),
    /// sorted by thrust. Stability comes from the eigenvalues of the Jacobian
    /// `[[0, 1], [∂T̈/∂T, ∂T̈/∂Ṫ]]`. Empty for a non-finite throttle or no real root.
    pub fn equilibria(&self, throttle_pct: f64) -> Vec<Equilibrium> {
        let v = self.v(throttle_pct);
        let a2 = self.k_tt;
        let a1 = self.k_t + self.b_t * v;
        let a0 = self.c + self.b_u * v;
        let mut roots: Vec<f64> = Vec::with_capacity(2);
        if a2 == 0.0 {
            if a1 != 0.0 {
                roots.push(-a0 / a1);
            }
        } else {
            let disc = a1 * a1 - 4.0 * a2 * a0;
            if disc >= 0.0 {
                // Numerically stable pair: q/a2 and a0/q.
                let q = -0.5 * (a1 + a1.signum() * disc.sqrt());
                if q == 0.0 {
                    roots.push(0.0);
                } else {
                    roots.push(q / a2);
                    roots.push(a0 / q);
                }
            }
        }
        roots.retain(|t| t.is_finite());
        roots.sort_by(f64::total_cmp);
        roots.dedup();
        roots
            .into_iter()
            .map(|thrust_n| Equilibrium { thrust_n, stable: self.is_stable_at(thrust_n, throttle_pct) })
            .collect()
    }

    /// Stable equilibrium with the highest thrust, the operating point an engine settles at.
    pub fn stable_equilibrium(&self, throttle_pct: f64) -> Option<f64> {
        self.equilibria(throttle_pct).into_iter().filter(|e| e.stable).map(|e| e.thrust_n).next_back()
    }

    fn is_stable_at(&self, thrust_n: f64, throttle_pct: f64) -> bool {
        let p = self.accel_partials(thrust_n, 0.0, throttle_pct);
        // Eigenvalues of [[0, 1], [a, b]] solve λ² − bλ − a = 0.
        let (a, b) = (p.d_thrust_per_s2, p.d_rate_per_s);
        let disc = b * b + 4.0 * a;
        let max_real = if disc >= 0.0 { 0.5 * (b + disc.sqrt()) } else { 0.5 * b };
        max_real < 0.0
    }

    /// Checks that every parameter is finite, so a bad file fails at load, not mid-run.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (name, value) in Self::NAMES.iter().zip(self.to_array()) {
            if !value.is_finite() {
                return Err(ModelError::NonFinite { name, value });
            }
        }
        Ok(())
    }
}
