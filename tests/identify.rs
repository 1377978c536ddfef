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

/// config/sim.toml with the turbojet as `[plant]` and `[limits]` replaced by `limits` (the
/// `p100` limit preset is sized to the ten-parameter plant's emulated RPM map, 122 000 rpm
/// at most; this engine runs to 154 000 rpm).
fn turbojet_config(name: &str, limits: &str) -> PathBuf {
    let text = std::fs::read_to_string(common::repo_root().join("config/sim.toml")).unwrap();
    let (head, tail) = text.split_once("\n[plant]").unwrap();
    let tail = tail.replacen("model = \"p100-diesel\"", "model = \"turbojet-p100\"", 1);
    let base = format!("{head}\n[plant]{tail}");
    let base = base.split("\n[limits]").next().unwrap();
    let path = scratch(name);
    std::fs::write(&path, format!("{base}\n[limits]\n{limits}\n")).unwrap();
    path
}

/// The simulated bench runs the turbojet plant: its thrust follows the throttle to the
/// turbojet's rest thrusts (not the ten-parameter model's), and the ECU reports the spool's
/// RPM and exhaust temperature consistent with that thrust.
#[test]
fn the_bench_runs_the_turbojet_plant_and_its_ecu_reports_the_spool() {
    use jetbench_model::turbojet::TurbojetParams;
    use jetbench_msgs::{channels, ecu_states};
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let profile = scratch("turbojet-steps.csv");
    let mut csv = String::from("time_s,throttle_pct\n");
    for k in 0..1400 {
        let u = match k {
            0..=199 => 25.0,
            200..=599 => 100.0,
            600..=999 => 40.0,
            _ => 70.0,
        };
        csv.push_str(&format!("{:.2},{u}\n", k as f64 * 0.01));
    }
    std::fs::write(&profile, csv).unwrap();
    let config = turbojet_config("turbojet.toml", "sensor_silent_s = \"off\"");
    let recording = scratch("turbojet.mcap");
    // A bus namespace of its own: the other live test of this file runs `up` at the same time.
    let (code, out, err) = common::run_jetbench(
        "identtj",
        &[
            "up",
            "--sim",
            "--config",
            &p(&config),
            "--open-loop",
            &p(&profile),
            "--duration",
            "15",
            "--record",
            &p(&recording),
            "--quiet",
        ],
        Duration::from_secs(120),
    );
    assert_eq!(code, 0, "up failed:\n{out}\n{err}");
    let rec = jetbench_record::Recording::open(&recording).unwrap();
    let truth = rec.samples(channels::SIM_TRUTH);
    let ecu: Vec<_> =
        rec.samples(channels::ECU).into_iter().filter(|t| t.flags == 0 && t.state == ecu_states::RUN as u32).collect();
    assert!(truth.len() > 1000 && ecu.len() > 100, "{} truth, {} ECU samples", truth.len(), ecu.len());
    let tj = TurbojetParams::p100();
    // Settled holds (the engine's throttle unchanged for 2 s): the turbojet's rest thrust.
    let mut held = 0usize;
    let mut checked = [false; 3];
    for w in truth.windows(2) {
        held = if (w[1].engine_throttle_pct - w[0].engine_throttle_pct).abs() < 1e-9 { held + 1 } else { 0 };
        let u = w[1].engine_throttle_pct;
        if held >= 250 {
            let want = tj.rest_thrust_n(u);
            assert!((w[1].thrust_n - want).abs() < 0.2, "{u} %: thrust {} N, turbojet at rest {want} N", w[1].thrust_n);
            for (i, level) in [100.0, 40.0, 70.0].iter().enumerate() {
                checked[i] |= (u - level).abs() < 1e-6;
            }
        }
    }
    assert_eq!(checked, [true; 3], "every hold of the profile settled on the bench");
    // The ECU's RPM is the spool's: the speed that gives the true thrust of the same moment.
    let mut worst = 0.0f64;
    let mut top = 0.0f64;
    for t in &ecu {
        let i = truth.partition_point(|s| s.stamp_ns < t.stamp_ns).min(truth.len() - 1);
        let near = &truth[i.saturating_sub(3)..(i + 3).min(truth.len())];
        let gap = near
            .iter()
            .map(|s| (t.rpm - tj.speed_at_thrust(s.thrust_n) * tj.rpm_max).abs())
            .fold(f64::INFINITY, f64::min);
        worst = worst.max(gap);
        top = top.max(t.rpm);
        assert!((300.0..800.0).contains(&t.egt_c), "EGT {} °C", t.egt_c);
    }
    eprintln!("turbojet bench: ECU RPM within {worst:.0} rpm of the spool speed of the true thrust, top {top:.0} rpm");
    assert!(worst < 0.02 * tj.rpm_max, "RPM off the spool's by {worst:.0} rpm");
    assert!(top > 0.97 * tj.rpm_max, "the ECU reports the spool at full speed: {top:.0} rpm");
}

/// `sim-record --plant PLANT` of 60 s (seed 4) without measurement noise into `out`; its
/// standard output.
fn sim_record_noiseless(plant: &str, out: &Path) -> String {
    let out = out.to_str().unwrap();
    let args = ["--duration", "60", "--seed", "4", "--noise-var", "0", "--out", out];
    let (code, stdout, err) = run(&[&["sim-record", "--plant", plant][..], &args].concat(), Duration::from_secs(60));
    assert_eq!(code, 0, "{err}");
    stdout
}

/// `sim-record --plant turbojet-p100` writes the turbojet's run; a plant file with a
/// `[turbojet]` table and effects works the same; a discrepancy is refused.
#[test]
fn sim_record_writes_the_turbojet_plant() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let out = scratch("turbojet-sim.csv");
    let stdout = sim_record_noiseless("turbojet-p100", &out);
    assert!(stdout.contains("6000 samples of turbojet-p100"), "{stdout}");
    let series = jetbench_record::series::Series::load(&out, true).unwrap();
    let tj = jetbench_model::turbojet::TurbojetParams::p100();
    let plant = jetbench_model::Plant::with_turbojet(tj, jetbench_model::Effects::none());
    let mut engine = plant.at_equilibrium(series.u_pct[0]);
    for k in 1..series.len() {
        let want = engine.step(series.u_pct[k - 1]).unwrap().measured_n;
        assert!((series.thrust_n[k] - want).abs() <= 0.006, "row {k}: {} vs {want}", series.thrust_n[k]);
    }
    let file = scratch("plant.toml");
    std::fs::write(&file, "[turbojet]\nbase = \"p100\"\n\n[effects.input_delay]\ndelay_s = 0.08\n").unwrap();
    let delayed = scratch("turbojet-delayed.csv");
    let stdout = sim_record_noiseless(&p(&file), &delayed);
    assert!(stdout.contains("input_delay"), "{stdout}");
    let later = jetbench_record::series::Series::load(&delayed, true).unwrap();
    for k in 0..later.len() - 8 {
        assert!((later.thrust_n[k + 8] - series.thrust_n[k]).abs() <= 0.011, "row {k}: the delay shifts the run");
    }
    let (code, _, err) = run(
        &[
            "sim-record",
            "--plant",
            "turbojet-p100",
            "--effect",
            "discrepancy:map_below=1,knot_below_pct=45",
            "--out",
            &p(&delayed),
        ],
        Duration::from_secs(60),
    );
    assert_ne!(code, 0);
    assert!(err.contains("turbojet"), "{err}");
    // A turbojet paces its spool with its own fuel schedule: a schedule on it is an error.
    let schedule = "accel_schedule:up_n_per_s=300,down_n_per_s=300,exponent=1.5,offset_n=3";
    let (code, _, err) = run(
        &["sim-record", "--plant", "turbojet-p100", "--effect", schedule, "--out", &p(&delayed)],
        Duration::from_secs(60),
    );
    assert_ne!(code, 0);
    assert!(err.contains("--effect accel_schedule") && err.contains("fuel schedule"), "{err}");
}

/// The MAE `jetbench simulate` prints of `model` run on `recording`.
fn simulated_mae_n(model: &Path, recording: &Path) -> f64 {
    let (code, _, err) = run(
        &["simulate", "--model", model.to_str().unwrap(), "--input", recording.to_str().unwrap()],
        Duration::from_secs(60),
    );
    assert_eq!(code, 0, "{err}");
    let at = err.find("MAE ").unwrap_or_else(|| panic!("no MAE in {err}")) + 4;
    err[at..].split_whitespace().next().and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("{err}"))
}

/// Structure that paces the engine: the turbojet's fuel schedule holds its full and mid-size
/// steps to a thrust rate that grows with the thrust, which the ten parameters mimic only as
/// slow dynamics. On this campaign (seed 2) `identify --schedule` paces its model with an
/// acceleration schedule, which pays on held-out data, and the model it writes runs closer to
/// a second campaign of the same engine than the ten parameters it started from. The bench
/// refuses the paced model (its ten parameters alone are not the engine).
#[test]
fn identify_paces_the_turbojet_with_an_acceleration_schedule() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let (first, second) = (scratch("paced-1.csv"), scratch("paced-2.csv"));
    for (seed, out) in [("2", &first), ("1002", &second)] {
        let (code, _, err) = run(
            &["sim-record", "--plant", "turbojet-p100", "--seed", seed, "--duration", "300", "--out", &p(out)],
            Duration::from_secs(120),
        );
        assert_eq!(code, 0, "{err}");
    }
    let written = scratch("paced.toml");
    let (code, out, err) =
        run(&["identify", &p(&first), "--schedule", "--json", "--out", &p(&written)], Duration::from_secs(300));
    assert_eq!(code, 0, "{err}");
    let json: Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("no JSON ({e}): {out}"));
    let structure = &json["structure"];
    assert_eq!(json["terms"], serde_json::json!(["accel_schedule"]), "{}", structure["verdict"]);
    let (refit, extended) = (structure["refit_mae_n"].as_f64().unwrap(), structure["extended_mae_n"].as_f64().unwrap());
    assert!(extended < 0.96 * refit, "held-out MAE {refit} → {extended} N");
    let file = std::fs::read_to_string(&written).unwrap();
    assert!(file.contains("[effects.accel_schedule]") && file.contains("up_n_per_s"), "{file}");
    // The ten parameters it started from, alone.
    let start = &json["methods"][json["best"].as_str().unwrap()]["params"];
    let ten: String = ["K_T", "K_TT", "K_D", "K_DD", "K_TD", "c", "B_U", "B_T", "B_D", "B_UU"]
        .iter()
        .map(|k| format!("{k} = {}\n", start[k].as_f64().unwrap()))
        .collect();
    let ten_file = scratch("ten.toml");
    std::fs::write(&ten_file, format!("[model]\n{ten}")).unwrap();
    let (paced, alone) = (simulated_mae_n(&written, &second), simulated_mae_n(&ten_file, &second));
    assert!(paced < 0.95 * alone, "second campaign: MAE {alone} N alone, {paced} N paced");
}

/// Whatever the recording, a model file `identify --out` writes is bounded over the throttle
/// range (checked here with the plausibility rules), and when it writes none it exits non-zero
/// with the reason: on truncated recordings of the turbojet (an engine the ten parameters do
/// not describe), on the method that diverges most often (LS) and on all.
#[test]
fn identify_writes_a_bounded_model_or_none_with_the_reason() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let (mut written, mut refused) = (0, 0);
    for (seed, seconds) in [(2u64, "40"), (5, "60"), (9, "90")] {
        let run_file = scratch(&format!("truncated-{seed}.csv"));
        let (code, _, err) = run(
            &[
                "sim-record",
                "--plant",
                "turbojet-p100",
                "--duration",
                seconds,
                "--seed",
                &seed.to_string(),
                "--out",
                &p(&run_file),
            ],
            Duration::from_secs(60),
        );
        assert_eq!(code, 0, "{err}");
        for method in ["ls", "all"] {
            let model = scratch(&format!("truncated-{seed}-{method}.toml"));
            let _ = std::fs::remove_file(&model);
            let (code, out, err) =
                run(&["identify", &p(&run_file), "--method", method, "--out", &p(&model)], Duration::from_secs(300));
            eprintln!(
                "seed {seed}, {seconds} s, {method}: exit {code}\n{}",
                out.lines().rev().take(3).collect::<Vec<_>>().join("\n")
            );
            if code == 0 {
                written += 1;
                let file = jetbench_model::ModelFile::load(&model).unwrap_or_else(|e| panic!("{e}\n{out}\n{err}"));
                if file.effects.is_empty() {
                    let check = jetbench_ident::identify::plausibility(&file.model);
                    assert!(check.is_bounded(), "a written model must be bounded: {check:?}\n{out}");
                } else {
                    // Extended by discrepancy terms: the whole model is held to the same rules.
                    let why = jetbench_ident::structure::unbounded_over(&file.plant(), 25.0, 100.0);
                    assert!(why.is_none(), "a written model must be bounded: {why:?}\n{out}");
                }
                assert!(out.contains("model file: the "), "the report says which model the file gets\n{out}");
                // And where to trust it: the held-out error by throttle band and by motion, in
                // the report and in the file's comments.
                assert!(out.contains("where to trust it (held-out free-run MAE over the noise floor"), "{out}");
                let text = std::fs::read_to_string(&model).unwrap();
                assert!(text.contains("\n# where to trust it: ") && text.contains("\n#   75–100 %: "), "{text}");
            } else {
                refused += 1;
                assert!(!model.exists(), "nothing is written when nothing is bounded");
                assert!(err.contains("nothing written") && err.contains("bounded"), "the reason: {err}");
            }
        }
    }
    eprintln!("bounded models written {written}, refused with the reason {refused}");
}

/// The iRonCub group's 13-coefficient jet on the command line: `sim-record --plant ironcub
/// --signal ironcub` records 544 s over 0–100 %, and `identify --out` writes the ten
/// parameters extended by input-gain terms, saying which and why.
#[test]
fn identify_extends_the_model_of_an_ironcub_recording() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let run_file = scratch("ironcub.csv");
    let args = ["sim-record", "--plant", "ironcub", "--signal", "ironcub", "--seed", "3", "--noise-var", "9"];
    let (code, stdout, err) = run(&[&args[..], &["--out", &p(&run_file)]].concat(), Duration::from_secs(60));
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("54400 samples of ironcub"), "{stdout}");
    let model = scratch("ironcub.toml");
    let _ = std::fs::remove_file(&model);
    let (code, out, err) =
        run(&["identify", &p(&run_file), "--method", "ls", "--out", &p(&model)], Duration::from_secs(300));
    assert_eq!(code, 0, "{out}\n{err}");
    eprintln!("{}", out.lines().rev().take(6).collect::<Vec<_>>().join("\n"));
    assert!(out.contains("structure: the ten parameters extended by"), "{out}");
    let text = std::fs::read_to_string(&model).unwrap();
    assert!(text.contains("# Structure chosen by the data") && text.contains("[effects.discrepancy]"), "{text}");
    let file = jetbench_model::ModelFile::load(&model).unwrap();
    let disc = file.effects.get(jetbench_model::EffectKind::Discrepancy).unwrap().values().to_vec();
    assert!(disc[6..9].iter().any(|&b| b != 0.0), "an input-gain term: {text}");
    assert!(jetbench_ident::structure::unbounded_over(&file.plant(), 0.0, 100.0).is_none());
}
