//! End-to-end identification: a campaign from `jetbench excite` is played open
//! loop on the live simulated bench for 300 s (the study's data-set size), the
//! recording is identified, and the same data as CSV must identify identically.
//!
//! The live run takes five minutes of wall time: it is the real service set,
//! recorded by the real recorder. Hangs are caught by a watchdog; no test
//! asserts a runtime.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::Value;

mod common;

const CAMPAIGN_S: f64 = 300.0;

fn scratch(name: &str) -> PathBuf {
    common::scratch("identify", name)
}

/// Runs `jetbench ARGS` to completion under the watchdog: exit code, stdout, stderr.
fn run(args: &[&str], limit: Duration) -> (i32, String, String) {
    common::run_jetbench("ident", args, limit)
}

fn identify_json(file: &Path) -> Value {
    let (code, out, err) = run(&["identify", file.to_str().unwrap(), "--json"], Duration::from_secs(120));
    assert_eq!(code, 0, "identify {}: {err}", file.display());
    eprintln!("{err}");
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("identify --json printed no JSON ({e}): {out}"))
}

/// The JSON without wall-time figures (they differ between any two runs) and
/// file names (which differ between the two files by design).
fn without_timings(mut v: Value) -> Value {
    if let Some(methods) = v["methods"].as_object_mut() {
        for m in methods.values_mut() {
            if let Some(o) = m.as_object_mut() {
                o.remove("fit_seconds");
                o.remove("diverged_file");
            }
        }
    }
    v
}

#[test]
fn live_campaign_identifies_to_the_noise_floor_from_mcap_and_csv_alike() {
    let campaign = scratch("campaign.csv");
    let recording = scratch("campaign.mcap");
    let csv = scratch("campaign-export.csv");
    let model = scratch("identified.toml");
    let plots = scratch("plots");
    let _ = std::fs::remove_dir_all(&plots);
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();

    let (code, out, err) =
        run(&["excite", "--duration", "300", "--seed", "11", "--out", &p(&campaign)], Duration::from_secs(60));
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("30000 samples") && out.contains("conditioning"), "{out}");

    // The service set, playing the campaign open loop, every channel recorded.
    let duration = format!("{}", CAMPAIGN_S + 2.0);
    let (code, out, err) = run(
        &["up", "--sim", "--open-loop", &p(&campaign), "--duration", &duration, "--record", &p(&recording), "--quiet"],
        Duration::from_secs(CAMPAIGN_S as u64 + 120),
    );
    assert_eq!(code, 0, "up failed:\n{out}\n{err}");

    let json = identify_json(&recording);
    let floor = json["noise_floor_n"].as_f64().unwrap();
    // The bench's noise: variance 7 N², so MAE √(2·7/π) = 2.11 N.
    assert!((floor - 2.111).abs() < 0.1, "noise floor {floor}");
    assert!(json["validation_samples"].as_u64().unwrap() >= 8900, "{json}");
    for method in ["ls", "ekf"] {
        let m = &json["methods"][method];
        let mae = m["mae_n"].as_f64().unwrap_or_else(|| panic!("{method}: {m}"));
        eprintln!("live campaign, {method}: validation MAE {mae:.3} N, noise floor {floor:.3} N");
        assert!(mae <= 1.10 * floor, "{method}: MAE {mae} N vs noise floor {floor} N");
        for key in ["K_T", "K_TT", "K_D", "K_DD", "K_TD", "c", "B_U", "B_T", "B_D", "B_UU"] {
            assert!(m["params"][key].is_f64(), "{method} lacks {key}: {m}");
        }
    }
    assert!(json["methods"]["sindy"]["params"].is_object(), "{json}");
    assert!(["ls", "ekf", "sindy"].contains(&json["best"].as_str().unwrap()), "{json}");

    // The same data as CSV identifies identically.
    let (code, _, err) = run(&["export", &p(&recording), "--out", &p(&csv)], Duration::from_secs(60));
    assert_eq!(code, 0, "{err}");
    assert_eq!(without_timings(identify_json(&csv)), without_timings(json));

    // The best model is written, plotted, and simulates the recording.
    let (code, _, err) = run(
        &["identify", &p(&csv), "--method", "ls", "--out", &p(&model), "--plot", &p(&plots)],
        Duration::from_secs(120),
    );
    assert_eq!(code, 0, "{err}");
    for name in ["ls-0.png", "ls-0.svg", "validation-all-0.png"] {
        assert!(plots.join(name).metadata().map(|m| m.len() > 1000).unwrap_or(false), "{name} missing");
    }
    let (code, out, err) =
        run(&["simulate", "--model", &p(&model), "--input", &p(&recording)], Duration::from_secs(60));
    assert_eq!(code, 0, "{err}");
    assert!(out.lines().count() > 29_000, "simulate printed {} lines", out.lines().count());
    assert!(err.contains("MAE"), "{err}");
}
