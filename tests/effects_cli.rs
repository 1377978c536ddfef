//! Plant effects on the command line: `jetbench sim-record --effect` records the
//! plant with the effect, `jetbench simulate` of a model file with the same
//! `[effects.*]` table reproduces it, and bad effect specs are clear errors.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::PathBuf;
use std::time::Duration;

use jetbench_model::{Effects, ModelFile, Preset};

mod common;

const SUITE: &str = "effects";

fn scratch(name: &str) -> PathBuf {
    common::scratch(SUITE, name)
}

/// Runs `jetbench ARGS` to completion under the watchdog: exit code, stdout, stderr.
fn run(args: &[&str]) -> (i32, String, String) {
    common::run_jetbench(SUITE, args, Duration::from_secs(120))
}

fn run_ok(args: &[&str]) -> String {
    let (code, out, err) = run(args);
    assert_eq!(code, 0, "jetbench {args:?} failed:\n{err}");
    out
}

/// Column `name` of a CSV file with a header row.
fn column(path: &PathBuf, name: &str) -> Vec<f64> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let c = header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("no column {name} in {header:?}"));
    lines.map(|l| l.split(',').nth(c).expect("field").parse().expect("number")).collect()
}

fn mae(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
}

#[test]
fn an_effect_on_the_command_line_is_reproduced_by_a_model_file_with_it() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let (delayed, nominal, truth) = (scratch("delayed.csv"), scratch("nominal.csv"), scratch("delayed-truth.csv"));
    let common = ["sim-record", "--model", "p100-diesel", "--duration", "60", "--seed", "2"];
    let delay = ["--effect", "input_delay:delay_s=0.1"];
    let out = run_ok(&[&common[..], &delay, &["--out", &p(&delayed)]].concat());
    assert!(out.contains("input_delay:delay_s=0.1"), "the summary names the effect: {out}");
    run_ok(&[&common[..], &["--out", &p(&nominal)]].concat());
    // Same campaign and plant, no noise: what the sensor read before the noise was added.
    run_ok(&[&common[..], &delay, &["--noise-var", "0", "--out", &p(&truth)]].concat());
    let measured = column(&delayed, "thrust_n");
    assert_ne!(measured, column(&nominal, "thrust_n"), "the delay changes the recording");

    let mut file = ModelFile::new(Preset::P100Diesel.params());
    file.effects = Effects::new(["input_delay:delay_s=0.1".parse().unwrap()]).unwrap();
    let model = scratch("p100-delayed.toml");
    file.save(&model).unwrap();
    assert!(std::fs::read_to_string(&model).unwrap().contains("[effects.input_delay]"));

    let simulate = |model: &str, name: &str| {
        let out = scratch(name);
        run_ok(&["simulate", "--model", model, "--input", &p(&delayed), "--out", &p(&out)]);
        column(&out, "thrust_n")
    };
    let with_effect = simulate(&p(&model), "sim-delayed.csv");
    let without = simulate("p100-diesel", "sim-nominal.csv");
    let truth = column(&truth, "thrust_n");
    let (mae_with, mae_without) = (mae(&with_effect, &measured), mae(&without, &measured));
    // White noise of variance 7 N²: mean absolute value sqrt(7·2/π) = 2.11 N.
    assert!((1.9..2.3).contains(&mae_with), "with the effect: MAE {mae_with:.3} N, the noise level");
    assert!(mae_without > mae_with + 0.05, "without the effect: MAE {mae_without:.3} N vs {mae_with:.3} N");
    let (err_with, err_without) = (mae(&with_effect, &truth), mae(&without, &truth));
    assert!(err_with < 0.05, "with the effect the noise-free plant is reproduced: MAE {err_with:.4} N");
    assert!(err_without > 0.2, "without it, it is not: MAE {err_without:.4} N");
}

#[test]
fn bad_effect_specs_are_clear_errors() {
    let out = scratch("never.csv");
    for (spec, names) in [
        ("input_dealy:delay_s=0.1", ["input_dealy", "unknown effect"]),
        ("input_delay:delay_s=abc", ["abc", "not a number"]),
        ("input_delay:delay_s=99", ["99", "out of range"]),
    ] {
        let args = ["sim-record", "--model", "p100-diesel", "--duration", "10", "--effect", spec];
        let (code, _, err) = run(&[&args[..], &["--out", out.to_str().unwrap()]].concat());
        assert!(code != 0 && code != -1, "{spec}: exit code {code}");
        assert!(!err.contains("panicked"), "{spec}: {err}");
        for name in names {
            assert!(err.contains(name), "{spec}: the message names `{name}`: {err}");
        }
        assert!(!out.exists(), "{spec}: no output written");
    }
}

#[test]
fn resonance_and_discrepancy_run_in_simulate_as_in_sim_record() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    for (i, spec) in [
        "stand_resonance:frequency_hz=1.5,damping_ratio=0.05",
        "discrepancy:map_below=1,knot_below_pct=40",
        "discrepancy:gain_history_per_n=-0.0005,history_time_constant_s=30,B_TT=2e-6",
    ]
    .into_iter()
    .enumerate()
    {
        let truth = scratch(&format!("new-effect-{i}.csv"));
        let common = ["sim-record", "--model", "p100-diesel", "--duration", "60", "--seed", "5", "--noise-var", "0"];
        run_ok(&[&common[..], &["--effect", spec, "--out", &p(&truth)]].concat());
        let mut file = ModelFile::new(Preset::P100Diesel.params());
        file.effects = Effects::new([spec.parse().unwrap()]).unwrap();
        let model = scratch(&format!("new-effect-{i}.toml"));
        file.save(&model).unwrap();
        let simulate = |model: &str, name: &str| {
            let out = scratch(name);
            run_ok(&["simulate", "--model", model, "--input", &p(&truth), "--out", &p(&out)]);
            column(&out, "thrust_n")
        };
        let measured = column(&truth, "thrust_n");
        let with_effect = simulate(&p(&model), &format!("sim-new-{i}.csv"));
        let without = simulate("p100-diesel", &format!("sim-new-nominal-{i}.csv"));
        let (err_with, err_without) = (mae(&with_effect, &measured), mae(&without, &measured));
        assert!(err_with < 0.05, "{spec}: the model file reproduces the recording (MAE {err_with:.4} N)");
        assert!(err_without > 0.1, "{spec}: without it, it does not (MAE {err_without:.4} N)");
    }
}

#[test]
fn sim_record_adds_bench_artefacts_and_refuses_unstable_noise() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let common = ["sim-record", "--model", "p100-diesel", "--duration", "60", "--seed", "6"];
    let (clean, messy) = (scratch("clean.csv"), scratch("messy.csv"));
    run_ok(&[&common[..], &["--out", &p(&clean)]].concat());
    let artefacts = ["--noise-ar", "0.6", "--spikes", "0.01", "--drop", "0.02"];
    run_ok(&[&common[..], &artefacts, &["--out", &p(&messy)]].concat());
    let (rows, kept) = (column(&clean, "time_s").len(), column(&messy, "time_s").len());
    let lost = rows - kept;
    assert!((60..200).contains(&lost), "{lost} of {rows} rows lost at 2 %");
    // A spike stands out from both neighbours, the same way.
    let spikes = column(&messy, "thrust_n")
        .windows(3)
        .filter(|w| {
            let (a, b) = (w[1] - w[0], w[1] - w[2]);
            a.abs() > 12.0 && b.abs() > 12.0 && a.signum() == b.signum()
        })
        .count();
    assert!((20..100).contains(&spikes), "{spikes} spikes at 1 %");
    let out = scratch("never.csv");
    for bad in [["--noise-ar", "1.0"], ["--spikes", "2"]] {
        let (code, _, err) = run(&[&common[..], &bad, &["--out", &p(&out)]].concat());
        assert!(code != 0 && code != -1 && !err.contains("panicked"), "{bad:?}: {code} {err}");
        assert!(err.contains("noise_ar") || err.contains("spike"), "{bad:?}: the message names it: {err}");
    }
}

#[test]
fn diagnose_writes_the_model_it_found() {
    let p = |x: &PathBuf| x.to_str().unwrap().to_owned();
    let suite = common::repo_root().join("recordings").join("scenarios");
    // Parameters off: the refitted parameters, no effect.
    let refitted = scratch("refitted.toml");
    let params = suite.join("params-p100.csv");
    run_ok(&["diagnose", "--model", "p100-diesel", &p(&params), "--out", &p(&refitted)]);
    let file = ModelFile::load(&refitted).unwrap();
    assert!(file.effects.is_empty(), "no physics: {}", file.effects);
    assert_ne!(file.model, Preset::P100Diesel.params(), "the parameters are refitted");
    // A dead band outside the catalogue: a discrepancy that simulate runs.
    let improved = scratch("dead-band.toml");
    let recording = suite.join("dead-band-p100.csv");
    run_ok(&["diagnose", "--model", "p100-diesel", &p(&recording), "--out", &p(&improved)]);
    let text = std::fs::read_to_string(&improved).unwrap();
    assert!(text.contains("[effects.discrepancy]") && text.contains("knot_below_pct"), "{text}");
    let simulated = |model: &str, name: &str| {
        let out = scratch(name);
        run_ok(&["simulate", "--model", model, "--input", &p(&recording), "--out", &p(&out)]);
        mae(&column(&out, "thrust_n"), &column(&out, "measured_n"))
    };
    let (with, without) = (simulated(&p(&improved), "dead-band-sim.csv"), simulated("p100-diesel", "preset-sim.csv"));
    assert!(with < without - 0.05, "the improved model fits better: MAE {with:.3} N vs {without:.3} N");
}
