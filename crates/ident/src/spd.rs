//! The one solve of a symmetric positive (semi-)definite system, shared by the
//! least-squares fit ([`crate::ls`]) and SINDy ([`crate::sindy`]): their normal
//! equations `ΘᵀΘ·w = Θᵀ·y` (SINDy's with a ridge).

use nalgebra::{Cholesky, DMatrix, DVector, Dyn, SVD};

/// Relative size, on the unit-diagonal scaled Gram matrix, below which a Cholesky pivot or
/// singular value counts as zero: directions where `Θ`'s columns are collinear to about
/// `1e-6` (the Gram matrix squares that).
pub const RANK_TOL: f64 = 1e-12;

/// Solver for a symmetric positive semi-definite system `M·w = b` (a Gram matrix, maybe with
/// a ridge): `M` is scaled to a unit diagonal (`D·M·D`, `D = diag(M)^-½`), which makes the
/// Cholesky pivots a direct measure of near-singularity, and factorised by Cholesky, or by an
/// SVD pseudo-inverse when a pivot falls below [`RANK_TOL`].
pub struct SpdSolver {
    scale: DVector<f64>,
    factor: Factor,
}

enum Factor {
    Cholesky(Cholesky<f64, Dyn>),
    PseudoInverse(DMatrix<f64>),
}

impl SpdSolver {
    /// Factorises `m`; `None` when even its SVD fails or has no usable direction.
    pub fn new(m: DMatrix<f64>) -> Option<Self> {
        // A zero diagonal entry is a zero column; scale 1 leaves it to the pseudo-inverse.
        let scale = m.diagonal().map(|d| if d > 0.0 { d.sqrt().recip() } else { 1.0 });
        let k = scale.len();
        let scaled = DMatrix::from_fn(k, k, |i, j| m[(i, j)] * scale[i] * scale[j]);
        let cholesky = Cholesky::new(scaled.clone())
            .filter(|c| c.l_dirty().diagonal().iter().all(|l| l * l > RANK_TOL && l.is_finite()));
        let factor = match cholesky {
            Some(c) => Factor::Cholesky(c),
            None => {
                let svd = SVD::try_new(scaled, true, true, f64::EPSILON, 10_000)?;
                let tol = RANK_TOL * svd.singular_values.max();
                Factor::PseudoInverse(svd.pseudo_inverse(tol).ok()?)
            }
        };
        Some(Self { scale, factor })
    }

    /// `w` with `m·w = b` (the least-norm solution on the directions kept when singular).
    pub fn solve(&self, b: &DVector<f64>) -> DVector<f64> {
        let scaled = b.component_mul(&self.scale);
        let w = match &self.factor {
            Factor::Cholesky(c) => c.solve(&scaled),
            Factor::PseudoInverse(p) => p * scaled,
        };
        w.component_mul(&self.scale)
    }
}
