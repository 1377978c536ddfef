//! Model files: the ten parameters in TOML, plus a table per effect they leave out.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::Deserialize;

use crate::ironcub::{IronCubJet, IRONCUB_PLANT};
use crate::turbojet::TurbojetParams;
use crate::{Effects, ModelError, Params, Plant, Preset};

/// A model file:
///
/// ```toml
/// [model]
/// K_T = -1.49676
/// K_TT = -0.045206
/// K_D = -2.43303
/// K_DD = 0.020352
/// K_TD = 0.064188
/// c = -19.926756
/// B_U = 0.589177
/// B_T = 0.016715
/// B_D = -0.021258
/// B_UU = 0.013878
/// ```
///
/// plus one optional table per effect the ten parameters leave out (names and keys
/// in [`EffectKind`](crate::EffectKind)), e.g.
///
/// ```toml
/// [effects.input_delay]
/// delay_s = 0.08
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct ModelFile {
    /// The ten coefficients.
    pub model: Params,
    /// What the coefficients leave out.
    pub effects: Effects,
}

/// The file as TOML sees it; checked into a [`ModelFile`].
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawModelFile {
    model: Params,
    #[serde(default)]
    effects: BTreeMap<String, toml::Table>,
}

impl ModelFile {
    /// A file holding just these parameters.
    pub fn new(model: Params) -> Self {
        Self { model, effects: Effects::none() }
    }

    /// The plant this file describes.
    pub fn plant(&self) -> Plant {
        Plant::new(self.model, self.effects.clone())
    }

    /// Reads and checks a model file.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ModelError::Io { path: path.to_path_buf(), source })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and checks model-file text held in memory.
    pub fn from_toml_str(s: &str) -> Result<Self, ModelError> {
        Self::parse(s, "<string>")
    }

    fn parse(text: &str, origin: &str) -> Result<Self, ModelError> {
        let raw: RawModelFile = toml::from_str(text)
            .map_err(|e| ModelError::Parse { path: origin.to_owned(), message: e.to_string().trim_end().to_owned() })?;
        raw.model.validate()?;
        Ok(Self { model: raw.model, effects: Effects::from_tables(&raw.effects)? })
    }

    /// TOML text that [`ModelFile::from_toml_str`] reads back bit for bit.
    pub fn to_toml_string(&self) -> String {
        let mut out = String::from("[model]\n");
        for (name, value) in Params::NAMES.iter().zip(self.model.to_array()) {
            // `{:?}` prints the shortest text that parses back to the same f64.
            let text = if value.is_nan() {
                "nan".to_owned()
            } else if value.is_infinite() {
                if value > 0.0 { "inf" } else { "-inf" }.to_owned()
            } else {
                format!("{value:?}")
            };
            let _ = writeln!(out, "{name} = {text}");
        }
        for effect in self.effects.iter() {
            let _ = writeln!(out, "\n[effects.{}]", effect.kind());
            for (key, value) in effect.params() {
                let _ = writeln!(out, "{key} = {value:?}");
            }
        }
        out
    }

    /// Writes [`ModelFile::to_toml_string`] to `path`.
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        std::fs::write(path, self.to_toml_string())
            .map_err(|source| ModelError::Io { path: path.to_path_buf(), source })
    }
}

/// The ten parameters of "a preset name or a path to a model file"; effects in the
/// file are not part of the answer (see [`resolve_model`] for the whole plant).
pub fn resolve_params(spec: &str) -> Result<Params, ModelError> {
    resolve_model(spec).map(|file| file.model)
}

/// "A preset name or a path to a model file": a preset name wins (`ironcub`, the
/// iRonCub group's 13-coefficient jet, is the ten parameters with its input-gain terms as
/// a discrepancy, [`crate::ironcub`]); anything else is loaded as a file, effects included.
pub fn resolve_model(spec: &str) -> Result<ModelFile, ModelError> {
    if let Ok(preset) = spec.parse::<Preset>() {
        return Ok(ModelFile::new(preset.params()));
    }
    if spec.trim().eq_ignore_ascii_case(IRONCUB_PLANT) {
        return Ok(IronCubJet::published().model_file());
    }
    let path = Path::new(spec);
    match ModelFile::load(path) {
        Ok(file) => Ok(file),
        Err(ModelError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            let valid = format!("{}, {IRONCUB_PLANT}", Preset::valid_names());
            Err(ModelError::UnknownSpec { spec: spec.to_owned(), valid, source })
        }
        Err(e) => Err(e),
    }
}

/// The simulated bench's turbojet plants by name: a physically based engine that is not
/// the ten-parameter model ([`crate::turbojet`]).
pub const TURBOJET_PLANTS: [&str; 2] = ["turbojet-p100", "turbojet-p220"];

/// True when `spec` names a built-in plant or model (a preset, a turbojet plant or
/// [`IRONCUB_PLANT`]) rather than a path.
pub fn names_a_plant(spec: &str) -> bool {
    let wanted = spec.trim();
    wanted.parse::<Preset>().is_ok()
        || wanted.eq_ignore_ascii_case(IRONCUB_PLANT)
        || TURBOJET_PLANTS.iter().any(|name| wanted.eq_ignore_ascii_case(name))
}

/// The engine a simulated bench runs, from "a turbojet plant (`turbojet-p100`,
/// `turbojet-p220`), a model preset (or `ironcub`), or a path": a plant file with a `[turbojet]` table
/// (`base` and any constant of [`TurbojetParams::NAMES`]) and optional `[effects.<name>]`
/// tables is a turbojet; any other file is a model file ([`resolve_model`]). Effects a
/// turbojet cannot take (a discrepancy) are an error.
pub fn resolve_plant(spec: &str) -> Result<Plant, ModelError> {
    let wanted = spec.trim().to_ascii_lowercase();
    if let Some(base) = wanted.strip_prefix("turbojet-").and_then(TurbojetParams::preset) {
        return Ok(Plant::with_turbojet(base, Effects::none()));
    }
    if spec.parse::<Preset>().is_ok() || wanted == IRONCUB_PLANT {
        return resolve_model(spec).map(|file| file.plant());
    }
    let path = Path::new(spec);
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(source) if source.kind() == std::io::ErrorKind::NotFound => {
            let valid = format!("{}, {IRONCUB_PLANT}, {}", TURBOJET_PLANTS.join(", "), Preset::valid_names());
            return Err(ModelError::UnknownSpec { spec: spec.to_owned(), valid, source });
        }
        Err(source) => return Err(ModelError::Io { path: path.to_path_buf(), source }),
    };
    let origin = path.display().to_string();
    let parse_error = |message: String| ModelError::Parse { path: origin.clone(), message };
    let table: toml::Table = toml::from_str(&text).map_err(|e| parse_error(e.to_string().trim_end().to_owned()))?;
    let Some(turbojet) = table.get("turbojet") else {
        return ModelFile::parse(&text, &origin).map(|file| file.plant());
    };
    let turbojet = turbojet.as_table().ok_or_else(|| parse_error("[turbojet] must be a table".into()))?;
    let params = TurbojetParams::from_table(turbojet).map_err(|e| parse_error(format!("[turbojet] {e}")))?;
    let mut effects = BTreeMap::new();
    for (key, value) in &table {
        match (key.as_str(), value) {
            ("turbojet", _) => {}
            ("effects", toml::Value::Table(tables)) => {
                for (name, t) in tables {
                    let t = t.as_table().ok_or_else(|| parse_error(format!("[effects.{name}] must be a table")))?;
                    effects.insert(name.clone(), t.clone());
                }
            }
            _ => return Err(parse_error(format!("unknown key `{key}` in a turbojet plant file (turbojet, effects)"))),
        }
    }
    let plant = Plant::with_turbojet(params, Effects::from_tables(&effects)?);
    match plant.turbojet_conflict() {
        Some((kind, message)) => Err(ModelError::EffectParam { effect: kind.name(), message }),
        None => Ok(plant),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str) -> std::path::PathBuf {
        let path = std::env::temp_dir().join(format!("jetbench-plant-{}-{name}.toml", std::process::id()));
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn plants_resolve_by_name_and_from_files() {
        let p100 = resolve_plant("turbojet-p100").unwrap();
        assert_eq!(p100.turbojet, Some(TurbojetParams::p100()));
        assert_eq!(resolve_plant(" Turbojet-P220 ").unwrap().turbojet, Some(TurbojetParams::p220()));
        assert_eq!(resolve_plant("p100-diesel").unwrap(), resolve_model("p100-diesel").unwrap().plant());
        let file = write(
            "ok",
            "[turbojet]\nbase = \"p220\"\nspool_time_constant_s = 0.3\n\n[effects.input_delay]\ndelay_s = 0.08\n",
        );
        let plant = resolve_plant(&file.display().to_string()).unwrap();
        let mut want = TurbojetParams::p220();
        want.spool_time_constant_s = 0.3;
        assert_eq!(plant.turbojet, Some(want));
        assert_eq!(plant.effects.input_delay_s(), 0.08);
        let model = write("model", &ModelFile::new(Preset::P220Kerosene.params()).to_toml_string());
        assert_eq!(resolve_plant(&model.display().to_string()).unwrap().turbojet, None);
        for (name, text, says) in [
            ("typo", "[turbojet]\nspool_time_constant = 0.3\n", "spool_time_constant"),
            ("base", "[turbojet]\nbase = \"p300\"\n", "p300"),
            ("bad", "[turbojet]\nrpm_idle = 200000\n", "rpm_idle"),
            ("text", "[turbojet]\nrpm_idle = \"fast\"\n", "rpm_idle"),
            ("extra", "[turbojet]\n[model]\nK_T = 1\n", "model"),
            ("disc", "[turbojet]\n[effects.discrepancy]\nmap_below = 1\nknot_below_pct = 45\n", "discrepancy"),
        ] {
            let path = write(name, text);
            let err = resolve_plant(&path.display().to_string()).unwrap_err().to_string();
            assert!(err.contains(says), "{name}: {err}");
            let _ = std::fs::remove_file(path);
        }
        let ironcub = resolve_plant(" iRonCub ").unwrap();
        assert_eq!(ironcub, IronCubJet::published().plant());
        assert!(ironcub.effects.get(crate::EffectKind::Discrepancy).is_some() && ironcub.turbojet.is_none());
        assert_eq!(resolve_model("ironcub").unwrap(), IronCubJet::published().model_file());
        assert!(names_a_plant("ironcub") && names_a_plant("turbojet-p100") && names_a_plant("p220-ls"));
        assert!(!names_a_plant("models/ironcub.toml"));
        let err = resolve_plant("turbojet-p999").unwrap_err().to_string();
        assert!(err.contains("turbojet-p100") && err.contains("p100-diesel") && err.contains("ironcub"), "{err}");
        let _ = std::fs::remove_file(file);
        let _ = std::fs::remove_file(model);
    }
}
