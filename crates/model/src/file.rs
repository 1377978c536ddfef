//! Model files: the ten parameters in TOML, plus a table per effect they leave out.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::Deserialize;

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

/// "A preset name or a path to a model file": a preset name wins; anything else is
/// loaded as a file, effects included.
pub fn resolve_model(spec: &str) -> Result<ModelFile, ModelError> {
    if let Ok(preset) = spec.parse::<Preset>() {
        return Ok(ModelFile::new(preset.params()));
    }
    let path = Path::new(spec);
    match ModelFile::load(path) {
        Ok(file) => Ok(file),
        Err(ModelError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            Err(ModelError::UnknownSpec { spec: spec.to_owned(), valid: Preset::valid_names(), source })
        }
        Err(e) => Err(e),
    }
}
