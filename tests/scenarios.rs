//! The concealed-effect suite (recordings/scenarios): `jetbench diagnose` runs blind on
//! every recording, given only the ten-parameter model a bench engineer would have, and
//! must name exactly the effects the plant had (none where there were none, only
//! `discrepancy` for physics outside the catalogue), fit every catalogue parameter within
//! 20 % (or two of its standard errors, when the fit resolves it to 25 % or better), give
//! the right cause (none, parameters, missing physics) and bring the validation MAE within
//! 10 % of the noise floor (where nothing is missing, `insufficient_data` naming a
//! class of effect the recording could not have shown is the honest answer too; `none` must
//! show every class excluded). Over every case without missing physics (clean,
//! coloured noise, spikes and lost rows, parameter errors) it must claim no physics at all.
//! A case whose recording cannot tell its truth from a rival (`cause = "ambiguous"`) passes
//! when the answer is `ambiguous` with the truth among the rivals, with its weight. An effect
//! of the truth listed as `hidden` (one the recording cannot show beside the rest, such as a
//! resonance behind a slow lag) is not expected among those named, but the verdict's probes
//! must say it could hide there.
//! The suite itself is checked to be concealed: the model's MAE before is at most 45 %
//! above the floor.
//!
//! Plus the errors a user meets: missing columns, NaN, time going backwards, garbage, a
//! truncated file, a rate that cannot be resampled, a model that diverges on the recorded
//! input.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use common::{jetbench, repo_root, run, scratch};
use serde_json::Value;

const PARAM_TOLERANCE: f64 = 0.20;
/// A parameter the fit gives a standard error under this share of its value passes within
/// two standard errors of the truth too: the data resolve it no finer than that.
const RESOLVED: f64 = 0.25;
const FLOOR_TOLERANCE: f64 = 0.10;
/// Concealed: the given model is at most this much worse than the floor.
const CONCEALED: f64 = 0.45;
/// A hung diagnosis, not a slow one.
const LIMIT: Duration = Duration::from_secs(600);

struct Case {
    name: String,
    model: String,
    /// Catalogue effects of the truth: names and parameters.
    truth: BTreeMap<String, BTreeMap<String, f64>>,
    /// Physics outside the catalogue: only `discrepancy` may be named.
    outside: bool,
    /// `none`, `parameters` or `missing_physics`.
    cause: String,
    /// Catalogue effects of the truth this recording cannot show beside the rest (`hidden`):
    /// not expected among the effects found, but the probes must say they could hide.
    hidden: Vec<String>,
    /// For physics no term of the library writes: the explanation that must be among the
    /// verdict's rivals (`rival`, with its weight), in place of the truth's; what an unclaimed
    /// verdict finds beside it is then not checked.
    rival: Option<Vec<String>>,
    /// A slow periodic force: the period the verdict must report, s (within 10 %).
    periodic_s: Option<f64>,
    file: String,
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
            let truth: BTreeMap<String, BTreeMap<String, f64>> = c
                .get("effects")
                .and_then(|e| e.as_array())
                .map(|a| a.as_slice())
                .unwrap_or_default()
                .iter()
                .map(|spec| {
                    let spec = spec.as_str().expect("effect spec");
                    let effect: jetbench_model::Effect = spec.parse().expect("valid effect in the manifest");
                    let params = effect.params().map(|(k, v)| (k.to_owned(), v)).collect();
                    (effect.kind().name().to_owned(), params)
                })
                .collect();
            let name = c["name"].as_str().expect("name").to_owned();
            let outside = c.get("outside").is_some();
            let missing = !truth.is_empty() || outside;
            let cause = c
                .get("cause")
                .and_then(|v| v.as_str())
                .unwrap_or(if missing { "missing_physics" } else { "none" })
                .to_owned();
            let file = format!("{name}.{}", if c.get("closed_loop").is_some() { "mcap" } else { "csv" });
            let hidden = c
                .get("hidden")
                .and_then(|h| h.as_array())
                .map(|a| a.iter().filter_map(|v| v.as_str().map(str::to_owned)).collect())
                .unwrap_or_default();
            let names = |key: &str| -> Option<Vec<String>> {
                let mut v: Vec<String> =
                    c.get(key)?.as_array()?.iter().filter_map(|v| v.as_str().map(str::to_owned)).collect();
                v.sort();
                Some(v)
            };
            Case {
                name,
                model: c["model"].as_str().expect("model").to_owned(),
                truth,
                outside,
                cause,
                hidden,
                rival: names("rival"),
                periodic_s: c.get("periodic_s").and_then(|v| v.as_float()),
                file,
            }
        })
        .collect()
}

/// `x ≤ limit`, false for NaN.
fn at_most(x: f64, limit: f64) -> bool {
    x <= limit
}

/// What is wrong with one diagnosis, if anything, and whether it names physics that is
/// not there.
fn judge(case: &Case, d: &Value) -> (Vec<String>, bool) {
    let mut problems = Vec::new();
    let found: BTreeMap<String, &Value> =
        d["effects"].as_array().expect("effects").iter().map(|e| (e["name"].as_str().unwrap().to_owned(), e)).collect();
    let mut expected: Vec<String> = case.truth.keys().filter(|k| !case.hidden.contains(k)).cloned().collect();
    if case.outside {
        expected.push("discrepancy".into());
        expected.sort();
    }
    let found_names: Vec<String> = found.keys().cloned().collect();
    // Only a claim can be false: `ambiguous`, `unexplained` and `insufficient_data` name
    // what the search found without claiming it.
    let claimed = matches!(d["cause"].as_str(), Some("none" | "parameters" | "missing_physics"));
    let false_claim = claimed && found_names.iter().any(|n| !expected.contains(n));
    if (case.cause == "ambiguous" && !expected.is_empty()) || case.rival.is_some() {
        // Honestly ambiguous: the truth must be among the rivals, with its weight (`rival` in
        // its place where the library cannot write it).
        let wanted = case.rival.as_ref().unwrap_or(&expected);
        let rivals = d["rivals"].as_array().cloned().unwrap_or_default();
        let has_truth = rivals.iter().any(|r| {
            let mut names: Vec<String> = r["effects"]
                .as_array()
                .map(|a| a.iter().filter_map(|e| e.as_str().map(str::to_owned)).collect())
                .unwrap_or_default();
            names.sort();
            names == *wanted && r["weight"].as_f64().is_some()
        });
        let right_claim = claimed && expected == found_names;
        if !(has_truth || right_claim) {
            problems.push(format!("the truth {wanted:?} is not among the rivals: {}", d["rivals"]));
        }
    } else if expected != found_names {
        problems.push(format!("found {found_names:?}, expected {expected:?}"));
    }
    for (name, params) in &case.truth {
        let Some(effect) = found.get(name) else { continue };
        for (key, truth) in params {
            let got = effect["params"][key].as_f64().unwrap_or(f64::NAN);
            let error = effect["uncertainty"][key].as_f64().filter(|e| *e <= RESOLVED * got.abs()).unwrap_or(0.0);
            if !at_most((got - truth).abs(), (PARAM_TOLERANCE * truth.abs()).max(2.0 * error)) {
                problems.push(format!("{name}.{key} = {got}, truth {truth}"));
            }
        }
    }
    // "Nothing is missing" and "only the parameters are off" are claims: where nothing (or
    // only the parameters) is off, the honest answers are that claim with every class of
    // effect shown to be excluded (beside the refit, for `parameters`), or
    // `insufficient_data` naming a class this recording could not have shown (at the size
    // that matters) and the experiment that would.
    let probes = d["detectability"].as_array().cloned().unwrap_or_default();
    for h in &case.hidden {
        // A probe of that class that would not show must say the truth's values could hide
        // too: every value within its `could_hide` range, key for key (the campaign's grader,
        // scripts/diagnose_campaign.py, alike).
        let truth = case.truth.get(h).cloned().unwrap_or_default();
        let holds = |p: &Value| -> bool {
            let Some(region) = p["could_hide"].as_object() else { return false };
            region.len() == truth.len()
                && truth.iter().all(|(key, v)| {
                    let range = &region.get(key.as_str()).cloned().unwrap_or(Value::Null);
                    let lo = range[0].as_f64().unwrap_or(f64::NEG_INFINITY);
                    let hi = range[1].as_f64().unwrap_or(f64::INFINITY);
                    region.contains_key(key.as_str()) && (lo - 1e-9..=hi + 1e-9).contains(v)
                })
        };
        let disclosed =
            probes.iter().any(|p| p["effect"] == h.as_str() && p["would_show"] == Value::Bool(false) && holds(p));
        if !disclosed {
            let of_class: Vec<&Value> = probes.iter().filter(|p| p["effect"] == h.as_str()).collect();
            problems.push(format!("{h} is in the truth but no probe says it could hide at its size: {of_class:?}"));
        }
    }
    let not_shown = probes.iter().filter(|p| p["would_show"] == Value::Bool(false)).count();
    let honest_not_shown =
        matches!(case.cause.as_str(), "none" | "parameters") && d["cause"] == "insufficient_data" && not_shown > 0;
    if d["cause"].as_str() != Some(case.cause.as_str()) && !honest_not_shown {
        problems.push(format!("cause {}, expected {}", d["cause"], case.cause));
    }
    if (d["cause"] == "none" || d["cause"] == "parameters") && (probes.is_empty() || not_shown > 0) {
        problems.push(format!("{} claimed although {not_shown} class(es) could not have shown", d["cause"]));
    }
    if case.cause == "ambiguous"
        && d["rivals"].as_array().is_none_or(|r| r.len() < 2 || r[0]["weight"].as_f64().is_none())
    {
        problems.push(format!("ambiguous without rivals and their weights: {}", d["rivals"]));
    }
    if case.cause == "parameters" && d["refit"]["params"]["K_T"].as_f64().is_none() {
        problems.push("re-identification is the answer but no refitted parameters are given".into());
    }
    let (before, after, floor) =
        (d["mae_before_n"].as_f64().unwrap(), d["mae_after_n"].as_f64().unwrap(), d["noise_floor_n"].as_f64().unwrap());
    // A claim must reach the floor; an honest refusal (`ambiguous`, `unexplained`) need not.
    let claim_expected = matches!(case.cause.as_str(), "none" | "parameters" | "missing_physics");
    if claim_expected && !at_most(after, (1.0 + FLOOR_TOLERANCE) * floor) {
        problems.push(format!("MAE after {after:.3} N is not within 10 % of the floor {floor:.3} N"));
    }
    if !at_most(before, (1.0 + CONCEALED) * floor) {
        problems.push(format!("not concealed: MAE before {before:.3} N against floor {floor:.3} N"));
    }
    if let Some(period) = case.periodic_s {
        let got = d["periodic"]["period_s"].as_f64().unwrap_or(f64::NAN);
        if !at_most((got - period).abs(), 0.1 * period) {
            problems.push(format!("a periodic force of period {period} s, reported: {}", d["periodic"]));
        }
    }
    if d["verdict"].as_str().is_none_or(str::is_empty) {
        problems.push("no verdict".into());
    }
    if d["cause"] == "none" {
        // Nothing missing must come with the whiteness evidence.
        if d["after"]["whiteness"]["white"] != Value::Bool(true) {
            problems.push(format!("residual of the true model not white: {}", d["after"]["whiteness"]));
        }
        if !d["verdict"].as_str().unwrap_or("").contains("white") {
            problems.push("verdict gives no whiteness evidence".into());
        }
    }
    (problems, false_claim)
}

#[test]
fn diagnose_finds_every_concealed_effect_blind() {
    let cases = cases();
    assert!(cases.len() >= 30, "the suite has {} cases", cases.len());
    let next = Mutex::new(0usize);
    let failures = Mutex::new(Vec::new());
    let false_claims = Mutex::new(Vec::new());
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
                let file = suite_dir().join(&case.file);
                let (status, out, err) = run(
                    jetbench("scen")
                        .arg("diagnose")
                        .arg("--model")
                        .arg(model_arg(&case.model))
                        .arg(&file)
                        .arg("--json"),
                    LIMIT,
                    &case.name,
                );
                let problems = if status.success() {
                    match serde_json::from_str::<Value>(&out) {
                        Ok(d) => {
                            let (p, false_claim) = judge(case, &d);
                            if false_claim && case.cause != "missing_physics" {
                                false_claims.lock().unwrap().push(case.name.clone());
                            }
                            eprintln!(
                                "{}: found {:?}, cause {}, MAE {:.3} -> {:.3} N (floor {:.3}){}",
                                case.name,
                                d["effects"]
                                    .as_array()
                                    .map(|a| a.iter().map(|e| e["name"].clone()).collect::<Vec<_>>()),
                                d["cause"],
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
    let without_physics = cases.iter().filter(|c| c.cause != "missing_physics").count();
    assert!(without_physics >= 8, "{without_physics} cases without missing physics");
    let false_claims = false_claims.into_inner().unwrap();
    assert!(false_claims.is_empty(), "physics claimed where there is none: {false_claims:?}");
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
    // A lost sample is left out, becomes a gap and is counted: never refused whole, never silent.
    let (status, out, err) =
        run(jetbench("scen").args(["diagnose", "--model", "p100-diesel"]).arg(&nan), LIMIT, "diagnose");
    let said = format!("{out}{err}");
    assert!(status.success() && !said.contains("panicked"), "{said}");
    assert!(said.contains("1 row(s) (0.0 %) left out, the first at line 1236") && said.contains("NaN"), "{said}");

    let backwards = write(
        "backwards.csv",
        &format!(
            "time_s,throttle_pct,thrust_n\n{}",
            rows(&|k| format!("{},50,25.0", if k == 2000 { 5.0 } else { k as f64 * 0.01 }))
        ),
    );
    let err = diagnose_err("p100-diesel", &backwards);
    assert!(err.contains("time") && (err.contains("increas") || err.contains("backwards")), "{err}");

    // The study's EKF P100 set escapes to infinity on a step from 70 % to 100 % (docs/model/README.md).
    let steps = write(
        "steps.csv",
        &format!(
            "time_s,throttle_pct,thrust_n\n{}",
            rows(&|k| format!("{},{},60.0", k as f64 * 0.01, if k < 500 { 70 } else { 100 }))
        ),
    );
    let err = diagnose_err("p100-ekf", &steps);
    assert!(err.contains("diverges"), "{err}");

    let garbage = write("garbage.csv", "\u{1}\u{2}not,a,csv\n\u{ff}\u{fe}%%%\n");
    let err = diagnose_err("p100-diesel", &garbage);
    assert!(err.contains("time_s") || err.contains("header"), "{err}");

    // A file cut off in the middle of a row.
    let text = format!("time_s,throttle_pct,thrust_n\n{}", rows(&|k| format!("{},50,25.0", k as f64 * 0.01)));
    // Its last line is left out and said (a number there may be cut short); the rest is used.
    let truncated = write("truncated.csv", &text[..text.len() - 7]);
    let (status, out, err) =
        run(jetbench("scen").args(["diagnose", "--model", "p100-diesel"]).arg(&truncated), LIMIT, "diagnose");
    let said = format!("{out}{err}");
    assert!(status.success() && !said.contains("panicked"), "{said}");
    assert!(said.contains("the last line (3001) ends the file with no line break"), "{said}");

    // 75 Hz: neither 100 Hz, faster, nor a whole multiple of 10 ms.
    let odd = write(
        "odd-rate.csv",
        &format!("time_s,throttle_pct,thrust_n\n{}", rows(&|k| format!("{},50,25.0", k as f64 / 75.0))),
    );
    let err = diagnose_err("p100-diesel", &odd);
    assert!(err.contains("75.0 Hz") && err.contains("resample it to 100 Hz first"), "{err}");

    // 20 s whose last 6 s sit at the force sensor's limit: the rows around every clipped
    // reading are left out, and the error says that is why so little is left. (A longer
    // recording clipped near its end holds out its share of the rows measured, and is diagnosed.)
    let clipped = write(
        "clipped.csv",
        &format!(
            "time_s,throttle_pct,thrust_n\n{}",
            (0..2_000)
                .map(|k| {
                    // Noise of about 2 N from a fixed scramble of the row number.
                    let noise = ((k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40) as f64 / (1u64 << 24) as f64;
                    let noise = 7.0 * (noise - 0.5);
                    let (u, y) = if k < 1400 {
                        (50.0, 40.0 + noise)
                    } else {
                        (96.0, if k % 3 == 0 { 84.7 } else { 84.0 + 0.1 * noise.abs() })
                    };
                    format!("{},{u:.2},{y:.2}\n", k as f64 * 0.01)
                })
                .collect::<String>()
        ),
    );
    let err = diagnose_err("p100-diesel", &clipped);
    assert!(err.contains("a diagnosis needs at least 1000") && err.contains("at or near its limit (84.7 N)"), "{err}");

    // An MCAP recording cut short: its header, then nothing usable.
    let mcap = scratch("scenarios", "truncated.mcap");
    std::fs::write(&mcap, b"\x89MCAP0\r\n\x01\x00\x00").expect("write scratch file");
    let err = diagnose_err("p100-diesel", &mcap);
    assert!(!err.is_empty(), "{err}");
}

#[test]
fn a_csv_at_another_rate_is_diagnosed_with_a_note() {
    // A concealed delay on a 50 Hz bench: each throttle is held for 20 ms and the thrust
    // sampled every 20 ms. Made from a campaign whose throttle changes only every 20 ms,
    // recorded at 100 Hz, every other row kept.
    let campaign = scratch("scenarios", "campaign-100hz.csv");
    let (status, _, err) = run(
        jetbench("scen").args(["excite", "--duration", "240", "--seed", "31", "--out"]).arg(&campaign),
        LIMIT,
        "excite",
    );
    assert!(status.success(), "{err}");
    let text = std::fs::read_to_string(&campaign).expect("read the campaign");
    let mut held = String::from("time_s,throttle_pct\n");
    let rows: Vec<&str> = text.lines().skip(1).collect();
    for pair in rows.chunks(2) {
        let throttle = pair[0].split(',').nth(1).expect("throttle");
        for row in pair {
            held.push_str(&format!("{},{throttle}\n", row.split(',').next().expect("time")));
        }
    }
    let profile = write("campaign-50hz.csv", &held);
    let recorded = scratch("scenarios", "delay-100hz.csv");
    let (status, _, err) = run(
        jetbench("scen")
            .args(["sim-record", "--model", "p100-diesel", "--seed", "31", "--effect", "input_delay:delay_s=0.15"])
            .arg("--profile")
            .arg(&profile)
            .arg("--out")
            .arg(&recorded),
        LIMIT,
        "sim-record",
    );
    assert!(status.success(), "{err}");
    let text = std::fs::read_to_string(&recorded).expect("read the recording");
    let mut lines = text.lines();
    let mut half = format!("{}\n", lines.next().expect("header"));
    for row in lines.step_by(2) {
        half.push_str(row);
        half.push('\n');
    }
    let file = write("delay-50hz.csv", &half);
    let (status, out, err) =
        run(jetbench("scen").args(["diagnose", "--model", "p100-diesel", "--json"]).arg(&file), LIMIT, "diagnose");
    assert!(status.success(), "{err}");
    let d: Value = serde_json::from_str(&out).expect("JSON");
    assert!(d["noise"]["notes"][0].as_str().unwrap_or("").contains("50.0 Hz"), "{}", d["noise"]);
    let names: Vec<&Value> = d["effects"].as_array().expect("effects").iter().map(|e| &e["name"]).collect();
    assert_eq!(names, ["input_delay"], "{}", d["verdict"]);
    let delay = d["effects"][0]["params"]["delay_s"].as_f64().unwrap_or(f64::NAN);
    assert!((delay - 0.15).abs() < 0.02, "{delay}");
}

/// The campaign's grader on made-up results (scripts/diagnose_campaign.py --self-test): a claim
/// naming the whole truth is true; one leaving out a resonance its verdict disclosed as able to
/// hide, over the resonance's frequency and damping, is true; one leaving it out undisclosed,
/// disclosed only above its frequency or at other dampings, a delay disclosed only up to a
/// smaller one, a drift at another time constant, physics outside the catalogue left out, or
/// an effect named that is not there, is false.
#[test]
fn the_campaign_grader_counts_a_left_out_effect_only_when_disclosed_at_its_size() {
    let root = repo_root();
    let (status, _, stderr) = run(
        std::process::Command::new("python3").arg(root.join("scripts/diagnose_campaign.py")).arg("--self-test"),
        Duration::from_secs(60),
        "the grader's self-test",
    );
    assert!(status.success(), "{stderr}");
    assert!(stderr.contains("grader self-test: passed"), "{stderr}");
}

/// A CI-sized draw of the randomised campaign (scripts/diagnose_campaign.py, its own
/// simulator), seed fixed: every claim it makes must be true, and a bad case is an error,
/// never a crash. The full campaign's figures are in docs/diagnose/CAMPAIGN.md. On seed
/// 2027 the draw makes 1 claim (a rate limit), true; the three noise-only cases are
/// `insufficient_data` (each could not have shown some class of effect at the size that
/// matters, so `none` is not claimed; before the detectability probes they were `none`), a
/// delay with a gain drift under coloured noise is `ambiguous` against a lag with the drift,
/// and a heteroscedastic noise-only case is `insufficient_data` too (it was `unexplained`
/// while the simulator sampled each row 10 ms late, after the row's throttle had acted).
#[test]
fn a_small_random_campaign_makes_no_false_claim() {
    let root = repo_root();
    let out = scratch("scenarios", "campaign.json");
    let exe = env!("CARGO_BIN_EXE_jetbench");
    let (status, _, stderr) = run(
        std::process::Command::new("python3")
            .arg(root.join("scripts/diagnose_campaign.py"))
            .args(["6", "2027", "--jobs", "2", "--jetbench", exe, "--json"])
            .arg(&out),
        Duration::from_secs(900),
        "the campaign",
    );
    assert!(status.success(), "{stderr}");
    let summary: Value = serde_json::from_str(&std::fs::read_to_string(&out).expect("campaign JSON")).expect("JSON");
    let (claims, true_claims) = (summary["claims"].as_u64().unwrap(), summary["true_claims"].as_u64().unwrap());
    assert_eq!(summary["errors"].as_u64(), Some(0), "{stderr}");
    assert_eq!(true_claims, claims, "false claims in the CI draw:\n{stderr}");
    assert!(claims >= 1, "the CI draw claims nothing, so it measures no precision:\n{stderr}");
}

/// Case `case` of the 300-case campaign drawn with `seed`, rerun on its own draw (the
/// campaign's simulator, `--case`): the campaign's JSON summary of it.
fn draw(seed: &str, case: &str) -> Value {
    draw_with(seed, case, &[])
}

/// [`draw`] with more options of the campaign script (`--discriminate`).
fn draw_with(seed: &str, case: &str, options: &[&str]) -> Value {
    let root = repo_root();
    let out = scratch("scenarios", &format!("campaign-{seed}-{case}{}.json", options.concat()));
    let (status, _, stderr) = run(
        std::process::Command::new("python3")
            .arg(root.join("scripts/diagnose_campaign.py"))
            .args(["300", seed, "--case", case, "--jetbench", env!("CARGO_BIN_EXE_jetbench"), "--json"])
            .arg(&out)
            .args(options),
        Duration::from_secs(300),
        "the campaign's case",
    );
    assert!(status.success(), "{stderr}");
    let summary: Value = serde_json::from_str(&std::fs::read_to_string(&out).expect("campaign JSON")).expect("JSON");
    assert_eq!(summary["errors"].as_u64(), Some(0), "{stderr}");
    summary
}

/// A gain drift and a soak slower than the recording look alike on one recording, and the
/// designed experiment tells them apart now that it can rebuild the soak from the discrepancy it
/// was weighed with. Fresh seed 7853's case 3 (a gain drift of 1.1 %/min on 100 s) is
/// `ambiguous` against the slow soak; excite used to refuse it ("cannot be simulated"). Played,
/// the designed campaign's recording with the first makes the drift a true claim. Seed 7829's
/// case 71, a fuel soak once claimed as a drift, gets its design too, and no drift is claimed.
#[test]
fn the_designed_experiment_tells_a_gain_drift_from_a_slow_soak() {
    let drift = draw_with("7853", "3", &["--discriminate"]);
    let result = &drift["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    assert!(rival_names(result).contains(&"slow_history"), "{result}");
    let second = &result["second"];
    assert!(second.get("refused").is_none(), "no design: {second}");
    assert_eq!(second["cause"], "missing_physics", "{second}");
    assert_eq!(second["found"], serde_json::json!(["gain_drift"]), "{second}");
    let soak = draw_with("7829", "71", &["--discriminate"]);
    let second = &soak["results"][0]["second"];
    assert!(second.get("refused").is_none(), "no design: {second}");
    let drift_claimed = second["cause"] == "missing_physics"
        && second["found"].as_array().is_some_and(|f| f.iter().any(|e| e == "gain_drift"));
    assert!(!drift_claimed, "a fuel soak claimed as a gain drift: {second}");
}

/// A sensor drift that had settled by the held-out part reads like a zero shift of the sensor
/// there, and the designed experiment now rebuilds the shift (a constant on what is read) to
/// tell them apart. Fresh seed 7853's case 23 (a drift of 1.1 %, τ 72 s, on 400 s under coloured
/// noise) is `ambiguous` with the shift leading; excite used to refuse it ("cannot be
/// simulated"). The first designed recording rules the shift out and leaves the drift against a
/// slow soak; a second round, designed from that diagnosis as the verdict asks, makes the drift a
/// true claim.
#[test]
fn the_designed_experiment_tells_a_settled_sensor_drift_from_a_zero_shift() {
    let summary = draw_with("7853", "23", &["--discriminate", "--rounds", "2"]);
    let result = &summary["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    assert!(rival_names(result).contains(&"sensor_offset"), "{result}");
    let second = &result["second"];
    assert!(second.get("refused").is_none(), "no design: {second}");
    assert_eq!(second["cause"], "missing_physics", "{second}");
    assert_eq!(second["found"], serde_json::json!(["sensor_drift"]), "{second}");
    assert_eq!(second["refit"], false, "the parameters were exact: {second}");
}

/// A fresh campaign's effect that was missed for a fault of the fit, rerun on its own draw.
/// Seed 4177's case 64: a delay of 216 ms on 100 s of a P220, the throttle ramping from the
/// recording's first row. Held at the engine start fitted without a delay (falling at 35 N/s
/// to meet a ramp the engine had not yet seen), the delay was fitted at 196 ± 2 ms, and a
/// discrepancy beside it took the rest: `ambiguous`. Each delay tried now starts from its own
/// fitted start: the delay is claimed at its size, and what it leaves is noise.
#[test]
fn a_fresh_campaign_delay_behind_a_ramp_from_the_first_row_is_claimed_at_its_size() {
    let summary = draw("4177", "64");
    let result = claimed_true(&summary);
    assert_eq!(result["cause"], "missing_physics", "{result}");
    assert_eq!(result["found"], serde_json::json!(["input_delay"]), "{result}");
    let verdict = result["verdict"].as_str().unwrap_or_default();
    let fitted: f64 = verdict
        .split("Modelled: ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(f64::NAN);
    let truth = result["case"]["effects"]["input_delay"]["delay_s"].as_f64().unwrap_or(f64::NAN);
    assert!((fitted - truth).abs() < 0.006, "delay {fitted} s against {truth} s: {verdict}");
}

/// Three false claims of fresh campaigns, rerun on their own draws (the campaign's simulator,
/// `--case`). Seed 9277's case 173, a sensor drift of 3 % and τ 20 s whose bias had settled
/// before the recording, was claimed as a discrepancy on the engine: it is now a true claim of
/// the drift. Seed 6703's case 26, a heat soak of τ 47 s on 100 s, was claimed as bearing
/// friction beside a discrepancy (the friction only held the history off its edge): no claim
/// now, the history freed of the edge among the rivals (held at a slower time constant it leads,
/// named and not claimed). Seed 7103's case 210, a fuel
/// soak of τ 74 s on 100 s, was claimed as a gain drift while the discrepancy had no history
/// that follows the throttle: it is now `ambiguous`, the drift against the soak. The first two
/// are not concealed (the given model 2.0× and 3.8× the floor), so they are not in the suite
/// above; the third is (1.17×), and its class is there too (`fuel-soak-or-gain-drift-100s-p220`).
/// Seed 7591's case 1, a delay of 73 ms on 200 s (1.02× the floor), was claimed as a lag of 77
/// ms: fitted both ways round, the lag led each way, the delay's value pinned to each part's
/// noise; fitted in sample the delay leads, and the case is `ambiguous` between the two. Seed
/// 7591's case 67, a fuel soak of τ 54 s on 150 s (2.0×), was claimed as a gain drift with the
/// parameters refitted: the soak's history, held at the edge of what 150 s can tell, is now
/// weighed freed of it beside the refit too (`slow_history`), and the case is `ambiguous`.
/// Seed 7591's case 222, a heat soak of τ 58 s on 300 s (3.9×), was claimed as a soak on the
/// throttle's history with a gain drift beside it: the soak on the thrust's history without
/// the drift is now weighed against it, 0.2 units behind. Every explanation in play holds a
/// soak, but not the same one: on the throttle's history in one, on the thrust's in the other.
/// For a while the label alone settled it and the soak was claimed, the gain drift undecided;
/// a discrepancy is settled only with the same terms in every explanation in play, and the
/// case is `ambiguous` between the two (docs/diagnose/README.md, "The part every explanation
/// in play holds"). Seed 7243's case 159, a delay of 219 ms beside a rate limit (1.76×), was
/// claimed as a lag beside the limit: the rate limit ran tick by tick, so every delay within a
/// tick gave the same response, and the delay's fit had no gradient and stayed at its start.
/// The limit now runs a tick that a delay splits in two parts (docs/model/README.md); the delay
/// is fitted at 226 ms, the rate limit is claimed, and the delay and a lag with a resonance
/// stay undecided beside it. Seed 7243's case 97, a heat soak of τ 72 s on 150 s (1.01×), was
/// claimed as a gain drift: the soak freed of its edge was weighed on the throttle's history
/// only, 10.1 units of held-out fit behind it; on the thrust's it is 5.7 behind, and the case is
/// `ambiguous` between the drift and the soak. Seed 7583's case 31, a heat soak of τ 63 s on
/// 200 s (1.08×), was claimed as a gain drift: the soak in the drift's place was fitted on the
/// throttle's history only, 26 units behind; on the thrust's it stops at the longest time
/// constant a fit explores, and freed of it, it is `ambiguous` with the drift. Seed 7669's case
/// 140, a sensor drift of 6 % with a stand ringing at 3.1 Hz (ζ 0.12) on 150 s (4.5×), was
/// claimed as the drift and a delay of 13 ms, the resonance's low-frequency lag: weighed both
/// ways round, the resonance's frequency, pinned only along that lag, paid for it. The drift is
/// now claimed alone, the delay and the resonance undecided beside it.
#[test]
fn fresh_campaign_false_claims_stay_answered_right() {
    let ringing = draw("7669", "140");
    let result = claimed_true(&ringing);
    assert_eq!(result["found"], serde_json::json!(["sensor_drift"]), "{result}");
    let names = rival_names(result);
    assert!(names.contains(&"input_delay") && names.contains(&"stand_resonance"), "{result}");
    let drift = draw("9277", "173");
    let result = claimed_true(&drift);
    assert_eq!(result["found"], serde_json::json!(["sensor_drift"]), "{result}");
    // Held at slower time constants, the freed history leads every explanation jetbench
    // models by 15 units of fit: the soak is named as the best explanation, not claimed.
    let soak = draw("6703", "26");
    let result = &soak["results"][0];
    assert_eq!(soak["claims"].as_u64(), Some(0), "{result}");
    assert!(matches!(result["cause"].as_str(), Some("ambiguous" | "unexplained")), "{result}");
    assert!(
        rival_names(result).contains(&"slow_history"),
        "the history freed of its edge is not among the rivals: {result}"
    );
    // What it leaves is white: the verdict does not call it systematic in the same breath.
    let verdict = result["verdict"].as_str().unwrap_or_default();
    assert!(
        !(verdict.contains("is white under the noise model") && verdict.contains("residual is systematic")),
        "{verdict}"
    );
    let fuel = draw("7103", "210");
    let result = &fuel["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    let names = rival_names(result);
    assert!(names.contains(&"gain_drift") && names.contains(&"slow_history"), "{result}");
    let look_alike = draw("7591", "1");
    let result = &look_alike["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    let names = rival_names(result);
    assert!(names.contains(&"input_delay") && names.contains(&"actuator_lag"), "{result}");
    let soak = draw("7591", "67");
    let result = &soak["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    assert!(rival_names(result).contains(&"slow_history"), "{result}");
    let heat = draw("7591", "222");
    let result = &heat["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    let with_drift = result["rivals"]
        .as_array()
        .into_iter()
        .flatten()
        .any(|r| r[0] == serde_json::json!(["discrepancy", "gain_drift"]));
    assert!(with_drift, "the soak with the gain drift is not among the rivals: {result}");
    let without_drift =
        result["rivals"].as_array().into_iter().flatten().any(|r| r[0] == serde_json::json!(["discrepancy"]));
    assert!(without_drift, "the soak on the other history, without the drift, is not among the rivals: {result}");
    // A delay of 219 ms beside a rate limit was claimed as a lag: the delay's fit could not
    // move beside the limit. It moves now, and no lag is claimed.
    let delay = draw("7243", "159");
    let result = &delay["results"][0];
    assert_eq!(delay["claims"].as_u64(), delay["true_claims"].as_u64(), "{result}");
    let found: Vec<&str> = result["found"].as_array().into_iter().flatten().filter_map(Value::as_str).collect();
    assert!(found.contains(&"rate_limit") && !found.contains(&"actuator_lag"), "{result}");
    assert!(rival_names(result).contains(&"input_delay"), "the delay is not among the rivals: {result}");
    let heat = draw("7243", "97");
    let result = &heat["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    let names = rival_names(result);
    assert!(names.contains(&"gain_drift") && names.contains(&"slow_history"), "{result}");
    let heat = draw("7583", "31");
    let result = &heat["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    let names = rival_names(result);
    assert!(names.contains(&"gain_drift") && names.contains(&"slow_history"), "{result}");
}

/// A soak slower than the calibration part settles is weighed at slower time constants too.
/// Fresh seed 7829's case 71: a fuel soak (outside the catalogue, τ 68 s) on 100 s of a P220
/// under white noise was claimed as a gain drift, the only explanation listed. The soak freed
/// of its edge was fitted at τ 56 s on the first 70 s and predicted the held-out 30 s 13 units
/// worse than the drift, while the truth predicted them as well. Held at twice the edge, its
/// gain fitted, it is a few units behind: `ambiguous` between the drift and the slow soak, and
/// the verdict says why the drift, which wins every resample, is not claimed.
#[test]
fn a_fuel_soak_slower_than_the_calibration_part_is_no_claimed_gain_drift() {
    let summary = draw("7829", "71");
    let result = &summary["results"][0];
    assert_eq!(summary["claims"].as_u64(), summary["true_claims"].as_u64(), "{result}");
    assert_eq!(result["cause"], "ambiguous", "{result}");
    let names = rival_names(result);
    assert!(names.contains(&"gain_drift") && names.contains(&"slow_history"), "{result}");
    let verdict = result["verdict"].as_str().unwrap_or_default();
    assert!(verdict.contains("but is not claimed"), "{verdict}");
}

/// An explanation that wins every resample is not claimed when its lead is consistent but
/// small, and the verdict says so. Seed 7789's case 154: a gain drift of 1.1 %/min on 100 s of
/// a fast P100 (the given model 1.01× the floor). The drift wins every resample over a refit
/// of the ten parameters, but fits the held-out data only a few units better, short of what
/// blames physics rather than the parameters: `ambiguous`, with the weights 100 % and 0 %.
/// The verdict used to stop there, as if contradicting itself; it now names the rival the
/// drift does not clear and the bar it falls short of.
#[test]
fn a_favourite_that_is_not_claimed_is_explained() {
    let summary = draw("7789", "154");
    let result = &summary["results"][0];
    assert_eq!(summary["claims"].as_u64(), summary["true_claims"].as_u64(), "{result}");
    let verdict = result["verdict"].as_str().unwrap_or_default();
    match result["cause"].as_str() {
        Some("ambiguous") => {
            assert!(verdict.contains("gain_drift wins 100 % of the resamples but is not claimed"), "{verdict}");
            assert!(verdict.contains("standard errors of the paired difference"), "{verdict}");
        }
        Some("missing_physics") => assert_eq!(result["found"], serde_json::json!(["gain_drift"]), "{result}"),
        other => panic!("{other:?}: {verdict}"),
    }
}

/// Parameters that are off beside an effect, a class the campaign draws since seed 7541
/// (scripts/diagnose_campaign.py, `--draw 2`; until then parameters off were drawn alone). Seed 7523's case 32: an actuator lag of 0.28 s
/// on a P100 whose given model has parameters 3-12 % off (2.0× the floor). The lag is claimed,
/// and whether the parameters are off too is left open beside it (a refit among what is
/// undecided): a claim of the lag on the given parameters, as if they were right, would be
/// false.
#[test]
fn a_lag_beside_parameters_that_are_off_is_claimed_without_clearing_the_parameters() {
    let summary = draw("7523", "32");
    let result = claimed_true(&summary);
    assert_eq!(result["case"]["params_off"], serde_json::json!(true), "{result}");
    assert_eq!(result["cause"], "missing_physics", "{result}");
    assert_eq!(result["found"], serde_json::json!(["actuator_lag"]), "{result}");
    let refit_open = [&result["refit"], &result["undecided_refit"], &result["parameters_open"]]
        .iter()
        .any(|v| v.as_bool() == Some(true));
    assert!(refit_open, "the lag is claimed on parameters that are off, as if they were right: {result}");
}

/// Two false claims of that class on fresh seed 7541, rerun on their own draws. Case 37: 1.5 N
/// of friction with B_U 9 % low and K_TD 6 % high (150 s) was claimed as the friction with a
/// discrepancy (a hinged throttle map and B_TT) standing in for the parameters: the few
/// parameters that are off are now fitted beside the friction in the discrepancy's place, and
/// the friction is claimed with B_U and K_TD refitted. Case 45: an actuator lag of 0.50 s with
/// K_D 11 % off (300 s) was claimed as a lag of 0.53 s on the given parameters, as if they were
/// right, although a refit beside the lag fitted the held-out data better: the lag is claimed,
/// and the verdict now says the recording cannot tell whether the parameters are off as well.
/// Fresh seed 7607's case 85: 1.16 N of friction with K_T, K_D and B_U 5-9 % off (600 s) was
/// claimed as the friction beside a thrust-history gain (τ 10 s) or a gain drift, the
/// parameters not said: the few parameters are now fitted beside the friction in their place,
/// and a refit is among what is undecided beside it. Fresh seed 7757's case 55: 2.1 N of
/// friction on a P220 whose K_T, K_D and B_T are 5-9 % off (200 s, 1.69× the floor) was claimed
/// as the friction with a discrepancy and a sensor drift: on top of the refit, only the effects
/// that helped the physics search's first round were tried, and the friction, fitted at nothing
/// there beside the parameters' error, paid only in its second. Every effect the physics search
/// kept is now tried on top of the refit, and the friction is claimed alone. Fresh seed 7879's
/// case 223: a gain drift of 0.61 %/min on a P220 whose K_D, c and B_T are 6-10 % off was claimed
/// as a discrepancy (the map 13 % flatter above 47.6 %) with a drift of 0.37 %/min. The drift lost
/// the physics search's first round to the discrepancy and paid in its second, so it was never
/// tried on top of the refit; given there at its truth, the refit beat the discrepancy by 8.6
/// standard errors. Every effect that helped any physics round is now tried on top of the refit,
/// and the refit with the drift leads; the case is `ambiguous` against a slow soak. And exact
/// parameters are not claimed off beside a drift the refit took part of (7919/143, below), nor is
/// the size a refit gave the drift reported as settled.
#[test]
fn parameters_off_beside_an_effect_are_refitted_or_left_open_never_passed_as_right() {
    let friction = draw("7541", "37");
    let result = claimed_true(&friction);
    assert_eq!(result["found"], serde_json::json!(["bearing_friction"]), "{result}");
    assert_eq!(result["refit"], serde_json::json!(true), "{result}");
    let lag = draw("7541", "45");
    let result = claimed_true(&lag);
    assert_eq!(result["found"], serde_json::json!(["actuator_lag"]), "{result}");
    assert_eq!(result["parameters_open"], serde_json::json!(true), "{result}");
    assert!(
        result["verdict"].as_str().unwrap_or_default().contains("The parameters are not cleared"),
        "the verdict does not say the parameters are open: {result}"
    );
    let stand_in = draw("7607", "85");
    let result = claimed_true(&stand_in);
    assert_eq!(result["found"], serde_json::json!(["bearing_friction"]), "{result}");
    assert_eq!(result["undecided_refit"], serde_json::json!(true), "{result}");
    let late = draw("7757", "55");
    let result = claimed_true(&late);
    assert_eq!(result["found"], serde_json::json!(["bearing_friction"]), "{result}");
    let drift = draw("7879", "223");
    let result = &drift["results"][0];
    assert_eq!(drift["claims"].as_u64(), drift["true_claims"].as_u64(), "{result}");
    let refit_with_drift = result["rivals"]
        .as_array()
        .into_iter()
        .flatten()
        .chain(std::iter::once(&serde_json::json!([result["found"], result["refit"]])))
        .any(|r| r[0] == serde_json::json!(["gain_drift"]) && r[1] == serde_json::json!(true));
    assert!(refit_with_drift, "the refit with the gain drift is not in play: {result}");
    // The other way: exact parameters claimed off. Fresh seed 7919's case 143, a rate limit with
    // a sensor drift of 4.1 % (τ 119 s) on 150 s, was claimed as the limit, a drift of 1.2 % (τ
    // 26 s) and a refit (none of the ten moved by three standard errors). The drift on the given
    // parameters is now fitted again from its own start grid, and leads.
    let exact = draw("7919", "143");
    let result = claimed_true(&exact);
    assert_eq!(result["case"]["params_off"], serde_json::json!(false), "{result}");
    assert_eq!(result["found"], serde_json::json!(["rate_limit", "sensor_drift"]), "{result}");
    assert_eq!(result["refit"], serde_json::json!(false), "the exact parameters claimed off: {result}");
    // The claim's sizes are the search's fit's, beside the refit (the drift 1.2 %, τ 26 s); the
    // limit and the drift on the given parameters, which lead, hold the drift near its truth.
    let verdict = result["verdict"].as_str().unwrap_or_default();
    assert!(
        verdict.contains("Its size is not settled: rate_limit + sensor_drift"),
        "a size the explanations in play disagree on is reported as settled: {verdict}"
    );
}

/// Parameters off by less than a recording can tell, beside an effect: seed 5003's case 69, an
/// input delay of 0.28 s on 200 s of a P220 whose given `c` is 7.7 % off. A refit beside the delay
/// fits the held-out data no better, so the delay is claimed on the given parameters; the claim
/// used to say nothing of them, as if they were exact. It now says how far each could be off
/// with this recording unable to tell (`parameter_ranges`), and the engine's `c` is inside.
#[test]
fn parameters_off_by_less_than_the_recording_tells_are_bounded_beside_the_claim() {
    let summary = draw("5003", "69");
    let result = claimed_true(&summary);
    assert_eq!(result["case"]["params_off"], serde_json::json!(true), "{result}");
    assert_eq!(result["found"], serde_json::json!(["input_delay"]), "{result}");
    let ranges = result["ranges"].as_object().expect("the parameters' ranges beside a claim on them");
    assert_eq!(ranges.len(), 10, "{result}");
    for (key, engine) in result["case"]["params"].as_object().into_iter().flatten() {
        let (engine, [lo, hi]) = (engine.as_f64().unwrap_or(f64::NAN), [&ranges[key][0], &ranges[key][1]]);
        let (lo, hi) = (lo.as_f64().unwrap_or(f64::NEG_INFINITY), hi.as_f64().unwrap_or(f64::INFINITY));
        assert!((lo..=hi).contains(&engine), "the engine's {key} {engine} outside its range {lo}..{hi}: {result}");
    }
    let verdict = result["verdict"].as_str().unwrap_or_default();
    assert!(verdict.contains("The parameters as given agree with this recording"), "{verdict}");
}

/// A part every explanation in play holds is claimed only where each of them holds it with a
/// size the data can tell from zero. Seed 7559's case 55: an input delay of 67 ms on 100 s of
/// a P100 whose given `K_TD` is 8 % low and `c` 6 % low. Every explanation in play held a gain
/// drift by name, and a drift of 0.4 %/min was claimed; the engine has none. In the leading
/// explanation, the delay beside a refit of `K_TD` and `c`, the drift was 0.09 ± 0.13 %/min:
/// that explanation does not hold it, and fitted without it, it leads: the delay, with `K_TD`
/// and `c` refitted. It was claimed when weighed both ways round; with a zero shift of the
/// sensor beside the model found among the rivals (one jetbench cannot fit the other way
/// round), that second weighing is not made, and the case is `ambiguous` with the delay and
/// the refit leading. Either way, no drift is claimed.
#[test]
fn a_part_one_explanation_in_play_holds_at_no_size_the_data_tell_is_not_claimed() {
    let summary = draw("7559", "55");
    let result = &summary["results"][0];
    assert_eq!(result["case"]["params_off"], serde_json::json!(true), "{result}");
    assert_eq!(summary["claims"].as_u64(), summary["true_claims"].as_u64(), "{result}");
    if summary["claims"].as_u64() == Some(1) {
        assert_eq!(result["found"], serde_json::json!(["input_delay"]), "{result}");
        assert_eq!(result["refit"], serde_json::json!(true), "{result}");
    } else {
        assert_eq!(result["cause"], "ambiguous", "{result}");
        let lead = &result["rivals"][0];
        assert_eq!((&lead[0], &lead[1]), (&serde_json::json!(["input_delay"]), &serde_json::json!(true)), "{result}");
    }
}

/// Sensor drifts whose bias had nearly settled by the held-out part, left `unexplained` on a
/// fresh draw (seed 7573): the "periodic" rival, a sine with a constant beside it, took the
/// settled bias in its constant (its sine held 0.1-0.8 % of the residual's variance) and tied
/// with the drift. A sine is now weighed only where it earns its parameters against the
/// constant alone, and the constant alone is weighed as what it is, a zero shift of the sensor
/// since the tare, where it fits the calibration part about as well as the model found.
/// Case 41 (a drift of 1.1 %, τ 61 s, on 400 s of a P220): the drift is claimed. Case 95 (5.9
/// %, τ 90 s, on 150 s): the bias had nearly settled before the recording began, and the
/// recording cannot tell the drift from a zero shift: `ambiguous` between the two, never a
/// periodic force.
#[test]
fn a_settled_sensor_drift_is_not_taken_for_a_periodic_force() {
    let summary = draw("7573", "41");
    let result = claimed_true(&summary);
    assert_eq!(result["found"], serde_json::json!(["sensor_drift"]), "{result}");
    let names = rival_names(result);
    assert!(!names.contains(&"periodic") && !names.contains(&"sensor_offset"), "{result}");
    let summary = draw("7573", "95");
    let result = &summary["results"][0];
    assert_eq!(result["cause"], "ambiguous", "{result}");
    let names = rival_names(result);
    assert!(names.contains(&"sensor_drift") && names.contains(&"sensor_offset"), "{result}");
    assert!(!names.contains(&"periodic"), "{result}");
}

/// A claim needs what its explanation leaves to be noise. What the whiteness test calls not
/// white but no statistic of the residual locates (no window, class mean, drift, throttle
/// correlation or band of excess power) is noise a little more coloured than its model: seed
/// 7699's case 176, a rate limit on 150 s of coloured noise with spikes, left Ljung–Box p 0.006
/// with the truth itself given, and was `unexplained`. It is claimed now. A residual located
/// somewhere still stops the claim: seed 7741's case 11, bearing friction beside a sensor drift
/// of τ 100 s, both found but the drift's time constant at 36 s, leaves a drift over the run.
/// (Case 81 of seed 7699 stood here until the start inside the play band was fitted: its
/// located residual was that start, and it is a true claim now.)
#[test]
fn a_residual_located_nowhere_does_not_stop_a_claim_and_one_located_does() {
    let limit = draw("7699", "176");
    let result = claimed_true(&limit);
    assert_eq!(result["found"], serde_json::json!(["rate_limit"]), "{result}");
    let both = draw("7741", "11");
    let result = &both["results"][0];
    assert_eq!(result["cause"], "unexplained", "{result}");
    assert_eq!(result["found"], serde_json::json!(["bearing_friction", "sensor_drift"]), "{result}");
    let friction = draw("7699", "81");
    let result = claimed_true(&friction);
    assert_eq!(result["found"], serde_json::json!(["bearing_friction"]), "{result}");
}

/// Two effects that hide each other are fitted as a pair, and a pair's joint fit can trade one
/// into a corner the way adding one effect to another can: seed 7741's case 231, a force sensor
/// drifting 2.4 % (τ 116 s) and an engine losing 0.94 %/min on 300 s of a P220, was `unexplained`.
/// The pair was fitted with the gain drift added to the sensor drift fitted alone, whose time
/// constant went to the edge of what a fit can tell (1000 s), and was no claim. A pair is now
/// fitted the other way round as well when its joint fit pushes the first effect so, and both
/// drifts are claimed at their sizes.
#[test]
fn two_drifts_that_partly_cancel_are_found_together() {
    let both = draw("7741", "231");
    let result = claimed_true(&both);
    assert_eq!(result["found"], serde_json::json!(["gain_drift", "sensor_drift"]), "{result}");
}

/// A frame that sits inside its bearings' play when the recording starts reads where it sits,
/// whatever the engine's starting rate: the start is fitted along the thrust alone there. Seed
/// 7703's case 248 (a 2.93 N band, coloured noise) started 1.7 N high from its first ten samples,
/// and that first hold was located in the residual of the friction found at the truth's MAE.
#[test]
fn a_frame_inside_its_play_band_at_the_start_reads_the_first_seconds_and_the_friction_is_claimed() {
    let friction = draw("7703", "248");
    let result = claimed_true(&friction);
    assert_eq!(result["found"], serde_json::json!(["bearing_friction"]), "{result}");
    let verdict = result["verdict"].as_str().unwrap_or_default();
    assert!(!verdict.contains("Something remains"), "{verdict}");
}

/// The one case of a campaign draw (see [`draw`]), its one claim checked true.
fn claimed_true(summary: &Value) -> &Value {
    let result = &summary["results"][0];
    assert_eq!((summary["claims"].as_u64(), summary["true_claims"].as_u64()), (Some(1), Some(1)), "{result}");
    result
}

/// Every effect name among a campaign result's rivals.
fn rival_names(result: &Value) -> Vec<&str> {
    result["rivals"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|r| r[0].as_array())
        .flatten()
        .filter_map(Value::as_str)
        .collect()
}
