//! Rest points, their stability, and the throttle-map inversion.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_model::{Engine, Params, Preset, State, STEP_S};

const PUBLISHED: [(f64, f64); 4] = [(25.0, -0.094), (50.0, 24.868), (75.0, 52.877), (100.0, 86.177)];

#[test]
fn p100_diesel_stable_equilibria_match_plant_md() {
    let params = Preset::P100Diesel.params();
    for (throttle_pct, expected_n) in PUBLISHED {
        let stable: Vec<_> = params.equilibria(throttle_pct).into_iter().filter(|e| e.stable).collect();
        assert_eq!(stable.len(), 1, "one stable rest point at {throttle_pct} %");
        assert!(
            (stable[0].thrust_n - expected_n).abs() < 0.01,
            "{throttle_pct} %: {} N vs {expected_n} N",
            stable[0].thrust_n
        );
    }
}

#[test]
fn p100_diesel_engine_settles_at_the_equilibria() {
    let params = Preset::P100Diesel.params();
    for (throttle_pct, expected_n) in PUBLISHED {
        let mut engine = Engine::new(params, State::default());
        let steps = (60.0 / STEP_S) as usize;
        let mut last = State::default();
        for _ in 0..steps {
            last = engine.step(throttle_pct).unwrap();
        }
        assert!(
            (last.thrust_n - expected_n).abs() < 0.01,
            "{throttle_pct} %: simulated {} N vs {expected_n} N",
            last.thrust_n
        );
        assert!(last.thrust_rate_n_per_s.abs() < 1e-3);
    }
}

#[test]
fn p100_diesel_has_one_stable_equilibrium_per_throttle_in_range() {
    let params = Preset::P100Diesel.params();
    for throttle_pct in (25..=120).map(f64::from) {
        let stable = params.equilibria(throttle_pct).iter().filter(|e| e.stable).count();
        assert_eq!(stable, 1, "at {throttle_pct} %");
    }
}

#[test]
fn p100_ekf_has_an_unstable_negative_equilibrium() {
    let params = Preset::P100Ekf.params();
    let eq = params.equilibria(100.0);
    assert!(eq.iter().any(|e| e.thrust_n < 0.0 && !e.stable), "{eq:?}");
    assert!(eq.iter().any(|e| e.thrust_n > 0.0 && e.stable), "{eq:?}");
}

#[test]
fn equilibria_handle_the_linear_case_and_bad_throttle() {
    let mut params = Preset::P100Diesel.params();
    params.k_tt = 0.0;
    let eq = params.equilibria(50.0);
    assert_eq!(eq.len(), 1);
    let root = eq[0].thrust_n;
    assert!(params.accel(root, 0.0, 50.0).abs() < 1e-9);
    assert!(params.equilibria(f64::NAN).is_empty());
}

#[test]
fn equilibria_are_roots_of_the_acceleration() {
    for preset in Preset::ALL {
        let params = preset.params();
        for throttle_pct in [25.0, 60.0, 100.0] {
            for e in params.equilibria(throttle_pct) {
                let scale = 1.0 + e.thrust_n.abs();
                assert!(
                    params.accel(e.thrust_n, 0.0, throttle_pct).abs() < 1e-9 * scale * scale,
                    "{preset} at {throttle_pct} %: {e:?}"
                );
            }
        }
    }
}

#[test]
fn invert_v_round_trips_on_the_rising_branch_for_all_presets() {
    for preset in Preset::ALL {
        let params = preset.params();
        for i in 0..=240 {
            let u = f64::from(i) * 0.5;
            let slope = 1.0 + 2.0 * params.b_uu * u;
            let v = params.v(u);
            // Where v(u) falls (p220-ls above 33 %), u is only recovered once v < 0: the
            // smallest non-negative root is the documented choice.
            if slope > 1e-3 || v < 0.0 {
                let back = params.invert_v(v).unwrap();
                assert!((back - u).abs() < 1e-9, "{preset}: u {u} -> v {v} -> {back}");
            } else {
                let back = params.invert_v(v).unwrap();
                assert!((params.v(back) - v).abs() < 1e-9, "{preset}: u {u}");
                assert!(back <= u);
            }
        }
    }
}

#[test]
fn invert_v_is_exact_for_zero_and_tiny_curvature() {
    let mut params = Preset::P100Diesel.params();
    params.b_uu = 0.0;
    assert_eq!(params.invert_v(42.5), Some(42.5));
    assert_eq!(params.invert_v(-1.0), None);
    params.b_uu = 1e-15;
    for u in [0.0, 25.0, 100.0, 1e4] {
        let back = params.invert_v(params.v(u)).unwrap();
        assert!((back - u).abs() <= 1e-12 * (1.0 + u), "{u} -> {back}");
    }
}

#[test]
fn invert_v_survives_huge_values() {
    for preset in Preset::ALL {
        let params = preset.params();
        for v in [1e300, -1e300, 1e307] {
            if let Some(u) = params.invert_v(v) {
                assert!(u.is_finite() && u >= 0.0, "{preset}: {v} -> {u}");
                let back = params.v(u);
                assert!(((back - v) / v).abs() < 1e-9, "{preset}: {v} -> {u} -> {back}");
            }
        }
    }
    let mut steep = Preset::P100Diesel.params();
    steep.b_uu = 10.0;
    let u = steep.invert_v(1e308).unwrap();
    assert!(((steep.v(u) - 1e308) / 1e308).abs() < 1e-9, "{u}");
    assert!(steep.invert_v(f64::MAX).is_some_and(f64::is_finite));
}

#[test]
fn invert_v_rejects_unreachable_values() {
    let params = Preset::P100Diesel.params();
    assert_eq!(params.invert_v(-0.5), None);
    assert_eq!(params.invert_v(f64::NAN), None);
    assert_eq!(params.invert_v(f64::INFINITY), None);
    let ls = Preset::P220Ls.params();
    let u_peak = -1.0 / (2.0 * ls.b_uu);
    assert_eq!(ls.invert_v(ls.v(u_peak) + 1.0), None);
    // Negative v has exactly one positive root, beyond twice the peak.
    let back = ls.invert_v(-50.0).unwrap();
    assert!(back > 2.0 * u_peak && (ls.v(back) + 50.0).abs() < 1e-9);
}

#[test]
fn array_conversion_follows_names() {
    let params = Preset::P220Ls.params();
    let a = params.to_array();
    assert_eq!(Params::from_array(a), params);
    assert_eq!(Params::NAMES[5], "c");
    assert_eq!(a[5], params.c);
    assert_eq!(a[9], params.b_uu);
}

#[test]
fn accel_partials_match_finite_differences() {
    let params = Preset::P100Ekf.params();
    let (t, d, u) = (40.0, 12.0, 70.0);
    let p = params.accel_partials(t, d, u);
    let h = 1e-5;
    let dt = (params.accel(t + h, d, u) - params.accel(t - h, d, u)) / (2.0 * h);
    let dd = (params.accel(t, d + h, u) - params.accel(t, d - h, u)) / (2.0 * h);
    assert!((p.d_thrust_per_s2 - dt).abs() < 1e-6);
    assert!((p.d_rate_per_s - dd).abs() < 1e-6);
}

#[test]
fn validate_names_the_bad_parameter() {
    let mut params = Preset::P100Diesel.params();
    assert!(params.validate().is_ok());
    params.b_t = f64::INFINITY;
    let err = params.validate().unwrap_err();
    assert!(err.to_string().contains("B_T"), "{err}");
}
