//! `jetbench diagnose` as a user meets it, the binary run for real: a 25 s campaign is too
//! little data and says so (how much there is, how much the question needs, how weak the
//! answer is) instead of claiming a delay; no figure is printed as `NaN`; the report goes to
//! standard output and the logs to standard error; the plots show the throttle beside the
//! thrust under a title that fits.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

mod common;

use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

use common::{jetbench, run, scratch};
use serde_json::Value;

const LIMIT: Duration = Duration::from_secs(300);

/// A 25 s campaign of the simulated P100 with white noise, and a model identified on the same
/// 25 s (what a new user does first): made once for every test here.
fn short_campaign() -> &'static (PathBuf, PathBuf) {
    static FILES: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    FILES.get_or_init(|| {
        let csv = scratch("diagnose_cli", "short.csv");
        let model = scratch("diagnose_cli", "short.toml");
        let (status, _, err) = run(
            jetbench("diagnose_cli").args([
                "sim-record",
                "--model",
                "p100-diesel",
                "--duration",
                "25",
                "--seed",
                "3",
                "--out",
                csv.to_str().unwrap(),
            ]),
            LIMIT,
            "sim-record",
        );
        assert!(status.success(), "sim-record failed: {err}");
        let (status, _, err) = run(
            jetbench("diagnose_cli").args([
                "identify",
                "--method",
                "ls",
                csv.to_str().unwrap(),
                "--out",
                model.to_str().unwrap(),
            ]),
            LIMIT,
            "identify",
        );
        assert!(status.success(), "identify failed: {err}");
        (csv, model)
    })
}

fn diagnose(extra: &[&str], envs: &[(&str, &str)]) -> (String, String) {
    let (csv, model) = short_campaign();
    let mut command = jetbench("diagnose_cli");
    command.args(["diagnose", "--model", model.to_str().unwrap(), csv.to_str().unwrap()]).args(extra);
    for (k, v) in envs {
        command.env(k, v);
    }
    let (status, out, err) = run(&mut command, LIMIT, "diagnose");
    assert!(status.success(), "diagnose failed:\n{err}");
    (out, err)
}

#[test]
fn a_25_s_campaign_is_called_too_little_data_and_claims_nothing() {
    let (out, err) = diagnose(&["--json"], &[]);
    let d: Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("stdout is not JSON ({e}):\n{out}"));
    assert_eq!(d["cause"], "insufficient_data", "{}", d["verdict"]);
    let verdict = d["verdict"].as_str().unwrap();
    // How little there is, how much the question needs, how weak the answer would be.
    for words in ["25 s of recording", "held out", "needs at least", "independent stretches", "300 s"] {
        assert!(verdict.contains(words), "the verdict does not say `{words}`: {verdict}");
    }
    assert!(
        !verdict.contains("input delay left out") && !verdict.contains("Modelled:"),
        "a claim in a verdict on 25 s: {verdict}"
    );
    // The human report is beside the logs, on stderr, when stdout is the JSON.
    assert!(err.contains("cause: insufficient_data"), "no human report on stderr:\n{err}");
}

#[test]
fn no_figure_is_printed_as_nan() {
    // The short campaign leaves hypotheses without a fit and values without a standard error.
    let (out, err) = diagnose(&[], &[]);
    for (name, text) in [("stdout", &out), ("stderr", &err)] {
        assert!(!text.contains("NaN"), "NaN printed on {name}:\n{text}");
        assert!(!text.to_lowercase().contains("± nan") && !text.contains("±NaN"), "± NaN on {name}:\n{text}");
    }
    // A missing figure is said to be missing, and why.
    if out.contains("±n/a") {
        assert!(out.contains("the data give no standard error"), "±n/a without its reason:\n{out}");
    }
    let (json, _) = diagnose(&["--json"], &[]);
    assert!(!json.contains("NaN"), "NaN in the JSON:\n{json}");
}

#[test]
fn the_report_goes_to_stdout_and_the_logs_to_stderr() {
    let (out, err) = diagnose(&[], &[("RUST_LOG", "debug")]);
    assert!(out.contains("\ncause: "), "the report is not on stdout:\n{out}");
    assert!(out.contains("locate (residual of the model as given)"), "the report is not on stdout:\n{out}");
    assert!(!err.contains("\ncause: "), "the report went to stderr:\n{err}");
    assert!(err.contains("diagnose stage done"), "no debug log on stderr:\n{err}");
    assert!(!out.contains("diagnose stage done"), "a log line on stdout:\n{out}");
}

#[test]
fn the_plots_show_the_throttle_beside_the_thrust_under_a_title_that_fits() {
    let dir = scratch("diagnose_cli", "plots");
    let _ = std::fs::remove_dir_all(&dir);
    let (_, err) = diagnose(&["--plot", dir.to_str().unwrap()], &[]);
    assert!(err.contains("plots: "), "{err}");
    let svg = std::fs::read_to_string(dir.join("diagnose-fit-0.svg")).unwrap();
    assert!(svg.contains("throttle (%)"), "no throttle panel in the fit plot");
    assert!(svg.contains("thrust"), "no thrust axis in the fit plot");
    // The whole title is drawn (a title too wide is set smaller or shortened in the middle,
    // never cut at the edges): its start and its end are both there.
    assert!(svg.contains("short.csv: model as given"), "the title's start is missing");
    assert!(svg.contains("floor"), "the title's end is missing");
    let spectrum = std::fs::read_to_string(dir.join("diagnose-spectrum.svg")).unwrap();
    assert!(spectrum.contains("frequency (Hz)"), "the spectrum has no frequency axis");
}
