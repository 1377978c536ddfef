//! Faults injected into the simulated bench's sensor path, on request.
//!
//! `jetbench up --sim --inject KIND:KEY=VALUE,...` (repeatable; the kinds
//! compose) or `[plant] inject = ["KIND:KEY=VALUE,...", ...]` in the bench
//! config, so a recording's metadata says what was injected:
//!
//! | kind | keys | what the sensor does |
//! |---|---|---|
//! | `spikes` | `rate_per_s`, `size_n`, `seed` (0) | at random frames (Poisson, `rate_per_s` on average) a reading off by ±`size_n` on the thrust axis |
//! | `stuck` | `at_s`, `for_s` | the same reading over and over (frames keep coming) |
//! | `nan` | `at_s`, `for_s` (0.01) | a reading that is not a number |
//! | `silence` | `at_s`, `for_s` | no frames at all |
//! | `offset` | `at_s`, `for_s`, `size_n` | readings shifted by `size_n` on the thrust axis (a mount or calibration fault) |
//!
//! Times count from the sensor's first frame (frame `k` at `k`·10 ms), so every
//! process that sees the frames agrees on them without a shared clock, and the
//! spike frames are a function of the seed: a run is reproducible. sim-bench
//! applies spikes, stuck readings and silences to what its sensor sends
//! ([`FaultySensor`]). A NaN cannot travel in the sensor's CAN frames (16-bit
//! integers), so `nan` enters where a NaN could come from at a bench, the
//! reading sensing decodes, before calibration ([`crate::sensing::SensingStep::with_faults`]).
//! Every injected frame is marked in `sim/truth` (`faults`, `injected_n`) for
//! evaluation; no service on the control path sees that channel.
//!
//! ```
//! use jetbench_stack::inject::FaultPlan;
//!
//! let plan = FaultPlan::parse(["spikes:rate_per_s=2,size_n=30", "stuck:at_s=10,for_s=1.5"])?;
//! assert!(plan.at(1000).stuck && plan.at(1149).stuck && !plan.at(1150).stuck);
//! let spikes = (0..3000).filter(|&k| plan.at(k).spike_n != 0.0).count();
//! assert!((40..=80).contains(&spikes), "about 2 per second over 30 s: {spikes}");
//! # Ok::<(), jetbench_stack::inject::InjectError>(())
//! ```

use std::fmt;
use std::str::FromStr;

use jetbench_io::ForceReading;
use jetbench_msgs::sim_faults;

use crate::runtime::clock::PERIOD_NS;

/// Why a fault specification was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum InjectError {
    /// A fault kind the simulated bench does not know.
    #[error(
        "unknown fault `{kind}`; --inject takes spikes, stuck, nan, silence, offset or ecu (e.g. spikes:rate_per_s=2,size_n=30, ecu:flameout_at_s=15)"
    )]
    UnknownKind {
        /// The kind as written.
        kind: String,
    },
    /// A key of a known kind is missing, unknown or out of range.
    #[error("--inject {kind}: {message} (keys: {keys})")]
    Key {
        /// The fault kind.
        kind: &'static str,
        /// The keys it takes.
        keys: &'static str,
        /// What is wrong.
        message: String,
    },
}

/// When a fault that lasts is on: from `at_s` for `for_s` (at least one frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    /// Start, s from the start of the run.
    pub at_s: f64,
    /// Duration, s.
    pub for_s: f64,
}

impl Window {
    fn contains(&self, frame: u64) -> bool {
        let from = frame_at(self.at_s);
        frame >= from && frame < from + frame_at(self.for_s).max(1)
    }
}

fn frame_at(t_s: f64) -> u64 {
    (t_s * 1e9 / PERIOD_NS as f64).round() as u64
}

/// One injected fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fault {
    /// Spikes on the thrust axis at random frames.
    Spikes {
        /// Mean spikes per second.
        rate_per_s: f64,
        /// Size of each spike, N (either sign).
        size_n: f64,
        /// Seed of the frames and signs.
        seed: u64,
    },
    /// The sensor repeats one reading.
    Stuck(Window),
    /// The sensor sends NaN.
    NotANumber(Window),
    /// The sensor sends nothing.
    Silence(Window),
    /// The sensor's zero shifts by `size_n` (a knocked mount, a thermal shift).
    Offset {
        /// When.
        window: Window,
        /// The shift, N on the thrust axis.
        size_n: f64,
    },
}

impl Fault {
    fn kind(&self) -> &'static str {
        match self {
            Fault::Spikes { .. } => "spikes",
            Fault::Stuck(_) => "stuck",
            Fault::NotANumber(_) => "nan",
            Fault::Silence(_) => "silence",
            Fault::Offset { .. } => "offset",
        }
    }
}

/// `KIND:KEY=VALUE,...`; every key of the kind is required unless it has a default.
impl FromStr for Fault {
    type Err = InjectError;

    fn from_str(spec: &str) -> Result<Self, InjectError> {
        let (kind, rest) = spec.trim().split_once(':').unwrap_or((spec.trim(), ""));
        let (kind, keys, defaults): (&'static str, &'static str, &[(&str, f64)]) = match kind {
            "spikes" => ("spikes", "rate_per_s, size_n, seed", &[("seed", 0.0)]),
            "stuck" => ("stuck", "at_s, for_s", &[]),
            "nan" => ("nan", "at_s, for_s", &[("for_s", 0.01)]),
            "silence" => ("silence", "at_s, for_s", &[]),
            "offset" => ("offset", "at_s, for_s, size_n", &[]),
            other => return Err(InjectError::UnknownKind { kind: other.into() }),
        };
        let err = |message: String| InjectError::Key { kind, keys, message };
        let mut values: Vec<(&str, f64)> = defaults.to_vec();
        for pair in rest.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (key, value) = pair.split_once('=').ok_or_else(|| err(format!("`{pair}` is not KEY=VALUE")))?;
            let key = keys.split(", ").find(|k| *k == key.trim()).ok_or_else(|| err(format!("unknown key `{key}`")))?;
            let value: f64 = value.trim().parse().map_err(|_| err(format!("{key} = `{value}` is not a number")))?;
            if !(value.is_finite() && value >= 0.0) {
                return Err(err(format!("{key} = {value} must be a number >= 0")));
            }
            values.retain(|(k, _)| *k != key);
            values.push((key, value));
        }
        let get = |key: &str| {
            values.iter().find(|(k, _)| *k == key).map(|(_, v)| *v).ok_or_else(|| err(format!("missing {key}")))
        };
        let window = || Ok::<_, InjectError>(Window { at_s: get("at_s")?, for_s: get("for_s")? });
        Ok(match kind {
            "spikes" => {
                Fault::Spikes { rate_per_s: get("rate_per_s")?, size_n: get("size_n")?, seed: get("seed")? as u64 }
            }
            "stuck" => Fault::Stuck(window()?),
            "nan" => Fault::NotANumber(window()?),
            "offset" => Fault::Offset { window: window()?, size_n: get("size_n")? },
            _ => Fault::Silence(window()?),
        })
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Fault::Spikes { rate_per_s, size_n, seed } => {
                write!(f, "spikes:rate_per_s={rate_per_s},size_n={size_n},seed={seed}")
            }
            Fault::Stuck(w) | Fault::NotANumber(w) | Fault::Silence(w) => {
                write!(f, "{}:at_s={},for_s={}", self.kind(), w.at_s, w.for_s)
            }
            Fault::Offset { window: w, size_n } => {
                write!(f, "offset:at_s={},for_s={},size_n={size_n}", w.at_s, w.for_s)
            }
        }
    }
}

/// What the faults do to one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameFaults {
    /// Added to the thrust axis, N (0: no spike).
    pub spike_n: f64,
    /// The previous reading is repeated.
    pub stuck: bool,
    /// The reading is NaN.
    pub nan: bool,
    /// No frame is sent.
    pub silent: bool,
    /// The shift of an `offset` fault, N.
    pub offset_n: f64,
}

impl FrameFaults {
    /// The [`sim_faults`] bits of this frame.
    pub fn bits(&self) -> u64 {
        [
            (self.spike_n != 0.0, sim_faults::SPIKE),
            (self.stuck, sim_faults::STUCK),
            (self.nan, sim_faults::NAN),
            (self.silent, sim_faults::SILENCE),
            (self.offset_n != 0.0, sim_faults::OFFSET),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |bits, (_, bit)| bits | bit)
    }
}

/// The faults of a run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FaultPlan {
    faults: Vec<Fault>,
}

impl FaultPlan {
    /// Parses every specification (`KIND:KEY=VALUE,...`).
    pub fn parse<S: AsRef<str>>(specs: impl IntoIterator<Item = S>) -> Result<Self, InjectError> {
        // `ecu:...` faults are the emulated ECU's (`PlantSection::ecu_faults`).
        let faults = specs
            .into_iter()
            .filter(|s| !jetbench_io::ecu::emulator::EcuFaults::is_ecu_spec(s.as_ref()))
            .map(|s| s.as_ref().parse())
            .collect::<Result<_, _>>()?;
        Ok(FaultPlan { faults })
    }

    /// True when no fault is planned.
    pub fn is_empty(&self) -> bool {
        self.faults.is_empty()
    }

    /// The planned faults.
    pub fn faults(&self) -> &[Fault] {
        &self.faults
    }

    /// The faults of sensor frame `frame` (counted from the first, 10 ms apart).
    pub fn at(&self, frame: u64) -> FrameFaults {
        let mut out = FrameFaults::default();
        for fault in &self.faults {
            match *fault {
                Fault::Spikes { rate_per_s, size_n, seed } => {
                    // A spike in a frame with probability rate·Δt, drawn from a hash of
                    // (seed, frame): no state, so any process evaluates the same plan.
                    let h = splitmix64(seed ^ splitmix64(frame));
                    let uniform = (h >> 11) as f64 / (1u64 << 53) as f64;
                    if uniform < rate_per_s * PERIOD_NS as f64 * 1e-9 {
                        out.spike_n += if h & 1 == 0 { size_n } else { -size_n };
                    }
                }
                Fault::Stuck(w) => out.stuck |= w.contains(frame),
                Fault::NotANumber(w) => out.nan |= w.contains(frame),
                Fault::Silence(w) => out.silent |= w.contains(frame),
                Fault::Offset { window, size_n } => {
                    if window.contains(frame) {
                        out.offset_n += size_n;
                    }
                }
            }
        }
        out
    }
}

impl fmt::Display for FaultPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, fault) in self.faults.iter().enumerate() {
            write!(f, "{}{fault}", if i > 0 { " " } else { "" })?;
        }
        Ok(())
    }
}

/// SplitMix64's finaliser: a well-mixed 64-bit hash of `x`.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// What a faulty sensor sends for one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Injected {
    /// The reading sent, or `None`: silent.
    pub reading: Option<ForceReading>,
    /// [`sim_faults`] bits.
    pub faults: u64,
    /// Sent minus true reading on the thrust axis, N (0 when silent or clean).
    pub injected_n: f64,
}

/// The simulated sensor's faults: a [`FaultPlan`] applied frame by frame to
/// the readings sim-bench sends (the thrust on x, as its sensor has it).
#[derive(Clone, Debug, Default)]
pub struct FaultySensor {
    plan: FaultPlan,
    frame: u64,
    frozen: Option<ForceReading>,
    last: Option<ForceReading>,
}

impl FaultySensor {
    /// A sensor that will suffer `plan`.
    pub fn new(plan: FaultPlan) -> Self {
        FaultySensor { plan, ..FaultySensor::default() }
    }

    /// Its plan.
    pub fn plan(&self) -> &FaultPlan {
        &self.plan
    }

    /// The next frame: `reading` as the sensor measured it, as the faults make it.
    pub fn apply(&mut self, reading: ForceReading) -> Injected {
        let faults = self.plan.at(self.frame);
        self.frame += 1;
        let mut sent = reading;
        if faults.stuck {
            // Frozen at the last reading before the fault; the counter runs on.
            let frozen = *self.frozen.get_or_insert(self.last.unwrap_or(reading));
            sent = ForceReading { counter: reading.counter, status: reading.status, ..frozen };
        } else {
            self.frozen = None;
        }
        sent.force_n[0] += faults.spike_n + faults.offset_n;
        self.last = Some(reading);
        let injected_n = if faults.silent { 0.0 } else { sent.force_n[0] - reading.force_n[0] };
        Injected { reading: (!faults.silent).then_some(sent), faults: faults.bits(), injected_n }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specifications_parse_print_and_refuse_clearly() {
        let plan = FaultPlan::parse([
            "spikes:rate_per_s=2,size_n=30",
            "stuck:at_s=10,for_s=1.5",
            "nan:at_s=20",
            "silence:at_s=30,for_s=0.5",
        ])
        .unwrap();
        assert_eq!(
            plan.to_string(),
            "spikes:rate_per_s=2,size_n=30,seed=0 stuck:at_s=10,for_s=1.5 nan:at_s=20,for_s=0.01 \
             silence:at_s=30,for_s=0.5"
        );
        assert_eq!(FaultPlan::parse(plan.to_string().split(' ')).unwrap(), plan, "printed specs parse back");
        for (bad, says) in [
            ("sparks:rate_per_s=1", "unknown fault `sparks`"),
            ("spikes:rate_per_s=2", "missing size_n"),
            ("stuck:at_s=1,for_s=x", "for_s = `x` is not a number"),
            ("silence:at_s=1,for_s=1,volume=3", "unknown key `volume`"),
            ("nan:at_s=-1", "at_s = -1 must be a number >= 0"),
            ("stuck:at_s", "`at_s` is not KEY=VALUE"),
        ] {
            let e = bad.parse::<Fault>().unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn windows_cover_their_frames_and_spikes_come_at_the_rate_asked() {
        let plan =
            FaultPlan::parse(["nan:at_s=20", "silence:at_s=30,for_s=0.5", "spikes:rate_per_s=2,size_n=30"]).unwrap();
        let nan: Vec<u64> = (0..4000).filter(|&k| plan.at(k).nan).collect();
        assert_eq!(nan, [2000], "one frame by default");
        assert_eq!((0..4000).filter(|&k| plan.at(k).silent).count(), 50);
        // 2 per second over 1000 s: 2000 expected, Poisson sd 45.
        let spikes: Vec<f64> = (0..100_000).map(|k| plan.at(k).spike_n).filter(|s| *s != 0.0).collect();
        assert!((1850..2150).contains(&spikes.len()), "{} spikes", spikes.len());
        assert!(spikes.iter().all(|s| s.abs() == 30.0));
        let up = spikes.iter().filter(|s| **s > 0.0).count() as f64 / spikes.len() as f64;
        assert!((0.45..0.55).contains(&up), "both signs: {up}");
        let other_seed = FaultPlan::parse(["spikes:rate_per_s=2,size_n=30,seed=1"]).unwrap();
        assert_ne!(
            (0..1000).map(|k| plan.at(k).spike_n).collect::<Vec<_>>(),
            (0..1000).map(|k| other_seed.at(k).spike_n).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_stuck_sensor_repeats_its_last_reading_and_a_silent_one_sends_nothing() {
        let mut sensor = FaultySensor::new(
            FaultPlan::parse(["stuck:at_s=0.02,for_s=0.03", "silence:at_s=0.06,for_s=0.01"]).unwrap(),
        );
        let reading =
            |k: u32| ForceReading { force_n: [40.0 + f64::from(k), 0.0, 0.0], counter: k, ..ForceReading::default() };
        let sent: Vec<Injected> = (0..8).map(|k| sensor.apply(reading(k))).collect();
        let thrust: Vec<Option<f64>> = sent.iter().map(|i| i.reading.map(|r| r.force_n[0])).collect();
        assert_eq!(thrust, [Some(40.0), Some(41.0), Some(41.0), Some(41.0), Some(41.0), Some(45.0), None, Some(47.0)]);
        assert_eq!(sent[4].reading.map(|r| r.counter), Some(4), "the counter runs on");
        assert_eq!((sent[3].faults, sent[3].injected_n), (sim_faults::STUCK, -2.0));
        assert_eq!(sent[6].faults, sim_faults::SILENCE);
    }
}
