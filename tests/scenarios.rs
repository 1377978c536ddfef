//! The concealed-effect suite (recordings/scenarios): `jetbench diagnose` runs blind on
//! every recording, given only the plant's ten-parameter model, and must name exactly
//! the effects the plant had (none where there were none), fit every parameter within
//! 20 % and bring the validation MAE within 10 % of the noise floor. The suite itself is
//! checked to be concealed: the model's MAE before is at most 45 % above the floor.
//!
//! Plus the errors a user meets: missing columns, NaN, time going backwards, a model
//! that diverges on the recorded input.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use common::{jetbench, repo_root, run, scratch};
use serde_json::Value;

const PARAM_TOLERANCE: f64 = 0.20;
const FLOOR_TOLERANCE: f64 = 0.10;
/// Concealed: the given model is at most this much worse than the floor.
const CONCEALED: f64 = 0.45;
/// A hung diagnosis, not a slow one.
const LIMIT: Duration = Duration::from_secs(600);

struct Case {
    name: String,
    model: String,
    truth: BTreeMap<String, BTreeMap<String, f64>>,
}

fn suite_dir() -> PathBuf {
    repo_root().join("recordings").join("scenarios")
}

fn model_arg(model: &str) -> String {
    if model.ends_with(".toml") {
        suite_dir().join(model).display().to_string()
    } else {
        model.to_owned()
    }
}

fn cases() -> Vec<Case> {
    let text = std::fs::read_to_string(suite_dir().join("scenarios.toml")).expect("read scenarios.toml");
    let manifest: toml::Table = toml::from_str(&text).expect("parse scenarios.toml");
    let list = manifest["case"].as_array().expect("[[case]] tables");
    list.iter()
        .map(|c| {
            let truth = c["effects"]
                .as_array()
                .expect("effects list")
                .iter()
                .map(|spec| {
                    let spec = spec.as_str().expect("effect spec");
                    let effect: jetbench_model::Effect = spec.parse().expect("valid effect in the manifest");
                    let params = effect.params().map(|(k, v)| (k.to_owned(), v)).collect();
                    (effect.kind().name().to_owned(), params)
                })
                .collect();
            Case {
                name: c["name"].as_str().expect("name").to_owned(),
                model: c["model"].as_str().expect("model").to_owned(),
                truth,
            }
        })
        .collect()
}

/// `x ≤ limit`, false for NaN.
fn at_most(x: f64, limit: f64) -> bool {
    x <= limit
}

/// What is wrong with one diagnosis, if anything.
fn judge(case: &Case, d: &Value) -> Vec<String> {
    let mut problems = Vec::new();
    let found: BTreeMap<String, &Value> =
        d["effects"].as_array().expect("effects").iter().map(|e| (e["name"].as_str().unwrap().to_owned(), e)).collect();
    let (truth_names, found_names): (Vec<_>, Vec<_>) = (case.truth.keys().collect(), found.keys().collect());
    if truth_names != found_names {
        problems.push(format!("found {found_names:?}, truth {truth_names:?}"));
    }
    for (name, params) in &case.truth {
        let Some(effect) = found.get(name) else { continue };
        for (key, truth) in params {
            let got = effect["params"][key].as_f64().unwrap_or(f64::NAN);
            if !at_most((got - truth).abs(), PARAM_TOLERANCE * truth.abs()) {
                problems.push(format!("{name}.{key} = {got}, truth {truth}"));
            }
        }
    }
    let (before, after, floor) =
        (d["mae_before_n"].as_f64().unwrap(), d["mae_after_n"].as_f64().unwrap(), d["noise_floor_n"].as_f64().unwrap());
    if !at_most(after, (1.0 + FLOOR_TOLERANCE) * floor) {
        problems.push(format!("MAE after {after:.3} N is not within 10 % of the floor {floor:.3} N"));
    }
    if !at_most(before, (1.0 + CONCEALED) * floor) {
        problems.push(format!("not concealed: MAE before {before:.3} N against floor {floor:.3} N"));
    }
    if d["verdict"].as_str().is_none_or(str::is_empty) {
        problems.push("no verdict".into());
    }
    if case.truth.is_empty() {
        // Nothing missing must come with the whiteness evidence.
        if d["before"]["whiteness"]["white"] != Value::Bool(true) {
            problems.push(format!("residual of the true model not white: {}", d["before"]["whiteness"]));
        }
        if !d["verdict"].as_str().unwrap_or("").contains("white") {
            problems.push("verdict gives no whiteness evidence".into());
        }
    }
    problems
}

#[test]
fn diagnose_finds_every_concealed_effect_blind() {
    let cases = cases();
    assert!(cases.len() >= 15, "the suite has {} cases", cases.len());
    let next = Mutex::new(0usize);
    let failures = Mutex::new(Vec::new());
    // Two at a time: the machine has two cores and each diagnosis is single-threaded.
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| loop {
                let i = {
                    let mut n = next.lock().unwrap();
                    *n += 1;
                    *n - 1
                };
                let Some(case) = cases.get(i) else { break };
                let csv = suite_dir().join(format!("{}.csv", case.name));
                let (status, out, err) = run(
                    jetbench("scen").arg("diagnose").arg("--model").arg(model_arg(&case.model)).arg(&csv).arg("--json"),
                    LIMIT,
                    &case.name,
                );
                let problems = if status.success() {
                    match serde_json::from_str::<Value>(&out) {
                        Ok(d) => {
                            let p = judge(case, &d);
                            eprintln!(
                                "{}: found {:?}, MAE {:.3} -> {:.3} N (floor {:.3}){}",
                                case.name,
                                d["effects"]
                                    .as_array()
                                    .map(|a| a.iter().map(|e| e["name"].clone()).collect::<Vec<_>>()),
                                d["mae_before_n"].as_f64().unwrap_or(f64::NAN),
                                d["mae_after_n"].as_f64().unwrap_or(f64::NAN),
                                d["noise_floor_n"].as_f64().unwrap_or(f64::NAN),
                                if p.is_empty() { "" } else { "  <- FAILS" }
                            );
                            p
                        }
                        Err(e) => vec![format!("output is not JSON ({e}): {out}")],
                    }
                } else {
                    vec![format!("exit {status}: {err}")]
                };
                if !problems.is_empty() {
                    failures.lock().unwrap().push(format!("{}: {}", case.name, problems.join("; ")));
                }
            });
        }
    });
    let failures = failures.into_inner().unwrap();
    assert!(failures.is_empty(), "{} of {} cases fail:\n{}", failures.len(), cases.len(), failures.join("\n"));
}

fn write(name: &str, text: &str) -> PathBuf {
    let path = scratch("scenarios", name);
    std::fs::write(&path, text).expect("write scratch file");
    path
}

fn diagnose_err(model: &str, file: &Path) -> String {
    let (status, _, err) = run(jetbench("scen").args(["diagnose", "--model", model]).arg(file), LIMIT, "diagnose");
    assert!(!status.success(), "diagnose accepted {}", file.display());
    assert!(!err.contains("panicked"), "{err}");
    err
}

#[test]
fn bad_input_gets_a_clear_error() {
    let rows = |f: &dyn Fn(usize) -> String| -> String { (0..3000).map(|k| f(k) + "\n").collect() };
    let missing =
        write("missing.csv", &format!("time_s,throttle_pct\n{}", rows(&|k| format!("{},50", k as f64 * 0.01))));
    assert!(diagnose_err("p100-diesel", &missing).contains("thrust_n"));

    let nan = write(
        "nan.csv",
        &format!(
            "time_s,throttle_pct,thrust_n\n{}",
            rows(&|k| format!("{},50,{}", k as f64 * 0.01, if k == 1234 { "NaN".into() } else { "25.0".to_owned() }))
        ),
    );
    let err = diagnose_err("p100-diesel", &nan);
    assert!(err.to_lowercase().contains("nan") || err.contains("not a finite"), "{err}");

    let backwards = write(
        "backwards.csv",
        &format!(
            "time_s,throttle_pct,thrust_n\n{}",
            rows(&|k| format!("{},50,25.0", if k == 2000 { 5.0 } else { k as f64 * 0.01 }))
        ),
    );
    let err = diagnose_err("p100-diesel", &backwards);
    assert!(err.contains("time") && (err.contains("increas") || err.contains("backwards")), "{err}");

    // The study's EKF P100 set escapes to infinity on a step from 70 % to 100 % (plant.md).
    let steps = write(
        "steps.csv",
        &format!(
            "time_s,throttle_pct,thrust_n\n{}",
            rows(&|k| format!("{},{},60.0", k as f64 * 0.01, if k < 500 { 70 } else { 100 }))
        ),
    );
    let err = diagnose_err("p100-ekf", &steps);
    assert!(err.contains("diverges"), "{err}");
}
