//! Model files: the ten parameters in TOML, plus (later) tables for extra effects.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::{ModelError, Params, Preset};

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
/// `[effects.<name>]` tables (input delay, actuator lag, ...) are reserved for later work.
/// They are parsed so the file format is fixed now, but [`ModelFile::load`] rejects any,
/// because a simulator that silently dropped an effect would mislead.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelFile {
    /// The ten coefficients.
    pub model: Params,
    /// Extra effects by name; must be empty in this version.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub effects: BTreeMap<String, toml::Table>,
}

impl ModelFile {
    /// A file holding just these parameters.
    pub fn new(model: Params) -> Self {
        Self { model, effects: BTreeMap::new() }
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
        let file: Self = toml::from_str(text)
            .map_err(|e| ModelError::Parse { path: origin.to_owned(), message: e.to_string().trim_end().to_owned() })?;
        if let Some(name) = file.effects.keys().next() {
            return Err(ModelError::UnsupportedEffect { name: name.clone() });
        }
        file.model.validate()?;
        Ok(file)
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
        if !self.effects.is_empty() {
            #[derive(Serialize)]
            struct Effects<'a> {
                effects: &'a BTreeMap<String, toml::Table>,
            }
            match toml::to_string(&Effects { effects: &self.effects }) {
                Ok(text) => {
                    out.push('\n');
                    out.push_str(&text);
                }
                Err(e) => {
                    let _ = writeln!(out, "\n# effects could not be written: {e}");
                }
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

/// Parameters from "a preset name or a path to a model file": a preset name wins;
/// anything else is loaded as a file.
pub fn resolve_params(spec: &str) -> Result<Params, ModelError> {
    if let Ok(preset) = spec.parse::<Preset>() {
        return Ok(preset.params());
    }
    let path = Path::new(spec);
    match ModelFile::load(path) {
        Ok(file) => Ok(file.model),
        Err(ModelError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            Err(ModelError::UnknownSpec { spec: spec.to_owned(), valid: Preset::valid_names(), source })
        }
        Err(e) => Err(e),
    }
}
