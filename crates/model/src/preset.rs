//! Named parameter sets: the public iRonCub configurations and the study's table.

use std::fmt;
use std::str::FromStr;

use crate::{ModelError, Params};

/// A built-in parameter set, selectable by name from the CLI or a config file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Preset {
    /// `p100-diesel`: iRonCub P100 on diesel; the default plant.
    #[default]
    P100Diesel,
    /// `p220-kerosene`: iRonCub P220 on kerosene.
    P220Kerosene,
    /// `p100-ekf`: study table, EKF P100 (locally valid only).
    P100Ekf,
    /// `p220-ekf`: study table, EKF P220.
    P220Ekf,
    /// `p100-ls`: study table, least squares P100.
    P100Ls,
    /// `p220-ls`: study table, least squares P220.
    P220Ls,
}

impl Preset {
    /// Every preset, default first.
    pub const ALL: [Preset; 6] =
        [Preset::P100Diesel, Preset::P220Kerosene, Preset::P100Ekf, Preset::P220Ekf, Preset::P100Ls, Preset::P220Ls];

    /// Name used on the command line and in config files.
    pub fn name(&self) -> &'static str {
        match self {
            Preset::P100Diesel => "p100-diesel",
            Preset::P220Kerosene => "p220-kerosene",
            Preset::P100Ekf => "p100-ekf",
            Preset::P220Ekf => "p220-ekf",
            Preset::P100Ls => "p100-ls",
            Preset::P220Ls => "p220-ls",
        }
    }

    /// The coefficients, as published (docs/model/README.md).
    pub fn params(&self) -> Params {
        // Array order is Params::NAMES: K_T, K_TT, K_D, K_DD, K_TD, c, B_U, B_T, B_D, B_UU.
        let a = match self {
            Preset::P100Diesel => [
                -1.496760, -0.045206, -2.433030, 0.020352, 0.064188, -19.926756, 0.589177, 0.016715, -0.021258,
                0.013878,
            ],
            Preset::P220Kerosene => {
                [0.237755, -0.012799, -0.860374, 0.023606, 0.008599, -0.692913, 1.139026, 0.019914, -0.050257, 0.000302]
            }
            Preset::P100Ekf => [-1.460, -0.059, -2.430, 0.0787, 0.1188, -19.92, 0.4317, 0.0116, -0.026, 0.0314],
            Preset::P220Ekf => [-0.280, -0.010, 0.5883, 0.0421, 0.0058, -7.839, 0.1874, 0.0137, -0.032, 0.0074],
            Preset::P100Ls => [-0.617, -0.015, -0.737, -0.002, 0.0020, -5.631, 0.2175, 0.0090, -0.001, 0.0078],
            Preset::P220Ls => [0.2027, -0.003, -0.196, 0.0023, -0.002, 20.624, -1.364, -0.002, 0.0067, -0.015],
        };
        Params::from_array(a)
    }

    /// One line on where the set comes from and how far to trust it.
    pub fn describe(&self) -> &'static str {
        match self {
            Preset::P100Diesel => {
                "JetCat P100-RX on diesel, public iRonCub configuration; well behaved over \
                 25-120 %, the default plant"
            }
            Preset::P220Kerosene => {
                "JetCat P220-RXi on kerosene, public iRonCub configuration; its throttle scale \
                 differs (about 84 N at 25 %)"
            }
            Preset::P100Ekf => {
                "P100, EKF identification from the study; only a local fit: a step from 70 % to \
                 100 % diverges"
            }
            Preset::P220Ekf => "P220, EKF identification from the study",
            Preset::P100Ls => "P100, least-squares identification from the study",
            Preset::P220Ls => {
                "P220, least-squares identification from the study; B_U < 0 and B_UU < 0, so \
                 v(u) peaks near 33 %"
            }
        }
    }

    /// Comma-separated preset names, for error messages.
    pub(crate) fn valid_names() -> String {
        Self::ALL.iter().map(Preset::name).collect::<Vec<_>>().join(", ")
    }
}

impl FromStr for Preset {
    type Err = ModelError;

    /// Parses a preset name, ignoring ASCII case and surrounding blanks.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let wanted = s.trim();
        Self::ALL
            .into_iter()
            .find(|p| p.name().eq_ignore_ascii_case(wanted))
            .ok_or_else(|| ModelError::UnknownPreset { name: s.to_owned(), valid: Self::valid_names() })
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}
