//! Choosing the controller, its model and the reference on the command line, end to end:
//! `jetbench up --sim --controller ... --model ... --plant ... --profile ...` with real
//! processes, scored by `jetbench metrics`; and the mistakes a user can make doing it.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde_json::Value;

mod common;

const SUITE: &str = "control";

fn p(path: &Path) -> &str {
    path.to_str().expect("UTF-8 path")
}

/// Runs `jetbench ARGS` under the watchdog: exit code, stdout, stderr.
fn jetbench(args: &[&str], limit_s: u64) -> (i32, String, String) {
    common::run_jetbench(SUITE, args, Duration::from_secs(limit_s))
}

/// `jetbench up --sim --quiet --record FILE ARGS`, which must succeed; the recording.
/// Each test's service sets get their own bus namespace (`bus`), as tests run at once.
fn up(bus: &str, name: &str, args: &[&str]) -> PathBuf {
    let record = common::scratch(SUITE, name);
    let args = [&["up", "--sim", "--quiet", "--record", p(&record)], args].concat();
    let what = format!("jetbench {args:?}");
    let mut command = common::jetbench(&format!("{SUITE}{bus}"));
    let (status, _, err) = common::run(command.args(&args), Duration::from_secs(180), &what);
    assert!(status.success(), "{what} failed:\n{err}");
    record
}

fn metrics(record: &Path) -> Value {
    let (code, out, err) = jetbench(&["metrics", "--json", "--skip", "1", p(record)], 60);
    assert_eq!(code, 0, "jetbench metrics failed:\n{err}");
    let runs: Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(runs.as_array().map(Vec::len), Some(1), "one run: {runs}");
    runs[0].clone()
}

fn number(run: &Value, key: &str) -> f64 {
    run["metrics"][key].as_f64().unwrap_or_else(|| panic!("metrics.{key}: {}", run["metrics"][key]))
}

/// The MPC on a plant with an input delay, with the model that knows it, on the built-in
/// steps (which saturate the throttle): it runs in the live loop, is recorded as the MPC
/// with its solve times, tracks, and holds the levels.
#[test]
fn mpc_with_a_delay_aware_model_tracks_the_steps_live() {
    let dir = common::scratch(SUITE, "models");
    std::fs::create_dir_all(&dir).unwrap();
    let plant = dir.join("delayed.toml");
    let mut file = jetbench_model::ModelFile::new(jetbench_model::Preset::P100Diesel.params());
    file.effects = jetbench_model::Effects::new(["input_delay:delay_s=0.1".parse().unwrap()]).unwrap();
    file.save(&plant).unwrap();
    let record = up(
        "mpc",
        "mpc.mcap",
        &["--duration", "16", "--controller", "mpc", "--plant", p(&plant), "--model", p(&plant), "--profile", "steps"],
    );
    let run = metrics(&record);
    assert_eq!(run["controller"], "mpc");
    let cycles = number(&run, "samples");
    assert!(cycles > 1300.0, "{cycles} cycles");
    // A solve failure falls back to FBL and is counted; on a loaded CI machine a few may.
    let fallbacks = number(&run, "fallbacks");
    assert!(fallbacks < 0.05 * cycles, "{fallbacks} fallbacks in {cycles} cycles");
    let solve = &run["metrics"]["solve_us"];
    assert!(solve["p50"].as_u64().unwrap() > 0, "solve times recorded: {solve}");
    let mae_n = number(&run, "mae_n");
    assert!(mae_n < 3.0, "MAE {mae_n:.2} N");
    // Holds at 50 and 30 % of the range (the first starts from idle).
    let holds = run["metrics"]["holds"].as_array().expect("holds");
    assert!(holds.len() >= 2, "{holds:?}");
    for hold in &holds[1..] {
        let e = hold["steady_state_error_pct"].as_f64().unwrap();
        assert!(e.abs() < 5.0, "steady-state error {e:.2} % on {hold}");
    }
}

/// Sliding mode with gains from a config file: the run is recorded as SMC, and the
/// study's gains, put back in a copy of config/sim.toml (which ships gains tuned for the
/// sensor noise), show in the throttle.
#[test]
fn smc_gains_come_from_the_config() {
    let config = common::repo_root().join("config/sim.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    let dir = common::scratch(SUITE, "configs");
    std::fs::create_dir_all(&dir).unwrap();
    let study_config = dir.join("smc-study.toml");
    let study_text = text.replace("a1 = 10.0\nbeta = 100.0\nk = 0.05", "a1 = 20.0\nbeta = 900.0\nk = 0.15");
    assert_ne!(study_text, text, "config/sim.toml ships the tuned SMC gains");
    std::fs::write(&study_config, study_text).unwrap();
    let study = up("smc", "smc-study.mcap", &["--duration", "6", "--controller", "smc", "--config", p(&study_config)]);
    let tuned = up("smc", "smc-tuned.mcap", &["--duration", "6", "--controller", "smc"]);
    let (study, tuned) = (metrics(&study), metrics(&tuned));
    assert_eq!(study["controller"], "smc");
    // The study's switching amplitude spans the throttle range: the throttle spends most
    // of its time at a limit; the tuned gains keep it inside.
    let (sat_study, sat_tuned) = (number(&study, "saturation_pct"), number(&tuned, "saturation_pct"));
    assert!(sat_tuned < 0.6 * sat_study, "at a limit {sat_tuned:.0} % of the time tuned vs {sat_study:.0} %");
}

#[test]
fn mistakes_are_explained() {
    let (code, _, err) = jetbench(&["up", "--sim", "--duration", "1", "--controller", "pid"], 30);
    assert_ne!(code, 0);
    assert!(err.contains("pid") && err.contains("mpc"), "{err}");

    let (code, _, err) = jetbench(&["up", "--sim", "--duration", "1", "--profile", "square"], 30);
    assert_ne!(code, 0);
    assert!(err.contains("square") && err.contains("campaign"), "{err}");

    let (code, _, err) = jetbench(&["up", "--config", "config/sim.toml", "--plant", "p220-kerosene"], 30);
    assert_ne!(code, 0);
    assert!(err.contains("--sim"), "{err}");

    let text = std::fs::read_to_string(common::repo_root().join("config/sim.toml")).unwrap();
    let dir = common::scratch(SUITE, "configs-bad");
    std::fs::create_dir_all(&dir).unwrap();
    for (bad, key) in [
        (text.replace("horizon_s = 0.8", "horizon = 0.8"), "horizon"),
        (text.replace("moves = 10", "moves = 0"), "moves"),
        (text.replace("controller = \"fbl\"", "controller = \"lqr\""), "lqr"),
    ] {
        let path = dir.join(format!("{key}.toml"));
        std::fs::write(&path, bad).unwrap();
        let (code, _, err) = jetbench(&["up", "--sim", "--duration", "1", "--config", p(&path)], 30);
        assert_ne!(code, 0, "{key}");
        assert!(err.contains(key), "the error names {key}: {err}");
    }

    let (code, _, err) = jetbench(&["up", "--sim", "--duration", "1", "--model", "no-such-model.toml"], 30);
    assert_ne!(code, 0);
    assert!(err.contains("no-such-model.toml"), "{err}");
}
