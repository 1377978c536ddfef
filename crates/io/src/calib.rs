//! Force/torque calibration: a 6×6 matrix and tare offsets.
//!
//! `calibrated = C · raw − tare`, with `raw = [Fx, Fy, Fz, Tx, Ty, Tz]` as the
//! sensor sends it (N, N·m), `C` the sensor's 6×6 calibration matrix and
//! `tare` the calibrated reading at rest (N, N·m). Thrust is the calibrated
//! force on the configured axis.
//!
//! ```
//! use jetbench_io::calib::{Calibration, Tare};
//! use jetbench_io::ForceReading;
//!
//! let mut c = Calibration::identity();
//! let at_rest = ForceReading { force_n: [1.5, 0.0, 0.0], ..ForceReading::default() };
//! let mut tare = Tare::new();
//! for _ in 0..100 {
//!     tare.add(&c.calibrated_untared(&at_rest));
//! }
//! c.tare = tare.offsets().unwrap();
//! let running = ForceReading { force_n: [41.5, 0.0, 0.0], ..ForceReading::default() };
//! assert!((c.apply(&running)[0] - 40.0).abs() < 1e-12);
//! ```

use nalgebra::{SMatrix, SVector};

use crate::ForceReading;

/// The 6×6 matrix type.
pub type Matrix6 = SMatrix<f64, 6, 6>;
/// A force/torque vector `[Fx, Fy, Fz, Tx, Ty, Tz]`, N and N·m.
pub type Wrench = [f64; 6];

/// Why a calibration is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    /// An entry of the config's `calibration` matrix is NaN or infinite.
    #[error("calibration matrix entry [{row}][{col}] = {value} is not a finite number")]
    NotFinite {
        /// Its row, 0..6 (Fx, Fy, Fz, Tx, Ty, Tz).
        row: usize,
        /// Its column, 0..6.
        col: usize,
        /// The value.
        value: f64,
    },
    /// A tare offset is NaN or infinite.
    #[error("tare offset {axis} = {value} is not a finite number")]
    TareNotFinite {
        /// Its axis, 0..6 (Fx, Fy, Fz, Tx, Ty, Tz).
        axis: usize,
        /// The value.
        value: f64,
    },
    /// A tare was asked of no readings.
    #[error("no samples to tare with")]
    NoSamples,
}

/// Calibration matrix and tare offsets.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    /// `C`: maps the raw reading (forces N, torques N·m, as the sensor reports them)
    /// to calibrated ones, axes in the order Fx, Fy, Fz, Tx, Ty, Tz (the sensor's
    /// calibration sheet gives it; identity for a sensor that is calibrated itself).
    pub matrix: Matrix6,
    /// Subtracted after the matrix, N (0..3) and N·m (3..6).
    pub tare: Wrench,
}

impl Default for Calibration {
    fn default() -> Self {
        Self::identity()
    }
}

impl Calibration {
    /// The identity matrix and no tare: readings pass unchanged.
    pub fn identity() -> Self {
        Calibration { matrix: Matrix6::identity(), tare: [0.0; 6] }
    }

    /// From rows as written in the config (`calibration = [[...], ...]`).
    pub fn new(rows: &[[f64; 6]; 6], tare: Wrench) -> Result<Self, CalibrationError> {
        for (row, r) in rows.iter().enumerate() {
            for (col, value) in r.iter().enumerate() {
                if !value.is_finite() {
                    return Err(CalibrationError::NotFinite { row, col, value: *value });
                }
            }
        }
        if let Some((axis, value)) = tare.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(CalibrationError::TareNotFinite { axis, value: *value });
        }
        Ok(Calibration { matrix: Matrix6::from_fn(|r, c| rows[r][c]), tare })
    }

    /// `C · raw`, before the tare (what `jetbench tare` averages).
    pub fn calibrated_untared(&self, raw: &ForceReading) -> Wrench {
        let v = SVector::<f64, 6>::from_iterator(raw.force_n.iter().chain(&raw.torque_nm).copied());
        let out = self.matrix * v;
        std::array::from_fn(|i| out[i])
    }

    /// `C · raw − tare`.
    pub fn apply(&self, raw: &ForceReading) -> Wrench {
        let c = self.calibrated_untared(raw);
        std::array::from_fn(|i| c[i] - self.tare[i])
    }
}

/// Averages calibrated readings at rest into tare offsets.
#[derive(Clone, Debug, Default)]
pub struct Tare {
    sum: [f64; 6],
    sum_sq: [f64; 6],
    n: u64,
}

impl Tare {
    /// No readings yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one calibrated, untared reading taken at rest
    /// ([`Calibration::calibrated_untared`]).
    pub fn add(&mut self, calibrated: &Wrench) {
        for ((sum, sum_sq), v) in self.sum.iter_mut().zip(&mut self.sum_sq).zip(calibrated) {
            *sum += v;
            *sum_sq += v * v;
        }
        self.n += 1;
    }

    /// Readings added.
    pub fn samples(&self) -> u64 {
        self.n
    }

    /// The mean per axis.
    pub fn offsets(&self) -> Result<Wrench, CalibrationError> {
        if self.n == 0 {
            return Err(CalibrationError::NoSamples);
        }
        Ok(self.sum.map(|s| s / self.n as f64))
    }

    /// Sample standard deviation per axis (0 with fewer than two samples).
    pub fn std_dev(&self) -> Wrench {
        if self.n < 2 {
            return [0.0; 6];
        }
        let n = self.n as f64;
        std::array::from_fn(|i| ((self.sum_sq[i] - self.sum[i] * self.sum[i] / n).max(0.0) / (n - 1.0)).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrix_then_tare() {
        let mut rows = [[0.0; 6]; 6];
        for (i, r) in rows.iter_mut().enumerate() {
            r[i] = 2.0;
        }
        rows[0][1] = 0.5; // Fy leaks into Fx
        let c = Calibration::new(&rows, [1.0, 0.0, 0.0, 0.0, 0.0, 0.1]).unwrap();
        let raw = ForceReading { force_n: [10.0, 4.0, 0.0], torque_nm: [0.0, 0.0, 1.0], ..ForceReading::default() };
        let out = c.apply(&raw);
        assert!((out[0] - (20.0 + 2.0 - 1.0)).abs() < 1e-12, "{out:?}");
        assert!((out[1] - 8.0).abs() < 1e-12);
        assert!((out[5] - 1.9).abs() < 1e-12);
        rows[3][3] = f64::NAN;
        assert_eq!(
            Calibration::new(&rows, [0.0; 6]).map(|_| ()).map_err(|e| e.to_string()),
            Err("calibration matrix entry [3][3] = NaN is not a finite number".into())
        );
    }

    #[test]
    fn tare_averages_and_spreads() {
        let mut t = Tare::new();
        assert_eq!(t.offsets(), Err(CalibrationError::NoSamples));
        for v in [1.0, 2.0, 3.0] {
            t.add(&[v, 0.0, 0.0, 0.0, 0.0, -v]);
        }
        assert_eq!(t.offsets().unwrap(), [2.0, 0.0, 0.0, 0.0, 0.0, -2.0]);
        assert!((t.std_dev()[0] - 1.0).abs() < 1e-12);
    }
}
