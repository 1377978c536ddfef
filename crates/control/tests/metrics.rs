//! Tracking metrics on synthetic runs with known answers.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_control::{
    tracking_metrics, MetricsError, MetricsOptions, Profile, ProfileSpec, ThrottleLimit, TrackingMetrics,
    TrackingSample,
};

const DT_S: f64 = 0.01;

/// `duration_s` of samples at 100 Hz, each made by `sample(t_s)` with its time filled in.
fn run(duration_s: f64, sample: impl Fn(f64) -> TrackingSample) -> Vec<TrackingSample> {
    let n = (duration_s / DT_S).round() as usize;
    (0..n)
        .map(|k| {
            let t_s = k as f64 * DT_S;
            TrackingSample { time_s: t_s, ..sample(t_s) }
        })
        .collect()
}

/// A sample tracking `profile` with thrust `thrust_n`, throttle 50 %.
fn on_profile(profile: &Profile, t_s: f64, thrust_n: impl Fn(f64) -> f64) -> TrackingSample {
    let r = profile.at(t_s);
    TrackingSample {
        reference_n: r.thrust_n,
        reference_rate_n_per_s: r.thrust_rate_n_per_s,
        thrust_n: thrust_n(r.thrust_n),
        throttle_pct: 50.0,
        ..TrackingSample::default()
    }
}

fn metrics(samples: &[TrackingSample]) -> TrackingMetrics {
    tracking_metrics(samples, &MetricsOptions::default()).expect("valid samples")
}

fn assert_close(actual: f64, expected: f64, tolerance: f64, what: &str) {
    assert!((actual - expected).abs() <= tolerance, "{what}: {actual}, expected {expected} ± {tolerance}");
}

/// Raw steps 20 → 50 N at 2.5 s, held 5 s; the thrust responds as `τ = 0.3 s` first order.
fn first_order_step(t_s: f64) -> TrackingSample {
    let (reference_n, thrust_n) =
        if t_s < 2.5 { (20.0, 20.0) } else { (50.0, 50.0 - 30.0 * (-(t_s - 2.5) / 0.3).exp()) };
    TrackingSample { reference_n, thrust_n, throttle_pct: 50.0, ..TrackingSample::default() }
}

#[test]
fn a_first_order_response_settles_in_tau_ln_20_without_overshoot() {
    let m = metrics(&run(7.5, first_order_step));
    assert_eq!(m.holds.len(), 2, "{:?}", m.holds);
    assert_eq!(m.steps.len(), 1);
    let step = &m.steps[0];
    assert_eq!((step.from_n, step.to_n), (20.0, 50.0));
    assert_close(step.start_s, 2.5, 1e-9, "the step starts at the jump");
    assert_eq!(step.overshoot_pct, 0.0);
    // |T − 50| ≤ 5 % of 30 N once e^(−t/τ) ≤ 0.05: t = 0.3·ln 20 = 0.899 s, the next sample 0.90 s.
    assert_close(step.settling_time_s.expect("settles"), 0.3 * 20f64.ln(), DT_S, "settling time");
    assert!(!step.saturated);
    assert_eq!(m.mean_settling_time_s, step.settling_time_s);
    assert_eq!(m.unsettled_steps, 0);
    // Steady window: the last 40 % of 2.5-7.49 s; the remaining error there is below 30·e^(−10) N.
    assert_close(m.holds[1].window_start_s, 7.49 - 0.4 * 4.99, DT_S, "window start");
    assert_close(m.holds[1].steady_state_error_pct, 0.0, 0.01, "steady-state error");
}

#[test]
fn an_underdamped_response_overshoots_by_the_textbook_figure() {
    // ζ = 0.5, ωn = 5 rad/s: overshoot exp(−πζ/√(1 − ζ²)) = 16.30 % of the step.
    let (zeta, wn) = (0.5f64, 5.0f64);
    let wd = wn * (1.0 - zeta * zeta).sqrt();
    let response =
        |t: f64| 1.0 - (-zeta * wn * t).exp() * ((wd * t).cos() + zeta / (1.0 - zeta * zeta).sqrt() * (wd * t).sin());
    let samples = run(8.0, |t_s| {
        let (reference_n, thrust_n) = if t_s < 3.0 { (60.0, 60.0) } else { (40.0, 60.0 - 20.0 * response(t_s - 3.0)) };
        TrackingSample { reference_n, thrust_n, throttle_pct: 50.0, ..TrackingSample::default() }
    });
    let m = metrics(&samples);
    assert_eq!(m.steps.len(), 1);
    let expected_pct = 100.0 * (-std::f64::consts::PI * zeta / (1.0 - zeta * zeta).sqrt()).exp();
    assert_close(m.steps[0].overshoot_pct, expected_pct, 0.05, "overshoot of a step down");
    assert_eq!(m.max_overshoot_pct, Some(m.steps[0].overshoot_pct));
    // It last leaves the ±5 % band at 1.0578 s (the analytic response scanned at 1 µs); the
    // next sample is 1.06 s.
    assert_close(m.steps[0].settling_time_s.expect("settles"), 1.06, 1e-6, "settling time");
}

#[test]
fn a_thrust_on_the_smoothed_steps_profile_settles_when_the_prefilter_does() {
    let profile = Profile::default(); // 20, 50, 35, 70, 45, 30 N; 2.5 s each; τ = 0.2 s
    let m = metrics(&run(15.0, |t_s| on_profile(&profile, t_s, |r| r)));
    let levels: Vec<f64> = m.holds.iter().map(|h| h.level_n).collect();
    assert_eq!(levels.len(), 6, "one hold per level: {levels:?}");
    for (level, expected) in levels.iter().zip([20.0, 50.0, 35.0, 70.0, 45.0, 30.0]) {
        assert_close(*level, expected, 0.01, "hold level");
    }
    let moves: Vec<(f64, f64)> = m.steps.iter().map(|s| (s.from_n.round(), s.to_n.round())).collect();
    assert_eq!(moves, [(20.0, 50.0), (50.0, 35.0), (35.0, 70.0), (70.0, 45.0), (45.0, 30.0)]);
    // A critically damped prefilter is within the band b of its jump J once
    // (1 + x)·e^(−x) ≤ b/J, x = t/τ; b = max(5 % of J, 1 N). The step starts at the first
    // sample after the jump.
    for step in &m.steps {
        let jump_n = (step.to_n - step.from_n).abs();
        let band_n = (0.05 * jump_n).max(1.0);
        let x = bisect(|x| (1.0 + x) * (-x).exp() - band_n / jump_n, 1.0, 10.0);
        assert_close(step.settling_time_s.expect("settles"), 0.2 * x, 2.0 * DT_S, "settling time");
        assert_eq!(step.overshoot_pct, 0.0);
        assert_close(step.start_s % 2.5, 0.0, DT_S + 1e-9, "a step starts at a jump");
    }
    for hold in &m.holds {
        assert_close(hold.steady_state_error_pct, 0.0, 1e-9, "no error");
        // The last 40 % of each 2.5 s level: its last second.
        assert_close(hold.end_s - hold.window_start_s, 1.0, 2.0 * DT_S, "steady window");
    }
    assert_eq!(m.mae_n, 0.0);
    assert_eq!(m.within_5pct, 100.0);
}

/// Root of a function that changes sign between `a` and `b`.
fn bisect(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64) -> f64 {
    for _ in 0..100 {
        let mid = 0.5 * (a + b);
        if f(a).signum() == f(mid).signum() {
            a = mid;
        } else {
            b = mid;
        }
    }
    0.5 * (a + b)
}

#[test]
fn a_constant_offset_gives_a_known_steady_state_error_on_every_hold() {
    let profile = Profile::default();
    let m = metrics(&run(15.0, |t_s| on_profile(&profile, t_s, |r| r - 1.5)));
    assert_eq!(m.holds.len(), 6);
    for hold in &m.holds {
        assert_close(hold.steady_state_error_n, 1.5, 1e-9, "error, N");
        assert_close(hold.steady_state_error_pct, 150.0 / hold.level_n, 1e-6, "error, %");
    }
    // Worst on the 20 N hold; the mean of 1.5 N over the six levels (a hold's level is the
    // reference at its end, within 0.01 N of the nominal level).
    assert_close(m.worst_steady_state_error_pct.unwrap(), 7.5, 1e-6, "worst");
    let mean = [20.0, 50.0, 35.0, 70.0, 45.0, 30.0].iter().map(|l| 150.0 / l).sum::<f64>() / 6.0;
    assert_close(m.mean_steady_state_error_pct.unwrap(), mean, 1e-3, "mean");
    assert_close(m.mae_n, 1.5, 1e-9, "MAE");
    assert_close(m.rmse_n, 1.5, 1e-9, "RMSE");

    // Thrust above the reference: the error is negative, the worst and mean are magnitudes.
    let above = metrics(&run(15.0, |t_s| on_profile(&profile, t_s, |r| r + 1.5)));
    assert_close(above.holds[0].steady_state_error_pct, -7.5, 1e-6, "signed error");
    assert_close(above.worst_steady_state_error_pct.unwrap(), 7.5, 1e-6, "worst magnitude");
}

#[test]
fn a_throttle_square_wave_has_a_known_total_variation() {
    // 40 % and 60 % in turn every 0.5 s for 10 s: 19 changes of 20 %.
    let samples = run(10.0, |t_s| TrackingSample {
        reference_n: 30.0,
        thrust_n: 30.0,
        throttle_pct: if ((t_s + 1e-9) / 0.5).floor() as i64 % 2 == 0 { 40.0 } else { 60.0 },
        ..TrackingSample::default()
    });
    let m = metrics(&samples);
    assert_close(m.throttle_tv_pct, 380.0, 1e-9, "total variation");
    assert_close(m.throttle_tv_pct_per_s, 380.0 / 9.99, 1e-9, "per second");
    assert_close(m.throttle_change_rms_pct, (19.0 * 400.0 / 999.0f64).sqrt(), 1e-9, "RMS change");
    assert_close(m.mean_throttle_pct, 50.0, 1e-9, "mean throttle");
    assert_eq!(m.samples, 1000);
    assert_close(m.duration_s, 9.99, 1e-9, "duration");
}

#[test]
fn the_saturation_share_is_exact() {
    let mut samples = run(10.0, |_| TrackingSample { reference_n: 30.0, thrust_n: 30.0, ..TrackingSample::default() });
    for x in &mut samples[100..237] {
        x.saturated = Some(ThrottleLimit::Low);
    }
    for x in &mut samples[500..750] {
        x.saturated = Some(ThrottleLimit::High);
    }
    let m = metrics(&samples);
    assert_close(m.saturated_low_pct, 13.7, 1e-9, "low");
    assert_close(m.saturated_high_pct, 25.0, 1e-9, "high");
    assert_close(m.saturation_pct, 38.7, 1e-9, "either");
}

#[test]
fn a_step_is_saturated_only_by_saturation_early_in_it() {
    let mut samples = run(15.0, |t_s| {
        // Raw steps 20 → 50 → 20 N, 5 s each; a first-order response.
        let (from, to, since) = match t_s {
            t if t < 5.0 => (20.0, 20.0, t),
            t if t < 10.0 => (20.0, 50.0, t - 5.0),
            t => (50.0, 20.0, t - 10.0),
        };
        let thrust_n = to + (from - to) * (-since / 0.3).exp();
        TrackingSample { reference_n: to, thrust_n, throttle_pct: 50.0, ..TrackingSample::default() }
    });
    // Full throttle 0.2-0.7 s into the first step; idle 3 s into the second (after its window).
    for x in &mut samples[520..570] {
        x.saturated = Some(ThrottleLimit::High);
    }
    for x in &mut samples[1300..1310] {
        x.saturated = Some(ThrottleLimit::Low);
    }
    let m = metrics(&samples);
    assert_eq!(m.steps.len(), 2);
    assert!(m.steps[0].saturated);
    assert_close(m.steps[0].saturated_s, 0.5, 1e-9, "50 saturated cycles");
    assert!(!m.steps[1].saturated);
    assert_eq!(m.steps[1].saturated_s, 0.0);
    assert_eq!(m.saturated_steps, 1);
    // Only the unsaturated step counts towards the mean settling time.
    assert_eq!(m.mean_settling_time_s, m.steps[1].settling_time_s);
}

#[test]
fn a_step_that_never_settles_has_no_settling_time() {
    // 20 → 50 N, but the thrust stops at 45 N: outside ±1.5 N of 50 N to the end.
    let samples = run(6.0, |t_s| {
        let (reference_n, thrust_n) = if t_s < 2.5 { (20.0, 20.0) } else { (50.0, 45.0) };
        TrackingSample { reference_n, thrust_n, ..TrackingSample::default() }
    });
    let m = metrics(&samples);
    assert_eq!(m.steps.len(), 1);
    assert_eq!(m.steps[0].settling_time_s, None);
    assert_eq!(m.mean_settling_time_s, None);
    assert_eq!(m.unsettled_steps, 1);
    assert_close(m.holds[1].steady_state_error_pct, 10.0, 1e-9, "5 N below 50 N");
}

#[test]
fn ramps_between_holds_are_steps_that_settle_at_the_ramp_end() {
    // 20 N for 3 s, a 2 s ramp to 60 N (20 N/s), 3 s there, a ramp back, 3 s at 20 N.
    let profile = Profile::from(ProfileSpec::Ramps { levels_n: vec![20.0, 60.0], ramp_s: 2.0, hold_s: 3.0 });
    let m = metrics(&run(13.0, |t_s| on_profile(&profile, t_s, |r| r)));
    assert_eq!(m.steps.len(), 2, "{:?}", m.steps);
    assert_eq!((m.steps[0].from_n, m.steps[0].to_n), (20.0, 60.0));
    assert_eq!((m.steps[1].from_n, m.steps[1].to_n), (60.0, 20.0));
    // Within 2 N (5 % of 40 N) of 60 N at 58 N: 1.9 s into the ramp.
    assert_close(m.steps[0].settling_time_s.unwrap(), 1.9, DT_S + 1e-9, "settling on a ramp");
}

#[test]
fn sines_and_chirps_have_no_holds_but_all_other_figures() {
    let sines = Profile::from(ProfileSpec::Sines { offset_n: 45.0, amplitude_n: 20.0, period_s: 4.0 });
    let chirp =
        Profile::from(ProfileSpec::Chirp { offset_n: 45.0, amplitude_n: 15.0, f0_hz: 0.1, f1_hz: 2.0, sweep_s: 20.0 });
    for profile in [sines, chirp] {
        let m = metrics(&run(20.0, |t_s| on_profile(&profile, t_s, |r| r + 0.5)));
        assert!(m.holds.is_empty(), "{}: {:?}", profile.kind(), m.holds);
        assert!(m.steps.is_empty());
        assert_eq!(m.worst_steady_state_error_pct, None);
        assert_eq!(m.max_overshoot_pct, None);
        assert_eq!(m.mean_settling_time_s, None);
        assert_close(m.mae_n, 0.5, 1e-9, "MAE");
        assert_eq!(m.within_5pct, 100.0);
    }
}

/// `duration_s` of a constant reference, the thrust at `before_n` until `switch_s`, then at `after_n`.
fn held(duration_s: f64, reference_n: f64, switch_s: f64, before_n: f64, after_n: f64) -> Vec<TrackingSample> {
    run(duration_s, |t_s| TrackingSample {
        reference_n,
        thrust_n: if t_s < switch_s { before_n } else { after_n },
        ..TrackingSample::default()
    })
}

#[test]
fn the_tracking_band_has_a_floor_near_zero_thrust() {
    // At 10 N, 5 % is 0.5 N; the 1 N floor widens it. Half the samples 0.8 N off, half 1.2 N.
    let samples = held(4.0, 10.0, 2.0, 9.2, 8.8);
    assert_close(metrics(&samples).within_5pct, 50.0, 1e-9, "within the floor");
    // At 100 N the 5 % band (5 N) applies.
    let samples = held(4.0, 100.0, 1.0, 94.0, 96.0);
    assert_close(metrics(&samples).within_5pct, 75.0, 1e-9, "within 5 %");
}

#[test]
fn skip_leaves_out_the_start_up_transient() {
    // 50 N reference; the first second the thrust is 50 N short, then on it.
    let samples = held(5.0, 50.0, 1.0, 0.0, 50.0);
    assert_close(metrics(&samples).mae_n, 10.0, 1e-9, "with the transient");
    let skipped = tracking_metrics(&samples, &MetricsOptions { skip_s: 1.0, ..MetricsOptions::default() }).unwrap();
    assert_eq!(skipped.mae_n, 0.0);
    assert_eq!(skipped.samples, 400);
}

#[test]
fn solve_time_percentiles_are_nearest_rank_and_fallbacks_are_counted() {
    let mut samples = run(1.0, |_| TrackingSample { reference_n: 30.0, thrust_n: 30.0, ..TrackingSample::default() });
    for (k, x) in samples.iter_mut().enumerate() {
        x.solve_us = 100 - k as u32; // 100 down to 1 µs
        x.fallback = k % 25 == 0;
    }
    let m = metrics(&samples);
    assert_eq!((m.solve_us.p50, m.solve_us.p99, m.solve_us.max), (50, 99, 100));
    assert_eq!(m.fallbacks, 4);
}

#[test]
fn bad_input_is_a_typed_error_not_a_panic() {
    let options = MetricsOptions::default();
    assert_eq!(tracking_metrics(&[], &options), Err(MetricsError::TooFewSamples { samples: 0 }));
    let mut samples = run(2.0, |_| TrackingSample { reference_n: 30.0, thrust_n: 30.0, ..TrackingSample::default() });
    assert_eq!(tracking_metrics(&samples[..1], &options), Err(MetricsError::TooFewSamples { samples: 1 }));

    let too_long = MetricsOptions { skip_s: 5.0, ..options };
    assert!(matches!(tracking_metrics(&samples, &too_long), Err(MetricsError::SkippedEverything { left: 0, .. })));
    let nan_option = MetricsOptions { min_hold_s: f64::NAN, ..options };
    assert!(matches!(
        tracking_metrics(&samples, &nan_option),
        Err(MetricsError::InvalidOption { name: "min_hold_s", .. })
    ));

    samples[17].thrust_n = f64::NAN;
    assert!(matches!(
        tracking_metrics(&samples, &options),
        Err(MetricsError::NonFinite { index: 17, field: "thrust_n", .. })
    ));
    samples[17].thrust_n = 30.0;
    samples[40].time_s = samples[39].time_s;
    let error = tracking_metrics(&samples, &options).unwrap_err();
    assert!(matches!(error, MetricsError::TimeNotIncreasing { index: 40, .. }));
    assert!(error.to_string().contains("sort the samples by time"), "{error}");
}
