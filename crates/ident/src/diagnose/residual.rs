//! Where a residual is systematic: the statistics a careful engineer looks at before
//! blaming any physics.
//!
//! Everything is judged against the sensor's own noise model (an AR process estimated
//! from the data, [`crate::noise`]), not against white noise, so coloured noise is
//! not mistaken for physics:
//!
//! - whiteness is tested on the innovations (the residual prewhitened by the noise
//!   model), each divided by the noise's own scale at its thrust: their autocorrelation
//!   against ±1.96/√N and the Ljung–Box statistic. A force sensor's noise often grows
//!   with thrust (the frame shakes more); white noise of a changing scale is still white,
//!   but its autocorrelations spread wider than 1/√N, and the test would reject the truth
//!   itself far more often than its level says ([`noise_scale`]);
//! - a mean over `n` samples is significant against the noise's long-run variance
//!   `σ_w²/(1 − Σφ)²/n`, the variance the mean of `n` samples of that noise has;
//! - the spectrum is shown relative to the noise model's own spectrum.
//!
//! Statistics are pooled over the runs of every file; lost and rejected samples are
//! skipped, never paired across.

use std::sync::Arc;

use jetbench_model::STEP_S;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::problem::{Problem, Sim};
use crate::noise::ArModel;

/// Autocorrelation lags shown (0.5 s).
pub const ACF_LAGS: usize = 50;
/// Lags in the Ljung–Box statistic.
pub const LJUNG_BOX_LAGS: usize = 20;
/// Thrust bins of the noise's scale ([`noise_scale`]).
const SCALE_BINS: usize = 8;
/// Fewest second differences a bin of the noise's scale needs.
const SCALE_BIN_MIN: usize = 200;
/// Significance level of every "significant" in a report.
pub const ALPHA: f64 = 0.01;
/// A mean is called systematic beyond this many standard errors.
pub const T_SIGNIFICANT: f64 = 4.0;
/// Cross-correlation lags with the throttle change: from −0.5 s to +2 s.
const XCORR_LAGS: (i64, i64) = (-50, 200);
/// Lags of the Bartlett correction of the throttle correlation's bound (1 s).
const BARTLETT_LAGS: usize = 100;
/// Samples per Welch segment (10.24 s).
const WELCH_SEGMENT: usize = 1024;
/// Block length for locating systematic windows (2 s).
const WINDOW_BLOCK: usize = 200;
/// Thrust rate below which the engine is called steady, N/s.
const STEADY_RATE_N_PER_S: f64 = 2.0;
/// Longest run of missing samples the spectrum interpolates over.
const SPECTRUM_FILL: usize = 5;

/// Are the innovations (the residual prewhitened by the noise model) white?
#[derive(Clone, Debug, Serialize)]
pub struct Whiteness {
    /// Autocorrelation of the innovations at lags 1..=ACF_LAGS (10 ms each).
    pub acf: Vec<f64>,
    /// 95 % bound of a white sequence's autocorrelation, ±1.96/√N.
    pub bound: f64,
    /// Lags outside the bound (about 5 % of them for white noise).
    pub outside: usize,
    /// Ljung–Box statistic over lags 1..=LJUNG_BOX_LAGS.
    pub ljung_box_q: f64,
    /// Its p-value under whiteness (χ² with LJUNG_BOX_LAGS degrees of freedom).
    pub p_value: f64,
    /// `p_value ≥ ALPHA`.
    pub white: bool,
    /// The noise's scale against the thrust, relative to its whole (`[from N, to N,
    /// factor]` per bin of the model's thrust), by which each innovation was divided
    /// before the test; empty when the recording is too short to tell (every factor 1).
    pub scale_by_thrust: Vec<[f64; 3]>,
}

/// Correlation of the residual with earlier throttle changes.
#[derive(Clone, Debug, Serialize)]
pub struct InputCorrelation {
    /// Lags, s (positive: the residual follows the throttle change).
    pub lags_s: Vec<f64>,
    /// Correlation of `r[k]` with `Δu[k − lag]`.
    pub values: Vec<f64>,
    /// 95 % bound of a white residual.
    pub bound: f64,
    /// Lag of the largest |correlation|, s.
    pub peak_lag_s: f64,
    /// The correlation there.
    pub peak: f64,
}

/// Mean residual in one class of samples.
#[derive(Clone, Debug, Serialize)]
pub struct ClassMean {
    /// What the class is ("rising", "40–60 N", ...).
    pub class: String,
    /// Residual samples in the class.
    pub samples: usize,
    /// Mean residual (measured − model), N.
    pub mean_n: f64,
    /// RMS residual, N.
    pub rms_n: f64,
    /// Mean over its standard error under the noise model.
    pub t_stat: f64,
}

/// Slow change of the residual over the run.
#[derive(Clone, Debug, Serialize)]
pub struct Drift {
    /// Least-squares slope of the residual against time, N/min.
    pub slope_n_per_min: f64,
    /// The slope over its standard error under the noise model.
    pub t_stat: f64,
    /// Mean residual per tenth of the recording: (start s, end s, mean N).
    pub tenths: Vec<(f64, f64, f64)>,
}

/// Power spectrum of the residual relative to the noise model's.
#[derive(Clone, Debug, Serialize)]
pub struct Spectrum {
    /// Frequencies, Hz.
    pub freq_hz: Vec<f64>,
    /// Power over the noise model's power at each frequency.
    pub ratio: Vec<f64>,
    /// Mean ratio in bands: (from Hz, to Hz, ratio).
    pub bands: Vec<(f64, f64, f64)>,
    /// Where the largest ratio above 0.5 Hz is, Hz.
    pub peak_hz: f64,
    /// That ratio (1: the noise's own power).
    pub peak_ratio: f64,
}

/// A stretch of time where the residual is systematic.
#[derive(Clone, Debug, Serialize)]
pub struct Window {
    /// Which file (index in the order given).
    pub file: usize,
    /// Where the stretch starts in the recording, s.
    pub start_s: f64,
    /// Where it ends, s.
    pub end_s: f64,
    /// Mean residual there, N.
    pub mean_n: f64,
}

/// Everything known about one residual.
#[derive(Clone, Debug, Serialize)]
pub struct Analysis {
    /// Held-out residual samples analysed.
    pub samples: usize,
    /// Mean residual (measured − model), N.
    pub mean_n: f64,
    /// RMS residual, N.
    pub rms_n: f64,
    /// RMS of the part the noise does not explain, `√max(0, rms² − σ²)`, N.
    pub systematic_rms_n: f64,
    /// Ljung–Box whiteness of the prewhitened residual under the noise model.
    pub whiteness: Whiteness,
    /// Cross-correlation of the residual with the throttle's changes, by lag.
    pub input_correlation: InputCorrelation,
    /// By the direction the modelled thrust moves.
    pub by_direction: Vec<ClassMean>,
    /// By operating point (quintiles of modelled thrust).
    pub by_thrust: Vec<ClassMean>,
    /// Slow change of the residual over the run.
    pub drift: Drift,
    /// Power of the residual against the noise model's, by frequency.
    pub spectrum: Spectrum,
    /// The most systematic windows, largest first.
    pub windows: Vec<Window>,
    /// What stands out, in words.
    pub findings: Vec<String>,
}

impl Analysis {
    /// True when something is located beyond a failed whiteness test: a systematic window,
    /// a class mean or a drift beyond [`T_SIGNIFICANT`], a throttle correlation, power
    /// above the noise model's. Without any of these a non-white residual is noise a
    /// little more coloured than its model, not something left out.
    pub fn systematic(&self) -> bool {
        self.findings.len() > 1
    }
}

/// One run's residual and what it is compared with, on the grid (NaN: no sample).
struct RunView {
    file: usize,
    r: Vec<f64>,
    /// Innovations at the run's stride (see [`Problem::whiten`]).
    w: Vec<f64>,
    yhat: Vec<f64>,
    rate: Vec<f64>,
    du: Vec<f64>,
    t0_s: f64,
}

impl RunView {
    fn t(&self, k: usize) -> f64 {
        self.t0_s + k as f64 * STEP_S
    }

    /// (residual, index) of the samples present.
    fn present(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.r.iter().copied().enumerate().filter(|(_, r)| r.is_finite())
    }
}

/// Analyses `measured − sim` over every run of `problem` (both parts).
pub(crate) fn analyse(problem: &Problem<'_>, sim: &Sim) -> Analysis {
    let ar = problem.ar();
    let runs: Vec<RunView> = problem
        .runs
        .iter()
        .enumerate()
        .map(|(i, run)| {
            let r = problem.residual(i, sim);
            let yhat = sim[i].clone();
            let n = yhat.len();
            let rate = (0..n)
                .map(|j| {
                    let (a, b) = (j.saturating_sub(1), (j + 1).min(n.saturating_sub(1)));
                    if b > a {
                        (yhat[b] - yhat[a]) / ((b - a) as f64 * STEP_S)
                    } else {
                        0.0
                    }
                })
                .collect();
            let du = (0..run.u.len()).map(|k| if k == 0 { 0.0 } else { run.u[k] - run.u[k - 1] }).collect();
            let w = problem.whiten(i, &r);
            RunView { file: run.series, r, w, yhat, rate, du, t0_s: run.t0_s }
        })
        .collect();
    let n: usize = runs.iter().map(|v| v.present().count()).sum();
    let all_r = || runs.iter().flat_map(|v| v.present().map(|(_, r)| r));
    let mean_n = all_r().sum::<f64>() / n.max(1) as f64;
    let rms_n = (all_r().map(|x| x * x).sum::<f64>() / n.max(1) as f64).sqrt();
    let sigma_n = problem.noise.sigma_n;
    let systematic_rms_n = (rms_n * rms_n - sigma_n * sigma_n).max(0.0).sqrt();
    // Long-run variance of the noise: the variance of a mean of n samples is this over n.
    let long_run_var = long_run_variance(ar);

    let class = |name: String, values: &mut dyn Iterator<Item = f64>| -> ClassMean {
        let (mut sum, mut sq, mut count) = (0.0, 0.0, 0usize);
        for v in values {
            sum += v;
            sq += v * v;
            count += 1;
        }
        let mean = sum / count.max(1) as f64;
        let se = (long_run_var / count.max(1) as f64).sqrt();
        ClassMean {
            class: name,
            samples: count,
            mean_n: mean,
            rms_n: (sq / count.max(1) as f64).sqrt(),
            t_stat: mean / se,
        }
    };
    let by_direction = [("rising", 1.0), ("falling", -1.0), ("steady", 0.0)]
        .into_iter()
        .map(|(name, sign)| {
            let pick = |rate: f64| {
                if sign == 0.0 {
                    rate.abs() <= STEADY_RATE_N_PER_S
                } else {
                    rate * sign > STEADY_RATE_N_PER_S
                }
            };
            class(
                name.to_owned(),
                &mut runs.iter().flat_map(|v| v.present().filter(|(k, _)| pick(v.rate[*k])).map(|p| p.1)),
            )
        })
        .collect();

    let mut sorted: Vec<f64> = runs.iter().flat_map(|v| v.yhat.iter().copied()).filter(|x| x.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let quantile = |q: f64| sorted.get(((sorted.len().saturating_sub(1)) as f64 * q) as usize).copied().unwrap_or(0.0);
    let edges: Vec<f64> = (0..=5).map(|i| quantile(i as f64 / 5.0)).collect();
    let by_thrust = edges
        .windows(2)
        .enumerate()
        .map(|(b, w)| {
            let (lo, hi) = (w[0], w[1]);
            let inside = |y: f64| y >= lo && (y < hi || (b == 4 && y <= hi));
            class(
                format!("{lo:.0}–{hi:.0} N"),
                &mut runs.iter().flat_map(|v| v.present().filter(|(k, _)| inside(v.yhat[*k])).map(|p| p.1)),
            )
        })
        .collect();

    let mut analysis = Analysis {
        samples: n,
        mean_n,
        rms_n,
        systematic_rms_n,
        whiteness: whiteness(&runs, &noise_scale(problem, &runs)),
        input_correlation: input_correlation(&runs, n),
        by_direction,
        by_thrust,
        drift: drift(&runs, long_run_var),
        spectrum: spectrum(&runs, ar),
        windows: windows(&runs, long_run_var),
        findings: Vec::new(),
    };
    analysis.findings = findings(&analysis);
    analysis
}

/// `σ_w²/(1 − Σφ)²`: the spectral density of the noise at zero frequency, in the
/// units of a variance (the variance of a mean of `n` samples is this over `n`).
fn long_run_variance(ar: &ArModel) -> f64 {
    let sum: f64 = ar.phi.iter().sum();
    ar.innovation_var / (1.0 - sum).powi(2).max(1e-6)
}

/// The noise's scale against the thrust: the second differences of the measured thrust
/// (the engine's own part of them is hundredths of a newton, see [`crate::noise`]) binned
/// by the model's thrust at the same sample, each bin's root mean square over the whole's.
/// Measured on the recording, not on the residual, so a misfit (smooth, with no second
/// difference to speak of) is never taken for noise. Returns the bins and, per run, the
/// factor of each innovation (1 where the model has no thrust); no bins and factors of 1
/// when a bin would hold fewer than [`SCALE_BIN_MIN`] differences.
fn noise_scale(problem: &Problem<'_>, runs: &[RunView]) -> (Vec<[f64; 3]>, Vec<Vec<f64>>) {
    let ones = || runs.iter().map(|v| vec![1.0; v.w.len()]).collect();
    let strided = |x: &[f64], stride: usize| -> Vec<f64> { x.iter().copied().step_by(stride).collect() };
    let mut pairs: Vec<(f64, f64)> = Vec::new();
    for (run, view) in problem.runs.iter().zip(runs) {
        let (y, level) = (strided(&run.y, run.stride), strided(&view.yhat, run.stride));
        for j in 1..y.len().saturating_sub(1) {
            let d = y[j + 1] - 2.0 * y[j] + y[j - 1];
            if d.is_finite() && level.get(j).is_some_and(|l| l.is_finite()) {
                pairs.push((level[j], d * d));
            }
        }
    }
    if pairs.len() < SCALE_BINS * SCALE_BIN_MIN {
        return (Vec::new(), ones());
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let whole = pairs.iter().map(|p| p.1).sum::<f64>() / pairs.len() as f64;
    if whole <= 0.0 {
        return (Vec::new(), ones());
    }
    let bins: Vec<[f64; 3]> = (0..SCALE_BINS)
        .map(|b| {
            let part = &pairs[b * pairs.len() / SCALE_BINS..(b + 1) * pairs.len() / SCALE_BINS];
            let mean = part.iter().map(|p| p.1).sum::<f64>() / part.len() as f64;
            [part[0].0, part[part.len() - 1].0, (mean / whole).sqrt()]
        })
        .collect();
    let factor = |level: f64| {
        if !level.is_finite() {
            return 1.0;
        }
        // The bin holding `level`; below the first or above the last, the nearest.
        let b = bins.partition_point(|bin| bin[1] < level).min(SCALE_BINS - 1);
        bins[b][2].max(1e-3)
    };
    let factors = problem
        .runs
        .iter()
        .zip(runs)
        .map(|(run, view)| {
            (0..view.w.len()).map(|j| factor(view.yhat.get(j * run.stride).copied().unwrap_or(f64::NAN))).collect()
        })
        .collect();
    (bins, factors)
}

/// Whiteness of the innovations of `runs`, each divided by its factor in `scale` (see
/// [`noise_scale`]).
fn whiteness(runs: &[RunView], scale: &(Vec<[f64; 3]>, Vec<Vec<f64>>)) -> Whiteness {
    let (bins, factors) = scale;
    let scaled: Vec<Vec<f64>> =
        runs.iter().zip(factors).map(|(v, f)| v.w.iter().zip(f).map(|(w, f)| w / f).collect()).collect();
    let present = || scaled.iter().flat_map(|w| w.iter().copied().filter(|x| x.is_finite()));
    let n = present().count();
    let mean = present().sum::<f64>() / n.max(1) as f64;
    let denom: f64 = present().map(|x| (x - mean).powi(2)).sum::<f64>().max(1e-300) / n.max(1) as f64;
    let acf: Vec<f64> = (1..=ACF_LAGS)
        .map(|lag| {
            let (mut sum, mut pairs) = (0.0, 0usize);
            for w in &scaled {
                for (a, b) in w.iter().zip(w.iter().skip(lag)) {
                    if a.is_finite() && b.is_finite() {
                        sum += (a - mean) * (b - mean);
                        pairs += 1;
                    }
                }
            }
            sum / pairs.max(1) as f64 / denom
        })
        .collect();
    let nf = n as f64;
    let bound = 1.96 / nf.sqrt();
    let q = nf
        * (nf + 2.0)
        * acf[..LJUNG_BOX_LAGS].iter().enumerate().map(|(k, r)| r * r / (nf - (k + 1) as f64)).sum::<f64>();
    let p_value = ChiSquared::new(LJUNG_BOX_LAGS as f64).map_or(f64::NAN, |c| c.sf(q));
    Whiteness {
        outside: acf.iter().filter(|r| r.abs() > bound).count(),
        acf,
        bound,
        ljung_box_q: q,
        p_value,
        white: p_value >= ALPHA,
        scale_by_thrust: bins.clone(),
    }
}

fn input_correlation(runs: &[RunView], n: usize) -> InputCorrelation {
    let mr = runs.iter().flat_map(|v| v.present().map(|p| p.1)).sum::<f64>() / n.max(1) as f64;
    let count_du: usize = runs.iter().map(|v| v.du.len()).sum();
    let mu = runs.iter().flat_map(|v| v.du.iter()).sum::<f64>() / count_du.max(1) as f64;
    let sr = runs.iter().flat_map(|v| v.present().map(|p| (p.1 - mr).powi(2))).sum::<f64>().max(1e-300).sqrt();
    // Δu over the samples present, so both norms count the same pairs.
    let su = runs.iter().flat_map(|v| v.present().map(|(k, _)| (v.du[k] - mu).powi(2))).sum::<f64>().max(1e-300).sqrt();
    let lags: Vec<i64> = (XCORR_LAGS.0..=XCORR_LAGS.1).collect();
    let values: Vec<f64> = lags
        .iter()
        .map(|&lag| {
            let mut sum = 0.0;
            for v in runs {
                let len = v.r.len() as i64;
                for k in lag.max(0)..len.min(len + lag) {
                    let j = k - lag;
                    let r = v.r[k as usize];
                    if r.is_finite() && (0..len).contains(&j) {
                        sum += (r - mr) * (v.du[j as usize] - mu);
                    }
                }
            }
            sum / (sr * su)
        })
        .collect();
    let (peak_index, peak) =
        values.iter().copied().enumerate().max_by(|a, b| a.1.abs().total_cmp(&b.1.abs())).unwrap_or((0, 0.0));
    // Bartlett: a cross-correlation of two autocorrelated series varies more than 1/N,
    // by 1 + 2·Σ ρ_r(k)·ρ_Δu(k) (ramps make Δu correlated, coloured noise makes r so).
    let acf = |f: &dyn Fn(&RunView) -> &Vec<f64>, lag: usize, mean: f64, ss: f64| -> f64 {
        let mut sum = 0.0;
        for v in runs {
            let x = f(v);
            for (a, b) in x.iter().zip(x.iter().skip(lag)) {
                if a.is_finite() && b.is_finite() {
                    sum += (a - mean) * (b - mean);
                }
            }
        }
        sum / ss
    };
    let factor = 1.0
        + 2.0
            * (1..=BARTLETT_LAGS)
                .map(|k| acf(&|v| &v.r, k, mr, sr * sr) * acf(&|v| &v.du, k, mu, su * su))
                .sum::<f64>();
    InputCorrelation {
        lags_s: lags.iter().map(|&l| l as f64 * STEP_S).collect(),
        bound: 1.96 * (factor.max(1.0) / n as f64).sqrt(),
        peak_lag_s: lags[peak_index] as f64 * STEP_S,
        peak,
        values,
    }
}

fn drift(runs: &[RunView], long_run_var: f64) -> Drift {
    let pairs = || runs.iter().flat_map(|v| v.present().map(|(k, r)| (v.t(k), r)));
    let n = pairs().count().max(1) as f64;
    let (mt, mr) = (pairs().map(|p| p.0).sum::<f64>() / n, pairs().map(|p| p.1).sum::<f64>() / n);
    let stt = pairs().map(|(t, _)| (t - mt).powi(2)).sum::<f64>().max(1e-12);
    let slope = pairs().map(|(t, r)| (t - mt) * (r - mr)).sum::<f64>() / stt;
    let se = (long_run_var / stt).sqrt();
    let (t_first, t_last) = pairs().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (t, _)| (a.min(t), b.max(t)));
    let width = (t_last - t_first) / 10.0;
    let tenths = (0..10)
        .map(|i| {
            let (lo, hi) = (t_first + i as f64 * width, t_first + (i + 1) as f64 * width);
            let (sum, count) = pairs()
                .filter(|(t, _)| *t >= lo && (*t < hi || i == 9))
                .fold((0.0, 0usize), |(s, c), (_, r)| (s + r, c + 1));
            (lo, hi, sum / count.max(1) as f64)
        })
        .collect();
    Drift { slope_n_per_min: slope * 60.0, t_stat: slope / se, tenths }
}

/// Stretches of the residual with short holes filled by linear interpolation.
fn filled_pieces(r: &[f64]) -> Vec<Vec<f64>> {
    let mut pieces = Vec::new();
    let mut current: Vec<f64> = Vec::new();
    let mut k = 0;
    while k < r.len() {
        if r[k].is_finite() {
            current.push(r[k]);
            k += 1;
            continue;
        }
        let hole = r[k..].iter().take_while(|x| !x.is_finite()).count();
        let next = r.get(k + hole).copied();
        match (current.last().copied(), next) {
            (Some(a), Some(b)) if hole <= SPECTRUM_FILL => {
                current.extend((1..=hole).map(|j| a + (b - a) * j as f64 / (hole + 1) as f64));
            }
            _ => pieces.push(std::mem::take(&mut current)),
        }
        k += hole;
    }
    pieces.push(current);
    pieces.retain(|p| !p.is_empty());
    pieces
}

fn spectrum(runs: &[RunView], ar: &ArModel) -> Spectrum {
    let fft: Arc<dyn Fft<f64>> = FftPlanner::new().plan_fft_forward(WELCH_SEGMENT);
    let window: Vec<f64> = (0..WELCH_SEGMENT)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / WELCH_SEGMENT as f64).cos())
        .collect();
    let window_power: f64 = window.iter().map(|w| w * w).sum();
    let bins = WELCH_SEGMENT / 2 + 1;
    let mut psd = vec![0.0; bins];
    let mut segments = 0usize;
    let mut buffer = vec![Complex::new(0.0, 0.0); WELCH_SEGMENT];
    for piece in runs.iter().flat_map(|v| filled_pieces(&v.r)) {
        let mut start = 0;
        while start + WELCH_SEGMENT <= piece.len() {
            let seg = &piece[start..start + WELCH_SEGMENT];
            let mean = seg.iter().sum::<f64>() / WELCH_SEGMENT as f64;
            for (b, (x, w)) in buffer.iter_mut().zip(seg.iter().zip(&window)) {
                *b = Complex::new((x - mean) * w, 0.0);
            }
            fft.process(&mut buffer);
            for (p, c) in psd.iter_mut().zip(&buffer) {
                *p += c.norm_sqr() / window_power;
            }
            segments += 1;
            start += WELCH_SEGMENT / 2;
        }
    }
    let freq_hz: Vec<f64> = (0..bins).map(|i| i as f64 / (WELCH_SEGMENT as f64 * STEP_S)).collect();
    if segments == 0 {
        return Spectrum {
            freq_hz,
            ratio: vec![f64::NAN; bins],
            bands: Vec::new(),
            peak_hz: f64::NAN,
            peak_ratio: f64::NAN,
        };
    }
    // The noise model's power at each bin, in the same units (|FFT|²/Σw² → variance per bin).
    let noise_power = |f: f64| -> f64 {
        let omega = 2.0 * std::f64::consts::PI * f * STEP_S;
        let a = ar
            .phi
            .iter()
            .enumerate()
            .fold(Complex::new(1.0, 0.0), |acc, (i, p)| acc - Complex::from_polar(*p, -omega * (i + 1) as f64));
        ar.innovation_var / a.norm_sqr()
    };
    let ratio: Vec<f64> = psd.iter().zip(&freq_hz).map(|(p, f)| p / segments as f64 / noise_power(*f)).collect();
    let band = |lo: f64, hi: f64| {
        let v: Vec<f64> = freq_hz.iter().zip(&ratio).filter(|(f, _)| **f > lo && **f <= hi).map(|(_, r)| *r).collect();
        (lo, hi, v.iter().sum::<f64>() / v.len().max(1) as f64)
    };
    let bands = vec![band(0.0, 0.1), band(0.1, 0.5), band(0.5, 2.0), band(2.0, 10.0), band(10.0, 50.0)];
    let (peak_hz, peak_ratio) = freq_hz
        .iter()
        .zip(&ratio)
        .filter(|(f, _)| **f > 0.5)
        .map(|(f, r)| (*f, *r))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or((f64::NAN, f64::NAN));
    Spectrum { freq_hz, ratio, bands, peak_hz, peak_ratio }
}

fn windows(runs: &[RunView], long_run_var: f64) -> Vec<Window> {
    let mut found: Vec<Window> = Vec::new();
    for v in runs {
        let blocks = v.r.len() / WINDOW_BLOCK;
        let stats = |a: usize, b: usize| -> (f64, usize) {
            let (sum, count) =
                v.r[a..b].iter().filter(|x| x.is_finite()).fold((0.0, 0usize), |(s, c), x| (s + x, c + 1));
            (sum / count.max(1) as f64, count)
        };
        let mut current: Option<(usize, usize, f64)> = None; // (first block, last block, sign)
        let close = |c: (usize, usize, f64), found: &mut Vec<Window>| {
            let (a, b) = (c.0 * WINDOW_BLOCK, (c.1 + 1) * WINDOW_BLOCK);
            found.push(Window { file: v.file, start_s: v.t(a), end_s: v.t(b - 1) + STEP_S, mean_n: stats(a, b).0 });
        };
        for b in 0..blocks {
            let (m, count) = stats(b * WINDOW_BLOCK, (b + 1) * WINDOW_BLOCK);
            let se = (long_run_var / count.max(1) as f64).sqrt();
            let flagged = count > WINDOW_BLOCK / 2 && m.abs() > T_SIGNIFICANT * se;
            match (current, flagged) {
                (Some(c), true) if c.2 == m.signum() && c.1 + 1 == b => current = Some((c.0, b, c.2)),
                (Some(c), true) => {
                    close(c, &mut found);
                    current = Some((b, b, m.signum()));
                }
                (Some(c), false) => {
                    close(c, &mut found);
                    current = None;
                }
                (None, true) => current = Some((b, b, m.signum())),
                (None, false) => {}
            }
        }
        if let Some(c) = current {
            close(c, &mut found);
        }
    }
    found.sort_by(|a, b| (b.mean_n.abs() * (b.end_s - b.start_s)).total_cmp(&(a.mean_n.abs() * (a.end_s - a.start_s))));
    found.truncate(8);
    found
}

/// How the innovations were scaled for the whiteness test, when the noise's scale changes
/// with thrust by more than a tenth ("" otherwise).
fn scaled_by_thrust(w: &Whiteness) -> String {
    let factors = || w.scale_by_thrust.iter().map(|b| b[2]);
    let (lo, hi) = (factors().fold(f64::INFINITY, f64::min), factors().fold(0.0, f64::max));
    if w.scale_by_thrust.is_empty() || hi < 1.1 * lo {
        return String::new();
    }
    format!(" (each innovation scaled by the noise's own scale at its thrust: ×{lo:.2} to ×{hi:.2} of the whole)")
}

fn findings(a: &Analysis) -> Vec<String> {
    let mut out = Vec::new();
    let w = &a.whiteness;
    if w.white {
        out.push(format!(
            "residual is white under the noise model: Ljung–Box Q({LJUNG_BOX_LAGS}) = {:.1}, p = {:.2}; {} of \
             {ACF_LAGS} autocorrelations outside ±{:.3}{}",
            w.ljung_box_q,
            w.p_value,
            w.outside,
            w.bound,
            scaled_by_thrust(w)
        ));
        return out;
    }
    out.push(format!(
        "residual is not white under the noise model: lag-1 autocorrelation of the innovations {:.3} (white: \
         within ±{:.3}), Ljung–Box Q({LJUNG_BOX_LAGS}) = {:.0}, p = {:.1e}; systematic part {:.2} N RMS{}",
        w.acf[0],
        w.bound,
        w.ljung_box_q,
        w.p_value,
        a.systematic_rms_n,
        scaled_by_thrust(w)
    ));
    let systematic = |classes: &[ClassMean]| -> Vec<String> {
        classes
            .iter()
            .filter(|c| c.t_stat.abs() > T_SIGNIFICANT)
            .map(|c| format!("{} {:+.2} N", c.class, c.mean_n))
            .collect()
    };
    let directions = systematic(&a.by_direction);
    if !directions.is_empty() {
        out.push(format!("mean residual by direction of change: {}", directions.join(", ")));
    }
    let ops = systematic(&a.by_thrust);
    if !ops.is_empty() {
        out.push(format!("mean residual by operating point: {}", ops.join(", ")));
    }
    if a.drift.t_stat.abs() > T_SIGNIFICANT {
        out.push(format!(
            "residual drifts over the run: {:+.3} N/min (t = {:.1})",
            a.drift.slope_n_per_min, a.drift.t_stat
        ));
    }
    let x = &a.input_correlation;
    if x.peak.abs() > 2.0 * x.bound {
        out.push(format!(
            "residual correlates with throttle changes {:.2} s earlier (correlation {:+.3}, white: ±{:.3})",
            x.peak_lag_s, x.peak, x.bound
        ));
    }
    if let Some(&(lo, hi, ratio)) = a.spectrum.bands.iter().max_by(|p, q| p.2.total_cmp(&q.2)) {
        if ratio > 2.0 {
            out.push(format!("residual power is concentrated at {lo}–{hi} Hz ({ratio:.1}× the noise model's)"));
        }
    }
    if a.spectrum.peak_ratio > 20.0 {
        out.push(format!(
            "spectral peak at {:.2} Hz ({:.0}× the noise model's): a resonance?",
            a.spectrum.peak_hz, a.spectrum.peak_ratio
        ));
    }
    if let Some(w) = a.windows.first() {
        out.push(format!(
            "{} systematic window(s); largest {:.0}–{:.0} s, mean {:+.2} N",
            a.windows.len(),
            w.start_s,
            w.end_s,
            w.mean_n
        ));
    }
    out
}

/// A slow periodic part of the residual (a force on the stand, a sensor's thermal cycle).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Periodic {
    /// Its period, s.
    pub period_s: f64,
    /// Amplitude of the sine, N.
    pub amplitude_n: f64,
    /// Share of the residual's variance it explains.
    pub share: f64,
}

/// The sine of period 4 s to a third of the longest run that fits the residual best, when it
/// is large (at least 0.5 N and 10 % of the residual's variance) and seen over at least three
/// periods: something that repeats, which no effect of the model explains.
pub(crate) fn periodic(problem: &Problem<'_>, sim: &Sim) -> Option<Periodic> {
    let residuals: Vec<Vec<f64>> = (0..problem.runs.len()).map(|i| problem.residual(i, sim)).collect();
    let longest = residuals.iter().map(Vec::len).max()? as f64 * STEP_S;
    let (mut sum, mut sq, mut n) = (0.0, 0.0, 0.0);
    for r in residuals.iter().flatten().filter(|r| r.is_finite()) {
        sum += r;
        sq += r * r;
        n += 1.0;
    }
    if n < 100.0 || longest < 12.0 {
        return None;
    }
    let mean = sum / n;
    let var = sq / n - mean * mean;
    let mut best: Option<Periodic> = None;
    let (lo, hi) = (4.0_f64, longest / 3.0);
    let steps = 120;
    for i in 0..=steps {
        let period = lo * (hi / lo).powf(i as f64 / steps as f64);
        let w = 2.0 * std::f64::consts::PI / period;
        // Least squares on sin and cos (the normal equations, 2×2).
        let (mut ss, mut cc, mut sc, mut ys, mut yc) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (k, r) in residuals.iter().flat_map(|r| r.iter().enumerate()).filter(|(_, r)| r.is_finite()) {
            let (s, c) = (w * k as f64 * STEP_S).sin_cos();
            let y = r - mean;
            ss += s * s;
            cc += c * c;
            sc += s * c;
            ys += y * s;
            yc += y * c;
        }
        let det = ss * cc - sc * sc;
        if det.abs() < 1e-9 {
            continue;
        }
        let a = (ys * cc - yc * sc) / det;
        let b = (yc * ss - ys * sc) / det;
        let explained = (a * ys + b * yc) / n;
        let p = Periodic { period_s: period, amplitude_n: a.hypot(b), share: explained / var.max(1e-12) };
        if best.is_none_or(|q| p.share > q.share) {
            best = Some(p);
        }
    }
    best.filter(|p| p.amplitude_n >= 0.5 && p.share >= 0.1)
}

/// A sine `mean + a·sin(ωt) + b·cos(ωt)` fitted to a residual.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sine {
    pub period_s: f64,
    pub a: f64,
    pub b: f64,
    pub mean: f64,
    /// Share of the residual's variance it explains.
    pub share: f64,
}

impl Sine {
    pub fn at(&self, t_s: f64) -> f64 {
        let (s, c) = (2.0 * std::f64::consts::PI * t_s / self.period_s).sin_cos();
        self.mean + self.a * s + self.b * c
    }

    pub fn amplitude_n(&self) -> f64 {
        self.a.hypot(self.b)
    }
}

/// Least squares of a sine of `period_s` (and a constant) through `(t, r)` samples.
fn sine_at(samples: &[(f64, f64)], period_s: f64) -> Option<Sine> {
    let n = samples.len() as f64;
    let mean = samples.iter().map(|s| s.1).sum::<f64>() / n;
    let var = samples.iter().map(|s| (s.1 - mean).powi(2)).sum::<f64>() / n;
    let w = 2.0 * std::f64::consts::PI / period_s;
    let (mut ss, mut cc, mut sc, mut ys, mut yc, mut s_sum, mut c_sum) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for &(t, r) in samples {
        let (s, c) = (w * t).sin_cos();
        let y = r - mean;
        ss += s * s;
        cc += c * c;
        sc += s * c;
        ys += y * s;
        yc += y * c;
        s_sum += s;
        c_sum += c;
    }
    // Centred regressors: the constant is fitted jointly.
    let (ss, cc, sc) = (ss - s_sum * s_sum / n, cc - c_sum * c_sum / n, sc - s_sum * c_sum / n);
    let det = ss * cc - sc * sc;
    if det.abs() < 1e-9 * n * n {
        return None;
    }
    let a = (ys * cc - yc * sc) / det;
    let b = (yc * ss - ys * sc) / det;
    let explained = (a * ys + b * yc) / n;
    Some(Sine { period_s, a, b, mean: mean - (a * s_sum + b * c_sum) / n, share: explained / var.max(1e-12) })
}

/// The sine of period 4 s to `longest_s / 2.5` that fits the `(t, r)` samples best (a log grid,
/// then a golden-section search around the best point), so that its period is precise enough
/// to be carried over a held-out stretch.
pub(crate) fn fit_sine(samples: &[(f64, f64)], longest_s: f64) -> Option<Sine> {
    let (lo, hi) = (4.0_f64, longest_s / 2.5);
    if samples.len() < 100 || hi <= lo {
        return None;
    }
    let steps = 160;
    let period = |i: f64| lo * (hi / lo).powf(i / steps as f64);
    let share = |p: f64| sine_at(samples, p).map_or(f64::NEG_INFINITY, |s| s.share);
    let best = (0..=steps).map(|i| (i, share(period(i as f64)))).max_by(|a, b| a.1.total_cmp(&b.1))?.0 as f64;
    let (mut x0, mut x1) = ((best - 1.0).max(0.0), (best + 1.0).min(steps as f64));
    let g = 0.618_033_988_749_895;
    for _ in 0..30 {
        let (m0, m1) = (x1 - g * (x1 - x0), x0 + g * (x1 - x0));
        if share(period(m0)) >= share(period(m1)) {
            x1 = m1;
        } else {
            x0 = m0;
        }
    }
    sine_at(samples, period(0.5 * (x0 + x1)))
}
