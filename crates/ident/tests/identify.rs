//! Identification on synthetic recordings of plants in and outside the model
//! structure: the acceptance figures of LS and EKF against the noise floor.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_ident::excite::{campaign, ironcub_signal};
use jetbench_ident::identify::{hold_out, identify, Method, Options, POOR_FIT_RATIO};
use jetbench_ident::series::Series;
use jetbench_ident::{synth, validate};
use jetbench_model::ironcub::IronCubJet;
use jetbench_model::{Effects, Engine, Plant, Preset};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn check_within_noise_floor(preset: Preset, noise_var: f64, campaign_seed: u64) {
    let profile = campaign(300.0, campaign_seed).profile;
    let recording = synth::record(&preset.params(), &profile, noise_var, campaign_seed + 17).unwrap();
    let (cal, val) = hold_out(&[recording], 0.3);
    let options = Options { methods: vec![Method::Ls, Method::Ekf], ..Options::default() };
    let report = identify(&cal, &val, &options, |_, _| {}).unwrap();
    let floor = report.noise.mae_n;
    let expected_floor = (noise_var * 2.0 / std::f64::consts::PI).sqrt();
    assert!((floor - expected_floor).abs() < 0.03 * expected_floor, "floor {floor} vs {expected_floor}");
    for method in [Method::Ls, Method::Ekf] {
        let r = report.results.iter().find(|r| r.method == method).unwrap();
        let mae = r.validation_score.unwrap().mae_n;
        println!(
            "{preset:?} noise {noise_var} campaign {campaign_seed}: {} MAE {mae:.3} N, floor {floor:.3} N",
            method.name()
        );
        assert!(mae <= 1.10 * floor, "{preset:?} {}: MAE {mae:.3} N vs floor {floor:.3} N", method.name());
        assert!(r.plausibility.warnings.is_empty(), "{:?}", r.plausibility.warnings);
    }
    assert!(report.verdict.starts_with("good fit"), "{}", report.verdict);
    // No false structure: the plant is the ten parameters, so no term of the library pays.
    let structure = report.structure.as_ref().unwrap().as_ref().unwrap();
    println!("structure: {}", structure.verdict);
    assert!(report.chosen_structure().is_none() && structure.chosen.is_empty(), "{}", structure.verdict);
}

/// Structure chosen by the data: the iRonCub group's 13-coefficient jet (input gain in
/// T², Ṫ² and T·Ṫ), driven by a 544 s signal over 0–100 %, makes `identify` extend the ten
/// parameters by input-gain terms, and the extension is better on a second run.
#[test]
fn the_ironcub_jet_makes_identify_choose_input_gain_terms() {
    let plant = IronCubJet::published().plant();
    let record = |seed: u64| synth::record_plant(&plant, &ironcub_signal(seed).profile, 9.0, seed + 17).unwrap();
    let (cal, val) = hold_out(&[record(1)], 0.3);
    let options = Options { methods: vec![Method::Ls], ..Options::default() };
    let report = identify(&cal, &val, &options, |_, _| {}).unwrap();
    let structure = report.structure.as_ref().unwrap().as_ref().unwrap();
    println!("structure: {}", structure.verdict);
    let chosen = report.chosen_structure().expect("input-gain terms chosen");
    assert!(chosen.chosen.iter().any(|t| ["B_TT", "B_DD", "B_TD"].contains(&t.key)), "{}", structure.verdict);
    assert!(chosen.chosen.iter().all(|t| t.held_out_gain > 0.0), "{:?}", chosen.chosen);
    let text = report.model_file_text().unwrap();
    assert!(text.contains("[effects.discrepancy]") && text.contains("held-out score"), "{text}");
    // On a second run of the same engine (another signal, fresh noise) the extension wins.
    let second = record(2);
    let (_, ten) = report.best_params().unwrap();
    let extended = chosen.model.as_ref().unwrap().plant();
    let mae = |plant: &Plant| {
        let sim = validate::simulate(plant, std::slice::from_ref(&second));
        sim.score(std::slice::from_ref(&second)).unwrap().mae_n
    };
    let (ten_mae, ext_mae) = (mae(&Plant::new(ten, Effects::none())), mae(&extended));
    println!("second run: ten parameters {ten_mae:.3} N, extended {ext_mae:.3} N, floor {:.3} N", report.noise.mae_n);
    assert!(ext_mae < ten_mae, "extended {ext_mae:.3} N vs ten parameters {ten_mae:.3} N");
}

#[test]
fn default_plant_default_campaign() {
    check_within_noise_floor(Preset::P100Diesel, 7.0, 1);
}

#[test]
fn kerosene_plant_other_campaign_more_noise() {
    check_within_noise_floor(Preset::P220Kerosene, 9.0, 2);
}

#[test]
fn default_plant_third_campaign() {
    check_within_noise_floor(Preset::P100Diesel, 7.0, 3);
}

/// A plant outside the structure: the engine follows the throttle 0.3 s late
/// (ECU processing and fuel transport) and through a 0.3 s first-order lag
/// (fuel pump), which no ten-parameter model has.
#[test]
fn plant_outside_the_structure_is_called_a_poor_fit() {
    let params = Preset::P100Diesel.params();
    let profile = campaign(300.0, 5).profile;
    let mut engine = Engine::at_equilibrium(params, profile.u_pct[0]);
    let delay = 30; // samples
    let mut lagged = profile.u_pct[0];
    let noise = Normal::new(0.0, 7f64.sqrt()).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let mut thrust_n = Vec::new();
    for k in 0..profile.len() {
        thrust_n.push(engine.state().thrust_n + noise.sample(&mut rng));
        lagged += (profile.u_pct[k.saturating_sub(delay)] - lagged) * 0.01 / 0.3;
        engine.step(lagged).unwrap();
    }
    let recording = Series { name: "delayed plant".into(), thrust_n, ..profile };
    let (cal, val) = hold_out(&[recording], 0.3);
    let report = identify(&cal, &val, &Options::default(), |_, _| {}).unwrap();
    let best = report.results.iter().filter_map(|r| r.validation_score).map(|s| s.mae_n).fold(f64::MAX, f64::min);
    println!("{}", report.verdict);
    assert!(best > POOR_FIT_RATIO * report.noise.mae_n, "best {best} vs floor {}", report.noise.mae_n);
    assert!(report.verdict.contains("the fit is poor"), "{}", report.verdict);
    assert!(report.verdict.contains(&format!("{:.2} N", report.noise.mae_n)), "{}", report.verdict);
    // A poor fit makes the refinement run without being asked, and its model competes with
    // the others on held-out data: the best is never worse than the methods' own.
    let why = report.repair.as_deref().unwrap_or_default();
    assert!(
        why.starts_with("the best bounded model's validation MAE is") || why.starts_with("no chosen method"),
        "why the refinement ran: {why:?}"
    );
    let refined = report.results.iter().find(|r| r.method == Method::Oe).expect("the refinement ran");
    println!("refinement: {why}; its validation MAE {:?}", refined.validation_score.map(|s| s.mae_n));
    let others = report.results.iter().filter(|r| r.method != Method::Oe && r.is_bounded_params());
    let written = report.best_params().map(|(r, _)| r.validation_score.unwrap().mae_n).unwrap();
    for r in others {
        assert!(written <= r.validation_score.unwrap().mae_n, "{} beats the written model", r.method.name());
    }
}

/// Structure chosen by the data on the way in: a P100 engine that follows its throttle
/// through a 0.3 s first-order lag (a slow fuel pump, which no ten-parameter model has)
/// makes `identify` add the catalogue's actuator lag, near the truth, and the extension
/// reaches the floor where the ten parameters alone do not.
#[test]
fn a_lagged_throttle_makes_identify_choose_an_actuator_lag() {
    let effects = Effects::new(["actuator_lag:time_constant_s=0.3".parse().unwrap()]).unwrap();
    let plant = Plant::new(Preset::P100Diesel.params(), effects);
    let run = synth::record_plant(&plant, &campaign(300.0, 4).profile, 7.0, 21).unwrap();
    let (cal, val) = hold_out(&[run], 0.3);
    let options = Options { methods: vec![Method::Ls], ..Options::default() };
    let report = identify(&cal, &val, &options, |_, _| {}).unwrap();
    let structure = report.structure.as_ref().unwrap().as_ref().unwrap();
    println!("structure: {}", structure.verdict);
    let chosen = report.chosen_structure().expect("a throttle-path effect chosen");
    let lag = chosen.chosen.iter().find(|t| t.key == "actuator_lag").expect("the actuator lag");
    assert!((lag.value - 0.3).abs() <= 0.25 * 0.3, "time constant {} s against 0.3 s", lag.value);
    let floor = report.noise.mae_n;
    let extended = chosen.extended_mae_n.unwrap();
    assert!(extended <= 1.05 * floor, "extended {extended:.3} N against the floor {floor:.3} N");
    assert!(chosen.refit_mae_n > extended, "ten parameters {:.3} N, extended {extended:.3} N", chosen.refit_mae_n);
    let text = report.model_file_text().unwrap();
    assert!(text.contains("[effects.actuator_lag]") && text.contains("held-out score"), "{text}");
}
