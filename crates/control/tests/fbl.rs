//! Feedback linearisation: closed-loop tracking on the model and output bounds.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_control::{
    clamp_throttle, throttle_for_virtual, ControlError, Fbl, FblGains, Profile, ProfileSpec, Reference, ThrottleLimit,
};
use jetbench_model::{Engine, Preset, State, STEP_S, THROTTLE_MAX_PCT, THROTTLE_MIN_PCT};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Runs the loop with the true state and returns `(t_s, thrust_n, reference_n, saturated)`.
fn closed_loop(profile: &Profile, initial: State, duration_s: f64) -> Vec<(f64, f64, f64, bool)> {
    let params = Preset::P100Diesel.params();
    let mut engine = Engine::new(params, initial);
    let mut fbl = Fbl::new(params, FblGains::default());
    let steps = (duration_s / STEP_S).round() as usize;
    let mut trace = Vec::with_capacity(steps);
    for k in 0..steps {
        let t_s = k as f64 * STEP_S;
        let reference = profile.at(t_s);
        let state = engine.state();
        let command = fbl.step(state, &reference).unwrap();
        trace.push((t_s, state.thrust_n, reference.thrust_n, command.saturated));
        engine.step(command.throttle_pct).unwrap();
    }
    trace
}

#[test]
fn tracks_a_step_from_20_to_60_n() {
    let profile = Profile::from(ProfileSpec::Steps { levels_n: vec![20.0, 60.0], hold_s: 6.0, smoothing_s: 0.2 });
    let initial = State { thrust_n: 20.0, thrust_rate_n_per_s: 0.0 };
    let trace = closed_loop(&profile, initial, 12.0);
    for &(t_s, thrust_n, reference_n, _) in &trace {
        let settled = (3.0..6.0).contains(&t_s) || (9.0..12.0).contains(&t_s);
        if settled {
            let target_n = if t_s < 6.0 { 20.0 } else { 60.0 };
            assert!((reference_n - target_n).abs() < 1e-3);
            assert!((thrust_n - target_n).abs() < 0.5, "t = {t_s}: {thrust_n} N");
        }
    }
    // The 40 N jump asks for more than full throttle at first.
    assert!(trace.iter().any(|&(t_s, _, _, saturated)| t_s >= 6.0 && saturated));
}

#[test]
fn tracks_a_smooth_reference_closely_throughout() {
    let profile = Profile::from(ProfileSpec::Sines { offset_n: 45.0, amplitude_n: 15.0, period_s: 5.0 });
    let initial = State { thrust_n: 45.0, thrust_rate_n_per_s: 0.0 };
    let trace = closed_loop(&profile, initial, 20.0);
    for &(t_s, thrust_n, reference_n, saturated) in &trace {
        assert!(!saturated, "t = {t_s}");
        if t_s > 2.0 {
            assert!((thrust_n - reference_n).abs() < 0.5, "t = {t_s}: {thrust_n} vs {reference_n}");
        }
    }
}

#[test]
fn command_is_always_in_range_for_random_and_extreme_inputs() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let extremes = [
        0.0,
        -0.0,
        5e-324,
        1e-300,
        -1e-300,
        1.0,
        -1.0,
        1e4,
        -1e4,
        1e6,
        -1e6,
        1e150,
        -1e150,
        1e300,
        -1e300,
        f64::MAX,
        f64::MIN,
    ];
    let pick = |rng: &mut ChaCha8Rng| -> f64 {
        if rng.random_bool(0.3) {
            extremes[rng.random_range(0..extremes.len())]
        } else {
            let magnitude = 10f64.powf(rng.random_range(-3.0..6.0));
            if rng.random_bool(0.5) {
                magnitude
            } else {
                -magnitude
            }
        }
    };
    for preset in Preset::ALL {
        let mut fbl = Fbl::new(preset.params(), FblGains::default());
        for _ in 0..20_000 {
            let (thrust_n, rate) = (pick(&mut rng), pick(&mut rng));
            let reference = Reference {
                thrust_n: pick(&mut rng),
                thrust_rate_n_per_s: pick(&mut rng),
                thrust_accel_n_per_s2: pick(&mut rng),
            };
            let c = fbl.step(State::new(thrust_n, rate), &reference).unwrap();
            assert!(
                (THROTTLE_MIN_PCT..=THROTTLE_MAX_PCT).contains(&c.throttle_pct),
                "{preset}: {c:?} for T {thrust_n}, Tdot {rate}, {reference:?}"
            );
            assert!(c.unclamped_pct.is_finite() && c.virtual_input.is_finite(), "{c:?}");
            if !c.saturated {
                assert_eq!(c.throttle_pct, c.unclamped_pct);
            }
        }
    }
}

#[test]
fn inverts_the_model_exactly_when_not_saturated() {
    let params = Preset::P100Diesel.params();
    let mut fbl = Fbl::new(params, FblGains::default());
    let (thrust_n, rate) = (40.0, 5.0);
    let reference = Reference { thrust_n: 42.0, thrust_rate_n_per_s: 8.0, thrust_accel_n_per_s2: 3.0 };
    let c = fbl.step(State::new(thrust_n, rate), &reference).unwrap();
    assert!(!c.saturated);
    let gains = FblGains::default();
    let wanted = 3.0 + gains.kp * 2.0 + gains.kd * 3.0;
    assert!((params.accel(thrust_n, rate, c.throttle_pct) - wanted).abs() < 1e-9);
}

#[test]
fn saturates_in_the_right_direction() {
    let params = Preset::P100Diesel.params();
    let mut fbl = Fbl::new(params, FblGains::default());
    let up = fbl.step(State::new(20.0, 0.0), &Reference { thrust_n: 90.0, ..Reference::default() }).unwrap();
    assert_eq!(up.throttle_pct, THROTTLE_MAX_PCT);
    assert!(up.saturated && up.unclamped_pct > THROTTLE_MAX_PCT);
    let down = fbl.step(State::new(80.0, 0.0), &Reference { thrust_n: 10.0, ..Reference::default() }).unwrap();
    assert_eq!(down.throttle_pct, THROTTLE_MIN_PCT);
    assert!(down.saturated);

    // g = 0: nothing to divide by; go where the thrust must go.
    let mut flat = params;
    flat.b_u = 0.0;
    flat.b_t = 0.0;
    flat.b_d = 0.0;
    let mut fbl = Fbl::new(flat, FblGains::default());
    let c = fbl.step(State::new(20.0, 0.0), &Reference { thrust_n: 60.0, ..Reference::default() }).unwrap();
    assert_eq!((c.throttle_pct, c.saturated), (THROTTLE_MAX_PCT, true));
}

#[test]
fn no_root_picks_the_closest_reachable_throttle() {
    // p220-ls: v(u) peaks at 33 %, so a large positive v has no root; the best the
    // engine can do is the peak.
    let params = Preset::P220Ls.params();
    let peak_pct = -1.0 / (2.0 * params.b_uu);
    let mut fbl = Fbl::new(params, FblGains::default());
    let g = params.g(100.0, 0.0);
    assert!(g < 0.0);
    // Ask for a strongly negative acceleration: v = needed/g is large and positive.
    let c = fbl.step(State::new(100.0, 0.0), &Reference { thrust_n: -1000.0, ..Reference::default() }).unwrap();
    assert!(c.saturated);
    assert!((c.throttle_pct - peak_pct).abs() < 1e-9, "{c:?}");
}

#[test]
fn non_finite_inputs_and_settings_are_errors() {
    let params = Preset::P100Diesel.params();
    let mut fbl = Fbl::new(params, FblGains::default());
    let r = Reference::default();
    assert!(matches!(
        fbl.step(State::new(f64::NAN, 0.0), &r),
        Err(ControlError::NonFiniteInput { what: "thrust", .. })
    ));
    let bad = Reference { thrust_accel_n_per_s2: f64::INFINITY, ..r };
    assert!(fbl.step(State::new(10.0, 0.0), &bad).is_err());
    let mut fbl = Fbl::new(params, FblGains { kp: f64::NAN, kd: 1.0, ki: 0.0 });
    assert!(matches!(fbl.step(State::new(10.0, 0.0), &r), Err(ControlError::InvalidSetting { name: "kp", .. })));
}

#[test]
fn clamp_throttle_bounds_everything() {
    assert_eq!(clamp_throttle(10.0), 25.0);
    assert_eq!(clamp_throttle(60.0), 60.0);
    assert_eq!(clamp_throttle(1e9), 100.0);
    assert_eq!(clamp_throttle(f64::NAN), 25.0);
    assert_eq!(clamp_throttle(f64::NEG_INFINITY), 25.0);
}

#[test]
fn default_gains_are_the_study_gains() {
    let gains = FblGains::default();
    assert_eq!(gains.kp, 10.0);
    assert!((gains.kd - 2.0 * 10.0_f64.sqrt()).abs() < 1e-15);
    assert_eq!(gains.ki, 0.0);
    let parsed: FblGains = toml::from_str("kp = 4.0\nkd = 4.0\n").unwrap();
    assert_eq!(parsed, FblGains { kp: 4.0, kd: 4.0, ki: 0.0 });
    // Keys left out keep the study's values; a typo is an error.
    let parsed: FblGains = toml::from_str("ki = 1.0\n").unwrap();
    assert_eq!(parsed, FblGains { ki: 1.0, ..FblGains::default() });
    assert!(toml::from_str::<FblGains>("kp = 4.0\nkd = 4.0\nkj = 1.0\n").is_err());
}

#[test]
fn the_disturbance_is_cancelled_like_the_drift_and_zero_changes_nothing() {
    let params = Preset::P100Diesel.params();
    let state = State::new(40.0, 12.0);
    let reference = Reference { thrust_n: 45.0, thrust_rate_n_per_s: 5.0, thrust_accel_n_per_s2: 0.0 };
    let plain = Fbl::new(params, FblGains::default()).step(state, &reference).unwrap();
    let zero = Fbl::new(params, FblGains::default()).step_with_disturbance(state, 0.0, &reference).unwrap();
    assert_eq!(plain, zero, "a zero disturbance changes nothing, bit for bit");
    // A disturbance of 8 N/s² is cancelled as a model whose constant drift c is 8 higher.
    let disturbed = Fbl::new(params, FblGains::default()).step_with_disturbance(state, 8.0, &reference).unwrap();
    let mut shifted = params;
    shifted.c += 8.0;
    let expected = Fbl::new(shifted, FblGains::default()).step(state, &reference).unwrap();
    assert!((disturbed.throttle_pct - expected.throttle_pct).abs() < 1e-9, "{disturbed:?} vs {expected:?}");
    assert!(disturbed.throttle_pct < plain.throttle_pct, "an accelerating disturbance asks for less throttle");
    // A non-finite disturbance counts as none.
    let nan = Fbl::new(params, FblGains::default()).step_with_disturbance(state, f64::NAN, &reference).unwrap();
    assert_eq!(nan, plain);
}

#[test]
fn a_command_held_at_idle_sits_at_the_low_limit_even_when_nothing_below_idle_was_asked() {
    let params = Preset::P100Diesel.params();
    // A virtual input below zero has no root on this map (`B_UU` > 0): the command is idle,
    // and the throttle it reports asked for is idle itself, not below it. FBL asks for one
    // when the engine must slow faster than the drift alone does.
    let below = throttle_for_virtual(&params, -10.0);
    assert_eq!((below.throttle_pct, below.unclamped_pct, below.saturated), (THROTTLE_MIN_PCT, THROTTLE_MIN_PCT, true));
    assert_eq!(below.limit(), Some(ThrottleLimit::Low));
    let above = throttle_for_virtual(&params, params.v(THROTTLE_MAX_PCT) + 10.0);
    assert_eq!((above.throttle_pct, above.limit()), (THROTTLE_MAX_PCT, Some(ThrottleLimit::High)));
    let inside = throttle_for_virtual(&params, params.v(60.0));
    assert_eq!(inside.limit(), None);
}
