//! Sparse identification of nonlinear dynamics (SINDy) with PySINDy's STLSQ optimiser.
//!
//! ```
//! use jetbench_ident::sindy::{fit, PolynomialLibrary, StlsqOptions};
//!
//! // Samples of a damped oscillator: x' = y, y' = -4 x - 0.5 y (exact rates, no noise).
//! let t: Vec<f64> = (0..400).map(|k| k as f64 * 0.01).collect();
//! let (decay, w) = (|t: f64| (-0.25 * t).exp(), 1.984);
//! let x: Vec<f64> = t.iter().map(|&t| decay(t) * (w * t).cos()).collect();
//! let y: Vec<f64> = t.iter().map(|&t| decay(t) * (-0.25 * (w * t).cos() - w * (w * t).sin())).collect();
//! let (xdot, ydot): (Vec<f64>, Vec<f64>) = x.iter().zip(&y).map(|(x, y)| (*y, -4.0 * x - 0.5 * y)).unzip();
//!
//! let library = PolynomialLibrary::new(&["x", "y"], 2); // 1, x, y, x^2, x*y, y^2
//! let model = fit(library, &[&x, &y], &[("x", &xdot), ("y", &ydot)], &StlsqOptions::default())?;
//! assert_eq!(model.equation(0), "1.000 y");
//! assert_eq!(model.equation(1), "-4.000 x - 0.500 y");
//! # Ok::<(), jetbench_ident::sindy::SindyError>(())
//! ```
//!
//! SINDy regresses measured rates `Ẋ` on a library `Θ(X)` of candidate terms and keeps only
//! the terms that matter: `Ẋ ≈ Θ(X)·Ξ` with a sparse `Ξ`. The study (docs/model/README.md) found the
//! structure of the engine model this way, over the 56 monomials of degree ≤ 5 in `(T, Ṫ, u)`.
//!
//! [`fit`] runs STLSQ as PySINDy 2.x does (`pysindy.optimizers.STLSQ` with `unbias=True`):
//!
//! 1. start with every term active;
//! 2. ridge-regress the target on the active terms, `(Θ_SᵀΘ_S + α·I)·w = Θ_Sᵀ·y`;
//! 3. zero every coefficient with `|w| < threshold` and drop it from the active set;
//! 4. repeat 2–3 until the active set stops changing, at most `max_iter` times;
//! 5. finally refit the surviving terms (`|w| > 1e-14`) by plain least squares, without the
//!    ridge (PySINDy's `unbias` step, on by default).
//!
//! With `normalize_columns`, all of this happens on columns scaled to unit 2-norm — the
//! threshold and the ridge act on the scaled coefficients — and the result is scaled back.
//!
//! The Gram matrix `ΘᵀΘ` and `Θᵀy` are formed once, by one matrix product, so each
//! iteration only solves a system of the active-set size. The systems are scaled to a unit
//! diagonal and solved by Cholesky; when a pivot shows the system is numerically singular
//! (collinear or zero columns, e.g. a constant input next to the constant term) the solve falls
//! back to an SVD pseudo-inverse. The final least-squares refit is polished by iterative
//! refinement against the data itself (corrected semi-normal equations), which restores the
//! accuracy a QR solve of `Θ` would give although the Gram matrix squares the condition number.
//!
//! Targets are thresholded one after the other; PySINDy iterates them jointly, which gives
//! the same coefficients because a target whose active set has settled is refitted
//! identically. Differences from PySINDy, all deliberate:
//! - non-finite samples are an error ([`SindyError::NonFinite`]) instead of being dropped;
//! - fewer samples than library terms is an error instead of an under-determined fit;
//! - in the singular regime the pseudo-inverse ignores directions below `1e-12` of the largest
//!   (scaled) Gram eigenvalue, where PySINDy's LAPACK least squares keeps them; there both
//!   results are dominated by rounding;
//! - PySINDy only warns when STLSQ does not converge in `max_iter` iterations or eliminates
//!   every term; here [`SindyModel::converged`] reports the first, and the equation of a
//!   target that lost every term reads `0`.

use std::collections::HashMap;

use nalgebra::{DMatrix, DMatrixView, DVector, DVectorView};

use crate::spd::SpdSolver;

/// Iterative-refinement steps on the final least-squares refit; one usually reaches the
/// accuracy of a QR solve, the second covers condition numbers near the Cholesky limit.
const REFINEMENT_STEPS: usize = 2;

/// Why a SINDy fit or a derivative cannot be computed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SindyError {
    /// No target to fit was given.
    #[error("no target series given: pass at least one (name, values) to fit")]
    NoTargets,
    /// The number of state series differs from the library's variables.
    #[error("the library has {expected} variables but {got} state series were given")]
    VariableCount {
        /// Variables of the library.
        expected: usize,
        /// State series given.
        got: usize,
    },
    /// A series is not as long as the others.
    #[error("series {name} has {got} samples, the others have {expected}")]
    LengthMismatch {
        /// Variable or target name.
        name: String,
        /// Samples in the first series.
        expected: usize,
        /// Samples in this one.
        got: usize,
    },
    /// Fewer samples than library terms: the regression is under-determined.
    #[error("{samples} samples cannot determine {terms} library terms; record more data or lower the degree")]
    TooFewSamples {
        /// Samples given.
        samples: usize,
        /// Terms in the library.
        terms: usize,
    },
    /// A state or target sample is NaN or infinite.
    #[error("series {name} is not finite at sample {index} ({value}); clean or trim the data first")]
    NonFinite {
        /// Variable or target name.
        name: String,
        /// Sample index.
        index: usize,
        /// The offending value.
        value: f64,
    },
    /// A library term, a sum of squares or a product with a target overflows `f64` (huge
    /// values raised to a high power).
    #[error("{what} overflows f64 in the regression; rescale the data or lower the degree")]
    Overflow {
        /// The library term (e.g. `T^5`) or target concerned.
        what: String,
    },
    /// An optimiser setting is out of range.
    #[error("STLSQ option {name} = {value} is invalid: it must be {requirement}")]
    InvalidOption {
        /// Field of [`StlsqOptions`].
        name: &'static str,
        /// The offending value.
        value: f64,
        /// What is accepted.
        requirement: &'static str,
    },
    /// With `normalize_columns`, a term is zero at every sample and has no norm to divide by.
    #[error(
        "library term {term} is zero at every sample, so it cannot be normalised; drop normalize_columns or the term"
    )]
    ZeroColumn {
        /// Term name.
        term: String,
    },
    /// Even the SVD fallback failed on a regression system (it did not converge).
    #[error("the regression for target {target} could not be solved (SVD did not converge)")]
    Singular {
        /// Target name.
        target: String,
    },
    /// The sample spacing is zero, negative, NaN or infinite.
    #[error("sample spacing dt = {dt_s} s is invalid: it must be finite and positive")]
    InvalidStep {
        /// The offending spacing, s.
        dt_s: f64,
    },
    /// A series is too short for the finite-difference stencil.
    #[error("finite differences need at least 3 samples, the series has {len}")]
    TooShort {
        /// Samples in the series.
        len: usize,
    },
}

/// Every monomial of degree ≤ `degree` in the named variables, ordered like PySINDy's
/// `PolynomialLibrary`: the constant first, then by degree, and within a degree in
/// lexicographic order of the variable indices (`1, x, y, x^2, x*y, y^2, ...`).
#[derive(Clone, Debug, PartialEq)]
pub struct PolynomialLibrary {
    var_names: Vec<String>,
    degree: usize,
    names: Vec<String>,
    /// Variable indices multiplied in each term, ascending (empty for the constant).
    factors: Vec<Vec<usize>>,
    /// For each term after the constant: the index of the term without its last factor, and
    /// that factor. Lower-degree terms come first, so one pass evaluates the whole library.
    recurrence: Vec<(usize, usize)>,
}

impl PolynomialLibrary {
    /// The library over `var_names` up to `degree`: `C(n + degree, degree)` terms, e.g. 56 for
    /// `(T, Tdot, u)` at degree 5.
    pub fn new(var_names: &[&str], degree: usize) -> Self {
        let n = var_names.len();
        let mut factors: Vec<Vec<usize>> = vec![Vec::new()];
        let mut recurrence = Vec::new();
        let mut index: HashMap<Vec<usize>, usize> = HashMap::from([(Vec::new(), 0)]);
        for d in 1..=degree {
            if n == 0 {
                break;
            }
            // Multisets of size d in lexicographic order (Python's combinations_with_replacement);
            // each extends a term of degree d - 1, which is already indexed.
            let mut combo = vec![0; d];
            loop {
                recurrence.push((index[&combo[..d - 1]], combo[d - 1]));
                index.insert(combo.clone(), factors.len());
                factors.push(combo.clone());
                let Some(i) = combo.iter().rposition(|&v| v + 1 < n) else { break };
                let next = combo[i] + 1;
                combo[i..].fill(next);
            }
        }
        let names = factors.iter().map(|f| term_name(var_names, f)).collect();
        Self { var_names: var_names.iter().map(|s| s.to_string()).collect(), degree, names, factors, recurrence }
    }

    /// Number of terms.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Always false: the constant term is always there.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// Number of variables.
    pub fn n_vars(&self) -> usize {
        self.var_names.len()
    }

    /// The variables, in order.
    pub fn var_names(&self) -> &[String] {
        &self.var_names
    }

    /// The maximum degree.
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// Term names: `1`, `T`, `Tdot`, `T^2`, `T*Tdot`, `T^2*u`, ...
    pub fn term_names(&self) -> &[String] {
        &self.names
    }

    /// Evaluates every term at the point `x` (one value per variable) into `out`, without
    /// allocating.
    ///
    /// # Panics
    /// If `x.len() != self.n_vars()` or `out.len() != self.len()`.
    pub fn eval_into(&self, x: &[f64], out: &mut [f64]) {
        assert_eq!(x.len(), self.n_vars(), "one value per library variable");
        assert_eq!(out.len(), self.len(), "one output per library term");
        out[0] = 1.0;
        for (term, &(parent, var)) in self.recurrence.iter().enumerate() {
            out[term + 1] = out[parent] * x[var];
        }
    }

    /// Every term over samples `start..start + len` of `states`, column by column:
    /// term `t` is `out[t·MOMENT_BLOCK..][..len]` (`len ≤ MOMENT_BLOCK`). Returns `len`.
    fn columns_into(&self, states: &[&[f64]], start: usize, len: usize, out: &mut Vec<f64>) -> usize {
        out.resize(self.len() * MOMENT_BLOCK, 0.0);
        out[..len].fill(1.0);
        for (term, &(parent, var)) in self.recurrence.iter().enumerate() {
            let x = &states[var][start..start + len];
            let (done, rest) = out.split_at_mut((term + 1) * MOMENT_BLOCK);
            let from = &done[parent * MOMENT_BLOCK..parent * MOMENT_BLOCK + len];
            for ((o, a), v) in rest[..len].iter_mut().zip(from).zip(x) {
                *o = a * v;
            }
        }
        len
    }

    /// Value of one term at `x`.
    fn term_at(&self, term: usize, x: &[f64]) -> f64 {
        self.factors[term].iter().map(|&v| x[v]).product()
    }
}

/// `x`, `x^2`, `x*y`, `T^2*u`; `1` for no factor.
fn term_name(var_names: &[&str], factors: &[usize]) -> String {
    if factors.is_empty() {
        return "1".to_string();
    }
    let mut parts = Vec::new();
    let mut rest = factors;
    while let Some(&v) = rest.first() {
        let power = rest.iter().take_while(|&&w| w == v).count();
        parts.push(if power == 1 { var_names[v].to_string() } else { format!("{}^{power}", var_names[v]) });
        rest = &rest[power..];
    }
    parts.join("*")
}

/// Settings of the sequentially thresholded least squares; the defaults are PySINDy's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StlsqOptions {
    /// Coefficients with a smaller magnitude are set to zero (on the scaled coefficients with
    /// `normalize_columns`). PySINDy default 0.1.
    pub threshold: f64,
    /// Ridge weight `α` of `‖y − Θw‖² + α‖w‖²` in the thresholding iterations. PySINDy default 0.05.
    pub alpha: f64,
    /// Maximum thresholding iterations. PySINDy default 20.
    pub max_iter: usize,
    /// Regress on library columns scaled to unit 2-norm. PySINDy default false.
    pub normalize_columns: bool,
}

impl Default for StlsqOptions {
    fn default() -> Self {
        Self { threshold: 0.1, alpha: 0.05, max_iter: 20, normalize_columns: false }
    }
}

impl StlsqOptions {
    /// Checks every setting is in range.
    pub fn validate(&self) -> Result<(), SindyError> {
        for (name, value) in [("threshold", self.threshold), ("alpha", self.alpha)] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SindyError::InvalidOption { name, value, requirement: "finite and >= 0" });
            }
        }
        if self.max_iter == 0 {
            return Err(SindyError::InvalidOption { name: "max_iter", value: 0.0, requirement: "at least 1" });
        }
        Ok(())
    }
}

/// A fitted SINDy model: one sparse row of library coefficients per target.
#[derive(Clone, Debug, PartialEq)]
pub struct SindyModel {
    library: PolynomialLibrary,
    target_names: Vec<String>,
    coefficients: Vec<Vec<f64>>,
    /// Per target, the nonzero `(term, coefficient)` pairs, so evaluation skips the zeros.
    sparse: Vec<Vec<(usize, f64)>>,
    iterations: Vec<usize>,
    converged: Vec<bool>,
}

impl SindyModel {
    /// The library the model was fitted over.
    pub fn library(&self) -> &PolynomialLibrary {
        &self.library
    }

    /// Target names, in fit order.
    pub fn target_names(&self) -> &[String] {
        &self.target_names
    }

    /// Number of targets (fitted equations).
    pub fn n_targets(&self) -> usize {
        self.target_names.len()
    }

    /// All library coefficients of `target`, zeros included, in library order.
    ///
    /// # Panics
    /// If `target >= self.n_targets()`.
    pub fn coefficients(&self, target: usize) -> &[f64] {
        &self.coefficients[target]
    }

    /// Thresholding iterations STLSQ ran for `target`.
    ///
    /// # Panics
    /// If `target >= self.n_targets()`.
    pub fn iterations(&self, target: usize) -> usize {
        self.iterations[target]
    }

    /// Whether the active set of `target` stopped changing within `max_iter` iterations
    /// (PySINDy only warns when it did not).
    ///
    /// # Panics
    /// If `target >= self.n_targets()`.
    pub fn converged(&self, target: usize) -> bool {
        self.converged[target]
    }

    /// The fitted right-hand sides at the point `x` (one value per library variable) into
    /// `out` (one value per target), without allocating.
    ///
    /// # Panics
    /// If `x.len() != self.library().n_vars()` or `out.len() != self.n_targets()`.
    pub fn eval_into(&self, x: &[f64], out: &mut [f64]) {
        assert_eq!(x.len(), self.library.n_vars(), "one value per library variable");
        assert_eq!(out.len(), self.n_targets(), "one output per target");
        for (o, terms) in out.iter_mut().zip(&self.sparse) {
            *o = terms.iter().map(|&(term, c)| c * self.library.term_at(term, x)).sum();
        }
    }

    /// The selected (nonzero) terms of `target` with their coefficients, in library order.
    ///
    /// # Panics
    /// If `target >= self.n_targets()`.
    pub fn terms(&self, target: usize) -> Vec<(String, f64)> {
        self.sparse[target].iter().map(|&(term, c)| (self.library.names[term].clone(), c)).collect()
    }

    /// The equation of `target`, e.g. `-10.000 x + 10.000 y`: three decimals, or three
    /// significant digits in scientific notation below `1e-3` (high-degree terms of the jet
    /// library have tiny coefficients that PySINDy's printout would round away); `0` when
    /// every term was eliminated.
    ///
    /// # Panics
    /// If `target >= self.n_targets()`.
    pub fn equation(&self, target: usize) -> String {
        let mut eq = String::new();
        for (i, &(term, c)) in self.sparse[target].iter().enumerate() {
            let shown = if i == 0 { c } else { c.abs() };
            if i > 0 {
                eq.push_str(if c < 0.0 { " - " } else { " + " });
            }
            eq.push_str(&if c.abs() >= 1e-3 { format!("{shown:.3}") } else { format!("{shown:.3e}") });
            if term != 0 {
                eq.push(' ');
                eq.push_str(&self.library.names[term]);
            }
        }
        if eq.is_empty() {
            eq.push('0');
        }
        eq
    }
}

/// Fits one sparse equation per target: `targets[i].1 ≈ Θ(states)·ξ_i` by STLSQ.
///
/// `states` holds one series per library variable (in library order), `targets` the named
/// series to explain (typically time derivatives of the states); all have the same length.
pub fn fit(
    library: PolynomialLibrary,
    states: &[&[f64]],
    targets: &[(&str, &[f64])],
    options: &StlsqOptions,
) -> Result<SindyModel, SindyError> {
    options.validate()?;
    let Some(&(_, first)) = targets.first() else { return Err(SindyError::NoTargets) };
    if states.len() != library.n_vars() {
        return Err(SindyError::VariableCount { expected: library.n_vars(), got: states.len() });
    }
    let n = states.first().map_or(first.len(), |s| s.len());
    let named_series =
        library.var_names.iter().map(String::as_str).zip(states.iter().copied()).chain(targets.iter().copied());
    for (name, series) in named_series {
        if series.len() != n {
            return Err(SindyError::LengthMismatch { name: name.to_string(), expected: n, got: series.len() });
        }
        if let Some((index, &value)) = series.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(SindyError::NonFinite { name: name.to_string(), index, value });
        }
    }
    let p = library.len();
    if n < p {
        return Err(SindyError::TooFewSamples { samples: n, terms: p });
    }

    let gram = moment_gram(&library, states, n)?;
    fit_inner(&library, Theta::Polynomial { library: &library, states, n }, gram, targets, options)
}

/// Samples per block when summing moments: the block's monomial columns stay in cache. Not a
/// power of two: reading a row across columns 4 KiB apart defeats the cache.
const MOMENT_BLOCK: usize = 120;

/// `ΘᵀΘ` of a polynomial library from moments, without forming `Θ`.
///
/// Entry `(i, j)` is the sum over the samples of the monomial `term_i · term_j`,
/// and the library of degree `2d` has far fewer distinct monomials (286 for
/// three variables at degree 5) than the Gram matrix has entries (56² = 3136).
/// Monomials are evaluated column-wise over blocks of samples and summed with
/// several accumulators, so both vectorise.
fn moment_gram(library: &PolynomialLibrary, states: &[&[f64]], n: usize) -> Result<DMatrix<f64>, SindyError> {
    let names: Vec<&str> = library.var_names.iter().map(String::as_str).collect();
    let double = PolynomialLibrary::new(&names, 2 * library.degree);
    let index: HashMap<&[usize], usize> = double.factors.iter().enumerate().map(|(i, f)| (f.as_slice(), i)).collect();
    let p = library.len();
    let mut pair = vec![0usize; p * p];
    let mut merged = Vec::new();
    for i in 0..p {
        for j in 0..p {
            merged.clear();
            merged.extend_from_slice(&library.factors[i]);
            merged.extend_from_slice(&library.factors[j]);
            merged.sort_unstable();
            pair[i * p + j] = index[merged.as_slice()];
        }
    }
    let mut moments = vec![0.0; double.len()];
    let mut columns = Vec::new();
    for start in (0..n).step_by(MOMENT_BLOCK) {
        let b = double.columns_into(states, start, MOMENT_BLOCK.min(n - start), &mut columns);
        for (m, column) in moments.iter_mut().zip(columns.chunks_exact(MOMENT_BLOCK)) {
            *m += lane_sum(&column[..b]);
        }
    }

    // The library's own terms are the first `p` monomials: a term that overflows
    // makes its own sum non-finite before any product does.
    if let Some(j) = (0..p).find(|&j| !moments[j].is_finite()) {
        return Err(SindyError::Overflow { what: format!("library term {}", library.names[j]) });
    }
    // |G_ij| ≤ √(G_ii·G_jj), so a finite diagonal means a finite Gram matrix.
    if let Some(j) = (0..p).find(|&j| !moments[pair[j * p + j]].is_finite()) {
        return Err(SindyError::Overflow { what: format!("sum of squares of library term {}", library.names[j]) });
    }
    Ok(DMatrix::from_fn(p, p, |i, j| moments[pair[i * p + j]]))
}

/// The library matrix `Θ`, as rows the caller evaluated, or as a polynomial
/// library of states evaluated block by block when needed (30 000 × 56 values
/// need not be stored: writing them costs more than computing them twice).
enum Theta<'a> {
    /// Row `k` is `values[k·p..(k+1)·p]`.
    Rows(&'a [f64]),
    Polynomial {
        library: &'a PolynomialLibrary,
        states: &'a [&'a [f64]],
        n: usize,
    },
}

impl Theta<'_> {
    /// `Θᵀ·v`.
    fn tr_mul(&self, p: usize, v: &[f64]) -> DVector<f64> {
        match self {
            Theta::Rows(values) => DMatrixView::from_slice(values, p, v.len()) * DVectorView::from_slice(v, v.len()),
            Theta::Polynomial { library, states, n } => {
                let mut out = DVector::zeros(p);
                let mut columns = Vec::new();
                for start in (0..*n).step_by(MOMENT_BLOCK) {
                    let b = library.columns_into(states, start, MOMENT_BLOCK.min(n - start), &mut columns);
                    for (o, column) in out.iter_mut().zip(columns.chunks_exact(MOMENT_BLOCK)) {
                        *o += lane_dot(&column[..b], &v[start..start + b]);
                    }
                }
                out
            }
        }
    }

    /// `Θᵀ·(y − Θ·w)`, the gradient of the residual, in one pass over the samples.
    fn residual_gradient(&self, y: &[f64], w: &DVector<f64>) -> DVector<f64> {
        let p = w.len();
        match self {
            Theta::Rows(values) => {
                let theta_t = DMatrixView::from_slice(values, p, y.len());
                theta_t * (DVectorView::from_slice(y, y.len()) - theta_t.tr_mul(w))
            }
            Theta::Polynomial { library, states, n } => {
                let mut out = DVector::zeros(p);
                let mut columns = Vec::new();
                let mut residual = [0.0; MOMENT_BLOCK];
                for start in (0..*n).step_by(MOMENT_BLOCK) {
                    let b = library.columns_into(states, start, MOMENT_BLOCK.min(n - start), &mut columns);
                    let residual = &mut residual[..b];
                    residual.copy_from_slice(&y[start..start + b]);
                    for (&wt, column) in w.iter().zip(columns.chunks_exact(MOMENT_BLOCK)) {
                        if wt != 0.0 {
                            for (r, c) in residual.iter_mut().zip(&column[..b]) {
                                *r -= wt * c;
                            }
                        }
                    }
                    for (o, column) in out.iter_mut().zip(columns.chunks_exact(MOMENT_BLOCK)) {
                        *o += lane_dot(&column[..b], residual);
                    }
                }
                out
            }
        }
    }
}

/// Dot product with eight independent accumulators.
fn lane_dot(a: &[f64], b: &[f64]) -> f64 {
    let mut lanes = [0.0; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f64 = ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in ca.zip(cb) {
        for ((l, x), y) in lanes.iter_mut().zip(x).zip(y) {
            *l += x * y;
        }
    }
    lanes.iter().sum::<f64>() + tail
}

/// Sum with eight independent accumulators (a plain fold is one long chain of
/// dependent additions that the compiler may not reorder).
fn lane_sum(x: &[f64]) -> f64 {
    let mut lanes = [0.0; 8];
    let chunks = x.chunks_exact(8);
    let tail: f64 = chunks.remainder().iter().sum();
    for chunk in chunks {
        for (l, v) in lanes.iter_mut().zip(chunk) {
            *l += v;
        }
    }
    lanes.iter().sum::<f64>() + tail
}

/// Like [`fit`], with the library already evaluated: `theta` holds one row of
/// `library.len()` values per sample (row-major), e.g. library columns that were
/// filtered the same way as the target. Every target has one value per row.
pub fn fit_rows(
    library: PolynomialLibrary,
    theta: Vec<f64>,
    targets: &[(&str, &[f64])],
    options: &StlsqOptions,
) -> Result<SindyModel, SindyError> {
    let p = library.len();
    let Some(&(_, first)) = targets.first() else { return Err(SindyError::NoTargets) };
    let n = first.len();
    if theta.len() != n * p {
        return Err(SindyError::LengthMismatch { name: "library rows".into(), expected: n * p, got: theta.len() });
    }
    if let Some(i) = theta.iter().position(|v| !v.is_finite()) {
        return Err(SindyError::Overflow { what: format!("library term {}", library.names[i % p]) });
    }
    let gram = DMatrixView::from_slice(&theta, p, n) * DMatrixView::from_slice_with_strides(&theta, n, p, p, 1);
    if let Some(j) = (0..p).find(|&j| !gram[(j, j)].is_finite()) {
        return Err(SindyError::Overflow { what: format!("sum of squares of library term {}", library.names[j]) });
    }
    fit_inner(&library, Theta::Rows(&theta), gram, targets, options)
}

/// The regression shared by [`fit`] and [`fit_rows`]; `gram` is `ΘᵀΘ` when the
/// caller already has it.
fn fit_inner(
    library: &PolynomialLibrary,
    theta: Theta<'_>,
    gram_raw: DMatrix<f64>,
    targets: &[(&str, &[f64])],
    options: &StlsqOptions,
) -> Result<SindyModel, SindyError> {
    options.validate()?;
    let p = library.len();
    let Some(&(_, first)) = targets.first() else { return Err(SindyError::NoTargets) };
    let n = first.len();
    for &(name, series) in targets {
        if series.len() != n {
            return Err(SindyError::LengthMismatch { name: name.to_string(), expected: n, got: series.len() });
        }
        if let Some((index, &value)) = series.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(SindyError::NonFinite { name: name.to_string(), index, value });
        }
    }
    if n < p {
        return Err(SindyError::TooFewSamples { samples: n, terms: p });
    }

    // Working coordinates: columns scaled by `scale` (unit norm with normalize_columns).
    let mut scale = DVector::from_element(p, 1.0);
    if options.normalize_columns {
        for (j, s) in scale.iter_mut().enumerate() {
            let norm = gram_raw[(j, j)].sqrt();
            if norm == 0.0 {
                return Err(SindyError::ZeroColumn { term: library.names[j].clone() });
            }
            *s = norm.recip();
        }
    }
    // Symmetrised, so both triangles agree bit for bit whatever the product's summation order.
    let gram = DMatrix::from_fn(p, p, |i, j| 0.5 * (gram_raw[(i, j)] + gram_raw[(j, i)]) * scale[i] * scale[j]);

    let mut model = SindyModel {
        target_names: targets.iter().map(|(name, _)| name.to_string()).collect(),
        coefficients: Vec::with_capacity(targets.len()),
        sparse: Vec::with_capacity(targets.len()),
        iterations: Vec::with_capacity(targets.len()),
        converged: Vec::with_capacity(targets.len()),
        library: library.clone(),
    };
    let singular = |target: &str| SindyError::Singular { target: target.to_string() };
    for &(name, y) in targets {
        let rhs = theta.tr_mul(p, y).component_mul(&scale);
        if rhs.iter().any(|v| !v.is_finite()) {
            return Err(SindyError::Overflow { what: format!("library times target {name}") });
        }
        let outcome = stlsq(&gram, &rhs, options).ok_or_else(|| singular(name))?;

        // PySINDy's unbias step: plain least squares on the surviving terms, polished against
        // the data so the Gram matrix's squared conditioning does not limit accuracy.
        let support: Vec<usize> = (0..p).filter(|&j| outcome.coefficients[j].abs() > 1e-14).collect();
        let mut coefficients = DVector::zeros(p);
        if !support.is_empty() {
            let solver = SpdSolver::new(submatrix(&gram, &support, 0.0)).ok_or_else(|| singular(name))?;
            let mut w = solver.solve(&gather(&rhs, &support));
            for _ in 0..REFINEMENT_STEPS {
                scatter(&w, &support, &mut coefficients);
                let raw = coefficients.component_mul(&scale);
                let gradient = theta.residual_gradient(y, &raw).component_mul(&scale);
                w += solver.solve(&gather(&gradient, &support));
            }
            scatter(&w, &support, &mut coefficients);
        }
        let coefficients: Vec<f64> = coefficients.component_mul(&scale).iter().copied().collect();
        model.sparse.push(coefficients.iter().enumerate().filter(|(_, c)| **c != 0.0).map(|(j, c)| (j, *c)).collect());
        model.coefficients.push(coefficients);
        model.iterations.push(outcome.iterations);
        model.converged.push(outcome.converged);
    }
    Ok(model)
}

/// Result of the thresholding iterations for one target.
struct Thresholded {
    coefficients: DVector<f64>,
    iterations: usize,
    converged: bool,
}

/// Sequentially thresholded ridge regression on the Gram system `gram·w = rhs`, exactly the
/// loop of PySINDy's `STLSQ._reduce` for one target. `None` if a system cannot be solved.
fn stlsq(gram: &DMatrix<f64>, rhs: &DVector<f64>, options: &StlsqOptions) -> Option<Thresholded> {
    let p = rhs.len();
    let mut active: Vec<usize> = (0..p).collect();
    let mut coefficients = DVector::zeros(p);
    for iteration in 1..=options.max_iter {
        if active.is_empty() {
            // PySINDy: "Sparsity parameter is too big and eliminated all coefficients".
            return Some(Thresholded { coefficients, iterations: iteration - 1, converged: true });
        }
        let w = SpdSolver::new(submatrix(gram, &active, options.alpha))?.solve(&gather(rhs, &active));
        coefficients.fill(0.0);
        let mut kept = Vec::with_capacity(active.len());
        for (&j, &wj) in active.iter().zip(w.iter()) {
            if wj.abs() >= options.threshold {
                coefficients[j] = wj;
                kept.push(j);
            }
        }
        if kept == active {
            return Some(Thresholded { coefficients, iterations: iteration, converged: true });
        }
        active = kept;
    }
    Some(Thresholded { coefficients, iterations: options.max_iter, converged: false })
}

/// `m[idx, idx] + ridge·I`.
fn submatrix(m: &DMatrix<f64>, idx: &[usize], ridge: f64) -> DMatrix<f64> {
    DMatrix::from_fn(idx.len(), idx.len(), |a, b| m[(idx[a], idx[b])] + if a == b { ridge } else { 0.0 })
}

/// `v[idx]`.
fn gather(v: &DVector<f64>, idx: &[usize]) -> DVector<f64> {
    DVector::from_iterator(idx.len(), idx.iter().map(|&j| v[j]))
}

/// `out[idx] = w`, other entries zero.
fn scatter(w: &DVector<f64>, idx: &[usize], out: &mut DVector<f64>) {
    out.fill(0.0);
    for (&j, &wj) in idx.iter().zip(w.iter()) {
        out[j] = wj;
    }
}

/// `dx/dt` of `x` sampled every `dt` seconds, as PySINDy's default differentiation
/// (`FiniteDifference(order=2)` in PySINDy 2.x): centred `(x[k+1] − x[k−1]) / 2dt` inside, and
/// the second-order one-sided `(−3x[0] + 4x[1] − x[2]) / 2dt` (mirrored at the end) at the edges.
pub fn finite_difference(x: &[f64], dt: f64) -> Result<Vec<f64>, SindyError> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(SindyError::InvalidStep { dt_s: dt });
    }
    let n = x.len();
    if n < 3 {
        return Err(SindyError::TooShort { len: n });
    }
    let half = 0.5 / dt;
    let mut out = Vec::with_capacity(n);
    out.push((-3.0 * x[0] + 4.0 * x[1] - x[2]) * half);
    out.extend(x.windows(3).map(|w| (w[2] - w[0]) * half));
    out.push((3.0 * x[n - 1] - 4.0 * x[n - 2] + x[n - 3]) * half);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn library_order_and_names_follow_pysindy() {
        let lib = PolynomialLibrary::new(&["x", "y", "z"], 2);
        // PySINDy: PolynomialLibrary(degree=2).get_feature_names(["x", "y", "z"]), with "*" for " ".
        let want = ["1", "x", "y", "z", "x^2", "x*y", "x*z", "y^2", "y*z", "z^2"];
        assert_eq!(lib.term_names(), want);
        assert_eq!(lib.len(), 10);
        assert!(!lib.is_empty());

        let jet = PolynomialLibrary::new(&["T", "Tdot", "u"], 5);
        assert_eq!(jet.len(), 56);
        let names = jet.term_names();
        assert_eq!(&names[..10], ["1", "T", "Tdot", "u", "T^2", "T*Tdot", "T*u", "Tdot^2", "Tdot*u", "u^2"]);
        assert_eq!(names[10..20].first().map(String::as_str), Some("T^3"));
        assert!(names.iter().any(|n| n == "T^2*u"));
        assert_eq!(names[55], "u^5");

        assert_eq!(PolynomialLibrary::new(&[], 3).term_names(), ["1"]);
        assert_eq!(PolynomialLibrary::new(&["a", "b"], 0).term_names(), ["1"]);
    }

    #[test]
    fn library_evaluates_every_monomial() {
        let lib = PolynomialLibrary::new(&["T", "Tdot", "u"], 5);
        let x = [1.5, -2.0, 0.5];
        let mut out = vec![0.0; lib.len()];
        lib.eval_into(&x, &mut out);
        for (term, value) in out.iter().enumerate() {
            let direct: f64 = lib.factors[term].iter().map(|&v| x[v]).product();
            assert!((value - direct).abs() <= 1e-12 * direct.abs(), "{}: {value} vs {direct}", lib.names[term]);
        }
        let t2u = lib.term_names().iter().position(|n| n == "T^2*u").unwrap();
        assert!((out[t2u] - 1.5 * 1.5 * 0.5).abs() < 1e-15);
    }

    /// Noiseless samples of `y = 2 − 3x + 0.5·x·z + 4·z²` over a Lissajous path.
    fn sparse_quadratic(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let x: Vec<f64> = (0..n).map(|k| (k as f64 * 0.013).sin() * 2.0).collect();
        let z: Vec<f64> = (0..n).map(|k| (k as f64 * 0.029).cos() + 0.3).collect();
        let y = x.iter().zip(&z).map(|(x, z)| 2.0 - 3.0 * x + 0.5 * x * z + 4.0 * z * z).collect();
        (x, z, y)
    }

    #[test]
    fn recovers_a_sparse_polynomial_exactly() {
        let (x, z, y) = sparse_quadratic(2000);
        let model =
            fit(PolynomialLibrary::new(&["x", "z"], 3), &[&x, &z], &[("y", &y)], &StlsqOptions::default()).unwrap();
        let terms = model.terms(0);
        let names: Vec<&str> = terms.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["1", "x", "x*z", "z^2"]);
        for ((_, got), want) in terms.iter().zip([2.0, -3.0, 0.5, 4.0]) {
            assert!((got - want).abs() < 1e-10, "{got} vs {want}");
        }
        assert!(model.converged(0));
        let mut rhs = [0.0];
        model.eval_into(&[0.7, -0.2], &mut rhs);
        assert!((rhs[0] - (2.0 - 2.1 - 0.07 + 0.16)).abs() < 1e-10);
    }

    #[test]
    fn normalised_columns_threshold_the_scaled_coefficients_like_pysindy() {
        // PySINDy 2.1.0 on the same data:
        //   Θ = ps.PolynomialLibrary(degree=3).fit_transform(np.column_stack([x, z]))
        //   opt = ps.STLSQ(threshold=10.0, normalize_columns=True); opt.fit(Θ, y)
        //   -> 3 iterations (len(opt.history_) == 4), support 1, x, x*z, z^2, x^3, x*z^2, z^3,
        //      coef_ [2, -3, 0, 0, 0.5, 4, 2e-16, 0, -1e-15, -3e-15].
        // The column norms are 35-200, so threshold 0.1 would keep every term.
        let (x, z, y) = sparse_quadratic(2000);
        let options = StlsqOptions { threshold: 10.0, normalize_columns: true, ..StlsqOptions::default() };
        let model = fit(PolynomialLibrary::new(&["x", "z"], 3), &[&x, &z], &[("y", &y)], &options).unwrap();
        assert_eq!(model.iterations(0), 3);
        let want = [2.0, -3.0, 0.0, 0.0, 0.5, 4.0, 0.0, 0.0, 0.0, 0.0];
        for (got, want) in model.coefficients(0).iter().zip(want) {
            assert!((got - want).abs() < 1e-10, "{got} vs {want}");
        }
        let eliminated: Vec<&str> = (0..10)
            .filter(|&j| model.coefficients(0)[j] == 0.0)
            .map(|j| model.library().term_names()[j].as_str())
            .collect();
        assert_eq!(eliminated, ["z", "x^2", "x^2*z"]);
    }

    #[test]
    fn refinement_recovers_an_ill_conditioned_fit() {
        // Degree-6 monomials of a throttle in [25, 100] %: the column-scaled Θ has a condition
        // number near 1e5, so the Gram matrix alone leaves errors near 5e-5 (in y at u = 100 %);
        // refined against the data, the fit is as exact as a QR solve would be.
        let u: Vec<f64> = (0..3000).map(|k| 62.5 + 37.5 * (k as f64 * 0.01).sin()).collect();
        let want = [-19.9, 0.59, 0.0139, -2e-4, 1e-6, 3e-9, -1e-11];
        let y: Vec<f64> = u.iter().map(|u| want.iter().rev().fold(0.0, |acc, c| acc * u + c)).collect();
        let options = StlsqOptions { threshold: 0.0, alpha: 0.0, ..StlsqOptions::default() };
        let model = fit(PolynomialLibrary::new(&["u"], 6), &[&u], &[("y", &y)], &options).unwrap();
        for (k, (got, want)) in model.coefficients(0).iter().zip(want).enumerate() {
            let error_at_full_throttle = (got - want).abs() * 100f64.powi(k as i32);
            assert!(error_at_full_throttle < 1e-9, "u^{k}: {got} vs {want}");
        }
    }

    #[test]
    fn collinear_and_zero_columns_fall_back_to_the_pseudo_inverse() {
        // A constant input is collinear with the constant term; a zero state gives zero columns.
        let n = 500;
        let x: Vec<f64> = (0..n).map(|k| (k as f64 * 0.05).sin()).collect();
        let u = vec![2.0; n];
        let zero = vec![0.0; n];
        let y: Vec<f64> = x.iter().map(|x| 3.0 + 1.5 * x).collect();
        let model =
            fit(PolynomialLibrary::new(&["x", "u", "s"], 2), &[&x, &u, &zero], &[("y", &y)], &StlsqOptions::default())
                .unwrap();
        let mut rhs = [0.0];
        for &xi in &[0.3, -0.8] {
            model.eval_into(&[xi, 2.0, 0.0], &mut rhs);
            assert!((rhs[0] - (3.0 + 1.5 * xi)).abs() < 1e-9, "{} at x = {xi}", rhs[0]);
        }
        assert!(model.coefficients(0).iter().all(|c| c.is_finite()));
        let with_norm = StlsqOptions { normalize_columns: true, ..StlsqOptions::default() };
        let err = fit(PolynomialLibrary::new(&["x", "s"], 1), &[&x, &zero], &[("y", &y)], &with_norm).unwrap_err();
        assert_eq!(err, SindyError::ZeroColumn { term: "s".into() });
    }

    #[test]
    fn equation_formats_signs_and_eliminated_targets() {
        let (x, z, y) = sparse_quadratic(400);
        let zeros = vec![0.0; y.len()];
        let model = fit(
            PolynomialLibrary::new(&["x", "z"], 2),
            &[&x, &z],
            &[("y", &y), ("q", &zeros)],
            &StlsqOptions::default(),
        )
        .unwrap();
        assert_eq!(model.equation(0), "2.000 - 3.000 x + 0.500 x*z + 4.000 z^2");
        assert_eq!(model.equation(1), "0");
        let tiny = fit(
            PolynomialLibrary::new(&["x"], 1),
            &[&x],
            &[("y", &x.iter().map(|x| -2.5e-5 * x).collect::<Vec<_>>())],
            &StlsqOptions { threshold: 1e-6, ..StlsqOptions::default() },
        )
        .unwrap();
        assert_eq!(tiny.equation(0), "-2.500e-5 x");
        assert!(model.terms(1).is_empty());
        assert_eq!(model.target_names(), ["y", "q"]);
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        let lib = || PolynomialLibrary::new(&["x"], 2);
        let x = [0.0, 1.0, 2.0, 3.0];
        let y = [1.0, 2.0, 3.0, 4.0];
        let ok = StlsqOptions::default();
        assert_eq!(fit(lib(), &[&x], &[], &ok).unwrap_err(), SindyError::NoTargets);
        assert_eq!(
            fit(lib(), &[&x, &x], &[("y", &y)], &ok).unwrap_err(),
            SindyError::VariableCount { expected: 1, got: 2 }
        );
        assert_eq!(
            fit(lib(), &[&x], &[("y", &y[..3])], &ok).unwrap_err(),
            SindyError::LengthMismatch { name: "y".into(), expected: 4, got: 3 }
        );
        assert_eq!(
            fit(lib(), &[&x[..2]], &[("y", &y[..2])], &ok).unwrap_err(),
            SindyError::TooFewSamples { samples: 2, terms: 3 }
        );
        let nan = [1.0, f64::NAN, 3.0, 4.0];
        assert!(matches!(
            fit(lib(), &[&x], &[("y", &nan)], &ok),
            Err(SindyError::NonFinite { ref name, index: 1, .. }) if name == "y"
        ));
        let overflow = |what: &str| SindyError::Overflow { what: what.into() };
        let huge = [1e200, 1.0, 2.0, 3.0];
        assert_eq!(fit(lib(), &[&huge], &[("y", &y)], &ok).unwrap_err(), overflow("library term x^2"));
        let big = [1e160, 1.0, 2.0, 3.0];
        let linear = || PolynomialLibrary::new(&["x"], 1);
        assert_eq!(
            fit(linear(), &[&big], &[("y", &y)], &ok).unwrap_err(),
            overflow("sum of squares of library term x")
        );
        let big_y = [1e160, 1.0, 2.0, 3.0];
        let far = [1e150, 1.0, 2.0, 3.0];
        assert_eq!(fit(linear(), &[&far], &[("y", &big_y)], &ok).unwrap_err(), overflow("library times target y"));
        for options in [
            StlsqOptions { threshold: -1.0, ..ok },
            StlsqOptions { threshold: f64::NAN, ..ok },
            StlsqOptions { alpha: -0.1, ..ok },
            StlsqOptions { max_iter: 0, ..ok },
        ] {
            assert!(matches!(fit(lib(), &[&x], &[("y", &y)], &options), Err(SindyError::InvalidOption { .. })));
        }
        assert_eq!(finite_difference(&x, 0.0).unwrap_err(), SindyError::InvalidStep { dt_s: 0.0 });
        assert_eq!(finite_difference(&x[..2], 0.1).unwrap_err(), SindyError::TooShort { len: 2 });
    }

    #[test]
    fn finite_difference_is_exact_on_quadratics_like_pysindy() {
        // Second-order stencils everywhere, so a quadratic's derivative is exact, edges included.
        let dt = 0.1;
        let x: Vec<f64> = (0..6).map(|k| 1.0 + 2.0 * (k as f64 * dt) - 3.0 * (k as f64 * dt).powi(2)).collect();
        let d = finite_difference(&x, dt).unwrap();
        for (k, v) in d.iter().enumerate() {
            let want = 2.0 - 6.0 * k as f64 * dt;
            assert!((v - want).abs() < 1e-12, "sample {k}: {v} vs {want}");
        }
    }
}
