//! Reference profiles: derivatives, smoothing, repetition, frequency, config parsing.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_control::{ControlError, Profile, ProfileSpec, Reference};
use serde::Deserialize;

fn steps() -> Profile {
    Profile::from(ProfileSpec::Steps { levels_n: vec![20.0, 60.0, 35.0], hold_s: 2.0, smoothing_s: 0.2 })
}

fn ramps() -> Profile {
    Profile::from(ProfileSpec::Ramps { levels_n: vec![20.0, 60.0, 35.0], ramp_s: 1.5, hold_s: 1.0 })
}

fn sines() -> Profile {
    Profile::from(ProfileSpec::Sines { offset_n: 45.0, amplitude_n: 20.0, period_s: 4.0 })
}

fn chirp() -> Profile {
    Profile::from(ProfileSpec::Chirp { offset_n: 45.0, amplitude_n: 10.0, f0_hz: 0.2, f1_hz: 2.0, sweep_s: 20.0 })
}

/// Times away from the profile's kinks (jumps, corners, chirp wrap), where `r''` or `r'`
/// is discontinuous and a central difference is meaningless.
fn smooth_times(kinks_every_s: &[f64]) -> impl Iterator<Item = f64> + '_ {
    (1..4000).map(|k| f64::from(k) * 0.01 + 0.003).filter(move |t| {
        kinks_every_s.iter().all(|period| {
            let phase = t.rem_euclid(*period);
            phase > 1e-3 && period - phase > 1e-3
        })
    })
}

fn assert_close(what: &str, t: f64, analytic: f64, numeric: f64, scale: f64) {
    assert!(
        (analytic - numeric).abs() <= 1e-5 * scale,
        "{what} at t = {t}: analytic {analytic} vs finite difference {numeric}"
    );
}

fn check_derivatives(profile: &Profile, kinks_every_s: &[f64], rate_scale: f64, accel_scale: f64) {
    let h = 1e-5;
    for t in smooth_times(kinks_every_s) {
        let (lo, mid, hi) = (profile.at(t - h), profile.at(t), profile.at(t + h));
        let rate = (hi.thrust_n - lo.thrust_n) / (2.0 * h);
        let accel = (hi.thrust_rate_n_per_s - lo.thrust_rate_n_per_s) / (2.0 * h);
        assert_close("rate", t, mid.thrust_rate_n_per_s, rate, rate_scale);
        assert_close("accel", t, mid.thrust_accel_n_per_s2, accel, accel_scale);
    }
}

#[test]
fn steps_derivatives_match_finite_differences() {
    // Peak rate of a smoothed jump is Δ/(e·τ) = 74 N/s, peak acceleration Δ/τ² = 1000 N/s².
    check_derivatives(&steps(), &[2.0], 74.0, 1000.0);
}

#[test]
fn ramps_derivatives_match_finite_differences() {
    check_derivatives(&ramps(), &[2.5, 2.5], 30.0, 1.0);
    let during_ramp = ramps().at(1.75);
    assert!((during_ramp.thrust_n - 40.0).abs() < 1e-12);
    assert!((during_ramp.thrust_rate_n_per_s - 40.0 / 1.5).abs() < 1e-12);
}

#[test]
fn sines_derivatives_match_finite_differences() {
    check_derivatives(&sines(), &[], 32.0, 50.0);
}

#[test]
fn chirp_derivatives_match_finite_differences() {
    check_derivatives(&chirp(), &[20.0], 130.0, 1600.0);
}

#[test]
fn smoothed_steps_follow_the_critically_damped_response() {
    let profile = steps();
    let tau: f64 = 0.2;
    // Before the first jump: level 0, at rest.
    assert_eq!(profile.at(1.9), Reference { thrust_n: 20.0, ..Reference::default() });
    for s in [0.0_f64, 0.1, 0.2, 0.5, 1.0] {
        let expected = 20.0 + 40.0 * (1.0 - (1.0 + s / tau) * (-s / tau).exp());
        let got = profile.at(2.0 + s).thrust_n;
        assert!((got - expected).abs() < 1e-9, "s = {s}: {got} vs {expected}");
    }
    // No overshoot, and the level is reached by the end of the hold.
    let mut previous = 20.0;
    for k in 0..200 {
        let r = profile.at(2.0 + f64::from(k) * 0.01).thrust_n;
        assert!(r >= previous - 1e-12 && r <= 60.0 + 1e-12);
        previous = r;
    }
    // Ten time constants after the jump, (1 + 10)·e⁻¹⁰ of it is left: 0.02 N.
    assert!((profile.at(3.999).thrust_n - 60.0).abs() < 0.05);
}

#[test]
fn unsmoothed_steps_are_exact_levels() {
    let profile = Profile::from(ProfileSpec::Steps { levels_n: vec![20.0, 60.0], hold_s: 1.0, smoothing_s: 0.0 });
    assert_eq!(profile.at(0.999).thrust_n, 20.0);
    assert_eq!(profile.at(1.0).thrust_n, 60.0);
    assert_eq!(profile.at(1.5).thrust_rate_n_per_s, 0.0);
    assert_eq!(profile.at(2.0).thrust_n, 20.0);
}

#[test]
fn profiles_repeat() {
    for (profile, cycle_s) in [(steps(), 6.0), (ramps(), 7.5), (sines(), 4.0), (chirp(), 20.0)] {
        for k in 0..500 {
            let t = 30.0 + f64::from(k) * 0.0137;
            let (a, b) = (profile.at(t), profile.at(t + cycle_s));
            for (x, y) in [
                (a.thrust_n, b.thrust_n),
                (a.thrust_rate_n_per_s, b.thrust_rate_n_per_s),
                (a.thrust_accel_n_per_s2, b.thrust_accel_n_per_s2),
            ] {
                assert!((x - y).abs() < 1e-6 * (1.0 + x.abs()), "{} at {t}", profile.kind());
            }
        }
    }
    // The cycle wraps from the last level back to the first.
    assert!((steps().at(5.99).thrust_n - 35.0).abs() < 0.05);
    assert!((steps().at(7.99).thrust_n - 20.0).abs() < 0.05);
}

#[test]
fn chirp_sweeps_its_frequency_linearly() {
    let profile = chirp();
    let dt = 1e-4;
    let mut upward_crossings = Vec::new();
    let mut previous = profile.at(0.0).thrust_n - 45.0;
    for k in 1..(20.0 / dt) as usize {
        let t = k as f64 * dt;
        let x = profile.at(t).thrust_n - 45.0;
        if previous < 0.0 && x >= 0.0 {
            upward_crossings.push(t - dt * x / (x - previous));
        }
        previous = x;
    }
    assert!(upward_crossings.len() > 10);
    for pair in upward_crossings.windows(2) {
        let mid_s = 0.5 * (pair[0] + pair[1]);
        let expected_hz = 0.2 + (2.0 - 0.2) * mid_s / 20.0;
        let measured_hz = 1.0 / (pair[1] - pair[0]);
        assert!(
            (measured_hz - expected_hz).abs() < 0.01 * expected_hz,
            "at {mid_s} s: {measured_hz} Hz vs {expected_hz} Hz"
        );
    }
    // After the wrap it starts again at f0.
    assert_eq!(profile.at(20.5), profile.at(0.5));
}

#[test]
fn span_covers_what_the_profile_visits() {
    assert_eq!(steps().span_n(), (20.0, 60.0));
    assert_eq!(ramps().span_n(), (20.0, 60.0));
    assert_eq!(sines().span_n(), (25.0, 65.0));
    assert_eq!(chirp().span_n(), (35.0, 55.0));
    for profile in [steps(), ramps(), sines(), chirp()] {
        let (lo, hi) = profile.span_n();
        for k in 0..3000 {
            let r = profile.at(f64::from(k) * 0.01).thrust_n;
            assert!(r >= lo - 1e-9 && r <= hi + 1e-9, "{}: {r}", profile.kind());
        }
    }
}

#[test]
fn default_profile_stays_inside_the_default_plant_range() {
    let profile = Profile::default();
    profile.validate().unwrap();
    let (lo, hi) = profile.span_n();
    let params = jetbench_model::Preset::P100Diesel.params();
    let idle_n = params.stable_equilibrium(25.0).unwrap();
    let full_n = params.stable_equilibrium(100.0).unwrap();
    assert!(lo > idle_n + 5.0 && hi < full_n - 5.0, "{lo}..{hi} vs {idle_n}..{full_n}");
    assert_eq!(profile.at(0.0).thrust_n, 20.0);
}

#[test]
fn bad_times_count_as_zero() {
    let profile = sines();
    assert_eq!(profile.at(-3.0), profile.at(0.0));
    assert_eq!(profile.at(f64::NAN), profile.at(0.0));
    assert_eq!(profile.at(f64::INFINITY), profile.at(0.0));
}

#[test]
fn validate_rejects_bad_settings() {
    let cases = [
        (Profile::from(ProfileSpec::Steps { levels_n: vec![], hold_s: 1.0, smoothing_s: 0.1 }), "levels"),
        (Profile::from(ProfileSpec::Steps { levels_n: vec![1.0], hold_s: 0.0, smoothing_s: 0.1 }), "hold_s"),
        (Profile::from(ProfileSpec::Steps { levels_n: vec![f64::NAN], hold_s: 1.0, smoothing_s: 0.1 }), "levels_n"),
        (Profile::from(ProfileSpec::Steps { levels_n: vec![1.0], hold_s: 1.0, smoothing_s: -0.1 }), "smoothing_s"),
        (Profile::from(ProfileSpec::Ramps { levels_n: vec![1.0], ramp_s: 0.0, hold_s: 1.0 }), "ramp_s"),
        (Profile::from(ProfileSpec::Sines { offset_n: 1.0, amplitude_n: 1.0, period_s: -1.0 }), "period_s"),
        (
            Profile::from(ProfileSpec::Chirp {
                offset_n: 1.0,
                amplitude_n: 1.0,
                f0_hz: -0.1,
                f1_hz: 1.0,
                sweep_s: 1.0,
            }),
            "f0_hz",
        ),
        (
            Profile::from(ProfileSpec::Chirp {
                offset_n: 1.0,
                amplitude_n: f64::INFINITY,
                f0_hz: 0.1,
                f1_hz: 1.0,
                sweep_s: 1.0,
            }),
            "amplitude_n",
        ),
    ];
    for (profile, field) in cases {
        let err = profile.validate().unwrap_err();
        assert!(err.to_string().contains(field), "{profile:?}: {err}");
        // An invalid profile yields a zero reference, never NaN or a hang.
        assert_eq!(profile.at(5.0), Reference::default());
    }
    assert!(matches!(
        Profile::from(ProfileSpec::Steps { levels_n: vec![], hold_s: 1.0, smoothing_s: 0.1 }).validate(),
        Err(ControlError::EmptyLevels { kind: "steps" })
    ));
    // A config is checked when it is read, once: the verdict travels with the profile.
    let read = parse("[reference]\nkind = \"steps\"\nlevels_n = [20.0]\nhold_s = 0.0\nsmoothing_s = 0.2\n").unwrap();
    assert!(matches!(read.validate(), Err(ControlError::InvalidDuration { field: "hold_s", .. })));
    assert_eq!(read.at(1.0), Reference::default());
    // A campaign is as good as its worst part.
    let part = |profile: Profile| jetbench_control::Segment { duration_s: 2.0, profile };
    let campaign = Profile::from(ProfileSpec::Campaign { segments: vec![part(steps()), part(read)] });
    assert!(campaign.validate().is_err());
    assert_eq!(campaign.at(0.5), Reference::default());
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Config {
    reference: Profile,
}

fn parse(text: &str) -> Result<Profile, toml::de::Error> {
    toml::from_str::<Config>(text).map(|c| c.reference)
}

#[test]
fn profiles_parse_from_toml() {
    let text = r#"
        [reference]
        kind = "steps"            # steps | ramps | sines | chirp
        levels_n = [20.0, 50.0, 35.0, 70.0]
        hold_s = 2.5
        smoothing_s = 0.2
    "#;
    assert_eq!(
        parse(text).unwrap(),
        Profile::from(ProfileSpec::Steps { levels_n: vec![20.0, 50.0, 35.0, 70.0], hold_s: 2.5, smoothing_s: 0.2 })
    );
    let chirp_text = "[reference]\nkind = \"chirp\"\noffset_n = 45.0\namplitude_n = 10.0\n\
                      f0_hz = 0.2\nf1_hz = 2.0\nsweep_s = 20.0\n";
    assert_eq!(parse(chirp_text).unwrap(), chirp());
}

#[test]
fn typo_keys_and_unknown_kinds_are_rejected() {
    let typo = "[reference]\nkind = \"steps\"\nlevels_n = [20.0]\nhold_s = 2.5\nsmoothing_s = 0.2\nsmothing_s = 0.3\n";
    let err = parse(typo).unwrap_err();
    assert!(err.to_string().contains("smothing_s"), "{err}");
    let missing = "[reference]\nkind = \"sines\"\noffset_n = 1.0\namplitude_n = 1.0\n";
    assert!(parse(missing).unwrap_err().to_string().contains("period_s"));
    let unknown = "[reference]\nkind = \"square\"\nlevels_n = [1.0]\n";
    assert!(parse(unknown).unwrap_err().to_string().contains("square"));
}

#[test]
fn profiles_round_trip_through_toml() {
    for profile in [steps(), ramps(), sines(), chirp(), Profile::default()] {
        #[derive(serde::Serialize)]
        struct Out<'a> {
            reference: &'a Profile,
        }
        let text = toml::to_string(&Out { reference: &profile }).unwrap();
        assert_eq!(parse(&text).unwrap(), profile, "{text}");
    }
}
