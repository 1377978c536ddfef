//! The experiment that separates rivals, end to end on the simulated bench: a concealed
//! input delay on a short campaign leaves an actuator lag as a rival the diagnosis cannot
//! rule out (`ambiguous`); `jetbench excite --discriminate` designs the campaign that
//! separates them; the real service set plays it open loop on a plant with the delay
//! (`jetbench up --sim --plant truth.toml --open-loop design.csv --record`); and the
//! diagnosis of both recordings claims the delay, dominating the lag.
//!
//! The first recording is simulated faster than real time (`sim-record`, the same plant
//! and noise as the live bench); the designed one is the live set, recorded by the real
//! recorder. Which draw of the first campaign is ambiguous depends on the noise: the test
//! takes the first of a fixed list of seeds whose diagnosis names both rivals and claims
//! neither, and fails if none does (the case class would no longer leave two rivals).

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::Value;

const SUITE: &str = "discriminate";
/// Length of the first campaign, s: short, so a delay and a lag both fit it.
const FIRST_S: &str = "90";
/// Length of the designed campaign asked for first, s (played live, in real time). When
/// `excite` says it is too short, the test reruns it with the length it asks for, as an
/// engineer would, up to [`DESIGN_MAX_S`].
const DESIGN_S: f64 = 90.0;
const DESIGN_MAX_S: f64 = 300.0;
const SEEDS: [u64; 6] = [4, 3, 5, 6, 7, 8];

fn scratch(name: &str) -> PathBuf {
    common::scratch(SUITE, name)
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

fn jetbench(args: &[&str], limit_s: u64) -> (i32, String, String) {
    common::run_jetbench(SUITE, args, Duration::from_secs(limit_s))
}

fn diagnose(files: &[&Path]) -> Value {
    let mut args = vec!["diagnose", "--model", "p100-diesel", "--json"];
    args.extend(files.iter().map(|f| p(f)));
    let (code, out, err) = jetbench(&args, 600);
    assert_eq!(code, 0, "diagnose failed: {err}");
    serde_json::from_str(&out).unwrap_or_else(|e| panic!("diagnose --json printed no JSON ({e}): {out}"))
}

/// `name (weight)` for every rival, best first.
fn rivals(d: &Value) -> String {
    d["rivals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let effects: Vec<&str> = r["effects"].as_array().unwrap().iter().map(|e| e.as_str().unwrap()).collect();
            let refit = if r["refit"].as_bool().unwrap() { "+refit" } else { "" };
            format!("{}{refit} {:.3}", effects.join("+"), r["weight"].as_f64().unwrap())
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn weight_of(d: &Value, effect: &str) -> Option<f64> {
    d["rivals"].as_array()?.iter().find_map(|r| {
        let effects = r["effects"].as_array()?;
        (effects.len() == 1 && effects[0] == effect && r["refit"] == false).then_some(r["weight"].as_f64())?
    })
}

#[test]
fn an_ambiguous_delay_or_lag_is_resolved_by_the_designed_campaign_played_on_the_live_bench() {
    let truth = scratch("truth.toml");
    let mut file = jetbench_model::ModelFile::new(jetbench_model::Preset::P100Diesel.params());
    file.effects = jetbench_model::Effects::new(["input_delay:delay_s=0.05".parse().unwrap()]).unwrap();
    file.save(&truth).unwrap();

    // 1. A first campaign the diagnosis cannot decide on.
    let first = scratch("first.csv");
    let first_json = scratch("first.json");
    let mut tried = Vec::new();
    let mut before = None;
    for seed in SEEDS {
        let seed = seed.to_string();
        let (code, _, err) = jetbench(
            &["sim-record", "--model", p(&truth), "--duration", FIRST_S, "--seed", &seed, "--out", p(&first)],
            120,
        );
        assert_eq!(code, 0, "sim-record: {err}");
        let d = diagnose(&[&first]);
        let both = weight_of(&d, "input_delay").is_some() && weight_of(&d, "actuator_lag").is_some();
        tried.push(format!("seed {seed}: {} [{}]", d["cause"], rivals(&d)));
        if d["cause"] == "ambiguous" && both {
            std::fs::write(&first_json, serde_json::to_string_pretty(&d).unwrap()).unwrap();
            before = Some((seed, d));
            break;
        }
    }
    let Some((seed, before)) = before else {
        panic!("no first campaign left the delay and the lag as rivals:\n{}", tried.join("\n"))
    };
    eprintln!("first campaign (seed {seed}, {FIRST_S} s): {} [{}]", before["cause"], rivals(&before));

    // 2. The campaign that separates them, as long as excite says it must be.
    let design = scratch("design.csv");
    let excite = |seconds: f64| {
        let duration = format!("{seconds}");
        let args = [
            "excite",
            "--discriminate",
            p(&first_json),
            "--model",
            "p100-diesel",
            "--duration",
            &duration,
            "--out",
            p(&design),
        ];
        jetbench(&args, 300)
    };
    let mut design_s = DESIGN_S;
    let (mut code, mut out, mut err) = excite(design_s);
    if let Some(asked) = err.split("rerun with --duration ").nth(1).and_then(|r| r.split(')').next()) {
        design_s = asked.trim().parse().unwrap();
        assert!(design_s <= DESIGN_MAX_S, "excite asks for {design_s} s: {err}");
        (code, out, err) = excite(design_s);
    }
    assert_eq!(code, 0, "excite --discriminate failed:\n{out}\n{err}");
    eprintln!("{err}{out}");
    assert!(out.contains("input_delay") && out.contains("actuator_lag") && out.contains("decisive after"), "{out}");
    let rows = std::fs::read_to_string(&design).unwrap().lines().count();
    assert_eq!(rows, 1 + (design_s * 100.0) as usize, "design.csv rows");

    // 3. Played open loop on the live simulated bench with the delay, recorded.
    let recording = scratch("design.mcap");
    let live = format!("{}", design_s + 2.0);
    let (code, out, err) = jetbench(
        &[
            "up",
            "--sim",
            "--plant",
            p(&truth),
            "--open-loop",
            p(&design),
            "--duration",
            &live,
            "--record",
            p(&recording),
            "--quiet",
        ],
        design_s as u64 + 180,
    );
    assert_eq!(code, 0, "up failed:\n{out}\n{err}");

    // 4. Both recordings together decide, and the claim is the truth.
    let after = diagnose(&[&first, &recording]);
    eprintln!(
        "first + designed: {} [{}]; dominant {}; validation MAE {:.3} N (floor {:.3} N)",
        after["cause"],
        rivals(&after),
        after["dominant"],
        after["mae_after_n"].as_f64().unwrap(),
        after["noise_floor_n"].as_f64().unwrap()
    );
    assert_eq!(after["cause"], "missing_physics", "{}", after["verdict"]);
    let names: Vec<&str> = after["effects"].as_array().unwrap().iter().map(|e| e["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["input_delay"], "{}", after["verdict"]);
    assert!(after["refit"].is_null(), "the parameters are exact: {}", after["verdict"]);
    let delay = after["effects"][0]["params"]["delay_s"].as_f64().unwrap();
    assert!((delay - 0.05).abs() < 0.015, "delay {delay} s against the truth's 0.05 s");
    assert_eq!(after["dominant"].as_bool(), Some(true), "{}", rivals(&after));
    let w = weight_of(&after, "input_delay").unwrap();
    assert!(w >= 0.95, "input_delay weight {w}: {}", rivals(&after));
    let lag = weight_of(&after, "actuator_lag").unwrap_or(0.0);
    assert!(lag <= 0.05, "actuator_lag weight {lag}: {}", rivals(&after));
}

/// The refusals a user meets: a diagnosis with one explanation left, a file that is no
/// diagnosis, a missing --model, throttle limits given as fractions.
#[test]
fn excite_discriminate_refuses_what_it_cannot_design() {
    let csv = scratch("clear.csv");
    let json = scratch("clear.json");
    let (code, _, err) = jetbench(
        &[
            "sim-record",
            "--model",
            "p100-diesel",
            "--effect",
            "sensor_drift:gain=0.05,time_constant_s=60",
            "--duration",
            "120",
            "--seed",
            "1",
            "--out",
            p(&csv),
        ],
        120,
    );
    assert_eq!(code, 0, "{err}");
    let d = diagnose(&[&csv]);
    std::fs::write(&json, serde_json::to_string(&d).unwrap()).unwrap();
    let out = scratch("never.csv");
    let excite = |extra: &[&str]| {
        let mut args = vec!["excite", "--discriminate", p(&json), "--out", p(&out)];
        args.extend(extra);
        jetbench(&args, 120)
    };
    // One rival (the drift, claimed): nothing to separate.
    let (code, _, err) = excite(&["--model", "p100-diesel"]);
    assert_ne!(code, 0);
    assert!(err.contains("fewer than two rivals") && err.contains(d["cause"].as_str().unwrap()), "{err}");
    assert!(!out.exists(), "a refused design wrote a file");
    let (code, _, err) = excite(&[]);
    assert_ne!(code, 0);
    assert!(err.contains("needs --model"), "{err}");
    std::fs::write(&json, "time_s,throttle_pct\n0,25\n").unwrap();
    let (code, _, err) = excite(&["--model", "p100-diesel"]);
    assert_ne!(code, 0);
    assert!(err.contains("is not JSON") && err.contains("diagnose --json"), "{err}");
    std::fs::write(
        &json,
        serde_json::to_string(&serde_json::json!({"rivals": [
        {"effects": ["input_delay"], "refit": false, "weight": 0.5},
        {"effects": ["actuator_lag"], "refit": false, "weight": 0.5}],
        "rounds": [{"candidates": [
            {"name": "input_delay", "params": {"delay_s": 0.05}, "unphysical": null},
            {"name": "actuator_lag", "params": {"time_constant_s": 0.05}, "unphysical": null}]}],
        "noise": {"ar": [], "innovation_sigma_n": 2.6}}))
        .unwrap(),
    )
    .unwrap();
    let (code, _, err) = excite(&["--model", "p100-diesel", "--min", "0.25", "--max", "1"]);
    assert_ne!(code, 0);
    assert!(err.contains("percent, not a fraction"), "{err}");
}
