//! The terms of the `discrepancy` effect: physics outside the catalogue, as extra
//! thrust acceleration in the engine model.
//!
//! ```text
//! T̈ = f(T, Ṫ) + g(T, Ṫ)·v(u) + δ
//! δ = map_below·g·max(0, v(knot_below_pct) − v(u))      the throttle map flattens below a knot
//!   + map_above·g·max(0, v(u) − v(knot_above_pct))      ... or changes slope above one
//!   + gain_history_per_n·g·v(u)·H                       input gain that follows thrust history
//!   + gain_throttle_history_per_pct·g·v(u)·V            ... or the throttle's history
//!   + (B_TT·T² + B_DD·Ṫ² + B_TD·T·Ṫ)·v(u)               input gain beyond B_U + B_T·T + B_D·Ṫ
//! Ḣ = (T − H)/history_time_constant_s                    H starts at the initial thrust
//! V̇ = (v(u) − V)/throttle_history_time_constant_s        V starts at the initial v(u)
//! and while the thrust falls (Ṫ < 0) the whole acceleration is scaled:
//! T̈ = (1 + spool_down)·(f + g·v(u) + δ)                  spool-down slower (< 0) or faster
//! ```
//!
//! Each term is what a kind of physics the ten parameters cannot express does to the
//! engine: `map_below = 1` is a dead band (below the knot the engine runs as if at
//! it), `gain_history_per_n < 0` a gain that sags as the engine heat-soaks,
//! `gain_throttle_history_per_pct < 0` one that sags with the fuel that has flowed (fuel
//! warming in the lines with the pump's work: it follows what the throttle asked for,
//! not the thrust the engine made, whose map is far from straight), the
//! three `B_..` terms are the input gain of the iRonCub group's later jet model, and
//! `spool_down = −0.3` an engine that spools down 30 % more slowly than it spools up
//! (the ten parameters hold one time scale for both directions; a turbine's run-down
//! against its compressor is not its fuel-driven run-up). At rest nothing changes.
//!
//! In a model file only the terms present are written, each with the shape key it
//! needs:
//!
//! ```
//! use jetbench_model::{Effect, EffectKind};
//!
//! let e: Effect = "discrepancy:map_below=0.9,knot_below_pct=45".parse()?;
//! assert_eq!(e.kind(), EffectKind::Discrepancy);
//! assert_eq!(e.to_string(), "discrepancy:map_below=0.9,knot_below_pct=45");
//! # Ok::<(), jetbench_model::ModelError>(())
//! ```

/// One term of the discrepancy: its coefficient's key and the shape key it needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DiscrepancyTerm {
    /// Index of the coefficient in the effect's values.
    pub coefficient: usize,
    /// Index of the shape parameter (knot or time constant) the term needs, if any.
    pub shape: Option<usize>,
    /// Unit of the coefficient.
    pub unit: &'static str,
    /// What the term is, for help texts.
    pub meaning: &'static str,
}

/// Keys of the discrepancy effect, in the order of its values.
pub const DISCREPANCY_KEYS: [&str; 12] = [
    "map_below",
    "knot_below_pct",
    "map_above",
    "knot_above_pct",
    "gain_history_per_n",
    "history_time_constant_s",
    "B_TT",
    "B_DD",
    "B_TD",
    "spool_down",
    "gain_throttle_history_per_pct",
    "throttle_history_time_constant_s",
];

/// Ranges of the discrepancy's values, in the order of [`DISCREPANCY_KEYS`].
pub(crate) const DISCREPANCY_BOUNDS: [(f64, f64); 12] = [
    (-5.0, 5.0),
    (0.0, 150.0),
    (-5.0, 5.0),
    (0.0, 150.0),
    (-0.1, 0.1),
    (0.5, 3600.0),
    (-0.01, 0.01),
    (-0.01, 0.01),
    (-0.01, 0.01),
    (-0.9, 3.0),
    (-0.1, 0.1),
    (0.5, 3600.0),
];

/// Values of a discrepancy with no term (an absent term's shape key is never used).
pub const DISCREPANCY_DEFAULTS: [f64; 12] = [0.0, 50.0, 0.0, 90.0, 0.0, 30.0, 0.0, 0.0, 0.0, 0.0, 0.0, 30.0];

/// The terms, in the order of their coefficients.
pub const DISCREPANCY_TERMS: [DiscrepancyTerm; 8] = [
    DiscrepancyTerm {
        coefficient: 0,
        shape: Some(1),
        unit: "1",
        meaning:
            "g·max(0, v(knot_below_pct) − v(u)): the throttle map changes slope below a knot (1: flat, a dead band)",
    },
    DiscrepancyTerm {
        coefficient: 2,
        shape: Some(3),
        unit: "1",
        meaning:
            "g·max(0, v(u) − v(knot_above_pct)): the throttle map changes slope above a knot (−1: flat, saturated)",
    },
    DiscrepancyTerm {
        coefficient: 4,
        shape: Some(5),
        unit: "1/N",
        meaning: "g·v(u)·H, H the thrust history (first order, history_time_constant_s): gain that follows thrust \
                  history (< 0: heat soak)",
    },
    DiscrepancyTerm {
        coefficient: 6,
        shape: None,
        unit: "N/s² per N²",
        meaning: "T²·v(u): input gain growing with T²",
    },
    DiscrepancyTerm {
        coefficient: 7,
        shape: None,
        unit: "N/s² per (N/s)²",
        meaning: "Ṫ²·v(u): input gain growing with Ṫ²",
    },
    DiscrepancyTerm {
        coefficient: 8, shape: None, unit: "N/s² per N²/s", meaning: "T·Ṫ·v(u): input gain with T·Ṫ"
    },
    DiscrepancyTerm {
        coefficient: 9,
        shape: None,
        unit: "1",
        meaning: "while the thrust falls, the acceleration times 1 + spool_down: spool-down slower (< 0) or faster \
                  than spool-up",
    },
    DiscrepancyTerm {
        coefficient: 10,
        shape: Some(11),
        unit: "1/%",
        meaning: "g·v(u)·V, V the throttle map's history (first order, throttle_history_time_constant_s): gain that \
                  follows the throttle history (< 0: a fuel soak)",
    },
];

/// True when value `index` of a discrepancy matters: a non-zero coefficient, or the
/// shape key of one.
pub(crate) fn discrepancy_key_active(values: &[f64], index: usize) -> bool {
    DISCREPANCY_TERMS.iter().any(|t| values[t.coefficient] != 0.0 && (t.coefficient == index || t.shape == Some(index)))
}

/// The discrepancy flattened for a simulator's inner loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct DiscrepancyLaw {
    pub map_below: f64,
    pub knot_below_pct: f64,
    pub map_above: f64,
    pub knot_above_pct: f64,
    pub gain_history_per_n: f64,
    pub history_time_constant_s: f64,
    pub b_tt: f64,
    pub b_dd: f64,
    pub b_td: f64,
    pub spool_down: f64,
    pub gain_throttle_history_per_pct: f64,
    pub throttle_history_time_constant_s: f64,
}

impl DiscrepancyLaw {
    pub fn new(values: &[f64]) -> Self {
        Self {
            map_below: values[0],
            knot_below_pct: values[1],
            map_above: values[2],
            knot_above_pct: values[3],
            gain_history_per_n: values[4],
            history_time_constant_s: values[5],
            b_tt: values[6],
            b_dd: values[7],
            b_td: values[8],
            spool_down: values[9],
            gain_throttle_history_per_pct: values[10],
            throttle_history_time_constant_s: values[11],
        }
    }

    /// True when the law needs the throttle map's hinges.
    pub fn has_hinges(&self) -> bool {
        self.map_below != 0.0 || self.map_above != 0.0
    }

    /// `(max(0, v(knot_below) − v), max(0, v − v(knot_above)))` for `v = v(u)`, given
    /// `v(knot_below)` and `v(knot_above)`.
    pub fn hinges(v: f64, v_below: f64, v_above: f64) -> (f64, f64) {
        ((v_below - v).max(0.0), (v - v_above).max(0.0))
    }

    /// Extra acceleration δ, N/s², at thrust `t`, rate `d`, input gain `g`, throttle map
    /// `v`, its hinges (averaged over the step) and the histories.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn accel(&self, t: f64, d: f64, g: f64, v: f64, below: f64, above: f64, history: Histories) -> f64 {
        g * (self.map_below * below
            + self.map_above * above
            + (self.gain_history_per_n * history.thrust_n + self.gain_throttle_history_per_pct * history.throttle) * v)
            + (self.b_tt * t * t + self.b_dd * d * d + self.b_td * t * d) * v
    }

    /// The engine's acceleration with the discrepancy, N/s²: `base = f + g·v` (the ten
    /// parameters' own), the extra [`DiscrepancyLaw::accel`], and the whole scaled by
    /// `1 + spool_down` while the thrust falls.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn total(&self, base: f64, t: f64, d: f64, g: f64, v: f64, below: f64, above: f64, history: Histories) -> f64 {
        let a = base + self.accel(t, d, g, v, below, above, history);
        if d < 0.0 {
            a * (1.0 + self.spool_down)
        } else {
            a
        }
    }
}

/// The discrepancy's slow states at a step: the thrust history `H`, N, and the
/// throttle map's history `V`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Histories {
    pub thrust_n: f64,
    pub throttle: f64,
}
