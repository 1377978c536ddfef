//! Plots of measured and modelled series, written as PNG (for reports and quick looks) and SVG (for zooming and
//! papers).
//!
//! ```
//! use jetbench_plot::{write_fit_plot, FitPlot};
//!
//! let t_s: Vec<f64> = (0..1000).map(|i| i as f64 * 0.01).collect();
//! let measured_n: Vec<f64> = t_s.iter().map(|t| 40.0 * (1.0 - (-t).exp())).collect();
//! let model_n: Vec<f64> = t_s.iter().map(|t| 40.0 * (1.0 - (-1.1 * t).exp())).collect();
//! let dir = std::env::temp_dir().join("jetbench-plot-doc");
//! let files = write_fit_plot(
//!     &dir,
//!     "first_order",
//!     &FitPlot {
//!         title: "first-order lag",
//!         t_s: &t_s,
//!         measured_n: &measured_n,
//!         models: &[("first order", &model_n)],
//!         split_s: Some(7.0),
//!         windows: &[(1.0, 2.0, "spool-up")],
//!         throttle_pct: None,
//!     },
//! )?;
//! assert_eq!(files, [dir.join("first_order.png"), dir.join("first_order.svg")]);
//! # Ok::<(), jetbench_plot::PlotError>(())
//! ```
//!
//! Rendering uses `plotters` with its pure-Rust bitmap and SVG backends. Text in the PNG is rasterised with
//! `ab_glyph` from DejaVu Sans embedded in the binary (the `dejavu` crate), so plots come out with readable
//! labels on a machine with no fonts and no fontconfig installed. The SVG names the generic `sans-serif`
//! family and leaves the glyphs to the viewer.
//!
//! Long recordings are decimated before drawing: per pixel column only the first, minimum, maximum and last
//! sample are kept ([`decimate_min_max`]), which draws the same picture as the full series (spikes survive)
//! at a few thousand points instead of tens of thousands. Non-finite samples are never drawn: they split a
//! line into separate pieces, so a diverged simulation shows as a gap.
#![deny(missing_docs)]
#![doc = include_str!("../README.md")]

use std::io;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::backend::{BitMapBackend, SVGBackend};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use thiserror::Error;

/// Pixel size of a fit plot (width, height), chosen to show a several-minute run legibly on a laptop screen.
pub const FIT_PLOT_SIZE_PX: (u32, u32) = (1400, 800);
/// Pixel size of a line plot (width, height).
pub const LINE_PLOT_SIZE_PX: (u32, u32) = (1200, 700);

/// One figure: the measured thrust against one or more model outputs over time, and the residual(s).
#[derive(Debug, Clone, Copy)]
pub struct FitPlot<'a> {
    /// Figure title, drawn at the top.
    pub title: &'a str,
    /// Sample times (s), ascending; non-finite times are skipped.
    pub t_s: &'a [f64],
    /// Measured thrust (N), same length as `t_s`.
    pub measured_n: &'a [f64],
    /// Named model outputs, same length as t_s; NaN where a simulation diverged (draw gaps, do not panic).
    pub models: &'a [(&'a str, &'a [f64])],
    /// Time at which the validation (held-out) part begins: draw a vertical line and label "calibration" /
    /// "validation". Ignored if non-finite or outside the time axis.
    pub split_s: Option<f64>,
    /// Time windows (start s, end s, label) to shade, e.g. where a residual is systematic; either order of
    /// start and end works, windows with a non-finite bound are skipped.
    pub windows: &'a [(f64, f64, &'a str)],
    /// The throttle (%) the thrust answered, same length as `t_s`: drawn in a third panel under the
    /// residual, on the same time axis, so a reader sees what drove each error.
    pub throttle_pct: Option<&'a [f64]>,
}

/// A generic line chart (e.g. residual autocorrelation with confidence bounds, a spectrum).
#[derive(Debug, Clone, Copy)]
pub struct LinePlot<'a> {
    /// Figure title, drawn at the top.
    pub title: &'a str,
    /// Label of the x axis, with its unit, e.g. `"lag (s)"`.
    pub x_label: &'a str,
    /// Label of the y axis, with its unit.
    pub y_label: &'a str,
    /// Series as (name, x, y); `x` and `y` of one series have the same length. Decimated only where `x` is
    /// ascending (time series, spectra); other series are drawn point by point.
    pub series: &'a [(&'a str, &'a [f64], &'a [f64])],
    /// Horizontal reference lines (value, label), e.g. ±1.96/sqrt(N) confidence bounds.
    pub hlines: &'a [(f64, &'a str)],
    /// Logarithmic y axis; values `<= 0` are then skipped like non-finite ones.
    pub log_y: bool,
    /// Logarithmic x axis (a spectrum over frequency); `x <= 0` is then skipped.
    pub log_x: bool,
}

/// Why a plot could not be written, naming the figure (`<dir>/<stem>`) or file concerned.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum PlotError {
    /// The file stem is empty or would escape `dir`.
    #[error("plot `{}`: file stem {stem:?} must be non-empty and contain no path separator", .dir.display())]
    InvalidStem {
        /// Directory the plot was to be written to.
        dir: PathBuf,
        /// The rejected stem.
        stem: String,
    },
    /// An input slice (or the list of series) has no element, so there is nothing to plot.
    #[error("plot `{}`: `{what}` is empty; give at least one sample", .figure.display())]
    EmptyInput {
        /// `<dir>/<stem>`, without extension.
        figure: PathBuf,
        /// Which input, e.g. `t_s` or `series "acf"`.
        what: String,
    },
    /// Two inputs that pair up sample by sample have different lengths.
    #[error(
        "plot `{}`: `{what}` has {got} samples but `{reference}` has {expected}; they must have the same length",
        .figure.display()
    )]
    LengthMismatch {
        /// `<dir>/<stem>`, without extension.
        figure: PathBuf,
        /// The input whose length is wrong, e.g. `model "first order"`.
        what: String,
        /// Its length.
        got: usize,
        /// The input it must match, e.g. `t_s`.
        reference: String,
        /// The length of `reference`.
        expected: usize,
    },
    /// The output directory could not be created.
    #[error("cannot create plot directory `{}`: {source}", .dir.display())]
    CreateDir {
        /// The directory.
        dir: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: io::Error,
    },
    /// The embedded font was rejected by plotters (should not happen: the font is compiled in).
    #[error("cannot register the embedded DejaVu Sans font with plotters; text cannot be drawn")]
    Font,
    /// plotters failed to draw or to write a file (e.g. disk full, permission denied).
    #[error("cannot draw or write `{}`: {message}", .path.display())]
    Backend {
        /// The file being written.
        path: PathBuf,
        /// plotters' description of the failure.
        message: String,
    },
}

/// Writes `<dir>/<stem>.png` and `<dir>/<stem>.svg` (creating dir), returns both paths.
/// Top panel: measured (grey, thin) and each model (distinct colours, legend); bottom panel: residual
/// measured − model for each model, with a zero line; x axis "time (s)", y axes "thrust (N)" and
/// "residual (N)". Windows are shaded in both panels; the split is a dashed line in both.
///
/// The figure is [`FIT_PLOT_SIZE_PX`]. Axis ranges come from the finite samples with a 5 % margin; the
/// residual range always includes zero. `models` may be empty (then only the measurement is drawn). A model
/// that is NaN everywhere is listed in the legend as `"<name> (no finite output)"`.
///
/// # Errors
/// [`PlotError::EmptyInput`] if `t_s` is empty, [`PlotError::LengthMismatch`] if `measured_n` or a model
/// differs in length from `t_s`, [`PlotError::InvalidStem`], [`PlotError::CreateDir`], [`PlotError::Font`],
/// [`PlotError::Backend`].
pub fn write_fit_plot(dir: &Path, stem: &str, plot: &FitPlot) -> Result<Vec<PathBuf>, PlotError> {
    let figure = check_stem(dir, stem)?;
    if plot.t_s.is_empty() {
        return Err(PlotError::EmptyInput { figure, what: "t_s".into() });
    }
    let n = plot.t_s.len();
    check_len(&figure, "measured_n".into(), plot.measured_n.len(), "t_s", n)?;
    for (name, y) in plot.models {
        check_len(&figure, format!("model {name:?}"), y.len(), "t_s", n)?;
    }
    if let Some(u) = plot.throttle_pct {
        check_len(&figure, "throttle_pct".into(), u.len(), "t_s", n)?;
    }
    let prepared = PreparedFit::new(plot);
    write_figure(dir, stem, FIT_PLOT_SIZE_PX, &prepared)
}

/// Writes a generic line chart as `<dir>/<stem>.png` and `<dir>/<stem>.svg` (creating dir), returns both
/// paths.
///
/// The figure is [`LINE_PLOT_SIZE_PX`]; each series gets its own colour and a legend entry, each horizontal
/// line is dashed and labelled at its right end. Axis ranges come from the finite samples (positive ones if
/// `log_y`) and the reference lines, with a 5 % margin.
///
/// # Errors
/// [`PlotError::EmptyInput`] if `series` or the `x` of a series is empty, [`PlotError::LengthMismatch`] if a
/// series' `x` and `y` differ in length, [`PlotError::InvalidStem`], [`PlotError::CreateDir`],
/// [`PlotError::Font`], [`PlotError::Backend`].
pub fn write_line_plot(dir: &Path, stem: &str, plot: &LinePlot) -> Result<Vec<PathBuf>, PlotError> {
    let figure = check_stem(dir, stem)?;
    if plot.series.is_empty() {
        return Err(PlotError::EmptyInput { figure, what: "series".into() });
    }
    for (name, x, y) in plot.series {
        if x.is_empty() {
            return Err(PlotError::EmptyInput { figure, what: format!("x of series {name:?}") });
        }
        check_len(&figure, format!("y of series {name:?}"), y.len(), &format!("x of series {name:?}"), x.len())?;
    }
    let prepared = PreparedLine::new(plot);
    write_figure(dir, stem, LINE_PLOT_SIZE_PX, &prepared)
}

/// Reduces a line to at most four points per pixel column — the first, minimum, maximum and last sample of
/// the column, in their original order — so it draws the same as the full line (spikes included).
///
/// `x` must be ascending and all points finite (split a series at non-finite samples first); `columns` is
/// the number of pixel columns the x span of these points covers. Input that is already short
/// (`<= 4 * columns` points) or whose `x` is not ascending is returned unchanged. Lengths of `x` and `y` must
/// match; extra elements of the longer one are ignored.
pub fn decimate_min_max(x: &[f64], y: &[f64], columns: usize) -> Vec<(f64, f64)> {
    let n = x.len().min(y.len());
    let all = || x.iter().zip(y).map(|(&a, &b)| (a, b)).collect();
    let columns = columns.max(1);
    if n <= 4 * columns || x[..n].windows(2).any(|w| w[1] < w[0]) {
        return all();
    }
    let (x0, span) = (x[0], x[n - 1] - x[0]);
    let column_of = |xi: f64| {
        if span > 0.0 && span.is_finite() {
            // Saturating float-to-int cast; the last sample lands in column `columns`, clamp it.
            (((xi - x0) / span * columns as f64) as usize).min(columns - 1)
        } else {
            0
        }
    };
    let mut out = Vec::with_capacity(4 * columns);
    let mut flush = |first: usize, lo: usize, hi: usize, last: usize| {
        let mut idx = [first, lo, hi, last];
        idx.sort_unstable();
        let mut prev = usize::MAX;
        for i in idx {
            if i != prev {
                out.push((x[i], y[i]));
                prev = i;
            }
        }
    };
    let (mut col, mut first, mut lo, mut hi) = (column_of(x[0]), 0, 0, 0);
    for i in 1..n {
        let c = column_of(x[i]);
        if c != col {
            flush(first, lo, hi, i - 1);
            (col, first, lo, hi) = (c, i, i, i);
        } else {
            if y[i] < y[lo] {
                lo = i;
            }
            if y[i] > y[hi] {
                hi = i;
            }
        }
    }
    flush(first, lo, hi, n - 1);
    out
}

// ---------------------------------------------------------------------------------------------------------
// Input checks and data preparation (backend independent, done once for both files).

fn check_stem(dir: &Path, stem: &str) -> Result<PathBuf, PlotError> {
    let bad = stem.is_empty() || stem == "." || stem == ".." || stem.contains(['/', '\\']);
    if bad {
        return Err(PlotError::InvalidStem { dir: dir.to_path_buf(), stem: stem.to_string() });
    }
    Ok(dir.join(stem))
}

fn check_len(figure: &Path, what: String, got: usize, reference: &str, expected: usize) -> Result<(), PlotError> {
    if got == expected {
        return Ok(());
    }
    Err(PlotError::LengthMismatch { figure: figure.to_path_buf(), what, got, reference: reference.into(), expected })
}

/// Largest magnitude drawn; larger finite values are drawn at ±this (the panel edge). plotters' tick search
/// never ends on an axis span that overflows to infinity, and its rasterisers loop over (and can overflow
/// `i32` on) pixel coordinates far outside the image; no physical signal comes near this bound, only a
/// diverging simulation.
const VALUE_LIMIT: f64 = 1e300;

fn clamp_value(v: f64) -> f64 {
    v.clamp(-VALUE_LIMIT, VALUE_LIMIT)
}

/// A series ready to draw: finite runs (decimated) and isolated single points, which a line cannot show.
#[derive(Debug, Default)]
struct Trace {
    runs: Vec<Vec<(f64, f64)>>,
    dots: Vec<(f64, f64)>,
}

impl Trace {
    /// Splits `(x, y)` at samples that are non-finite or rejected by `keep` and decimates each run to
    /// `columns` pixel columns over the chart's x span `x_span`.
    fn new(x: &[f64], y: &[f64], keep: impl Fn(f64) -> bool, x_span: f64, columns: usize) -> Self {
        let mut trace = Trace::default();
        let ok = |i: usize| x[i].is_finite() && y[i].is_finite() && keep(y[i]);
        let n = x.len().min(y.len());
        let mut i = 0;
        while i < n {
            if !ok(i) {
                i += 1;
                continue;
            }
            let start = i;
            while i < n && ok(i) {
                i += 1;
            }
            if i - start == 1 {
                trace.dots.push((clamp_value(x[start]), clamp_value(y[start])));
                continue;
            }
            let xs: Vec<f64> = x[start..i].iter().map(|&v| clamp_value(v)).collect();
            let ys: Vec<f64> = y[start..i].iter().map(|&v| clamp_value(v)).collect();
            let run_span = (xs[xs.len() - 1] - xs[0]).abs();
            let frac = if x_span > 0.0 && x_span.is_finite() { (run_span / x_span).min(1.0) } else { 1.0 };
            let cols = ((columns as f64 * frac).ceil() as usize).max(1);
            trace.runs.push(decimate_min_max(&xs, &ys, cols));
        }
        trace
    }

    fn is_empty(&self) -> bool {
        self.runs.is_empty() && self.dots.is_empty()
    }
}

/// Lowest and highest of the values, or `None` if there are none.
fn min_max(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values.into_iter().fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// Linear axis range from finite data with a 5 % margin each side; a fallback when there is no data or it
/// is a single value, so plotters always gets a non-empty, finite range.
fn linear_range(bounds: Option<(f64, f64)>) -> (f64, f64) {
    let Some((lo, hi)) = bounds else { return (0.0, 1.0) };
    let (lo, hi) = (lo.clamp(-VALUE_LIMIT, VALUE_LIMIT), hi.clamp(-VALUE_LIMIT, VALUE_LIMIT));
    if hi <= lo {
        let pad = if lo == 0.0 { 1.0 } else { 0.05 * lo.abs() };
        return (lo - pad, hi + pad);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// Log axis range from positive finite data with a margin of 5 % of the decades spanned each side.
fn log_range(bounds: Option<(f64, f64)>) -> (f64, f64) {
    let Some((lo, hi)) = bounds else { return (0.1, 1.0) };
    // At most 300 decades: plotters' log tick search runs for as many steps as `ln(hi / lo)` and never ends if
    // that ratio overflows.
    let lo = lo.max(hi * 1e-300);
    let (a, b) = if hi <= lo {
        (lo / 2.0, hi * 2.0)
    } else {
        let pad = 10f64.powf(0.05 * (hi / lo).log10());
        (lo / pad, hi * pad)
    };
    // Without the margin where it would underflow to zero or overflow to infinity.
    (if a > 0.0 { a } else { lo }, if b.is_finite() { b } else { hi })
}

/// Union of two optional bounds.
fn union(a: Option<(f64, f64)>, b: Option<(f64, f64)>) -> Option<(f64, f64)> {
    match (a, b) {
        (Some((a0, a1)), Some((b0, b1))) => Some((a0.min(b0), a1.max(b1))),
        (a, None) => a,
        (None, b) => b,
    }
}

fn finite_bounds(values: &[f64]) -> Option<(f64, f64)> {
    min_max(values.iter().copied().filter(|v| v.is_finite()))
}

/// Bounds of the finite `y` whose `x` is finite too (only those are drawn).
fn paired_bounds(x: &[f64], y: &[f64], keep: impl Fn(f64) -> bool) -> Option<(f64, f64)> {
    min_max(x.iter().zip(y).filter(|(a, b)| a.is_finite() && b.is_finite() && keep(**b)).map(|(_, &b)| b))
}

struct PreparedModel {
    label: String,
    output: Trace,
    residual: Trace,
}

struct PreparedFit {
    title: String,
    x_range: (f64, f64),
    y_range: (f64, f64),
    r_range: (f64, f64),
    measured: Trace,
    models: Vec<PreparedModel>,
    split_s: Option<f64>,
    windows: Vec<(f64, f64, String)>,
    /// The throttle trace and its axis range, when given.
    throttle: Option<(Trace, (f64, f64))>,
}

impl PreparedFit {
    fn new(plot: &FitPlot) -> Self {
        let t = plot.t_s;
        let x_range = linear_range(finite_bounds(t));
        let x_span = x_range.1 - x_range.0;
        let columns = FIT_PLOT_SIZE_PX.0 as usize;
        let any = |_: f64| true;
        let mut y_bounds = paired_bounds(t, plot.measured_n, any);
        let mut r_bounds = Some((0.0, 0.0));
        let mut models = Vec::with_capacity(plot.models.len());
        for (name, y) in plot.models {
            let residual: Vec<f64> = plot.measured_n.iter().zip(y.iter()).map(|(m, s)| m - s).collect();
            let output = Trace::new(t, y, any, x_span, columns);
            let label = if output.is_empty() { format!("{name} (no finite output)") } else { name.to_string() };
            y_bounds = union(y_bounds, paired_bounds(t, y, any));
            r_bounds = union(r_bounds, paired_bounds(t, &residual, any));
            models.push(PreparedModel { label, output, residual: Trace::new(t, &residual, any, x_span, columns) });
        }
        let windows = plot
            .windows
            .iter()
            .filter(|(a, b, _)| a.is_finite() && b.is_finite())
            .map(|&(a, b, label)| (a.min(b), a.max(b), label.to_string()))
            .collect();
        PreparedFit {
            title: plot.title.to_string(),
            x_range,
            y_range: linear_range(y_bounds),
            r_range: linear_range(r_bounds),
            measured: Trace::new(t, plot.measured_n, any, x_span, columns),
            models,
            split_s: plot.split_s.filter(|s| s.is_finite()),
            windows,
            throttle: plot.throttle_pct.map(|u| {
                // The ECU's range, 25 (idle) to 100 %, widened to what the data holds.
                let range = linear_range(union(Some((25.0, 100.0)), paired_bounds(t, u, any)));
                (Trace::new(t, u, any, x_span, columns), range)
            }),
        }
    }
}

struct PreparedLine {
    title: String,
    x_label: String,
    y_label: String,
    x_range: (f64, f64),
    y_range: (f64, f64),
    series: Vec<(String, Trace)>,
    hlines: Vec<(f64, String)>,
    log_y: bool,
    log_x: bool,
}

impl PreparedLine {
    fn new(plot: &LinePlot) -> Self {
        let (log_x, log_y) = (plot.log_x, plot.log_y);
        let keep = move |v: f64| !log_y || v > 0.0;
        let keep_x = move |v: f64| v.is_finite() && (!log_x || v > 0.0);
        let x_bounds = plot
            .series
            .iter()
            .map(|(_, x, y)| {
                min_max(x.iter().zip(y.iter()).filter(|(a, b)| keep_x(**a) && b.is_finite()).map(|(&a, _)| a))
            })
            .fold(None, union);
        let x_range = if log_x { log_range(x_bounds) } else { linear_range(x_bounds) };
        let x_span = x_range.1 - x_range.0;
        let columns = LINE_PLOT_SIZE_PX.0 as usize;
        let hlines: Vec<(f64, String)> = plot
            .hlines
            .iter()
            .filter(|(v, _)| v.is_finite() && keep(*v))
            .map(|&(v, label)| (clamp_value(v), label.to_string()))
            .collect();
        let y_bounds = plot
            .series
            .iter()
            .map(|(_, x, y)| paired_bounds(x, y, keep))
            .fold(min_max(hlines.iter().map(|(v, _)| *v)), union);
        let series = plot
            .series
            .iter()
            .map(|(name, x, y)| {
                // On a log axis the points at x <= 0 are not drawn: give them a y that is skipped.
                let y: Vec<f64> = x.iter().zip(y.iter()).map(|(&a, &b)| if keep_x(a) { b } else { f64::NAN }).collect();
                (name.to_string(), Trace::new(x, &y, keep, x_span, columns))
            })
            .collect();
        PreparedLine {
            title: plot.title.to_string(),
            x_label: plot.x_label.to_string(),
            y_label: plot.y_label.to_string(),
            x_range,
            y_range: if log_y { log_range(y_bounds) } else { linear_range(y_bounds) },
            series,
            hlines,
            log_y,
            log_x,
        }
    }
}

// ---------------------------------------------------------------------------------------------------------
// Drawing (generic over the plotters backend, so PNG and SVG come from the same code).

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// A figure that can be drawn on any plotters backend.
trait Figure {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB>;
}

const FONT: &str = "sans-serif";
const TITLE_PX: u32 = 28;
/// Smallest title type before a title too long for the figure is shortened.
const TITLE_MIN_PX: u32 = 18;
const DESC_PX: u32 = 19;
const TICK_PX: u32 = 15;
const LEGEND_PX: u32 = 16;
const NOTE_PX: u32 = 15;

const MEASURED: RGBColor = RGBColor(125, 125, 125);
const THROTTLE: RGBColor = RGBColor(60, 60, 60);
const SPLIT: RGBColor = RGBColor(40, 40, 40);
const WINDOW_FILL: RGBAColor = RGBAColor(255, 165, 0, 0.18);
const WINDOW_TEXT: RGBColor = RGBColor(170, 90, 0);
const GRID_BOLD: RGBAColor = RGBAColor(0, 0, 0, 0.12);
const GRID_LIGHT: RGBAColor = RGBAColor(0, 0, 0, 0.04);

/// Distinct colours for models and series (Tableau 10 without grey, which is the measurement's).
const PALETTE: [RGBColor; 9] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn palette(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// Registers DejaVu Sans as plotters' `sans-serif` family once per process; plotters' `ab_glyph` text
/// backend has no system font lookup, so without this every text draw fails.
fn ensure_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok());
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

fn write_figure(dir: &Path, stem: &str, size_px: (u32, u32), figure: &impl Figure) -> Result<Vec<PathBuf>, PlotError> {
    ensure_font()?;
    std::fs::create_dir_all(dir).map_err(|source| PlotError::CreateDir { dir: dir.to_path_buf(), source })?;
    let png = dir.join(format!("{stem}.png"));
    let svg = dir.join(format!("{stem}.svg"));
    let backend_err = |path: &Path| {
        let path = path.to_path_buf();
        move |e: String| PlotError::Backend { path, message: e }
    };
    {
        let root = BitMapBackend::new(&png, size_px).into_drawing_area();
        figure.draw(&root).and_then(|()| root.present()).map_err(|e| e.to_string()).map_err(backend_err(&png))?;
    }
    {
        let root = SVGBackend::new(&svg, size_px).into_drawing_area();
        figure.draw(&root).and_then(|()| root.present()).map_err(|e| e.to_string()).map_err(backend_err(&svg))?;
    }
    Ok(vec![png, svg])
}

/// Tick label: plain decimals for ordinary magnitudes, scientific notation for very large or small ones.
/// `span` is the axis span: plotters' tick at zero can come out as `-1.1e-16`, which is shown as `0`.
fn tick_label(v: f64, span: f64) -> String {
    let a = v.abs();
    if a <= span.abs() * 1e-9 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.1e}")
    } else {
        // Round to a few significant digits, then let Display drop trailing zeros.
        let digits = (3 - a.log10().floor() as i32).clamp(0, 6);
        let scale = 10f64.powi(digits);
        format!("{}", (v * scale).round() / scale)
    }
}

fn text(size_px: u32) -> TextStyle<'static> {
    (FONT, size_px).into_font().into()
}

/// Draws a trace (lines for runs, small dots for isolated samples); with a label, adds a legend entry even
/// if the trace is empty, so a diverged model is still listed.
fn draw_trace<DB: DrawingBackend, X: Ranged<ValueType = f64>, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<X, Y>>,
    trace: &Trace,
    style: ShapeStyle,
    label: Option<&str>,
) -> DrawResult<DB> {
    if let Some(label) = label {
        let legend_style = ShapeStyle { stroke_width: style.stroke_width.max(2), ..style };
        chart
            .draw_series(LineSeries::new(std::iter::empty::<(f64, f64)>(), style))?
            .label(label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 24, y)], legend_style));
    }
    for run in &trace.runs {
        chart.draw_series(LineSeries::new(run.iter().copied(), style))?;
    }
    let dot_px = style.stroke_width.max(1) + 1;
    chart.draw_series(trace.dots.iter().map(|&p| Circle::new(p, dot_px, style.filled())))?;
    Ok(())
}

fn configure_legend<'a, DB: DrawingBackend + 'a, X: Ranged<ValueType = f64>, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
) -> DrawResult<DB> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.5))
        .label_font(text(LEGEND_PX))
        .draw()
}

impl PreparedFit {
    /// Shaded windows (both panels) and the calibration/validation split line; labels only in the top panel.
    fn draw_annotations<DB: DrawingBackend>(
        &self,
        chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
        y_range: (f64, f64),
        labels: bool,
    ) -> DrawResult<DB> {
        let (x0, x1) = self.x_range;
        let (y0, y1) = y_range;
        let visible = self.windows.iter().filter(|(a, b, _)| *b >= x0 && *a <= x1);
        for (a, b, label) in visible {
            let (a, b) = (a.max(x0), b.min(x1));
            chart.draw_series(std::iter::once(Rectangle::new([(a, y0), (b, y1)], WINDOW_FILL.filled())))?;
            if labels && !label.is_empty() {
                let style = text(NOTE_PX).color(&WINDOW_TEXT).pos(Pos::new(HPos::Left, VPos::Top));
                let note = EmptyElement::at((a, y1)) + Text::new(label.clone(), (4, 6), style);
                chart.draw_series(std::iter::once(note))?;
            }
        }
        if let Some(s) = self.split_s.filter(|s| (x0..=x1).contains(s)) {
            let line = DashedPathElement::new([(s, y0), (s, y1)], 8, 5, SPLIT.stroke_width(2));
            chart.draw_series(std::iter::once(line))?;
            if labels {
                let left = text(NOTE_PX).color(&SPLIT).pos(Pos::new(HPos::Right, VPos::Bottom));
                let right = text(NOTE_PX).color(&SPLIT).pos(Pos::new(HPos::Left, VPos::Bottom));
                let notes = EmptyElement::at((s, y0))
                    + Text::new("calibration", (-6, -6), left)
                    + Text::new("validation", (6, -6), right);
                chart.draw_series(std::iter::once(notes))?;
            }
        }
        Ok(())
    }
}

impl Figure for PreparedFit {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let (title, title_px) = fit_title(root, &self.title);
        let body = root.titled(&title, text(title_px))?;
        let height = body.dim_in_pixel().1;
        let (top, rest) = body.split_vertically(height * if self.throttle.is_some() { 50 } else { 62 } / 100);
        let (bottom, throttle_area) = match self.throttle {
            Some(_) => {
                let (b, t) = rest.split_vertically(height * 26 / 100);
                (b, Some(t))
            }
            None => (rest, None),
        };
        let (x0, x1) = self.x_range;
        let (y0, y1) = self.y_range;
        let (r0, r1) = self.r_range;
        let x_fmt = |v: &f64| tick_label(*v, x1 - x0);
        let y_fmt = |v: &f64| tick_label(*v, y1 - y0);
        let r_fmt = |v: &f64| tick_label(*v, r1 - r0);

        // Top panel: measurement and model outputs.
        let mut chart = ChartBuilder::on(&top)
            .margin_left(10)
            .margin_right(20)
            .margin_top(5)
            .x_label_area_size(30)
            .y_label_area_size(85)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .bold_line_style(GRID_BOLD)
            .light_line_style(GRID_LIGHT)
            .x_labels(12)
            .y_labels(8)
            .x_label_formatter(&x_fmt)
            .y_label_formatter(&y_fmt)
            .y_desc("thrust (N)")
            .axis_desc_style(text(DESC_PX))
            .label_style(text(TICK_PX))
            .draw()?;
        self.draw_annotations(&mut chart, self.y_range, true)?;
        draw_trace(&mut chart, &self.measured, MEASURED.stroke_width(1), Some("measured"))?;
        for (i, model) in self.models.iter().enumerate() {
            draw_trace(&mut chart, &model.output, palette(i).stroke_width(2), Some(&model.label))?;
        }
        configure_legend(&mut chart)?;

        // Bottom panel: residuals around a zero line, same time axis.
        let mut chart = ChartBuilder::on(&bottom)
            .margin_left(10)
            .margin_right(20)
            .margin_top(10)
            .margin_bottom(5)
            .x_label_area_size(if throttle_area.is_some() { 30 } else { 50 })
            .y_label_area_size(85)
            .build_cartesian_2d(x0..x1, r0..r1)?;
        chart
            .configure_mesh()
            .bold_line_style(GRID_BOLD)
            .light_line_style(GRID_LIGHT)
            .x_labels(12)
            .y_labels(5)
            .x_label_formatter(&x_fmt)
            .y_label_formatter(&r_fmt)
            .x_desc(if throttle_area.is_some() { "" } else { "time (s)" })
            .y_desc("residual (N)")
            .axis_desc_style(text(DESC_PX))
            .label_style(text(TICK_PX))
            .draw()?;
        self.draw_annotations(&mut chart, self.r_range, false)?;
        chart.draw_series(std::iter::once(PathElement::new([(x0, 0.0), (x1, 0.0)], BLACK.stroke_width(1))))?;
        for (i, model) in self.models.iter().enumerate() {
            let label = format!("measured − {}", model.label);
            draw_trace(&mut chart, &model.residual, palette(i).stroke_width(1), Some(&label))?;
        }
        if !self.models.is_empty() {
            configure_legend(&mut chart)?;
        }

        // Third panel: the throttle that drove the thrust, same time axis.
        if let (Some(area), Some((trace, (u0, u1)))) = (throttle_area, &self.throttle) {
            let u_fmt = |v: &f64| tick_label(*v, u1 - u0);
            let mut chart = ChartBuilder::on(&area)
                .margin_left(10)
                .margin_right(20)
                .margin_top(10)
                .margin_bottom(5)
                .x_label_area_size(50)
                .y_label_area_size(85)
                .build_cartesian_2d(x0..x1, *u0..*u1)?;
            chart
                .configure_mesh()
                .bold_line_style(GRID_BOLD)
                .light_line_style(GRID_LIGHT)
                .x_labels(12)
                .y_labels(4)
                .x_label_formatter(&x_fmt)
                .y_label_formatter(&u_fmt)
                .x_desc("time (s)")
                .y_desc("throttle (%)")
                .axis_desc_style(text(DESC_PX))
                .label_style(text(TICK_PX))
                .draw()?;
            self.draw_annotations(&mut chart, (*u0, *u1), false)?;
            draw_trace(&mut chart, trace, THROTTLE.stroke_width(1), None)?;
        }
        Ok(())
    }
}

/// The title and a font size at which it fits the figure's width: smaller type first, down to a
/// legible minimum, then the middle of the title left out (`…`), never cut at the edges.
fn fit_title<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, title: &str) -> (String, u32) {
    let available = root.dim_in_pixel().0.saturating_sub(40);
    let width = |t: &str, px: u32| root.estimate_text_size(t, &text(px)).map_or(0, |(w, _)| w);
    let mut px = TITLE_PX;
    while px > TITLE_MIN_PX && width(title, px) > available {
        px -= 1;
    }
    if width(title, px) <= available {
        return (title.to_string(), px);
    }
    let chars: Vec<char> = title.chars().collect();
    let mut keep = chars.len();
    while keep > 8 {
        keep -= 1;
        let head: String = chars[..keep / 2].iter().collect();
        let tail: String = chars[chars.len() - (keep - keep / 2)..].iter().collect();
        let shortened = format!("{head}…{tail}");
        if width(&shortened, px) <= available {
            return (shortened, px);
        }
    }
    (title.to_string(), px)
}

impl PreparedLine {
    fn draw_chart<DB: DrawingBackend, X, Y>(
        &self,
        root: &DrawingArea<DB, Shift>,
        x_spec: X,
        y_spec: Y,
    ) -> DrawResult<DB>
    where
        X: AsRangedCoord<Value = f64>,
        X::CoordDescType: ValueFormatter<f64>,
        Y: AsRangedCoord<Value = f64>,
        Y::CoordDescType: ValueFormatter<f64>,
    {
        root.fill(&WHITE)?;
        let (x0, x1) = self.x_range;
        let (title, title_px) = fit_title(root, &self.title);
        let mut chart = ChartBuilder::on(root)
            .caption(&title, text(title_px))
            .margin(15)
            .x_label_area_size(50)
            .y_label_area_size(85)
            .build_cartesian_2d(x_spec, y_spec)?;
        let (y0, y1) = self.y_range;
        let x_fmt = |v: &f64| tick_label(*v, if self.log_x { 0.0 } else { x1 - x0 });
        let y_fmt = |v: &f64| tick_label(*v, if self.log_y { 0.0 } else { y1 - y0 });
        chart
            .configure_mesh()
            .bold_line_style(GRID_BOLD)
            .light_line_style(GRID_LIGHT)
            .x_label_formatter(&x_fmt)
            .y_label_formatter(&y_fmt)
            .x_desc(self.x_label.as_str())
            .y_desc(self.y_label.as_str())
            .axis_desc_style(text(DESC_PX))
            .label_style(text(TICK_PX))
            .draw()?;
        for (v, label) in &self.hlines {
            let line = DashedPathElement::new([(x0, *v), (x1, *v)], 8, 5, SPLIT.mix(0.7).stroke_width(1));
            chart.draw_series(std::iter::once(line))?;
            if !label.is_empty() {
                let style = text(NOTE_PX).color(&SPLIT).pos(Pos::new(HPos::Right, VPos::Bottom));
                let note = EmptyElement::at((x1, *v)) + Text::new(label.clone(), (-6, -4), style);
                chart.draw_series(std::iter::once(note))?;
            }
        }
        for (i, (name, trace)) in self.series.iter().enumerate() {
            draw_trace(&mut chart, trace, palette(i).stroke_width(2), Some(name))?;
        }
        configure_legend(&mut chart)
    }
}

impl Figure for PreparedLine {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        let ((x0, x1), (y0, y1)) = (self.x_range, self.y_range);
        match (self.log_x, self.log_y) {
            (false, false) => self.draw_chart(root, x0..x1, y0..y1),
            (false, true) => self.draw_chart(root, x0..x1, (y0..y1).log_scale()),
            (true, false) => self.draw_chart(root, (x0..x1).log_scale(), y0..y1),
            (true, true) => self.draw_chart(root, (x0..x1).log_scale(), (y0..y1).log_scale()),
        }
    }
}
