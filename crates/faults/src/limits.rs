//! No false trips on a healthy engine: `jetbench up --sim` on a profile with
//! every limit of the P100 preset on (`[limits] preset = "p100"`, the sensor's
//! silence included), nothing injected, and each limit's trips counted from
//! `bench/events`. Beside the count, the margin: for each limit, the worst
//! value its monitored quantity held for the limit's hold time (what a trip
//! needs), recomputed from the recording the way the monitor sees it, and
//! how far that is from the limit.

use std::path::Path;

use jetbench_msgs::{channels, event_kinds, EcuTelemetry};
use jetbench_record::Recording;
use jetbench_stack::limits::{LimitKind, Limits, ThrustLag, EGT_RATE_WINDOW_NS};

use crate::set::run_to_end;
use crate::{Bench, FaultsError};

/// The profiles a healthy engine is run on.
pub const PROFILES: [&str; 2] = ["campaign", "steps"];

/// One healthy run.
#[derive(Clone, Debug, Default)]
pub struct HealthyRun {
    /// The reference profile run (`campaign` or `steps`).
    pub profile: String,
    /// Length of the run, s.
    pub duration_s: u32,
    /// Run with the config's real-time settings (`jetbench up --rt`).
    pub rt: bool,
    /// Trips in `bench/events`, by [`LimitKind::ALL`] order.
    pub trips: [u32; 8],
    /// The worst value held for each limit's hold while the engine ran (for
    /// `min_rpm` the lowest, for the others the highest), in the limit's unit.
    pub held: [Option<f64>; 8],
    /// The worst single value.
    pub peak: [Option<f64>; 8],
    /// The thrust-against-RPM disagreement held for its hold if the map had
    /// no lag (thrust compared with the RPM's thrust as they come), N: what
    /// the lag saves.
    pub band_without_lag: Option<f64>,
    /// Gaps between fresh ECU readings while the ECU said run that are
    /// longer than [`ECU_GAP_FLOOR_S`] (a poll missed or late), s.
    pub ecu_gaps: Vec<f64>,
    /// Gaps between force-sensor samples while the engine ran that are
    /// longer than [`SENSOR_GAP_FLOOR_S`] (a frame missed or late), s.
    pub sensor_gaps: Vec<f64>,
    /// The sensor's silence as control's limit monitor can see it, longer than
    /// [`SENSOR_GAP_FLOOR_S`], s: at each estimate, when it was published less
    /// the stamp of the estimate before it. The monitor judges the silence
    /// only with every waiting estimate taken, so a stall of the sensor or of
    /// estimation counts (control is blind either way), control's own lateness
    /// does not.
    pub monitor_ages: Vec<f64>,
    /// Time the ECU said run, s: what the gaps are counted over.
    pub running_s: f64,
    /// Polls in that time the ECU did not answer within the poll (samples
    /// flagged stale): a gap with them is the ECU's (or its line's) lateness,
    /// one without them the poller's own delay.
    pub ecu_stale: u32,
    /// What was wrong with the run (a trip, a failed launcher), in words.
    pub problems: Vec<String>,
}

/// An ECU gap worth counting, s: one and a half polls at the presets' 15 Hz
/// (a reading on time is 67 ms after the last; a missed poll makes 133 ms).
pub const ECU_GAP_FLOOR_S: f64 = 0.1;

/// A force-sensor gap worth counting, s: two frames at 100 Hz.
pub const SENSOR_GAP_FLOOR_S: f64 = 0.02;

/// The bench config of these runs: config/sim.toml with `[limits]` the P100
/// preset, every limit on.
pub fn config_text() -> String {
    let text = jetbench_stack::config::DEFAULT_SIM_CONFIG;
    let base = text.split("\n[limits]").next().unwrap_or(text);
    format!("{base}\n[limits]\npreset = \"p100\"\n")
}

/// Runs `jetbench up --sim --profile PROFILE` for `duration_s` (with `--rt`
/// when `rt`) and judges it.
pub fn healthy_run(bench: &Bench, profile: &str, duration_s: u32, rt: bool) -> Result<HealthyRun, FaultsError> {
    let namespace = bench.fresh_namespace();
    let config = bench.scratch(&format!("limits-{namespace}.toml"));
    std::fs::write(&config, config_text()).map_err(|source| FaultsError::Io { path: config.clone(), source })?;
    let record = bench.scratch(&format!("limits-{namespace}.mcap"));
    let mut command = bench.command(&namespace);
    command.args(["up", "--sim", "--quiet", "--duration", &duration_s.to_string(), "--profile", profile]);
    command.arg("--config").arg(&config).arg("--record").arg(&record);
    if rt {
        command.arg("--rt");
    }
    let (status, said) = run_to_end(&mut command, "jetbench up (healthy engine)")?;
    let mut run = judge(&Recording::open(&record)?, &Limits::preset("p100").expect("the p100 preset"));
    run.profile = profile.into();
    run.duration_s = duration_s;
    run.rt = rt;
    if !status.success() {
        run.problems.push(format!("jetbench up exited {status}: {}", said.lines().last().unwrap_or_default()));
    }
    for (kind, n) in LimitKind::ALL.iter().zip(run.trips) {
        if n > 0 {
            run.problems.push(format!("{} tripped {n} time(s) on a healthy engine ({profile})", kind.key()));
        }
    }
    let _ = std::fs::remove_file(&record);
    let _ = std::fs::remove_file(Path::new(&config));
    Ok(run)
}

/// A series of (time ns, value): the worst value held for `hold_s` (the
/// best of the window starting at each sample, worst over the windows whose
/// end the series reaches).
fn held(series: &[(u64, f64)], hold_s: f64, worst_is_high: bool) -> Option<f64> {
    let hold_ns = (hold_s * 1e9) as u64;
    let better = |a: f64, b: f64| if worst_is_high { a.min(b) } else { a.max(b) };
    let worse = |a: f64, b: f64| if worst_is_high { a.max(b) } else { a.min(b) };
    let mut out: Option<f64> = None;
    for (i, &(t0, v0)) in series.iter().enumerate() {
        // Held through the window: a sample comes after it (or the hold is 0).
        let mut v = v0;
        let mut reached = hold_ns == 0;
        for &(t, x) in &series[i + 1..] {
            if t > t0 + hold_ns {
                reached = true;
                break;
            }
            v = better(v, x);
        }
        if reached {
            out = Some(out.map_or(v, |o| worse(o, v)));
        }
    }
    out
}

fn peak(series: &[(u64, f64)], worst_is_high: bool) -> Option<f64> {
    series.iter().map(|(_, v)| *v).reduce(|a, b| if worst_is_high { a.max(b) } else { a.min(b) })
}

/// Judges a recording against `limits`: trips counted, margins measured
/// while the ECU said run.
pub fn judge(recording: &Recording, limits: &Limits) -> HealthyRun {
    let events = recording.samples(channels::EVENTS);
    let mut run = HealthyRun::default();
    for e in events.iter().filter(|e| e.kind == event_kinds::TRIP) {
        if let Some(kind) = LimitKind::from_code(e.code) {
            run.trips[kind as usize] += 1;
        }
    }
    let run_code = u32::from(jetbench_io::ecu::state::EcuState::Run.code());
    let ecu: Vec<EcuTelemetry> =
        recording.samples(channels::ECU).into_iter().filter(|t| t.flags == 0 && t.state == run_code).collect();
    let states = recording.samples(channels::STATE);
    let thrust = recording.samples(channels::THRUST);
    let (Some(first), Some(last)) = (ecu.first(), ecu.last()) else {
        run.problems.push("the engine never ran".into());
        return run;
    };
    let running = |t: u64| t >= first.stamp_ns && t <= last.stamp_ns;
    let estimate: Vec<(u64, f64)> =
        states.iter().filter(|s| running(s.stamp_ns)).map(|s| (s.stamp_ns, s.thrust_n)).collect();
    let egt: Vec<(u64, f64)> = ecu.iter().map(|t| (t.stamp_ns, t.egt_c)).collect();
    let rpm: Vec<(u64, f64)> = ecu.iter().map(|t| (t.stamp_ns, t.rpm)).collect();
    let mut rise = Vec::new();
    for (i, &(t, e)) in egt.iter().enumerate() {
        if let Some(&(t0, e0)) = egt[..i].iter().rev().find(|(t0, _)| t0 + EGT_RATE_WINDOW_NS <= t) {
            rise.push((t, (e - e0) / ((t - t0) as f64 * 1e-9)));
        }
    }
    let mut apart = Vec::new();
    let mut apart_now = Vec::new();
    if let Some(map) = limits.rpm_map {
        let mut j = 0;
        let mut lag = ThrustLag::new(map.lag_s);
        for &(t, x) in &estimate {
            let lagged = lag.step(t, x);
            while j + 1 < rpm.len() && rpm[j + 1].0 <= t {
                j += 1;
            }
            if rpm[j].0 <= t {
                apart.push((t, (lagged - map.thrust_n(rpm[j].1)).abs()));
                apart_now.push((t, (x - map.thrust_n(rpm[j].1)).abs()));
            }
        }
    }
    let gaps = |stamps: &[u64]| -> Vec<(u64, f64)> {
        stamps.windows(2).map(|w| (w[1], (w[1].saturating_sub(w[0])) as f64 * 1e-9)).collect()
    };
    let ecu_gaps = gaps(&ecu.iter().map(|t| t.stamp_ns).collect::<Vec<_>>());
    let sensor_gaps = gaps(&thrust.iter().map(|t| t.stamp_ns).filter(|t| running(*t)).collect::<Vec<_>>());
    run.ecu_gaps = ecu_gaps.iter().map(|g| g.1).filter(|g| *g > ECU_GAP_FLOOR_S).collect();
    run.sensor_gaps = sensor_gaps.iter().map(|g| g.1).filter(|g| *g > SENSOR_GAP_FLOOR_S).collect();
    run.running_s = (last.stamp_ns - first.stamp_ns) as f64 * 1e-9;
    let available: Vec<(u64, u64)> =
        states.iter().filter(|s| running(s.publish_ns)).map(|s| (s.stamp_ns, s.publish_ns)).collect();
    run.monitor_ages = available
        .windows(2)
        .map(|w| w[1].1.saturating_sub(w[0].0) as f64 * 1e-9)
        .filter(|a| *a > SENSOR_GAP_FLOOR_S)
        .collect();
    run.ecu_stale = recording
        .samples::<EcuTelemetry>(channels::ECU)
        .iter()
        .filter(|t| t.flags & jetbench_msgs::ecu_flags::STALE != 0 && running(t.stamp_ns))
        .count() as u32;
    for kind in LimitKind::ALL {
        let (series, high): (&[(u64, f64)], bool) = match kind {
            LimitKind::MaxThrust => (&estimate, true),
            LimitKind::MaxEgt => (&egt, true),
            LimitKind::MaxEgtRise => (&rise, true),
            LimitKind::MaxRpm => (&rpm, true),
            LimitKind::MinRpm => (&rpm, false),
            LimitKind::ThrustRpmBand => (&apart, true),
            LimitKind::EcuSilent => (&ecu_gaps, true),
            LimitKind::SensorSilent => (&sensor_gaps, true),
        };
        let hold_s = limits.get(kind).map_or(0.0, |l| l.hold_s);
        // A gap is held by itself: its length is what the limit compares.
        let silence = matches!(kind, LimitKind::EcuSilent | LimitKind::SensorSilent);
        run.held[kind as usize] = if silence { peak(series, high) } else { held(series, hold_s, high) };
        run.peak[kind as usize] = peak(series, high);
    }
    let band_hold = limits.get(LimitKind::ThrustRpmBand).map_or(0.0, |l| l.hold_s);
    run.band_without_lag = held(&apart_now, band_hold, true);
    run
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_counts_only_as_long_as_it_is_held() {
        let ms = 1_000_000u64;
        // 10 ms samples: 50 everywhere, 90 for 50 ms, 70 for 300 ms.
        let series: Vec<(u64, f64)> = (0..200u64)
            .map(|k| {
                let v = match k {
                    20..=24 => 90.0,
                    100..=129 => 70.0,
                    _ => 50.0,
                };
                (k * 10 * ms, v)
            })
            .collect();
        assert_eq!(peak(&series, true), Some(90.0));
        assert_eq!(held(&series, 0.0, true), Some(90.0));
        assert_eq!(held(&series, 0.1, true), Some(70.0));
        assert_eq!(held(&series, 0.5, true), Some(50.0));
        assert_eq!(held(&series, 0.1, false), Some(50.0));
    }
}
