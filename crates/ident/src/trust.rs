//! Where an identified model can be trusted: its free run's error on the held-out data,
//! split by operating range and by how fast the throttle moves, against the noise floor.
//!
//! A model can be good on average and poor where it matters: an engine the ten parameters do
//! not describe (a governed spool whose response time changes five-fold over its range) is
//! fitted best where the data spends most time, and a controller then plans with it at full
//! throttle or through a fast step. `identify` says so next to the model it writes: the
//! held-out MAE over each throttle band (25–50, 50–75, 75–100 %), over fast transients (the
//! [`TRANSIENT_S`] after the throttle moved by [`FAST_MOVE_PCT`] points within [`FAST_WINDOW_S`]) and
//! over the rest, each over the noise floor; a region above [`crate::identify::POOR_FIT_RATIO`]
//! is less trustworthy, one with fewer than [`MIN_SAMPLES`] held-out samples untested.
//!
//! ```
//! use jetbench_ident::series::Series;
//! use jetbench_ident::trust;
//!
//! // A held-out run at 40 % and then at 90 %; the model is 3 N off at 90 % only.
//! let n = 2000;
//! let u: Vec<f64> = (0..n).map(|k| if k < n / 2 { 40.0 } else { 90.0 }).collect();
//! let run = Series {
//!     name: "held out".into(),
//!     t_s: (0..n).map(|k| k as f64 * 0.01).collect(),
//!     u_pct: u.clone(),
//!     thrust_n: u.iter().map(|u| u + 1.0).collect(),
//! };
//! let sim: Vec<f64> = u.iter().map(|&u| if u > 75.0 { u - 2.0 } else { u }).collect();
//! let t = trust::assess(&[run], &[sim], 1.0);
//! let band = |label: &str| t.regions.iter().find(|r| r.label == label).unwrap();
//! assert!(!band("25–50 %").less_trustworthy());
//! assert!(band("75–100 %").less_trustworthy());
//! assert!(band("50–75 %").untested());
//! ```

use std::fmt::Write as _;

use serde::Serialize;

use crate::identify::POOR_FIT_RATIO;
use crate::series::Series;

/// A throttle move of at least this many points ...
pub const FAST_MOVE_PCT: f64 = 10.0;
/// ... within this long is fast, s.
pub const FAST_WINDOW_S: f64 = 0.3;
/// A fast move makes this long after the window that saw it a transient, s.
pub const TRANSIENT_S: f64 = 1.0;
/// Fewer held-out samples than this in a region leave it untested (3 s at 100 Hz).
pub const MIN_SAMPLES: usize = 300;

/// The throttle bands, %, with their labels.
const BANDS: [(&str, f64, f64); 3] =
    [("25–50 %", f64::NEG_INFINITY, 50.0), ("50–75 %", 50.0, 75.0), ("75–100 %", 75.0, f64::INFINITY)];

/// One region of the held-out data.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Region {
    /// What the region is: a throttle band (`"75–100 %"`), `"fast transients"` or
    /// `"steady and slow moves"`.
    pub label: String,
    /// Held-out samples in it.
    pub samples: usize,
    /// The model's free-run MAE there, N (None: no sample).
    pub mae_n: Option<f64>,
    /// That MAE over the noise floor (None: no sample, or a floor of zero).
    pub over_floor: Option<f64>,
}

impl Region {
    /// Too few held-out samples to say.
    pub fn untested(&self) -> bool {
        self.samples < MIN_SAMPLES
    }

    /// Tested, and its error above what a good fit leaves ([`POOR_FIT_RATIO`] × the floor).
    pub fn less_trustworthy(&self) -> bool {
        !self.untested() && self.over_floor.is_some_and(|r| r > POOR_FIT_RATIO)
    }
}

/// Where the model is less trustworthy.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Trust {
    /// The noise floor the regions are judged against, N.
    pub floor_n: f64,
    /// The throttle bands, then fast transients and the rest.
    pub regions: Vec<Region>,
}

/// Splits the error of a free run (`sim`, one vector per series of `held_out`) by region.
/// Non-finite samples (lost rows, a divergence) are left out.
pub fn assess(held_out: &[Series], sim: &[Vec<f64>], floor_n: f64) -> Trust {
    let labels = BANDS.iter().map(|(label, _, _)| *label).chain(["fast transients", "steady and slow moves"]);
    let mut sums: Vec<(f64, usize)> = vec![(0.0, 0); BANDS.len() + 2];
    for (run, sim) in held_out.iter().zip(sim) {
        let transient = transients(run);
        for (k, (&y, &s)) in run.thrust_n.iter().zip(sim).enumerate() {
            let u = run.u_pct[k];
            if !(y.is_finite() && s.is_finite() && u.is_finite()) {
                continue;
            }
            let band = BANDS.iter().position(|(_, lo, hi)| u >= *lo && u < *hi).unwrap_or(BANDS.len() - 1);
            let motion = BANDS.len() + usize::from(!transient[k]);
            for i in [band, motion] {
                sums[i].0 += (y - s).abs();
                sums[i].1 += 1;
            }
        }
    }
    let regions = labels
        .zip(sums)
        .map(|(label, (sum, samples))| {
            let mae_n = (samples > 0).then(|| sum / samples as f64);
            // A noiseless recording has no floor to judge against: the MAE alone is given.
            let over_floor = mae_n.filter(|_| floor_n > 0.0).map(|m| m / floor_n);
            Region { label: label.into(), samples, mae_n, over_floor }
        })
        .collect();
    Trust { floor_n, regions }
}

/// Per sample: within [`TRANSIENT_S`] after a fast throttle move.
fn transients(run: &Series) -> Vec<bool> {
    let n = run.u_pct.len().min(run.t_s.len());
    let mut out = vec![false; run.u_pct.len()];
    let (mut from, mut last_fast) = (0, f64::NEG_INFINITY);
    for (k, (&t, flag)) in run.t_s.iter().zip(&mut out).enumerate().take(n) {
        while run.t_s[from] < t - FAST_WINDOW_S {
            from += 1;
        }
        let window = run.u_pct[from..=k].iter().filter(|u| u.is_finite());
        let (lo, hi) = window.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &u| (lo.min(u), hi.max(u)));
        if hi - lo >= FAST_MOVE_PCT {
            last_fast = t;
        }
        *flag = t - last_fast <= TRANSIENT_S;
    }
    out
}

impl Trust {
    /// The regions the model is less trustworthy in.
    pub fn weak(&self) -> impl Iterator<Item = &Region> {
        self.regions.iter().filter(|r| r.less_trustworthy())
    }

    /// The same as comment lines of a model file: the floor, one line per region, then the
    /// verdict.
    pub fn comment(&self) -> String {
        let mut out =
            format!("# where to trust it: held-out free-run MAE over the noise floor of {:.2} N\n", self.floor_n);
        for r in &self.regions {
            let figure = match r.over_floor {
                _ if r.untested() => format!("untested ({} samples)", r.samples),
                Some(ratio) => format!("{ratio:.2}×"),
                None => format!("{:.3} N", r.mae_n.unwrap_or(f64::NAN)),
            };
            let weak = if r.less_trustworthy() { "  (less trustworthy)" } else { "" };
            let _ = writeln!(out, "#   {}: {figure}{weak}", r.label);
        }
        out
    }

    /// One line per kind of region: every region's error over the floor, then which are
    /// less trustworthy and which untested.
    pub fn text(&self) -> String {
        let figure = |r: &Region| match r.over_floor {
            _ if r.untested() => format!("{} untested ({} samples)", r.label, r.samples),
            Some(ratio) => format!("{} {ratio:.2}×", r.label),
            None => format!("{} {:.3} N", r.label, r.mae_n.unwrap_or(f64::NAN)),
        };
        let mut out = format!(
            "where to trust it (held-out free-run MAE over the noise floor of {:.2} N): {}",
            self.floor_n,
            self.regions.iter().map(figure).collect::<Vec<_>>().join(", ")
        );
        let weak: Vec<&str> = self.weak().map(|r| r.label.as_str()).collect();
        if weak.is_empty() {
            out.push_str("; no region above the bar of a good fit");
        } else {
            let _ = write!(out, "; less trustworthy (above {POOR_FIT_RATIO:.2}× the floor): {}", weak.join(", "));
        }
        let untested: Vec<&str> = self.regions.iter().filter(|r| r.untested()).map(|r| r.label.as_str()).collect();
        if !untested.is_empty() {
            let _ = write!(
                out,
                "; not exercised by the held-out data, so untested: {} (record a campaign that covers it)",
                untested.join(", ")
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(u: Vec<f64>) -> Series {
        Series {
            name: "test".into(),
            t_s: (0..u.len()).map(|k| k as f64 * 0.01).collect(),
            thrust_n: u.clone(),
            u_pct: u,
        }
    }

    #[test]
    fn a_fast_step_makes_the_next_second_a_transient_and_a_slow_ramp_does_not() {
        // A step of 20 points at 5 s, then a ramp of 10 points over 10 s.
        let u: Vec<f64> = (0..2500)
            .map(|k| match k {
                0..500 => 30.0,
                500..1000 => 50.0,
                _ => 50.0 + 10.0 * ((k - 1000) as f64 / 1000.0).min(1.0),
            })
            .collect();
        let flags = transients(&run(u));
        assert!(!flags[499]);
        assert!(flags[500] && flags[620], "the move is seen for 0.3 s, and a second follows");
        assert!(!flags[640], "1.4 s after the step");
        assert!(!flags[1500] && !flags[2400], "a ramp of 1 point per second is slow");
    }

    #[test]
    fn errors_land_in_their_region_and_lost_rows_are_left_out() {
        let u: Vec<f64> = (0..1000).map(|k| if k < 500 { 30.0 } else { 60.0 }).collect();
        let mut data = run(u.clone());
        data.thrust_n[10] = f64::NAN;
        // 1 N off in the first half, 3 N in the second.
        let sim: Vec<f64> = u.iter().enumerate().map(|(k, u)| if k < 500 { u + 1.0 } else { u + 3.0 }).collect();
        let t = assess(&[data], &[sim], 1.0);
        let region = |label: &str| t.regions.iter().find(|r| r.label == label).unwrap().clone();
        assert_eq!(region("25–50 %").samples, 499);
        assert_eq!(region("25–50 %").mae_n, Some(1.0));
        assert_eq!(region("50–75 %").mae_n, Some(3.0));
        let fast = region("fast transients").samples;
        assert!((125..=135).contains(&fast), "{fast} samples within 1.3 s of the step");
        assert_eq!(region("steady and slow moves").samples, 999 - fast);
        assert!(region("75–100 %").untested() && region("fast transients").untested());
        assert!(
            t.text().contains("less trustworthy (above 1.10× the floor): 50–75 %, steady and slow moves"),
            "{}",
            t.text()
        );
        assert!(t.text().contains("untested: 75–100 %, fast transients"), "{}", t.text());
    }

    #[test]
    fn a_noiseless_recording_gives_the_error_without_a_ratio() {
        let u: Vec<f64> = vec![40.0; 1000];
        let sim: Vec<f64> = u.iter().map(|u| u + 0.5).collect();
        let t = assess(&[run(u)], &[sim], 0.0);
        assert!(t.weak().next().is_none(), "nothing judged against a zero floor");
        assert!(t.text().contains("25–50 % 0.500 N"), "{}", t.text());
    }
}
