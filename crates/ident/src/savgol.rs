//! Savitzky–Golay smoothing and differentiation of uniformly sampled signals.
//!
//! ```
//! use jetbench_ident::SavitzkyGolay;
//!
//! // 100 Hz thrust samples of T(t) = 3·t² N: the fit is exact for polynomials up to the order.
//! let dt_s = 0.01;
//! let thrust_n: Vec<f64> = (0..200).map(|k| 3.0 * (k as f64 * dt_s).powi(2)).collect();
//! let sg = SavitzkyGolay::new(31, 3)?;
//! let rate = sg.apply(&thrust_n, 1, dt_s)?; // N/s
//! let accel = sg.apply(&thrust_n, 2, dt_s)?; // N/s²
//! assert!((rate[0] - 0.0).abs() < 1e-9 && (rate[150] - 9.0).abs() < 1e-9);
//! assert!(accel.iter().all(|a| (a - 6.0).abs() < 1e-9));
//! # Ok::<(), jetbench_ident::SavGolError>(())
//! ```
//!
//! Each output sample is the `deriv`-th derivative, at that sample, of the least-squares
//! polynomial of degree `order` through the `window` samples around it. The fit is linear in
//! the data, so it reduces to a dot product with a kernel that depends only on where the
//! sample sits in its window: the centred kernel for the interior and, for the first and last
//! `window / 2` samples, the polynomial of the first or last full window evaluated off-centre
//! (scipy's `savgol_filter(..., mode="interp")`). All kernels are computed once, in
//! [`SavitzkyGolay::new`], from a QR factorisation of the window's Vandermonde matrix, so
//! [`SavitzkyGolay::apply_into`] costs `O(n·window)` and never allocates.

use nalgebra::DMatrix;

/// Upper bound on the kernel table, `(order + 1)·window²` entries (32 MiB of `f64`), so a
/// mistyped window fails with an error instead of exhausting memory. Window 1001 at order 3
/// still fits.
const MAX_KERNEL_ENTRIES: usize = 1 << 22;

/// Why a filter cannot be built or applied.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum SavGolError {
    /// The window has an even number of samples, so it has no centre sample.
    #[error("Savitzky-Golay window {window} is even; use an odd number of samples")]
    EvenWindow {
        /// The requested window, samples.
        window: usize,
    },
    /// The window has too few samples to smooth with this order.
    #[error(
        "Savitzky-Golay window {window} is too short for order {order}: it needs at least order + 2 samples, \
         or the polynomial just interpolates the data"
    )]
    WindowTooShort {
        /// The requested window, samples.
        window: usize,
        /// The requested polynomial order.
        order: usize,
    },
    /// The kernel table, `(order + 1)·window²` entries, would exceed 2²² entries (32 MiB).
    #[error(
        "Savitzky-Golay window {window} at order {order} needs (order + 1)·window² = {entries} kernel entries, \
         more than the limit of {max}; use a shorter window or a lower order"
    )]
    TooLarge {
        /// The requested window, samples.
        window: usize,
        /// The requested polynomial order.
        order: usize,
        /// Entries the table would hold.
        entries: usize,
        /// The limit.
        max: usize,
    },
    /// The window's Vandermonde matrix is numerically singular (order far too high for `f64`).
    #[error("Savitzky-Golay fit of order {order} over {window} samples is numerically singular; lower the order")]
    Singular {
        /// The requested window, samples.
        window: usize,
        /// The requested polynomial order.
        order: usize,
    },
    /// A derivative above the polynomial order is identically zero, so it is refused.
    #[error("derivative {deriv} exceeds the Savitzky-Golay polynomial order {order}")]
    DerivTooHigh {
        /// The requested derivative.
        deriv: usize,
        /// The filter's polynomial order.
        order: usize,
    },
    /// The signal is shorter than one window, so not even the edge fit exists.
    #[error("signal has {len} samples, fewer than the Savitzky-Golay window of {window}")]
    InputTooShort {
        /// Samples in the signal.
        len: usize,
        /// The filter's window, samples.
        window: usize,
    },
    /// The sample spacing is zero, negative, NaN or infinite.
    #[error("sample spacing dt = {dt_s} s is invalid: it must be finite and positive")]
    InvalidStep {
        /// The offending spacing, s.
        dt_s: f64,
    },
    /// The output buffer of [`SavitzkyGolay::apply_into`] does not match the input length.
    #[error("output buffer holds {got} samples but the signal has {expected}")]
    OutputLength {
        /// Samples in the signal.
        expected: usize,
        /// Samples in the buffer.
        got: usize,
    },
}

/// A Savitzky–Golay filter: window, order and the kernel of every window position for every
/// derivative up to the order.
#[derive(Clone, Debug)]
pub struct SavitzkyGolay {
    window: usize,
    order: usize,
    /// `kernels[(deriv·window + pos)·window + j]`: weight of window sample `j` in the `deriv`-th
    /// derivative (unit sample spacing) of the window's polynomial at window position `pos`.
    kernels: Vec<f64>,
}

impl SavitzkyGolay {
    /// A filter fitting polynomials of degree `order` over `window` samples.
    ///
    /// `window` must be odd and at least `order + 2`; typical thrust settings at 100 Hz are
    /// window 31, order 3.
    pub fn new(window: usize, order: usize) -> Result<Self, SavGolError> {
        if window.is_multiple_of(2) {
            return Err(SavGolError::EvenWindow { window });
        }
        if window < order.saturating_add(2) {
            return Err(SavGolError::WindowTooShort { window, order });
        }
        let entries = (order + 1).saturating_mul(window).saturating_mul(window);
        if entries > MAX_KERNEL_ENTRIES {
            return Err(SavGolError::TooLarge { window, order, entries, max: MAX_KERNEL_ENTRIES });
        }

        // Least squares in the scaled abscissa u = s / half, s the sample offset from the
        // centre, keeps the Vandermonde matrix well conditioned for any window length.
        let half = (window / 2) as f64;
        let vandermonde = DMatrix::from_fn(window, order + 1, |j, k| ((j as f64 - half) / half).powi(k as i32));
        let qr = vandermonde.qr();
        // projection[(k, j)]: weight of sample j in the coefficient of u^k.
        let projection =
            qr.r().solve_upper_triangular(&qr.q().transpose()).ok_or(SavGolError::Singular { window, order })?;
        if projection.iter().any(|w| !w.is_finite()) {
            return Err(SavGolError::Singular { window, order });
        }

        // p(s) = Σ_k c_k (s/half)^k, so d^d p / ds^d = Σ_{k ≥ d} c_k k!/(k-d)! (s/half)^(k-d) / half^d.
        let mut kernels = vec![0.0; entries];
        for deriv in 0..=order {
            let falling_factorial = |k: usize| ((k - deriv + 1)..=k).map(|f| f as f64).product::<f64>();
            let scale = half.powi(deriv as i32).recip();
            for pos in 0..window {
                let u = (pos as f64 - half) / half;
                let row = &mut kernels[(deriv * window + pos) * window..][..window];
                for k in deriv..=order {
                    let weight = falling_factorial(k) * u.powi((k - deriv) as i32) * scale;
                    for (r, p) in row.iter_mut().zip(projection.row(k).iter()) {
                        *r += weight * p;
                    }
                }
            }
        }
        Ok(Self { window, order, kernels })
    }

    /// Window length, samples.
    pub fn window(&self) -> usize {
        self.window
    }

    /// Polynomial order.
    pub fn order(&self) -> usize {
        self.order
    }

    /// The `deriv`-th derivative (`0` = smoothed value) of `x`, sampled every `dt` seconds, at
    /// every sample: `x`'s unit per s^deriv.
    ///
    /// Interior samples use the centred kernel; the first and last `window / 2` samples use
    /// the polynomial of the first or last full window, like scipy's
    /// `savgol_filter(x, window, order, deriv=deriv, delta=dt, mode="interp")`. A NaN in `x`
    /// spreads to the outputs whose window contains it.
    pub fn apply(&self, x: &[f64], deriv: usize, dt: f64) -> Result<Vec<f64>, SavGolError> {
        let mut out = vec![0.0; x.len()];
        self.apply_into(x, deriv, dt, &mut out)?;
        Ok(out)
    }

    /// [`SavitzkyGolay::apply`] into a caller-provided buffer of `x.len()` samples, without
    /// allocating.
    pub fn apply_into(&self, x: &[f64], deriv: usize, dt: f64, out: &mut [f64]) -> Result<(), SavGolError> {
        if deriv > self.order {
            return Err(SavGolError::DerivTooHigh { deriv, order: self.order });
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SavGolError::InvalidStep { dt_s: dt });
        }
        let (n, w, half) = (x.len(), self.window, self.window / 2);
        if n < w {
            return Err(SavGolError::InputTooShort { len: n, window: w });
        }
        if out.len() != n {
            return Err(SavGolError::OutputLength { expected: n, got: out.len() });
        }

        let gain = dt.powi(deriv as i32).recip();
        let (first, last) = (&x[..w], &x[n - w..]);
        for (pos, o) in out[..half].iter_mut().enumerate() {
            *o = dot(self.kernel(deriv, pos), first) * gain;
        }
        let centred = self.kernel(deriv, half);
        for (o, win) in out[half..n - half].iter_mut().zip(x.windows(w)) {
            *o = dot(centred, win) * gain;
        }
        for (pos, o) in out[n - half..].iter_mut().enumerate() {
            *o = dot(self.kernel(deriv, half + 1 + pos), last) * gain;
        }
        Ok(())
    }

    /// Sum of squares of the centred kernel for `deriv` at unit sample spacing: white noise of
    /// variance `s²` comes out of the interior with variance `s² · noise_gain(deriv) / dt^(2·deriv)`.
    /// Zero for `deriv > order`, where the fitted polynomial's derivative vanishes.
    pub fn noise_gain(&self, deriv: usize) -> f64 {
        if deriv > self.order {
            return 0.0;
        }
        self.kernel(deriv, self.window / 2).iter().map(|k| k * k).sum()
    }

    fn kernel(&self, deriv: usize, pos: usize) -> &[f64] {
        &self.kernels[(deriv * self.window + pos) * self.window..][..self.window]
    }
}

/// Dot product with four partial sums, so the compiler can keep several FMAs in flight.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = a4.remainder().iter().zip(b4.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in a4.zip(b4) {
        for i in 0..4 {
            acc[i] += x[i] * y[i];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Value and derivatives of `Σ c_k t^k`.
    fn poly(c: &[f64], t: f64, deriv: usize) -> f64 {
        c.iter()
            .enumerate()
            .skip(deriv)
            .map(|(k, ck)| ck * ((k - deriv + 1)..=k).map(|f| f as f64).product::<f64>() * t.powi((k - deriv) as i32))
            .sum()
    }

    fn assert_close(got: &[f64], want: &[f64], rel: f64, what: &str) {
        assert_eq!(got.len(), want.len(), "{what}: length");
        let scale = want.iter().fold(1.0_f64, |m, w| m.max(w.abs()));
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            assert!((g - w).abs() <= rel * scale, "{what}[{i}]: got {g}, want {w} (scale {scale})");
        }
    }

    #[test]
    fn polynomials_up_to_the_order_are_reproduced_exactly_inside_and_at_the_edges() {
        let dt = 0.01;
        for (window, order) in [(5, 2), (7, 3), (31, 3), (21, 5)] {
            let sg = SavitzkyGolay::new(window, order).unwrap();
            // A polynomial of exactly `order`, offset in time so no coefficient vanishes.
            let c: Vec<f64> = (0..=order).map(|k| [2.5, -1.5, 0.75, 0.4, -0.2, 0.05][k]).collect();
            let t: Vec<f64> = (0..120).map(|k| 1.3 + k as f64 * dt).collect();
            let x: Vec<f64> = t.iter().map(|&ti| poly(&c, ti, 0)).collect();
            for deriv in 0..=order.min(2) {
                let want: Vec<f64> = t.iter().map(|&ti| poly(&c, ti, deriv)).collect();
                let got = sg.apply(&x, deriv, dt).unwrap();
                assert_close(&got, &want, 1e-9, &format!("window {window} order {order} deriv {deriv}"));
            }
        }
    }

    #[test]
    fn matches_scipy_savgol_filter_in_interp_mode() {
        // Reference values from scipy 1.17.1:
        //   x = np.array([0.3, -1.2, 2.5, 4.1, 3.3, 0.7, -0.8, 1.9, 5.2, 6.0, 4.4, 2.2, 2.9, 3.7, 1.1, -0.4])
        //   scipy.signal.savgol_filter(x, window, order, deriv=d, delta=0.1, mode="interp") for d = 0, 1, 2
        let x = [0.3, -1.2, 2.5, 4.1, 3.3, 0.7, -0.8, 1.9, 5.2, 6.0, 4.4, 2.2, 2.9, 3.7, 1.1, -0.4];
        #[rustfmt::skip]
        let w7_o3: [[f64; 16]; 3] = [
            [
                -0.3952380952380967, 0.545238095238092, 1.8880952380952356, 3.000000000000002, 2.6476190476190493,
                1.071428571428572, 0.7285714285714286, 2.1142857142857157, 4.228571428571431, 5.1285714285714326,
                4.433333333333336, 3.6047619047619075, 2.904761904761907, 2.7880952380952397, 1.8738095238095243,
                -0.6047619047619097,
            ],
            [
                5.281746031745993, 12.472222222222221, 13.329365079365093, 7.853174603174601, -19.305555555555568,
                -17.64285714285715, 6.154761904761909, 26.940476190476204, 21.95238095238096, -4.273809523809527,
                -16.432539682539698, -5.988095238095253, 0.2658730158730114, -3.8769841269841265, -15.686507936507965,
                -35.162698412698475,
            ],
            [
                103.57142857142902, 40.23809523809549, -23.095238095238052, -86.4285714285714, -57.38095238095236,
                67.14285714285711, 109.2857142857142, 42.14285714285708, -71.42857142857144, -100.71428571428571,
                -33.809523809523824, 1.9047619047618942, -3.095238095238093, -79.761904761905, -156.42857142857173,
                -233.09523809523847,
            ],
        ];
        #[rustfmt::skip]
        let w5_o2: [[f64; 16]; 3] = [
            [
                -0.5600000000000015, 0.7200000000000001, 1.8999999999999988, 4.022857142857141, 3.1028571428571414,
                0.6828571428571419, -0.22571428571428664, 1.8571428571428559, 4.9257142857142835, 5.854285714285712,
                4.254285714285712, 2.7399999999999984, 2.959999999999998, 3.0142857142857133, 1.7571428571428571,
                -0.6142857142857148,
            ],
            [
                13.30000000000002, 12.300000000000008, 11.300000000000008, 4.600000000000013, -9.999999999999991,
                -8.499999999999998, 5.000000000000001, 16.60000000000001, 14.500000000000018, -0.19999999999998064,
                -8.399999999999988, -6.0999999999999925, -5.0999999999999925, -6.999999999999991, -18.14285714285714,
                -29.28571428571429,
            ],
            [
                -10.00000000000011, -10.00000000000011, -10.000000000000092, -214.2857142857144, -114.28571428571435,
                115.71428571428565, 228.57142857142847, 74.28571428571419, -158.57142857142873, -191.42857142857162,
                -11.428571428571601, 109.9999999999998, -10.000000000000135, -111.4285714285715, -111.42857142857143,
                -111.42857142857143,
            ],
        ];
        for (window, order, table) in [(7, 3, w7_o3), (5, 2, w5_o2)] {
            let sg = SavitzkyGolay::new(window, order).unwrap();
            for (deriv, want) in table.iter().enumerate() {
                let got = sg.apply(&x, deriv, 0.1).unwrap();
                assert_close(&got, want, 1e-12, &format!("scipy window {window} order {order} deriv {deriv}"));
            }
        }
    }

    #[test]
    fn apply_into_fills_the_buffer_like_apply() {
        let sg = SavitzkyGolay::new(9, 3).unwrap();
        let x: Vec<f64> = (0..50).map(|k| (k as f64 * 0.3).sin()).collect();
        let mut out = vec![f64::NAN; x.len()];
        sg.apply_into(&x, 1, 0.02, &mut out).unwrap();
        assert_eq!(out, sg.apply(&x, 1, 0.02).unwrap());
    }

    #[test]
    fn noise_gain_matches_the_empirical_variance_of_filtered_white_noise() {
        // Closed forms for the centred kernels of window 5, order 2 at unit spacing:
        // smoothing (-3, 12, 17, 12, -3)/35, first derivative (-2, -1, 0, 1, 2)/10.
        let sg = SavitzkyGolay::new(5, 2).unwrap();
        assert!((sg.noise_gain(0) - 17.0 / 35.0).abs() < 1e-14);
        assert!((sg.noise_gain(1) - 0.1).abs() < 1e-14);
        assert_eq!(sg.noise_gain(3), 0.0);

        // Deterministic ±1 noise (variance 1) through window 31, order 3 at dt = 0.01 s.
        let sg = SavitzkyGolay::new(31, 3).unwrap();
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let noise: Vec<f64> = (0..40_000)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                if state & 1 == 0 {
                    1.0
                } else {
                    -1.0
                }
            })
            .collect();
        let dt = 0.01;
        let rate = sg.apply(&noise, 1, dt).unwrap();
        let interior = &rate[15..rate.len() - 15];
        let var = interior.iter().map(|r| r * r).sum::<f64>() / interior.len() as f64;
        let predicted = sg.noise_gain(1) / (dt * dt);
        assert!((var / predicted - 1.0).abs() < 0.05, "variance {var} vs predicted {predicted}");
    }

    #[test]
    fn invalid_settings_and_inputs_are_typed_errors() {
        assert_eq!(SavitzkyGolay::new(8, 3).unwrap_err(), SavGolError::EvenWindow { window: 8 });
        assert_eq!(SavitzkyGolay::new(0, 0).unwrap_err(), SavGolError::EvenWindow { window: 0 });
        assert_eq!(SavitzkyGolay::new(3, 2).unwrap_err(), SavGolError::WindowTooShort { window: 3, order: 2 });
        assert_eq!(SavitzkyGolay::new(1, 0).unwrap_err(), SavGolError::WindowTooShort { window: 1, order: 0 });
        assert_eq!(
            SavitzkyGolay::new(3, usize::MAX).unwrap_err(),
            SavGolError::WindowTooShort { window: 3, order: usize::MAX }
        );
        assert!(matches!(SavitzkyGolay::new(100_001, 3), Err(SavGolError::TooLarge { .. })));

        let sg = SavitzkyGolay::new(5, 2).unwrap();
        let x = [1.0, 2.0, 4.0, 7.0, 11.0, 16.0];
        assert_eq!(sg.apply(&x, 3, 0.1).unwrap_err(), SavGolError::DerivTooHigh { deriv: 3, order: 2 });
        assert_eq!(sg.apply(&x[..4], 0, 0.1).unwrap_err(), SavGolError::InputTooShort { len: 4, window: 5 });
        for dt in [0.0, -0.1, f64::NAN, f64::INFINITY] {
            assert!(matches!(sg.apply(&x, 1, dt), Err(SavGolError::InvalidStep { .. })), "dt = {dt}");
        }
        let mut short = [0.0; 5];
        assert_eq!(
            sg.apply_into(&x, 0, 0.1, &mut short).unwrap_err(),
            SavGolError::OutputLength { expected: 6, got: 5 }
        );
        // The smallest valid input, one window, is all edge: still exact on a quadratic.
        let d2 = sg.apply(&x[..5], 2, 1.0).unwrap();
        assert!(d2.iter().all(|v| (v - 1.0).abs() < 1e-12), "{d2:?}");
    }
}
