//! FBL, SMC and MPC on the model itself: limits, steady state, saturation, delay, failure.

use jetbench_control::{
    ControlError, ControllerKind, FblGains, Law, LawSettings, Mpc, MpcSettings, Profile, ProfileSpec, Reference,
    ReferenceShaper, ShaperSettings, Smc, SmcGains,
};
use jetbench_model::{Effects, Params, Plant, Preset, STEP_S};

/// One closed-loop run on the true state: reference, thrust, throttle per cycle.
struct Run {
    reference_n: Vec<f64>,
    thrust_n: Vec<f64>,
    throttle_pct: Vec<f64>,
    fallbacks: usize,
}

fn run(kind: ControllerKind, truth: &Plant, model: &Plant, settings: &LawSettings, profile: &Profile, s: f64) -> Run {
    let mut law = Law::new(kind, model, settings);
    let mut engine = truth.at_equilibrium(25.0);
    let mut out = Run { reference_n: vec![], thrust_n: vec![], throttle_pct: vec![], fallbacks: 0 };
    for k in 0..(s / STEP_S) as usize {
        let state = engine.state();
        let step = law.step(state.thrust_n, state.thrust_rate_n_per_s, k as f64 * STEP_S, profile).unwrap();
        engine.step(step.command.throttle_pct).unwrap();
        out.reference_n.push(step.reference.thrust_n);
        out.thrust_n.push(state.thrust_n);
        out.throttle_pct.push(step.command.throttle_pct);
        out.fallbacks += step.fallback as usize;
    }
    out
}

fn p100() -> Plant {
    Plant::new(Preset::P100Diesel.params(), Effects::none())
}

fn with_delay(delay_s: f64) -> Plant {
    let effect = format!("input_delay:delay_s={delay_s}").parse().unwrap();
    Plant::new(Preset::P100Diesel.params(), Effects::new([effect]).unwrap())
}

fn steps_profile(params: &Params) -> Profile {
    let idle = params.stable_equilibrium(25.0).unwrap();
    let max = params.stable_equilibrium(100.0).unwrap();
    Profile::builtin("steps", idle, max).unwrap()
}

/// Hold `j` of the built-in steps (5 s each): mean error over its settled middle, % of
/// the level (from 2.5 s in to 1 s before its end, when a previewing law leaves early).
fn hold_error_pct(run: &Run, j: usize) -> f64 {
    let range = j * 500 + 250..j * 500 + 400;
    let level = run.reference_n[range.start];
    let mean: f64 = range.clone().map(|k| run.thrust_n[k] - run.reference_n[k]).sum::<f64>() / range.len() as f64;
    100.0 * mean / level
}

fn mae_n(run: &Run) -> f64 {
    run.reference_n.iter().zip(&run.thrust_n).map(|(r, t)| (r - t).abs()).sum::<f64>() / run.thrust_n.len() as f64
}

fn total_variation_pct(run: &Run) -> f64 {
    run.throttle_pct.windows(2).map(|w| (w[1] - w[0]).abs()).sum()
}

#[test]
fn every_law_holds_the_steps_within_two_percent_and_the_throttle_in_range() {
    let plant = p100();
    let profile = steps_profile(&plant.params);
    for kind in ControllerKind::ALL {
        let r = run(kind, &plant, &plant, &LawSettings::default(), &profile, 55.0);
        assert!(r.throttle_pct.iter().all(|u| (25.0..=100.0).contains(u)), "{kind}");
        assert_eq!(r.fallbacks, 0, "{kind}");
        for j in 0..11 {
            let e = hold_error_pct(&r, j);
            assert!(e.abs() < 2.0, "{kind}: hold {j} at {:.1} N off by {e:.2} %", r.reference_n[j * 500 + 250]);
        }
    }
}

#[test]
fn mpc_tracks_saturating_steps_much_better_than_fbl() {
    let plant = p100();
    let profile = steps_profile(&plant.params);
    let settings = LawSettings::default();
    let fbl = mae_n(&run(ControllerKind::Fbl, &plant, &plant, &settings, &profile, 55.0));
    let mpc = mae_n(&run(ControllerKind::Mpc, &plant, &plant, &settings, &profile, 55.0));
    assert!(mpc < 0.7 * fbl, "MPC MAE {mpc:.2} N vs FBL {fbl:.2} N");
}

#[test]
fn the_diagnosed_delay_improves_every_law() {
    let truth = with_delay(0.12);
    let nominal = p100();
    let profile = steps_profile(&nominal.params);
    let settings = LawSettings::default();
    for kind in ControllerKind::ALL {
        let blind = mae_n(&run(kind, &truth, &nominal, &settings, &profile, 55.0));
        let aware = mae_n(&run(kind, &truth, &truth, &settings, &profile, 55.0));
        assert!(aware < 0.9 * blind, "{kind}: MAE {aware:.2} N with the delay vs {blind:.2} N without");
    }
}

#[test]
fn smc_is_the_study_law_and_its_boundary_layer_trades_chattering() {
    let params = Preset::P100Diesel.params();
    let gains = SmcGains::default();
    assert_eq!((gains.a1, gains.beta, gains.k), (20.0, 900.0, 0.15));
    // One step by hand: s = a1(T − T_d) + (Ṫ − Ṫ_d), v = −(a1(Ṫ − Ṫ_d) + f − T̈_d)/g − β tanh(K s).
    let soft = SmcGains { a1: 20.0, beta: 10.0, k: 0.01 };
    let mut smc = Smc::new(params, soft);
    let r = Reference { thrust_n: 40.0, thrust_rate_n_per_s: 1.0, thrust_accel_n_per_s2: 0.5 };
    let (t, d) = (39.0, 2.0);
    let s = 20.0 * (t - 40.0) + (d - 1.0);
    let v = -(20.0 * (d - 1.0) + params.f(t, d) - 0.5) / params.g(t, d) - 10.0 * (0.01 * s).tanh();
    let c = smc.step(t, d, &r).unwrap();
    assert!((c.virtual_input - v).abs() < 1e-9, "{} vs {v}", c.virtual_input);
    assert!((params.v(c.throttle_pct) - v).abs() < 1e-9);

    // A wider boundary layer (smaller k) means less throttle activity.
    let plant = p100();
    let profile = steps_profile(&params);
    let tv = |k: f64| {
        let settings = LawSettings { smc: SmcGains { k, ..SmcGains::default() }, ..LawSettings::default() };
        total_variation_pct(&run(ControllerKind::Smc, &plant, &plant, &settings, &profile, 20.0))
    };
    let (sharp, wide) = (tv(0.15), tv(0.005));
    assert!(wide < 0.5 * sharp, "total variation {wide:.0} % with k = 0.005 vs {sharp:.0} % with k = 0.15");
}

#[test]
fn a_diverging_model_makes_the_mpc_fall_back_not_stall() {
    // A model whose thrust runs away within the horizon whatever the throttle (an unstable
    // pole at 20/s): the MPC's predictions diverge, and FBL on the same model (which
    // cancels the pole) commands those cycles.
    let mut params = Preset::P100Diesel.params();
    params.k_t = 400.0;
    let model = Plant::new(params, Effects::none());
    let truth = p100();
    let profile = Profile::from(ProfileSpec::Steps { levels_n: vec![20.0, 80.0], hold_s: 3.0, smoothing_s: 0.0 });
    let mut mpc = Mpc::new(model, MpcSettings::default(), FblGains::default());
    let mut engine = truth.at_equilibrium(25.0);
    let mut fallbacks = 0;
    for k in 0..600 {
        let s = engine.state();
        let out = mpc.step(s.thrust_n, s.thrust_rate_n_per_s, k as f64 * STEP_S, &profile).unwrap();
        assert!((25.0..=100.0).contains(&out.command.throttle_pct));
        fallbacks += out.fallback as u64;
        engine.step(out.command.throttle_pct).unwrap();
    }
    assert!(fallbacks > 0);
    assert_eq!(fallbacks, mpc.fallbacks());
}

#[test]
fn bad_settings_and_inputs_are_errors_not_panics() {
    let plant = p100();
    let profile = Profile::default();
    let bad = MpcSettings { moves: 0, ..MpcSettings::default() };
    assert!(matches!(bad.validate(), Err(ControlError::SettingOutOfRange { name: "moves", .. })));
    let mut mpc = Mpc::new(plant.clone(), bad, FblGains::default());
    assert!(mpc.step(10.0, 0.0, 0.0, &profile).is_err());
    let mut law = Law::new(ControllerKind::Mpc, &plant, &LawSettings::default());
    assert!(matches!(law.step(f64::NAN, 0.0, 0.0, &profile), Err(ControlError::NonFiniteInput { .. })));
    let mut smc = Smc::new(plant.params, SmcGains { beta: f64::INFINITY, ..SmcGains::default() });
    assert!(matches!(smc.step(10.0, 0.0, &Reference::default()), Err(ControlError::InvalidSetting { .. })));
    let parsed: Result<LawSettings, _> = toml::from_str("[mpc]\nhorizon = 1.0\n");
    assert!(parsed.is_err(), "a typo in a key is an error");
}

#[test]
fn the_shaper_passes_a_feasible_reference_and_limits_an_infeasible_one() {
    let params = Preset::P100Diesel.params();
    let settings = ShaperSettings::default();
    // A slow sine inside the range passes unchanged once the shaper is on it.
    let sine = Profile::from(ProfileSpec::Sines { offset_n: 40.0, amplitude_n: 10.0, period_s: 8.0 });
    let mut shaper = ReferenceShaper::new(params, settings);
    for k in 0..800 {
        let t = k as f64 * STEP_S;
        let r = sine.at(t);
        let shaped = shaper.step(&r);
        if k > 0 {
            assert!((shaped.thrust_n - r.thrust_n).abs() < 0.05, "t = {t}: {} vs {}", shaped.thrust_n, r.thrust_n);
        }
    }
    // A raw step beyond full thrust: the shaped reference stays in the steady range and
    // never asks for more acceleration than the model has at full throttle.
    let step = Profile::from(ProfileSpec::Steps { levels_n: vec![20.0, 150.0], hold_s: 2.0, smoothing_s: 0.0 });
    let max_n = params.stable_equilibrium(100.0).unwrap();
    let mut shaper = ReferenceShaper::new(params, settings);
    shaper.start_at(20.0, 0.0);
    for k in 0..400 {
        let shaped = shaper.step(&step.at(k as f64 * STEP_S));
        assert!(shaped.thrust_n <= max_n + 1e-6);
        let full = params.accel(shaped.thrust_n, shaped.thrust_rate_n_per_s, 100.0);
        assert!(shaped.thrust_accel_n_per_s2 <= full.max(0.0) + 1e-9);
    }
}
