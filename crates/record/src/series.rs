//! Recordings as identification data: time, applied throttle and measured thrust.
//!
//! Every offline command reads CSV and MCAP alike (docs/stack/README.md, "Identification data (CSV)"):
//!
//! - CSV: header `time_s,throttle_pct,thrust_n`, extra columns allowed, any order.
//! - MCAP: `bench/thrust` gives the measured thrust and the time (the sensor's
//!   frame counter times 10 ms); `bench/actuation` gives the throttle the board
//!   applied.
//!
//! Convention: the throttle of row `k` is the throttle held from `time_s[k]` until
//! `time_s[k + 1]`, so the model maps `(T[k], u[k])` to `T[k + 1]`. In a live
//! recording the command computed from thrust sample `k` is applied before the
//! plant's next step, so `u[k]` is the last applied throttle published before
//! the next thrust sample was stamped. [`Series::write_csv`] writes exactly the
//! values a loader reads, so the same data as MCAP and as CSV identify alike.

use std::io::{Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::Recording;
use jetbench_model::{STEP_S, THROTTLE_MIN_PCT};
use jetbench_msgs::{actuation_flags, channels};

/// Largest relative deviation of a step from [`STEP_S`] before the series is split.
const GAP_FACTOR: f64 = 1.5;
/// Sampling periods further than this (relative) from [`STEP_S`] are refused.
const PERIOD_TOLERANCE: f64 = 0.05;
/// More thrust than this, N, is not a model jet engine in newtons (the largest
/// engines of the class give a few hundred).
const MAX_PLAUSIBLE_THRUST_N: f64 = 2000.0;

/// Why a recording cannot be used as identification data.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The file (a CSV) could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file given.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The rows cannot be used (too few, not monotonic, a throttle out of range, ...).
    #[error("{path}: {message}")]
    Invalid {
        /// The file given.
        path: String,
        /// What is wrong and what to do.
        message: String,
    },
    /// The recording itself could not be read.
    #[error(transparent)]
    Mcap(#[from] crate::RecordError),
}

/// Time, throttle and thrust, one row per 10 ms sample.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    /// Where the data came from (file name), for messages and plots.
    pub name: String,
    /// Time, s, strictly increasing, from the start of the recording.
    pub t_s: Vec<f64>,
    /// Throttle applied from `t_s[k]` to `t_s[k + 1]`, %.
    pub u_pct: Vec<f64>,
    /// Measured thrust at `t_s[k]`, N. Empty for an input-only profile.
    pub thrust_n: Vec<f64>,
}

impl Series {
    /// Rows (10 ms samples).
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// No rows at all.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// True when the file carried measured thrust (not only a throttle profile).
    pub fn has_thrust(&self) -> bool {
        !self.thrust_n.is_empty()
    }

    /// Rows `range` as a series of their own (time keeps its origin).
    pub fn slice(&self, range: Range<usize>) -> Series {
        Series {
            name: self.name.clone(),
            t_s: self.t_s[range.clone()].to_vec(),
            u_pct: self.u_pct[range.clone()].to_vec(),
            thrust_n: if self.has_thrust() { self.thrust_n[range].to_vec() } else { Vec::new() },
        }
    }

    /// Contiguous runs of rows: a step longer than 1.5 sample periods (a lost
    /// sample, a pause) ends a run, because the model steps 10 ms at a time.
    pub fn runs(&self) -> Vec<Range<usize>> {
        let mut runs = Vec::new();
        let mut start = 0;
        for k in 1..self.len() {
            if self.t_s[k] - self.t_s[k - 1] > GAP_FACTOR * STEP_S {
                runs.push(start..k);
                start = k;
            }
        }
        if start < self.len() {
            runs.push(start..self.len());
        }
        runs
    }

    /// Checks what every method assumes: finite values, time strictly
    /// increasing, sampled at 100 Hz (gaps allowed, see [`Series::runs`]).
    pub fn check(&self) -> Result<(), DataError> {
        self.check_values()?;
        let invalid = |message: String| DataError::Invalid { path: self.name.clone(), message };
        let median = self.median_period_s();
        if ((median - STEP_S) / STEP_S).abs() > PERIOD_TOLERANCE {
            return Err(invalid(format!(
                "sampled every {:.3} ms; the model is discretised at 10 ms, so resample to 100 Hz (`jetbench \
                 diagnose` does it for you)",
                median * 1e3
            )));
        }
        Ok(())
    }

    /// [`Series::check`] without the sampling rate: finite values, time strictly increasing.
    pub fn check_values(&self) -> Result<(), DataError> {
        let invalid = |message: String| DataError::Invalid { path: self.name.clone(), message };
        if self.u_pct.len() != self.len() || (self.has_thrust() && self.thrust_n.len() != self.len()) {
            return Err(invalid("columns have different lengths".into()));
        }
        if self.len() < 2 {
            return Err(invalid(format!("{} samples: too few to use", self.len())));
        }
        let row = |k: usize| k + 2; // header is line 1
        for k in 0..self.len() {
            if !self.t_s[k].is_finite() {
                return Err(invalid(format!("time_s is not a number at row {}", row(k))));
            }
            if !self.u_pct[k].is_finite() {
                return Err(invalid(format!("throttle_pct is not a number at row {} (t = {} s)", row(k), self.t_s[k])));
            }
            if self.has_thrust() && !self.thrust_n[k].is_finite() {
                return Err(invalid(format!("thrust_n is not a number at row {} (t = {} s)", row(k), self.t_s[k])));
            }
            if k > 0 && self.t_s[k] <= self.t_s[k - 1] {
                return Err(invalid(format!(
                    "time goes backwards at row {}: {} s after {} s; sort the file or split it",
                    row(k),
                    self.t_s[k],
                    self.t_s[k - 1]
                )));
            }
        }
        Ok(())
    }

    /// Checks the values the way a test engineer would before trusting them:
    /// the throttle is a percentage of the ECU's range (0–100 %, the engine idling
    /// below [`THROTTLE_MIN_PCT`]), the thrust a force in newtons pushing forward.
    /// Catches a throttle given as a fraction (0–1), a run that never leaves
    /// idle, and thrust in the wrong unit or with its sign reversed.
    pub fn check_inputs(&self) -> Result<(), DataError> {
        let invalid = |message: String| DataError::Invalid { path: self.name.clone(), message };
        if self.is_empty() {
            return Ok(());
        }
        let (u_min, u_max) = min_max(&self.u_pct);
        if u_max <= 1.0 && u_min >= 0.0 && u_max > 0.0 {
            return Err(invalid(format!(
                "throttle_pct goes from {u_min} to {u_max}: it looks like a fraction (0–1), but the column is in \
                 percent (0–100 %), so every row would be far below idle ({THROTTLE_MIN_PCT} %); multiply the \
                 column by 100"
            )));
        }
        if let Some(k) = self.u_pct.iter().position(|u| !(0.0..=100.0).contains(u)) {
            return Err(invalid(format!(
                "throttle_pct is {} at row {} (t = {} s), outside 0–100 %: the throttle is a percentage of the ECU's \
                 range; check the column's unit and scale",
                self.u_pct[k],
                k + 2,
                self.t_s[k]
            )));
        }
        if u_max < THROTTLE_MIN_PCT && self.has_thrust() {
            return Err(invalid(format!(
                "every throttle_pct is below idle ({THROTTLE_MIN_PCT} %; the highest is {u_max} %): the engine only \
                 idled, so the throttle's effect on thrust cannot be seen; record a run that moves the throttle \
                 between idle and full (`jetbench excite`)"
            )));
        }
        if !self.has_thrust() {
            return Ok(());
        }
        let mut sorted = self.thrust_n.clone();
        sorted.sort_by(f64::total_cmp);
        let (lowest, median, highest) = (sorted[0], sorted[sorted.len() / 2], sorted[sorted.len() - 1]);
        // Noise takes an idling engine's thrust below zero now and then; a reversed
        // sensor puts the whole run there, its peaks negative.
        if median < 0.0 && -lowest > 2.0 * highest.max(0.0) {
            return Err(invalid(format!(
                "thrust_n is mostly negative (median {median:.3} N, from {lowest:.3} to {highest:.3} N): thrust \
                 pushes forward and is positive, so the sensor's sign is reversed; multiply the column by −1 (or \
                 fix the axis sign in [sensor])"
            )));
        }
        // The 1st and 99th percentiles, so that a few spikes of a noisy bus do not count.
        let at = |q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
        let peak = at(0.99).max(-at(0.01));
        if peak > MAX_PLAUSIBLE_THRUST_N {
            return Err(invalid(format!(
                "thrust_n reaches {peak:.0} in 1 % of the rows: a model jet engine gives at most a few hundred newtons, so the column \
                 is not in newtons; from grams multiply by 0.00981, from millinewtons by 0.001"
            )));
        }
        Ok(())
    }

    /// The median time between rows, s (0 with fewer than two rows).
    pub fn median_period_s(&self) -> f64 {
        let mut steps: Vec<f64> = self.t_s.windows(2).map(|w| w[1] - w[0]).collect();
        if steps.is_empty() {
            return 0.0;
        }
        steps.sort_by(f64::total_cmp);
        steps[steps.len() / 2]
    }

    /// This series at the model's 100 Hz, with a note of what was done (`None` when it
    /// already is):
    ///
    /// - faster than 100 Hz: the thrust interpolated at every 10 ms (exactly a sample
    ///   when the rate is a whole multiple), the throttle averaged over each 10 ms it is
    ///   held for; no value is made up across a gap;
    /// - a whole multiple of 10 ms (50 Hz, 25 Hz, ...): the rows as they are, each
    ///   throttle held over the 10 ms steps until the next row, which a simulation on
    ///   the 10 ms grid does by itself (see [`Series::grid_steps`]);
    /// - anything else slower than 100 Hz is refused with what to do.
    pub fn to_100hz(self) -> Result<(Series, Option<String>), DataError> {
        let period_s = self.median_period_s();
        let ratio = period_s / STEP_S;
        let hz = 1.0 / period_s;
        if (ratio - 1.0).abs() <= PERIOD_TOLERANCE {
            return Ok((self, None));
        }
        let whole = ratio.round();
        if ratio > 1.0 && whole >= 2.0 && (ratio - whole).abs() <= PERIOD_TOLERANCE * whole {
            let note = format!(
                "{}: sampled every {:.1} ms ({hz:.1} Hz); each throttle is held for {whole:.0} steps of the 10 ms \
                 model and the thrust compared where it was sampled",
                self.name,
                period_s * 1e3
            );
            return Ok((self, Some(note)));
        }
        if ratio > 1.0 {
            return Err(DataError::Invalid {
                path: self.name.clone(),
                message: format!(
                    "sampled every {:.2} ms ({hz:.1} Hz): neither 100 Hz, faster, nor a whole multiple of 10 ms, so \
                     it cannot be put on the model's 10 ms grid without inventing data; resample it to 100 Hz first \
                     (time_s every 0.01 s, throttle_pct held over each 10 ms, thrust_n interpolated), or record at \
                     100 Hz or a rate that divides it",
                    period_s * 1e3
                ),
            });
        }
        let resampled = self.resample_faster(period_s);
        let note = format!(
            "{}: sampled every {:.2} ms ({hz:.0} Hz); resampled to 100 Hz: {} rows (thrust at every 10 ms, \
             interpolated unless a sample falls on it; throttle averaged over each 10 ms)",
            resampled.name,
            period_s * 1e3,
            resampled.len()
        );
        Ok((resampled, Some(note)))
    }

    /// Resamples a series sampled every `period_s` (< 10 ms) at 100 Hz.
    fn resample_faster(&self, period_s: f64) -> Series {
        let gap_s = GAP_FACTOR * period_s;
        let mut out = Series { name: self.name.clone(), ..Series::default() };
        let (first, last) = (self.t_s[0], self.t_s[self.len() - 1]);
        let mut j = 0;
        for k in 0.. {
            let t = first + k as f64 * STEP_S;
            if t > last + 1e-9 {
                break;
            }
            // Row j: the last one at or before t (with a tolerance for rounding in the file).
            while j + 1 < self.len() && self.t_s[j + 1] <= t + 1e-9 {
                j += 1;
            }
            let on_sample = (self.t_s[j] - t).abs() <= 1e-9;
            if !on_sample && (j + 1 >= self.len() || self.t_s[j + 1] - self.t_s[j] > gap_s) {
                continue; // inside a gap: nothing to interpolate from
            }
            // Throttle: row i is held from t_i to t_(i+1); average over [t, t + 10 ms).
            let (mut sum, mut covered, mut i) = (0.0, 0.0, j);
            while i < self.len() && self.t_s[i] < t + STEP_S - 1e-12 {
                let from = self.t_s[i].max(t);
                let to = self.t_s.get(i + 1).map_or(t + STEP_S, |n| n.min(t + STEP_S));
                if to > from {
                    sum += self.u_pct[i] * (to - from);
                    covered += to - from;
                }
                i += 1;
            }
            out.t_s.push(t);
            out.u_pct.push(if covered > 0.0 { sum / covered } else { self.u_pct[j] });
            if self.has_thrust() {
                let y = if on_sample {
                    self.thrust_n[j]
                } else {
                    let w = (t - self.t_s[j]) / (self.t_s[j + 1] - self.t_s[j]);
                    self.thrust_n[j] + w * (self.thrust_n[j + 1] - self.thrust_n[j])
                };
                out.thrust_n.push(y);
            }
        }
        out
    }

    /// For each row, how many 10 ms model steps it is after the previous one (0 for
    /// the first): 1 between consecutive samples, more across lost rows or at a lower
    /// rate. Robust to jitter and to a clock a little off 100 Hz: each interval is
    /// rounded on its own.
    pub fn grid_steps(&self) -> Vec<usize> {
        std::iter::once(0)
            .chain(self.t_s.windows(2).map(|w| ((w[1] - w[0]) / STEP_S).round().max(1.0) as usize))
            .collect()
    }

    /// Reads a CSV (`time_s,throttle_pct[,thrust_n]`, extra columns ignored), with a note of
    /// the rows left out ([`Series::parse_csv`]).
    pub fn from_csv<R: Read>(
        reader: R,
        name: &str,
        require_thrust: bool,
    ) -> Result<(Series, Option<String>), DataError> {
        let (series, note) = Self::parse_csv(reader, name, require_thrust)?;
        series.check()?;
        Ok((series, note))
    }

    /// Reads a CSV at any uniform rate and brings it to 100 Hz ([`Series::to_100hz`]),
    /// with a note of what was done.
    pub fn from_csv_any_rate<R: Read>(
        reader: R,
        name: &str,
        require_thrust: bool,
    ) -> Result<(Series, Option<String>), DataError> {
        let (series, lost) = Self::parse_csv(reader, name, require_thrust)?;
        series.check_values()?;
        let (series, note) = series.to_100hz()?;
        series.check_values()?;
        let notes: Vec<String> = lost.into_iter().chain(note).collect();
        Ok((series, (!notes.is_empty()).then(|| notes.join("; "))))
    }

    /// The rows of a CSV, with a note of those left out. A row whose time, throttle or
    /// thrust is not a number a sensor gives (`NaN`, `inf`, an empty field) is a lost sample:
    /// it is left out and becomes a gap, as a lost row does, and counted. So is a last line
    /// cut short (a file whose writer stopped mid-line). More than half the rows lost, or text
    /// where a number belongs, or a short line elsewhere, is an error: that is not this format.
    fn parse_csv<R: Read>(
        mut reader: R,
        name: &str,
        require_thrust: bool,
    ) -> Result<(Series, Option<String>), DataError> {
        let invalid = |message: String| DataError::Invalid { path: name.to_owned(), message };
        let mut bytes = Vec::new();
        reader.read_to_end(&mut bytes).map_err(|e| invalid(format!("cannot read the file: {e}")))?;
        // A last data line with no line break after it is where a writer stopped: a number
        // there may be cut short ("12.57" read as "12"), so the line is left out, and said.
        let body = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |at| at + 1);
        let tail = String::from_utf8_lossy(&bytes[body..]).trim().to_owned();
        let unterminated = (body > 0 && !tail.is_empty() && !tail.starts_with('#'))
            .then(|| bytes[..body].iter().filter(|&&b| b == b'\n').count() + 1);
        // (A comment there goes too, unsaid: the reader takes one with no line break for a row.)
        if body > 0 {
            bytes.truncate(body);
        }
        let mut csv = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .flexible(true)
            .from_reader(bytes.as_slice());
        let header = csv.headers().map_err(|e| invalid(format!("cannot read the CSV header: {e}")))?.clone();
        let column = |wanted: &str| header.iter().position(|h| h == wanted);
        let found = || header.iter().collect::<Vec<_>>().join(",");
        let (Some(t_col), Some(u_col)) = (column("time_s"), column("throttle_pct")) else {
            if header.is_empty() {
                return Err(invalid(
                    "the file is empty: a CSV needs a header `time_s,throttle_pct,thrust_n` and one row per sample"
                        .to_owned(),
                ));
            }
            return Err(invalid(format!(
                "the header must have time_s and throttle_pct (and thrust_n for identification); found: {}",
                found()
            )));
        };
        let y_col = column("thrust_n");
        if require_thrust && y_col.is_none() {
            return Err(invalid(format!("no thrust_n column (header: {}); identification needs it", found())));
        }
        let mut series = Series { name: name.to_owned(), ..Series::default() };
        // Fields a row needs: up to the last column read.
        let needed = t_col.max(u_col).max(y_col.unwrap_or(0)) + 1;
        let (mut rows, mut lost, mut first_lost) = (0usize, 0usize, None);
        let mut cut_short: Option<(usize, usize)> = None;
        for (i, record) in csv.records().enumerate() {
            let line = i + 2;
            let record = record.map_err(|e| invalid(format!("line {line}: {e}")))?;
            // A short line is only forgiven as the last one: a line after it is an error.
            if let Some((short, fields)) = cut_short {
                return Err(invalid(format!(
                    "line {short} has {fields} field(s) where the header has {}: the file is not one table",
                    header.len()
                )));
            }
            rows += 1;
            if record.len() < needed {
                cut_short = Some((line, record.len()));
                continue;
            }
            // `None`: a value a sensor or an export writes for a lost sample.
            let field = |col: usize, what: &str| -> Result<Option<f64>, DataError> {
                let text = record.get(col).unwrap_or_default();
                match text.parse::<f64>() {
                    Ok(v) if v.is_finite() => Ok(Some(v)),
                    Ok(_) => Ok(None),
                    Err(_) if text.is_empty() => Ok(None),
                    Err(_) => Err(invalid(format!("line {line}: {what} {text:?} is not a number"))),
                }
            };
            let t = field(t_col, "time_s")?;
            let u = field(u_col, "throttle_pct")?;
            let y = y_col.map(|c| field(c, "thrust_n")).transpose()?;
            // Checked here, where the file's own line is known (rows left out before it
            // would shift a count of the rows kept).
            if let (Some(t), Some(&before)) = (t, series.t_s.last()) {
                if t <= before {
                    return Err(invalid(format!(
                        "time goes backwards at row {line}: {t} s after {before} s; sort the file or split it"
                    )));
                }
            }
            match (t, u, y) {
                (Some(t), Some(u), Some(Some(y))) => {
                    series.t_s.push(t);
                    series.u_pct.push(u);
                    series.thrust_n.push(y);
                }
                (Some(t), Some(u), None) => {
                    series.t_s.push(t);
                    series.u_pct.push(u);
                }
                _ => {
                    lost += 1;
                    first_lost.get_or_insert(line);
                }
            }
        }
        if let Some((line, fields)) = cut_short.filter(|_| series.t_s.is_empty()) {
            return Err(invalid(format!("line {line} has {fields} field(s) where the header has {}", header.len())));
        }
        if rows > 0 && 2 * lost > rows {
            return Err(invalid(format!(
                "{lost} of {rows} rows have a time, throttle or thrust that is not a number (NaN, inf or empty), the \
                 first at line {}: too few samples to use",
                first_lost.unwrap_or(2)
            )));
        }
        let mut notes = Vec::new();
        if lost > 0 {
            notes.push(format!(
                "{name}: {lost} row(s) ({:.1} %) left out, the first at line {}: a time, throttle or thrust that is \
                 not a number (NaN, inf or empty); they become gaps, as lost rows do",
                100.0 * lost as f64 / rows as f64,
                first_lost.unwrap_or(2)
            ));
        }
        if let Some((line, fields)) = cut_short {
            notes.push(format!(
                "{name}: the last line ({line}) is cut short ({fields} of {} fields): left out",
                header.len()
            ));
        }
        if let Some(line) = unterminated {
            notes.push(format!(
                "{name}: the last line ({line}) ends the file with no line break, as a writer stopped mid-line \
                 leaves it: left out (a number there may be cut short)"
            ));
        }
        Ok((series, (!notes.is_empty()).then(|| notes.join("; "))))
    }

    /// Reads identification data from a recording (see the module docs).
    pub fn from_recording(recording: &Recording, name: &str) -> Result<Series, DataError> {
        Self::from_recording_noted(recording, name).map(|(series, _)| series)
    }

    /// [`Series::from_recording`], with a note of the rows left out because the throttle
    /// the board applied is not known there: the board had not acknowledged the command
    /// (`UNACKED`) or was silent (`BOARD_SILENT`). They become gaps, as lost rows do.
    pub fn from_recording_noted(recording: &Recording, name: &str) -> Result<(Series, Option<String>), DataError> {
        let invalid = |message: String| DataError::Invalid { path: name.to_owned(), message };
        let thrust = recording.samples(channels::THRUST);
        let mut actuation = recording.samples(channels::ACTUATION);
        if thrust.len() < 2 {
            return Err(invalid(format!("{} bench/thrust samples: nothing to identify from", thrust.len())));
        }
        if actuation.is_empty() {
            return Err(invalid("no bench/actuation samples: the applied throttle is unknown".into()));
        }
        actuation.sort_by_key(|a| a.publish_ns);
        let mut series = Series { name: name.to_owned(), ..Series::default() };
        let origin_frame = thrust[0].frame_seq;
        let mut next_actuation = 0;
        let mut applied: Option<(f64, u32)> = None;
        let mut unknown = 0usize;
        for (k, sample) in thrust.iter().enumerate() {
            // The throttle held until the next sample: the last one published before it.
            let until_ns = thrust.get(k + 1).map_or(sample.stamp_ns + (STEP_S * 1e9) as u64, |next| next.stamp_ns);
            while next_actuation < actuation.len() && actuation[next_actuation].publish_ns < until_ns {
                let a = &actuation[next_actuation];
                applied = Some((a.applied_pct, a.flags));
                next_actuation += 1;
            }
            // Before the first applied throttle the input is unknown: start after it.
            let Some((u, flags)) = applied else { continue };
            if flags & (actuation_flags::UNACKED | actuation_flags::BOARD_SILENT) != 0 {
                unknown += 1;
                continue;
            }
            // Time from the sensor's own frame counter: frames are sent every 10 ms,
            // while the receive stamps jitter with the PC's load. A lost frame still
            // shows as a gap.
            let frames = sample.frame_seq.wrapping_sub(origin_frame);
            if series.t_s.last().is_some_and(|&last| frames as f64 * STEP_S <= last) {
                continue; // a repeated frame
            }
            series.t_s.push(frames as f64 * STEP_S);
            series.u_pct.push(u);
            series.thrust_n.push(sample.thrust_n);
        }
        series.check()?;
        let note = (unknown > 0).then(|| {
            format!(
                "{name}: {unknown} row(s) ({:.1} %) left out: the board had not acknowledged the throttle or was \
                 silent, so what it applied is not known",
                100.0 * unknown as f64 / thrust.len() as f64
            )
        });
        Ok((series, note))
    }

    /// Loads a CSV or MCAP file, told apart by content, not by name: the MCAP magic
    /// bytes, or text (a CSV); anything else is refused as not an MCAP file. The
    /// values are checked as [`Series::check_inputs`] says.
    pub fn load(path: &Path, require_thrust: bool) -> Result<Series, DataError> {
        let name = path.display().to_string();
        let bytes = read(path)?;
        let series = if bytes.starts_with(mcap_magic()) {
            let recording = Recording::open(path)?;
            if recording.truncated {
                eprintln!("warning: {name} is truncated; using the data up to its last complete chunk");
            }
            Series::from_recording(&recording, &name)?
        } else {
            let (series, note) = Series::from_csv(text(path, &bytes)?, &name, require_thrust)?;
            if let Some(note) = note {
                eprintln!("warning: {note}");
            }
            series
        };
        series.check_inputs()?;
        Ok(series)
    }

    /// Like [`Series::load`], but a CSV at another uniform rate is brought to 100 Hz
    /// ([`Series::to_100hz`]) instead of refused; the note says what was done.
    pub fn load_any_rate(path: &Path, require_thrust: bool) -> Result<(Series, Option<String>), DataError> {
        let name = path.display().to_string();
        let bytes = read(path)?;
        let (series, note) = if bytes.starts_with(mcap_magic()) {
            let recording = Recording::open(path)?;
            let (series, note) = Series::from_recording_noted(&recording, &name)?;
            let truncated = recording.truncated.then(|| format!("{name} is truncated; the data up to its last chunk"));
            let notes: Vec<String> = truncated.into_iter().chain(note).collect();
            (series, (!notes.is_empty()).then(|| notes.join("; ")))
        } else {
            Series::from_csv_any_rate(text(path, &bytes)?, &name, require_thrust)?
        };
        series.check_inputs()?;
        Ok((series, note))
    }

    /// Writes `time_s,throttle_pct[,thrust_n]` with the shortest text that reads
    /// back to the same numbers.
    pub fn write_csv<W: Write>(&self, mut out: W) -> std::io::Result<()> {
        if self.has_thrust() {
            writeln!(out, "time_s,throttle_pct,thrust_n")?;
            for k in 0..self.len() {
                writeln!(out, "{:?},{:?},{:?}", self.t_s[k], self.u_pct[k], self.thrust_n[k])?;
            }
        } else {
            writeln!(out, "time_s,throttle_pct")?;
            for k in 0..self.len() {
                writeln!(out, "{:?},{:?}", self.t_s[k], self.u_pct[k])?;
            }
        }
        out.flush()
    }
}

/// The bytes of `path`, saying which file could not be read.
fn read(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|source| DataError::Read { path: path.into(), source })
}

/// `bytes` as CSV text, or the same "not an MCAP file" every command gives.
fn text<'a>(path: &Path, bytes: &'a [u8]) -> Result<&'a [u8], DataError> {
    if crate::looks_like_text(bytes) {
        Ok(bytes)
    } else {
        Err(crate::RecordError::not_mcap(path, bytes).into())
    }
}

/// Smallest and largest of finite values.
fn min_max(values: &[f64]) -> (f64, f64) {
    values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)))
}

/// The bytes every MCAP file starts with.
fn mcap_magic() -> &'static [u8] {
    b"\x89MCAP0\r\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv(text: &str) -> Result<Series, DataError> {
        Series::from_csv(text.as_bytes(), "test.csv", true).map(|(series, _)| series)
    }

    #[test]
    fn reads_columns_in_any_order_with_extras() {
        let s = csv("thrust_n,extra,time_s,throttle_pct\n1.5,x,0.0,25\n2.5,y,0.01,30\n3.5,z,0.02,35\n").unwrap();
        assert_eq!(s.t_s, vec![0.0, 0.01, 0.02]);
        assert_eq!(s.u_pct, vec![25.0, 30.0, 35.0]);
        assert_eq!(s.thrust_n, vec![1.5, 2.5, 3.5]);
    }

    #[test]
    fn csv_round_trip_is_exact() {
        let s = Series {
            name: "x".into(),
            t_s: (0..50).map(|k| k as f64 * 0.01 + 1e-7 * (k as f64).sin()).collect(),
            u_pct: (0..50).map(|k| 25.0 + (k as f64 * 0.37).cos() / 3.0).collect(),
            thrust_n: (0..50).map(|k| (k as f64).sqrt() * std::f64::consts::PI).collect(),
        };
        let mut text = Vec::new();
        s.write_csv(&mut text).unwrap();
        let (back, _) = Series::from_csv(text.as_slice(), "x", true).unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn bad_input_names_the_problem() {
        let cases = [
            ("time_s,thrust_n\n0,1\n0.01,2\n", "throttle_pct"),
            ("time_s,throttle_pct\n0,25\n0.01,25\n", "thrust_n"),
            ("time_s,throttle_pct,thrust_n\n0,25,NaN\n0.01,,1\n0.02,25,1\n", "2 of 3 rows"),
            ("time_s,throttle_pct,thrust_n\n0,25,1\n0.01,25\n0.02,25,1\n", "line 3 has 2 field(s)"),
            ("time_s,throttle_pct,thrust_n\n0,25,1\n0.01,25,abc\n", "line 3"),
            ("time_s,throttle_pct,thrust_n\n0,25,1\n0.01,25,1\n0.005,25,1\n", "backwards at row 4"),
            ("time_s,throttle_pct,thrust_n\n0,25,1\n0.02,25,1\n0.04,25,1\n", "resample to 100 Hz"),
            ("time_s,throttle_pct,thrust_n\n0,25\n", "line 2"),
        ];
        for (text, expected) in cases {
            let e = csv(text).unwrap_err().to_string();
            assert!(e.contains(expected), "{text:?}: {e}");
        }
    }

    #[test]
    fn lost_samples_and_a_last_line_cut_short_are_left_out_and_counted() {
        let mut text = rows(0.01, 200, |t| 10.0 + t, |_| 40.0);
        // Rows 10 and 11 (lines 12 and 13) lost: NaN thrust, an empty throttle; the last cut short.
        text = text.replace("0.1,40,10.1\n", "0.1,40,NaN\n").replace("0.11,40,", "0.11,,");
        text.push_str("2.0,4\n");
        let (s, note) = Series::from_csv(text.as_bytes(), "lost.csv", true).unwrap();
        assert_eq!(s.len(), 198, "200 rows, 2 lost");
        assert!(s.t_s.iter().all(|t| (*t - 0.1).abs() > 1e-9 && (*t - 0.11).abs() > 1e-9), "{:?}", &s.t_s[8..12]);
        let note = note.expect("a note");
        assert!(note.contains("2 row(s) (1.0 %) left out, the first at line 12"), "{note}");
        assert!(note.contains("the last line (202) is cut short (2 of 3 fields)"), "{note}");
        // Brought to the grid, the lost rows are a gap the diagnosis sees as one.
        assert_eq!(s.grid_steps().iter().filter(|&&g| g > 1).count(), 1);
        // A last line with every field but no line break may hold a number cut short: left
        // out. A comment there, or a header alone, is no data line.
        let cut = rows(0.01, 50, |t| 10.0 + t, |_| 40.0) + "0.5,40,1";
        let (s, note) = Series::from_csv(cut.as_bytes(), "cut.csv", true).unwrap();
        assert_eq!(s.len(), 50);
        assert!(note.is_some_and(|n| n.contains("the last line (52) ends the file with no line break")));
        let (s, note) =
            Series::from_csv(format!("{}# end", rows(0.01, 50, |t| t, |_| 40.0)).as_bytes(), "c", true).unwrap();
        assert_eq!((s.len(), note), (50, None));
        let e = csv("time_s,throttle_pct,thrust_n").unwrap_err().to_string();
        assert!(e.contains("0 samples"), "{e}");
    }

    fn rows(period_s: f64, n: usize, thrust: impl Fn(f64) -> f64, throttle: impl Fn(usize) -> f64) -> String {
        let mut text = String::from("time_s,throttle_pct,thrust_n\n");
        for k in 0..n {
            let t = k as f64 * period_s;
            text.push_str(&format!("{t},{},{}\n", throttle(k), thrust(t)));
        }
        text
    }

    #[test]
    fn other_rates_are_brought_to_100_hz_with_a_note_or_refused_with_how() {
        let any = |text: &str| Series::from_csv_any_rate(text.as_bytes(), "r.csv", true);
        // 100 Hz: as it is, no note.
        let (s, note) = any(&rows(0.01, 50, |t| t, |_| 30.0)).unwrap();
        assert!(note.is_none() && s.len() == 50);
        // 200 Hz: every other sample's thrust, the throttle averaged over each 10 ms.
        let (s, note) = any(&rows(0.005, 400, |t| 3.0 * t, |k| if k % 2 == 0 { 30.0 } else { 40.0 })).unwrap();
        assert!(note.unwrap().contains("resampled to 100 Hz"));
        assert_eq!(s.len(), 200);
        assert!(s.median_period_s() > 0.00999 && s.median_period_s() < 0.01001);
        for k in 0..200 {
            assert!((s.thrust_n[k] - 3.0 * s.t_s[k]).abs() < 1e-9, "row {k}");
            assert!((s.u_pct[k] - 35.0).abs() < 1e-9, "row {k}: {}", s.u_pct[k]);
        }
        s.check().unwrap();
        // 130 Hz: interpolated, still exact on a straight line.
        let (s, _) = any(&rows(1.0 / 130.0, 400, |t| 5.0 + 2.0 * t, |_| 50.0)).unwrap();
        assert!(s.thrust_n.iter().zip(&s.t_s).all(|(y, t)| (y - 5.0 - 2.0 * t).abs() < 1e-9));
        s.check().unwrap();
        // 50 Hz: the rows as they are, two model steps apart.
        let (s, note) = any(&rows(0.02, 100, |t| t, |_| 30.0)).unwrap();
        assert!(note.unwrap().contains("held for 2 steps"));
        assert!(s.grid_steps()[1..].iter().all(|&g| g == 2));
        // 75 Hz: refused, saying how.
        let e = any(&rows(1.0 / 75.0, 100, |t| t, |_| 30.0)).unwrap_err().to_string();
        assert!(e.contains("75.0 Hz") && e.contains("resample it to 100 Hz first"), "{e}");
        // Garbage is still an error.
        assert!(any("time_s,throttle_pct,thrust_n\n0,25,1\n0.005,25,x\n").is_err());
    }

    #[test]
    fn inputs_are_checked_as_a_test_engineer_would() {
        let series = |u: &dyn Fn(usize) -> f64, y: &dyn Fn(usize) -> f64| Series {
            name: "s.csv".into(),
            t_s: (0..1000).map(|k| k as f64 * 0.01).collect(),
            u_pct: (0..1000).map(u).collect(),
            thrust_n: (0..1000).map(y).collect(),
        };
        // An idling engine's noise dips below zero: that is fine.
        let noisy_idle = |k: usize| if k < 500 { 1.5 + 3.0 * ((k as f64) * 1.7).sin() } else { 60.0 };
        let step = |k: usize| if k < 500 { 25.0 } else { 75.0 };
        series(&step, &noisy_idle).check_inputs().unwrap();
        let err = |s: Series| s.check_inputs().unwrap_err().to_string();
        let e = err(series(&|k| step(k) / 100.0, &noisy_idle));
        assert!(e.contains("looks like a fraction") && e.contains("multiply the column by 100"), "{e}");
        let e = err(series(&|k| if k == 700 { 120.0 } else { step(k) }, &noisy_idle));
        assert!(e.contains("120 at row 702") && e.contains("outside 0–100 %"), "{e}");
        let e = err(series(&|_| 10.0, &|_| 1.0));
        assert!(e.contains("below idle"), "{e}");
        let e = err(series(&step, &|k| -noisy_idle(k)));
        assert!(e.contains("sign is reversed"), "{e}");
        let e = err(series(&step, &|k| noisy_idle(k) * 1000.0 / 9.81));
        assert!(e.contains("not in newtons"), "{e}");
        // A throttle profile (no thrust) may stay below idle: it is only an input.
        let profile = Series { thrust_n: Vec::new(), ..series(&|_| 10.0, &|_| 0.0) };
        profile.check_inputs().unwrap();
    }

    #[test]
    fn grid_steps_count_lost_rows_through_jitter() {
        let t = [0.0, 0.0102, 0.0199, 0.0401, 0.05, 0.0899];
        let s = Series { name: "j".into(), u_pct: vec![25.0; 6], thrust_n: vec![0.0; 6], t_s: t.to_vec() };
        assert_eq!(s.grid_steps(), vec![0, 1, 1, 2, 1, 4]);
    }

    #[test]
    fn runs_split_at_gaps() {
        let t: Vec<f64> = [0, 1, 2, 5, 6, 7, 8].iter().map(|&k| k as f64 * 0.01).collect();
        let s = Series { name: "g".into(), u_pct: vec![25.0; 7], thrust_n: vec![0.0; 7], t_s: t };
        assert_eq!(s.runs(), vec![0..3, 3..7]);
    }
}
