//! The iRonCub group's 13-coefficient jet model (2025): an engine whose input gain
//! depends on `T²`, `Ṫ²` and `T·Ṫ`, outside the ten parameters.
//!
//! The group's multi-rate MPC for the iRonCub humanoid (public code,
//! `ami-iit/paper_gorbani_2025_humanoids_multi-rate-mpc-ironcub`, the flight
//! controller's `JetModel`) models each jet in standardised variables
//!
//! ```text
//! T̄ = (T − μ_T)/σ_T      Ṫ̄ = Ṫ/σ_T      ū = (u − μ_u)/σ_u
//! T̈ = σ_T·(f(T̄, Ṫ̄) + g(T̄, Ṫ̄)·(ū + c₁₂·ū²))
//! f = c₀ + c₁·T̄ + c₂·Ṫ̄ + c₃·T̄·Ṫ̄ + c₄·T̄² + c₅·Ṫ̄²
//! g = c₆ + c₇·T̄ + c₈·Ṫ̄ + c₉·T̄·Ṫ̄ + c₁₀·T̄² + c₁₁·Ṫ̄²
//! ```
//!
//! with `μ_T` = 108.309 N, `σ_T` = 65.793 N, `μ_u` = 47.333 %, `σ_u` = 31.483 %. Its
//! throttle runs 0–100 %; the engine gives about 16 N at 0 % and 222 N at 100 %,
//! with one stable rest point at every throttle in between.
//!
//! The standardisation is affine, so the model is exactly the ten-parameter model
//! plus the three input-gain terms of the discrepancy library (`B_TT`, `B_DD`,
//! `B_TD`): [`IronCubJet::model_file`] writes it so, and the simulated bench runs it
//! through the same [`Plant`] as every other model. [`IronCubJet::accel`] is the
//! published form, which the tests hold the conversion to.
//!
//! ```
//! use jetbench_model::ironcub::IronCubJet;
//!
//! let jet = IronCubJet::published();
//! let file = jet.model_file();
//! let (t, d, u) = (120.0, 35.0, 60.0);
//! let disc = file.effects.get(jetbench_model::EffectKind::Discrepancy).unwrap().values();
//! let p = file.model;
//! let converted = p.accel(t, d, u) + (disc[6] * t * t + disc[7] * d * d + disc[8] * t * d) * p.v(u);
//! assert!((converted - jet.accel(t, d, u)).abs() < 1e-9 * jet.accel(t, d, u).abs().max(1.0));
//! ```

use crate::discrepancy::DISCREPANCY_DEFAULTS;
use crate::{Effect, EffectKind, Effects, ModelFile, Params, Plant};

/// Name of the iRonCub plant for `sim-record --plant` and `[plant] model`.
pub const IRONCUB_PLANT: &str = "ironcub";

/// Lowest throttle of the iRonCub model's range, % (its identification signal spans 0–100 %).
pub const IRONCUB_THROTTLE_MIN_PCT: f64 = 0.0;

/// The 13-coefficient jet model in its standardised variables (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IronCubJet {
    /// `c₀ … c₁₂`.
    pub coefficients: [f64; 13],
    /// `μ_T`, N.
    pub thrust_mean_n: f64,
    /// `σ_T`, N (also the scale of `Ṫ̄` and of `T̈`).
    pub thrust_std_n: f64,
    /// `μ_u`, %.
    pub throttle_mean_pct: f64,
    /// `σ_u`, %.
    pub throttle_std_pct: f64,
}

/// A quadratic `k₀ + k₁·x + k₂·y + k₃·x·y + k₄·x² + k₅·y²` in the order of the published
/// coefficients.
fn quadratic(k: &[f64], x: f64, y: f64) -> f64 {
    k[0] + k[1] * x + k[2] * y + k[3] * x * y + k[4] * x * x + k[5] * y * y
}

/// The coefficients of `q(a₁·T + a₀, a₁·Ṫ)` in physical variables, `q` a quadratic in
/// the published order: `[1, T, Ṫ, T·Ṫ, T², Ṫ²]`.
fn unstandardise(k: &[f64], a1: f64, a0: f64) -> [f64; 6] {
    [
        k[0] + k[1] * a0 + k[4] * a0 * a0,
        k[1] * a1 + 2.0 * k[4] * a0 * a1,
        k[2] * a1 + k[3] * a0 * a1,
        k[3] * a1 * a1,
        k[4] * a1 * a1,
        k[5] * a1 * a1,
    ]
}

impl IronCubJet {
    /// The coefficients and standardisation of the group's public 2025 code.
    pub const fn published() -> Self {
        Self {
            coefficients: [
                -4.64730485e-01,
                -8.13171858e+00,
                -6.19539230e+00,
                6.61113140e-01,
                1.67673231e+00,
                -4.83287064e-01,
                8.77996617e+00,
                -1.01096376e+00,
                -5.86442286e-01,
                5.19093322e-01,
                -4.23782666e-01,
                -1.45705257e+00,
                -7.83052261e-03,
            ],
            thrust_mean_n: 108.309,
            thrust_std_n: 65.793,
            throttle_mean_pct: 47.333,
            throttle_std_pct: 31.483,
        }
    }

    /// `T̈`, N/s², at thrust `t` (N), rate `d` (N/s) and throttle `u` (%), evaluated as
    /// published: standardise, evaluate `f + g·v`, scale back.
    pub fn accel(&self, t: f64, d: f64, u: f64) -> f64 {
        let c = &self.coefficients;
        let tb = (t - self.thrust_mean_n) / self.thrust_std_n;
        let db = d / self.thrust_std_n;
        let ub = (u - self.throttle_mean_pct) / self.throttle_std_pct;
        self.thrust_std_n * (quadratic(&c[0..6], tb, db) + quadratic(&c[6..12], tb, db) * (ub + c[12] * ub * ub))
    }

    /// The same model as the ten parameters and a discrepancy holding `B_TT`, `B_DD` and
    /// `B_TD`, exactly: `ū + c₁₂·ū² = α + β·(u + B_UU·u²)`, so the constant `α·g` joins the
    /// drift `f` and `σ_T·β·g` is the input gain, whose quadratic part is the three terms.
    pub fn model_file(&self) -> ModelFile {
        let c = &self.coefficients;
        let (m, s, c12) = (self.throttle_mean_pct, self.throttle_std_pct, c[12]);
        let alpha = -m / s + c12 * m * m / (s * s);
        let beta = 1.0 / s - 2.0 * c12 * m / (s * s);
        let gamma = c12 / (s * s);
        let sigma = self.thrust_std_n;
        let (a1, a0) = (1.0 / sigma, -self.thrust_mean_n / sigma);
        let f = unstandardise(&c[0..6], a1, a0);
        let g = unstandardise(&c[6..12], a1, a0);
        let drift: Vec<f64> = f.iter().zip(&g).map(|(f, g)| sigma * (f + alpha * g)).collect();
        let gain: Vec<f64> = g.iter().map(|g| sigma * beta * g).collect();
        // drift/gain order: [1, T, Ṫ, T·Ṫ, T², Ṫ²].
        let model = Params::from_array([
            drift[1],
            drift[4],
            drift[2],
            drift[5],
            drift[3],
            drift[0],
            gain[0],
            gain[1],
            gain[2],
            gamma / beta,
        ]);
        let mut values = DISCREPANCY_DEFAULTS;
        values[6] = gain[4];
        values[7] = gain[5];
        values[8] = gain[3];
        let effects = Effect::new(EffectKind::Discrepancy, &values)
            .and_then(|e| Effects::new([e]))
            .expect("the published input-gain terms lie within the discrepancy's bounds");
        ModelFile { model, effects }
    }

    /// The plant the simulated bench runs for [`IRONCUB_PLANT`].
    pub fn plant(&self) -> Plant {
        self.model_file().plant()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{State, STEP_S, SUBSTEPS};

    #[test]
    fn the_conversion_is_the_published_model() {
        let jet = IronCubJet::published();
        let file = jet.model_file();
        let p = file.model;
        let disc = file.effects.get(EffectKind::Discrepancy).unwrap().values().to_vec();
        for t in [0.0, 16.0, 60.0, 108.3, 180.0, 240.0] {
            for d in [-150.0, -20.0, 0.0, 35.0, 140.0] {
                for u in [0.0, 12.5, 47.333, 80.0, 100.0] {
                    let want = jet.accel(t, d, u);
                    let got = p.accel(t, d, u) + (disc[6] * t * t + disc[7] * d * d + disc[8] * t * d) * p.v(u);
                    assert!((got - want).abs() <= 1e-9 * want.abs().max(1.0), "T {t} Ṫ {d} u {u}: {got} vs {want}");
                }
            }
        }
        // The file reads back as written.
        let again = ModelFile::from_toml_str(&file.to_toml_string()).unwrap();
        assert_eq!(again, file);
    }

    /// Rest thrust of the published form by bisection on `T̈(T, 0, u) = 0` between 0 and 400 N
    /// (one sign change over the range: the stable root).
    fn published_rest(jet: &IronCubJet, u: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, 350.0);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if jet.accel(mid, 0.0, u) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    #[test]
    fn the_plant_runs_the_published_model_over_its_throttle_range() {
        let jet = IronCubJet::published();
        let plant = jet.plant();
        for u in [0.0, 25.0, 50.0, 75.0, 100.0] {
            let rest = plant.rest_thrust_n(u);
            assert!((rest - published_rest(&jet, u)).abs() < 1e-6, "{u} %: {rest}");
        }
        assert!((plant.rest_thrust_n(0.0) - 16.0).abs() < 0.1 && (plant.rest_thrust_n(100.0) - 222.1).abs() < 0.1);
        // Full steps both ways, against RK4 of the published form at 1 kHz.
        let mut engine = plant.at_equilibrium(0.0);
        let (mut t, mut d) = (published_rest(&jet, 0.0), 0.0);
        let h = STEP_S / SUBSTEPS as f64;
        for k in 0..1000 {
            let u = if k < 500 { 100.0 } else { 0.0 };
            let s = engine.step(u).unwrap();
            for _ in 0..SUBSTEPS {
                (t, d) = crate::rk4_step(t, d, h, |t, d| jet.accel(t, d, u));
            }
            assert!((s.state.thrust_n - t).abs() < 1e-6, "step {k}: {} vs {t}", s.state.thrust_n);
        }
        let State { thrust_n, .. } = engine.state();
        assert!(thrust_n > 15.0 && thrust_n < 40.0, "{thrust_n}");
    }
}
