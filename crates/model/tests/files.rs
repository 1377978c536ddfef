//! Model files, presets and model specs.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use std::path::PathBuf;

use jetbench_model::{resolve_params, EffectKind, ModelError, ModelFile, Params, Preset};

fn temp_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("jetbench-model-{}-{name}.toml", std::process::id()))
}

#[test]
fn model_file_round_trip_is_exact() {
    let mut sets: Vec<Params> = Preset::ALL.iter().map(Preset::params).collect();
    sets.push(Params::from_array([
        0.1 + 0.2,
        -0.0,
        1e-300,
        -1.7976931348623157e308,
        5e-324,
        1.0 / 3.0,
        1e16,
        123456789.0,
        -2.5e-7,
        0.0,
    ]));
    for params in sets {
        let text = ModelFile::new(params).to_toml_string();
        let back = ModelFile::from_toml_str(&text).unwrap();
        assert_eq!(back.model.to_array().map(f64::to_bits), params.to_array().map(f64::to_bits), "{text}");
        assert!(back.effects.is_empty());
    }
}

#[test]
fn typo_key_is_a_parse_error_naming_the_key() {
    let text = ModelFile::new(Preset::P100Diesel.params()).to_toml_string().replace("K_TT =", "K_TTT =");
    let err = ModelFile::from_toml_str(&text).unwrap_err();
    assert!(matches!(err, ModelError::Parse { ref path, .. } if path == "<string>"));
    assert!(err.to_string().contains("K_TTT"), "{err}");
}

#[test]
fn missing_key_and_unknown_table_are_parse_errors() {
    let text = ModelFile::new(Preset::P100Diesel.params()).to_toml_string();
    let missing = text.replace("B_UU = 0.013878\n", "");
    let err = ModelFile::from_toml_str(&missing).unwrap_err();
    assert!(err.to_string().contains("B_UU"), "{err}");
    let extra = format!("{text}\n[modle]\nx = 1\n");
    let err = ModelFile::from_toml_str(&extra).unwrap_err();
    assert!(err.to_string().contains("modle"), "{err}");
}

#[test]
fn effects_round_trip_and_bad_effects_are_errors_naming_them() {
    let base = ModelFile::new(Preset::P100Diesel.params()).to_toml_string();
    let text = format!(
        "{base}\n[effects.input_delay]\ndelay_s = 0.05\n\n[effects.rate_limit]\nup_pct_per_s = 60\ndown_pct_per_s = 120.5\n"
    );
    let file = ModelFile::from_toml_str(&text).unwrap();
    assert_eq!(file.effects.len(), 2);
    assert_eq!(file.effects.get(EffectKind::RateLimit).unwrap().values(), &[60.0, 120.5]);
    let back = ModelFile::from_toml_str(&file.to_toml_string()).unwrap();
    assert_eq!(back, file);
    for (bad, needle) in [
        ("[effects.input_dealy]\ndelay_s = 0.05\n", "input_dealy"),
        ("[effects.input_delay]\ndelay = 0.05\n", "delay"),
        ("[effects.input_delay]\ndelay_s = \"fast\"\n", "string"),
        ("[effects.actuator_lag]\n", "time_constant_s"),
        ("[effects.bearing_friction]\nforce_n = -1.0\n", "force_n"),
    ] {
        let err = ModelFile::from_toml_str(&format!("{base}\n{bad}")).unwrap_err();
        assert!(err.to_string().contains(needle), "{bad}: {err}");
    }
}

#[test]
fn non_finite_parameter_in_file_is_rejected() {
    let text = ModelFile::new(Preset::P100Diesel.params()).to_toml_string().replace("c = -19.926756", "c = nan");
    let err = ModelFile::from_toml_str(&text).unwrap_err();
    assert!(matches!(err, ModelError::NonFinite { name: "c", .. }), "{err}");
}

#[test]
fn save_and_load_and_resolve_a_file() {
    let path = temp_path("save");
    let params = Preset::P220Ekf.params();
    ModelFile::new(params).save(&path).unwrap();
    assert_eq!(ModelFile::load(&path).unwrap().model, params);
    let spec = path.to_str().unwrap();
    assert_eq!(resolve_params(spec).unwrap(), params);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn load_errors_carry_the_path() {
    let path = temp_path("broken");
    std::fs::write(&path, "[model]\nK_T = \n").unwrap();
    let err = ModelFile::load(&path).unwrap_err();
    assert!(err.to_string().contains(path.to_str().unwrap()), "{err}");
    std::fs::remove_file(&path).unwrap();
    let err = ModelFile::load(&path).unwrap_err();
    assert!(matches!(err, ModelError::Io { .. }), "{err}");
}

#[test]
fn presets_parse_by_name_and_unknown_names_list_valid_ones() {
    for preset in Preset::ALL {
        assert_eq!(preset.name().parse::<Preset>().unwrap(), preset);
        assert_eq!(preset.to_string(), preset.name());
        assert!(!preset.describe().is_empty());
        assert!(preset.params().validate().is_ok());
    }
    assert_eq!(Preset::default(), Preset::P100Diesel);
    assert_eq!("P100-Diesel".parse::<Preset>().unwrap(), Preset::P100Diesel);
    let err = "p100-dissel".parse::<Preset>().unwrap_err();
    let text = err.to_string();
    assert!(text.contains("p100-dissel"), "{text}");
    for preset in Preset::ALL {
        assert!(text.contains(preset.name()), "{text}");
    }
}

#[test]
fn resolve_params_prefers_presets_and_explains_misses() {
    assert_eq!(resolve_params("p100-ls").unwrap(), Preset::P100Ls.params());
    let err = resolve_params("p100-dissel").unwrap_err();
    assert!(matches!(err, ModelError::UnknownSpec { .. }), "{err}");
    assert!(err.to_string().contains("p100-diesel"), "{err}");
}

#[test]
fn p100_diesel_preset_matches_the_ironcub_numbers() {
    let p = Preset::P100Diesel.params();
    assert_eq!(p.k_t, -1.496760);
    assert_eq!(p.c, -19.926756);
    assert_eq!(p.b_uu, 0.013878);
    let ls = Preset::P220Ls.params();
    assert_eq!((ls.b_u, ls.c), (-1.364, 20.624));
}
