//! Plot files: both formats written with the requested size and text; bad input is an error, odd data
//! (NaN, infinities, single points, huge series) is drawn without panicking.
//!
//! The files land in `$TMPDIR/jetbench-plot-tests/<test>/` and are kept for a look after the run.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

use jetbench_plot::{
    decimate_min_max, write_fit_plot, write_line_plot, FitPlot, LinePlot, PlotError, FIT_PLOT_SIZE_PX,
    LINE_PLOT_SIZE_PX,
};

const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];

/// A fresh output directory per test, so tests can run in parallel.
fn out_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join("jetbench-plot-tests").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Runs `f` on its own thread and fails if it has not returned after a generous time, so that a hang (e.g.
/// plotters' tick search on a degenerate axis range) fails the test instead of stalling the suite.
fn watchdog(f: impl FnOnce() + Send + 'static) {
    let (done_tx, done_rx) = mpsc::channel();
    let worker = std::thread::spawn(move || {
        f();
        let _ = done_tx.send(());
    });
    match done_rx.recv_timeout(Duration::from_secs(120)) {
        Ok(()) => worker.join().unwrap(),
        Err(RecvTimeoutError::Disconnected) => std::panic::resume_unwind(worker.join().unwrap_err()),
        Err(RecvTimeoutError::Timeout) => panic!("plotting did not finish within 120 s"),
    }
}

/// Width and height from the PNG's IHDR chunk, which must come first after the signature.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap();
    assert!(bytes.len() > 24, "{} is too short for a PNG", path.display());
    assert_eq!(bytes[..8], PNG_SIGNATURE, "{} lacks the PNG signature", path.display());
    assert_eq!(&bytes[12..16], b"IHDR");
    let be = |at: usize| u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap());
    (be(16), be(20))
}

fn read_svg(path: &Path) -> String {
    let svg = std::fs::read_to_string(path).unwrap();
    assert!(svg.contains("<svg"), "{} is not an SVG", path.display());
    svg
}

/// First-order spool-up to a step, 10 ms samples, as a measurement with a ripple and two model outputs.
fn step_response(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let t_s: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
    let lag = |tau_s: f64| t_s.iter().map(|t| 60.0 * (1.0 - (-t / tau_s).exp())).collect::<Vec<f64>>();
    let measured_n: Vec<f64> = lag(0.8).iter().enumerate().map(|(i, y)| y + 0.8 * (i as f64 * 0.7).sin()).collect();
    let (fast, slow) = (lag(0.75), lag(1.0));
    (t_s, measured_n, fast, slow)
}

#[test]
fn fit_plot_writes_png_and_svg_with_size_title_and_legend() {
    let dir = out_dir("fit_basic");
    let (t_s, measured_n, fast, slow) = step_response(1000);
    let plot = FitPlot {
        title: "spool-up fit",
        t_s: &t_s,
        measured_n: &measured_n,
        models: &[("first order", &fast), ("slow lag", &slow)],
        split_s: Some(7.0),
        windows: &[(1.0, 2.5, "lag error")],
        throttle_pct: None,
    };
    let files = write_fit_plot(&dir, "fit", &plot).unwrap();
    assert_eq!(files, [dir.join("fit.png"), dir.join("fit.svg")]);
    for f in &files {
        assert!(std::fs::metadata(f).unwrap().len() > 1000, "{} is (nearly) empty", f.display());
    }
    assert_eq!(png_size(&files[0]), FIT_PLOT_SIZE_PX);
    assert_eq!(FIT_PLOT_SIZE_PX, (1400, 800));
    let svg = read_svg(&files[1]);
    for text in ["spool-up fit", "measured", "first order", "slow lag", "time (s)", "thrust (N)", "residual (N)"] {
        assert!(svg.contains(text), "SVG lacks {text:?}");
    }
    for text in ["calibration", "validation", "lag error"] {
        assert!(svg.contains(text), "SVG lacks annotation {text:?}");
    }
    assert!(svg.contains(r#"width="1400""#) && svg.contains(r#"height="800""#));
}

#[test]
fn fit_plot_draws_nan_gaps_and_all_nan_model_without_panicking() {
    watchdog(|| {
        let dir = out_dir("fit_nan");
        let (mut t_s, mut measured_n, mut gappy, _) = step_response(2000);
        let diverged = vec![f64::NAN; t_s.len()];
        for y in &mut gappy[500..800] {
            *y = f64::NAN;
        }
        gappy[1200] = f64::INFINITY;
        gappy[1300] = f64::NEG_INFINITY;
        measured_n[10] = f64::NAN;
        t_s[20] = f64::NAN;
        let plot = FitPlot {
            title: "diverging models",
            t_s: &t_s,
            measured_n: &measured_n,
            models: &[("gappy", &gappy), ("diverged", &diverged)],
            split_s: Some(f64::NAN),
            windows: &[(f64::NAN, 3.0, "ignored"), (15.0, 12.0, "reversed")],
            throttle_pct: None,
        };
        let files = write_fit_plot(&dir, "nan", &plot).unwrap();
        assert_eq!(png_size(&files[0]), FIT_PLOT_SIZE_PX);
        let svg = read_svg(&files[1]);
        assert!(svg.contains("diverged (no finite output)"));
        assert!(svg.contains("gappy"));
    });
}

#[test]
fn fit_plot_survives_degenerate_data() {
    watchdog(|| {
        let dir = out_dir("fit_degenerate");
        // One sample, no models.
        write_fit_plot(
            &dir,
            "single",
            &FitPlot {
                title: "one",
                t_s: &[0.0],
                measured_n: &[1.0],
                models: &[],
                split_s: None,
                windows: &[],
                throttle_pct: None,
            },
        )
        .unwrap();
        // Everything NaN.
        let nan = [f64::NAN; 3];
        write_fit_plot(
            &dir,
            "all_nan",
            &FitPlot {
                title: "nothing",
                t_s: &nan,
                measured_n: &nan,
                models: &[("m", &nan)],
                split_s: None,
                windows: &[],
                throttle_pct: None,
            },
        )
        .unwrap();
        // Constant data and extreme finite values.
        let t_s = [0.0, 1.0, 2.0, 3.0];
        let huge = [f64::MAX, -f64::MAX, 1e300, -1e300];
        write_fit_plot(
            &dir,
            "extreme",
            &FitPlot {
                title: "extreme",
                t_s: &t_s,
                measured_n: &[5.0; 4],
                models: &[("huge", &huge)],
                split_s: Some(1.5),
                windows: &[(0.5, 1.0, "w")],
                throttle_pct: None,
            },
        )
        .unwrap();
        for stem in ["single", "all_nan", "extreme"] {
            assert_eq!(png_size(&dir.join(format!("{stem}.png"))), FIT_PLOT_SIZE_PX);
        }
    });
}

#[test]
fn fit_plot_rejects_empty_and_mismatched_input() {
    let dir = out_dir("fit_errors");
    let empty =
        FitPlot { title: "e", t_s: &[], measured_n: &[], models: &[], split_s: None, windows: &[], throttle_pct: None };
    let err = write_fit_plot(&dir, "empty", &empty).unwrap_err();
    assert!(matches!(&err, PlotError::EmptyInput { what, .. } if what == "t_s"), "{err}");
    assert!(err.to_string().contains("empty"), "{err}");

    let t_s = [0.0, 1.0, 2.0];
    let short = FitPlot {
        title: "m",
        t_s: &t_s,
        measured_n: &[1.0, 2.0],
        models: &[],
        split_s: None,
        windows: &[],
        throttle_pct: None,
    };
    let err = write_fit_plot(&dir, "short", &short).unwrap_err();
    assert!(matches!(err, PlotError::LengthMismatch { got: 2, expected: 3, .. }), "{err}");

    let model = [1.0; 4];
    let long_model = FitPlot {
        title: "m",
        t_s: &t_s,
        measured_n: &[1.0; 3],
        models: &[("m4", &model)],
        split_s: None,
        windows: &[],
        throttle_pct: None,
    };
    let err = write_fit_plot(&dir, "long_model", &long_model).unwrap_err();
    assert!(matches!(&err, PlotError::LengthMismatch { what, got: 4, .. } if what.contains("m4")), "{err}");
    assert!(err.to_string().contains("long_model"), "error names the figure: {err}");

    let err = write_fit_plot(&dir, "../escape", &short).unwrap_err();
    assert!(matches!(err, PlotError::InvalidStem { .. }), "{err}");
    assert!(!dir.exists(), "nothing is written for rejected input");
}

#[test]
fn unwritable_directory_is_reported_with_its_path() {
    let dir = out_dir("fit_not_a_dir");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("plain_file");
    std::fs::write(&file, b"x").unwrap();
    let (t_s, measured_n, fast, _) = step_response(10);
    let plot = FitPlot {
        title: "t",
        t_s: &t_s,
        measured_n: &measured_n,
        models: &[("m", &fast)],
        split_s: None,
        windows: &[],
        throttle_pct: None,
    };
    let err = write_fit_plot(&file.join("sub"), "fit", &plot).unwrap_err();
    assert!(matches!(err, PlotError::CreateDir { .. }), "{err}");
    assert!(err.to_string().contains("plain_file"), "{err}");
}

/// Not a runtime assertion (see style.md): renders the size the brief calls for and prints how long it
/// took, for `cargo test --release -p jetbench-ident --test plot -- --nocapture`.
#[test]
fn fit_plot_of_30000_samples_and_3_models_renders() {
    let dir = out_dir("fit_30k");
    let (t_s, measured_n, fast, slow) = step_response(30_000);
    let mut spiky = fast.clone();
    spiky[12_345] += 80.0;
    let plot = FitPlot {
        title: "30 000 samples, 3 models",
        t_s: &t_s,
        measured_n: &measured_n,
        models: &[("first order", &fast), ("slow lag", &slow), ("spiky", &spiky)],
        split_s: Some(210.0),
        windows: &[(40.0, 60.0, "systematic residual")],
        throttle_pct: None,
    };
    let start = Instant::now();
    let files = write_fit_plot(&dir, "fit_30k", &plot).unwrap();
    let elapsed = start.elapsed();
    eprintln!("30 000-sample fit plot with 3 models: {elapsed:.2?} for {files:?}");
    assert_eq!(png_size(&files[0]), FIT_PLOT_SIZE_PX);
    // Decimation keeps the SVG small (raw: 7 lines x 30 000 points).
    let svg_bytes = std::fs::metadata(&files[1]).unwrap().len();
    assert!(svg_bytes < 3_000_000, "SVG has {svg_bytes} bytes");
}

#[test]
fn decimation_bounds_points_and_keeps_spikes() {
    let n = 30_000;
    let x: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
    let mut y: Vec<f64> = x.iter().map(|t| (t * 3.0).sin()).collect();
    y[7_777] = 50.0;
    y[20_001] = -50.0;
    let columns = 1000;
    let points = decimate_min_max(&x, &y, columns);
    assert!(points.len() <= 4 * columns, "{} points", points.len());
    assert!(points.contains(&(x[7_777], 50.0)));
    assert!(points.contains(&(x[20_001], -50.0)));
    assert_eq!(points.first(), Some(&(x[0], y[0])));
    assert_eq!(points.last(), Some(&(x[n - 1], y[n - 1])));
    assert!(points.windows(2).all(|w| w[0].0 <= w[1].0), "order is kept");
    // Short or non-monotone input passes through.
    assert_eq!(decimate_min_max(&x[..10], &y[..10], columns).len(), 10);
    let shuffled = [3.0, 1.0, 2.0];
    assert_eq!(decimate_min_max(&shuffled, &shuffled, 0).len(), 3);
}

#[test]
fn line_plot_writes_both_files_with_bounds_and_log_axis() {
    watchdog(|| {
        let dir = out_dir("line");
        let n = 500;
        let lags_s: Vec<f64> = (0..n).map(|k| k as f64 * 0.01).collect();
        let acf: Vec<f64> = lags_s.iter().map(|l| (-l * 4.0).exp() * (l * 20.0).cos()).collect();
        let bound = 1.96 / (n as f64).sqrt();
        let plot = LinePlot {
            title: "residual autocorrelation",
            x_label: "lag (s)",
            y_label: "autocorrelation (-)",
            series: &[("acf", &lags_s, &acf)],
            hlines: &[(bound, "+1.96/√N"), (-bound, "−1.96/√N")],
            log_y: false,
            log_x: false,
        };
        let files = write_line_plot(&dir, "acf", &plot).unwrap();
        assert_eq!(png_size(&files[0]), LINE_PLOT_SIZE_PX);
        let svg = read_svg(&files[1]);
        for text in ["residual autocorrelation", "acf", "lag (s)", "autocorrelation (-)", "1.96"] {
            assert!(svg.contains(text), "SVG lacks {text:?}");
        }

        // A spectrum on a log axis, with zeros and a NaN that must be skipped.
        let freq_hz: Vec<f64> = (0..n).map(|k| k as f64 * 0.1).collect();
        let mut psd: Vec<f64> = freq_hz.iter().map(|f| 1.0 / (1.0 + f * f)).collect();
        psd[3] = 0.0;
        psd[4] = f64::NAN;
        psd[5] = -1.0;
        let spectrum = LinePlot {
            title: "thrust residual spectrum",
            x_label: "frequency (Hz)",
            y_label: "PSD (N²/Hz)",
            series: &[("residual", &freq_hz, &psd), ("single", &[1.0], &[0.5])],
            hlines: &[(1e-3, "noise floor"), (-1.0, "not drawn on a log axis")],
            log_y: true,
            log_x: false,
        };
        let files = write_line_plot(&dir, "psd", &spectrum).unwrap();
        assert_eq!(png_size(&files[0]), LINE_PLOT_SIZE_PX);
        let svg = read_svg(&files[1]);
        assert!(svg.contains("noise floor") && svg.contains("single"));
    });
}

#[test]
fn line_plot_rejects_empty_and_mismatched_series() {
    let dir = out_dir("line_errors");
    let base =
        LinePlot { title: "t", x_label: "x", y_label: "y", series: &[], hlines: &[], log_y: false, log_x: false };
    let err = write_line_plot(&dir, "none", &base).unwrap_err();
    assert!(matches!(&err, PlotError::EmptyInput { what, .. } if what == "series"), "{err}");

    let err = write_line_plot(&dir, "empty", &LinePlot { series: &[("e", &[], &[])], ..base }).unwrap_err();
    assert!(matches!(err, PlotError::EmptyInput { .. }), "{err}");

    let err =
        write_line_plot(&dir, "mismatch", &LinePlot { series: &[("m", &[0.0, 1.0], &[1.0])], ..base }).unwrap_err();
    assert!(matches!(err, PlotError::LengthMismatch { got: 1, expected: 2, .. }), "{err}");
    assert!(!dir.exists(), "nothing is written for rejected input");
}

/// The throttle is drawn in its own panel under the thrust and residual; a title too long for the figure
/// is set smaller or shortened in the middle, never cut at the edges; a spectrum gets a log frequency axis
/// on which the 0 Hz bin is left out.
#[test]
fn throttle_panel_long_titles_and_a_log_frequency_axis() {
    watchdog(|| {
        let dir = out_dir("throttle_panel");
        let t_s: Vec<f64> = (0..3000).map(|k| k as f64 * 0.01).collect();
        let u: Vec<f64> = t_s.iter().map(|t| if (t / 5.0).floor() as i64 % 2 == 0 { 30.0 } else { 80.0 }).collect();
        let y: Vec<f64> = u.iter().map(|u| u - 25.0).collect();
        let title = "diagnose: a very long title that names the recording, the model, the cause and the figures \
                     before and after, longer than any figure is wide, so that it must be shortened to fit at all";
        let plot = FitPlot {
            title,
            t_s: &t_s,
            measured_n: &y,
            models: &[("model", &y)],
            split_s: Some(20.0),
            windows: &[],
            throttle_pct: Some(&u),
        };
        let files = write_fit_plot(&dir, "fit", &plot).unwrap();
        assert_eq!(png_size(&files[0]), FIT_PLOT_SIZE_PX);
        let svg = read_svg(&files[1]);
        assert!(svg.contains("throttle (%)") && svg.contains("thrust (N)"), "no throttle panel");
        assert!(svg.contains('…') && svg.contains("diagnose: a very") && svg.contains("to fit at all"), "title");
        let bad = FitPlot { throttle_pct: Some(&u[..10]), ..plot };
        assert!(matches!(write_fit_plot(&dir, "bad", &bad), Err(PlotError::LengthMismatch { .. })));

        let freq_hz: Vec<f64> = (0..500).map(|k| k as f64 * 0.01).collect();
        let ratio: Vec<f64> = freq_hz.iter().map(|f| 1.0 + 10.0 / (1.0 + (f - 0.3).powi(2) * 400.0)).collect();
        let spectrum = LinePlot {
            title: "residual spectrum over the noise model's",
            x_label: "frequency (Hz)",
            y_label: "ratio",
            series: &[("residual", &freq_hz, &ratio)],
            hlines: &[(1.0, "noise")],
            log_y: true,
            log_x: true,
        };
        let files = write_line_plot(&dir, "spectrum", &spectrum).unwrap();
        let svg = read_svg(&files[1]);
        assert!(svg.contains("frequency (Hz)"));
    });
}
