//! `diagnose` in the library: a concealed delay found, fitted and removed; a model
//! that explains its data left alone; an identified model of clean data left alone.

use jetbench_ident::diagnose::{diagnose, Options};
use jetbench_ident::{excite, ls, synth};
use jetbench_model::{Effect, EffectKind, Effects, ModelFile, Plant, Preset};

fn recording(plant: &Plant, seed: u64) -> jetbench_ident::series::Series {
    synth::record_plant(plant, &excite::campaign(200.0, seed).profile, 7.0, seed + 1).expect("recording")
}

#[test]
fn a_concealed_delay_is_named_fitted_and_removed() {
    let params = Preset::P220Kerosene.params();
    let delay: Effect = "input_delay:delay_s=0.12".parse().unwrap();
    let data = [recording(&Plant::new(params, Effects::new([delay]).unwrap()), 5)];
    let d = diagnose(&ModelFile::new(params), &data, &Options::default(), &mut |_| {}).unwrap();
    assert_eq!(d.effects.len(), 1, "{}", d.verdict);
    assert_eq!(d.effects[0].name, "input_delay");
    let fitted = d.effects[0].params["delay_s"];
    let error = d.effects[0].uncertainty["delay_s"];
    assert!((fitted - 0.12).abs() < 0.01, "{fitted}");
    assert!(error > 0.0 && (fitted - 0.12).abs() < 4.0 * error, "{fitted} ± {error}");
    assert!(d.mae_before_n > 1.05 * d.noise_floor_n && d.mae_after_n < 1.02 * d.noise_floor_n, "{}", d.verdict);
    assert!(!d.before.whiteness.white && d.after.whiteness.white);
    assert!(d.verdict.contains("input delay"), "{}", d.verdict);
    assert_eq!(d.improved.effects.get(EffectKind::InputDelay).map(|e| e.values()[0]), Some(fitted));
    // The improved model file reads back with its effect.
    let back = ModelFile::from_toml_str(&d.improved.to_toml_string()).unwrap();
    assert_eq!(back, d.improved);
}

#[test]
fn a_model_that_explains_the_data_gets_nothing() {
    let params = Preset::P100Diesel.params();
    let data = [recording(&Plant::new(params, Effects::none()), 8)];
    let d = diagnose(&ModelFile::new(params), &data, &Options::default(), &mut |_| {}).unwrap();
    assert!(d.effects.is_empty(), "{}", d.verdict);
    assert!(d.before.whiteness.white, "{:?}", d.before.whiteness);
    assert!(d.verdict.starts_with("Nothing left out"), "{}", d.verdict);
    assert_eq!(d.improved, ModelFile::new(params));

    // The same data through a model identified from it: still nothing to add.
    let identified = ls::fit(&data, &ls::LsOptions::default()).unwrap().params;
    let d = diagnose(&ModelFile::new(identified), &data, &Options::default(), &mut |_| {}).unwrap();
    assert!(d.effects.is_empty(), "{}", d.verdict);
}
