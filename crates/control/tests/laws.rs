//! FBL, SMC and MPC on the model itself: limits, steady state, saturation, delay, failure.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_control::{
    tracking_metrics, ControlError, Controller, FblGains, Law, LawSettings, MetricsOptions, Mpc, MpcSettings, Profile,
    ProfileSpec, Reference, ReferenceShaper, ShaperSettings, Smc, SmcGains, TrackingMetrics, TrackingSample,
};
use jetbench_estim::{ObserverConfig, ThrustObserver};
use jetbench_model::turbojet::TurbojetParams;
use jetbench_model::{Effects, ModelFile, Params, Plant, Preset, State, STEP_S, THROTTLE_MIN_PCT};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// One closed-loop run on the true state: reference, thrust, throttle per cycle.
struct Run {
    reference_n: Vec<f64>,
    thrust_n: Vec<f64>,
    throttle_pct: Vec<f64>,
    fallbacks: usize,
}

fn run(kind: Controller, truth: &Plant, model: &Plant, settings: &LawSettings, profile: &Profile, s: f64) -> Run {
    let mut law = Law::new(kind, model, settings).expect("a feedback law");
    let mut engine = truth.at_equilibrium(25.0);
    let mut out = Run { reference_n: vec![], thrust_n: vec![], throttle_pct: vec![], fallbacks: 0 };
    for k in 0..(s / STEP_S) as usize {
        let state = engine.state();
        let step = law.step(state, k as f64 * STEP_S, profile).unwrap();
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
    for kind in Controller::LAWS {
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
    let fbl = mae_n(&run(Controller::Fbl, &plant, &plant, &settings, &profile, 55.0));
    let mpc = mae_n(&run(Controller::Mpc, &plant, &plant, &settings, &profile, 55.0));
    assert!(mpc < 0.7 * fbl, "MPC MAE {mpc:.2} N vs FBL {fbl:.2} N");
}

/// One closed-loop run as on the simulated bench, 56 s: `law` on `model` driving `truth`, the
/// force sensor's noise (7 N², drawn from `seed`), an EKF observer of `config` between sensor
/// and law (its disturbance handed to the law, as the control service does), the throttle
/// applied reaching the observer a cycle later; scored on the true thrust.
fn observed_run(
    truth: &Plant,
    model: &Plant,
    law: (Controller, &LawSettings),
    config: ObserverConfig,
    profile: &Profile,
    seed: u64,
) -> TrackingMetrics {
    let mut law = Law::new(law.0, model, law.1).expect("a feedback law");
    let mut observer = ThrustObserver::new(model.params, config);
    let mut engine = truth.at_equilibrium(25.0);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 7.0_f64.sqrt()).unwrap();
    let mut applied_pct = THROTTLE_MIN_PCT;
    let mut samples = Vec::with_capacity(5600);
    for k in 0..5600 {
        let truth_state = engine.state();
        let estimate = observer.step(engine.measured_n() + noise.sample(&mut rng), applied_pct).unwrap();
        let time_s = k as f64 * STEP_S;
        let state = State::new(estimate.thrust_n, estimate.thrust_rate_n_per_s);
        let out = law.step_with_disturbance(state, estimate.disturbance_n_per_s2, time_s, profile).unwrap();
        applied_pct = out.command.throttle_pct;
        engine.step(applied_pct).unwrap();
        samples.push(TrackingSample {
            time_s,
            reference_n: out.reference.thrust_n,
            reference_rate_n_per_s: out.reference.thrust_rate_n_per_s,
            thrust_n: truth_state.thrust_n,
            throttle_pct: applied_pct,
            saturated: out.command.limit(),
            fallback: out.fallback,
            solve_us: 0,
        });
    }
    tracking_metrics(&samples, &MetricsOptions { skip_s: 1.0, ..MetricsOptions::default() }).unwrap()
}

/// [`observed_run`] on the model itself with the observer tuning the control issue was
/// accepted on (150 N/s² of unmodelled acceleration, no disturbance state). The MPC's
/// correction has no integral, as in config/sim.toml: the engine is the model.
fn noisy_run(kind: Controller, plant: &Plant, profile: &Profile, seed: u64) -> TrackingMetrics {
    let settings = LawSettings {
        mpc: MpcSettings { integral_rad_per_s: 0.0, ..MpcSettings::default() },
        ..LawSettings::default()
    };
    let config = ObserverConfig { measurement_var_n2: 7.0, accel_noise_n_per_s2: 150.0, ..ObserverConfig::default() };
    observed_run(plant, plant, (kind, &settings), config, profile, seed)
}

/// The control issue's acceptance on the steps with sensor noise: the MPC's MAE at least
/// 30 % below FBL's, its steady-state error under 2 %, and on the small steps where FBL
/// does not saturate (56 → 52, 52 → 34, 34 → 39 N on this plant) settling
/// (±max(5 % of the step, 1 N)) no slower than FBL's. Both settle as the smoothed
/// reference enters the band, 0.5-0.9 s after the step; noise moves a single run's entry
/// by a few 10 ms either way, and FBL, after lagging the reference, passes it and enters
/// up to a sample earlier, so the comparison is of the mean over noise draws, to within
/// two 10 ms samples. Every draw must settle every step. (Regression: planning from the
/// noisy estimate itself, the MPC's thrust wandered out of the ±1 N band, 56 → 52 N did
/// not settle at all and 52 → 34 N took 3.3 s.)
#[test]
fn with_sensor_noise_the_mpc_tracks_better_and_settles_small_steps_no_slower_than_fbl() {
    let plant = p100();
    let profile = steps_profile(&plant.params);
    let seeds = [1, 2, 3, 4];
    let (mut fbl_settling_s, mut mpc_settling_s) = (vec![0.0; 10], vec![0.0; 10]);
    // Steps FBL takes without saturating in some draw (52 → 34 N saturates it in some).
    let mut small_steps = [false; 10];
    for seed in seeds {
        let fbl = noisy_run(Controller::Fbl, &plant, &profile, seed);
        let mpc = noisy_run(Controller::Mpc, &plant, &profile, seed);
        assert!(mpc.mae_n < 0.7 * fbl.mae_n, "seed {seed}: MAE MPC {:.2} N vs FBL {:.2} N", mpc.mae_n, fbl.mae_n);
        assert_eq!((fbl.steps.len(), mpc.steps.len()), (10, 10), "seed {seed}");
        for hold in &mpc.holds[1..] {
            let e = hold.steady_state_error_pct;
            assert!(e.abs() < 2.0, "seed {seed}: MPC off by {e:.2} % at {:.1} N", hold.level_n);
        }
        for (j, (f, m)) in fbl.steps.iter().zip(&mpc.steps).enumerate() {
            small_steps[j] |= !f.saturated;
            let unsettled = |law| format!("seed {seed}: {law} never settles {:.1} -> {:.1} N", f.from_n, f.to_n);
            fbl_settling_s[j] += f.settling_time_s.unwrap_or_else(|| panic!("{}", unsettled("FBL"))) / 4.0;
            mpc_settling_s[j] += m.settling_time_s.unwrap_or_else(|| panic!("{}", unsettled("MPC"))) / 4.0;
        }
    }
    let small: Vec<usize> = (0..10).filter(|&j| small_steps[j]).collect();
    assert!([5, 6, 7].iter().all(|j| small.contains(j)), "steps FBL takes unsaturated: {small:?}");
    for j in small {
        let (f, m) = (fbl_settling_s[j], mpc_settling_s[j]);
        assert!(m <= f + 2.0 * STEP_S, "step {}: MPC settles in {m:.3} s on average, FBL in {f:.3} s", j + 1);
    }
}

#[test]
fn the_diagnosed_delay_improves_every_law() {
    let truth = with_delay(0.12);
    let nominal = p100();
    let profile = steps_profile(&nominal.params);
    let settings = LawSettings::default();
    for kind in Controller::LAWS {
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
    let c = smc.step(State::new(t, d), &r).unwrap();
    assert!((c.virtual_input - v).abs() < 1e-9, "{} vs {v}", c.virtual_input);
    assert!((params.v(c.throttle_pct) - v).abs() < 1e-9);

    // A wider boundary layer (smaller k) means less throttle activity.
    let plant = p100();
    let profile = steps_profile(&params);
    let tv = |k: f64| {
        let settings = LawSettings { smc: SmcGains { k, ..SmcGains::default() }, ..LawSettings::default() };
        total_variation_pct(&run(Controller::Smc, &plant, &plant, &settings, &profile, 20.0))
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
        let out = mpc.step(s, k as f64 * STEP_S, &profile).unwrap();
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
    for omega in [0.0, f64::NAN, 50.0] {
        let bad = MpcSettings { correction_rad_per_s: omega, ..MpcSettings::default() };
        assert!(matches!(bad.validate(), Err(ControlError::SettingOutOfRange { name: "correction_rad_per_s", .. })));
    }
    let mut mpc = Mpc::new(plant.clone(), bad, FblGains::default());
    assert!(mpc.step(State::new(10.0, 0.0), 0.0, &profile).is_err());
    let mut law = Law::new(Controller::Mpc, &plant, &LawSettings::default()).expect("a feedback law");
    assert!(matches!(law.step(State::new(f64::NAN, 0.0), 0.0, &profile), Err(ControlError::NonFiniteInput { .. })));
    let mut smc = Smc::new(plant.params, SmcGains { beta: f64::INFINITY, ..SmcGains::default() });
    assert!(matches!(smc.step(State::new(10.0, 0.0), &Reference::default()), Err(ControlError::InvalidSetting { .. })));
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

/// A law on `model` driving `truth` through the built-in steps (scaled to the model's
/// range, as on the bench), the bench's calm observer (`[estimator]` of config/sim.toml), the
/// MPC's integral at `integral_rad_per_s`: each hold's steady-state error, %.
fn holds_off_model(truth: &Plant, model: &Plant, kind: Controller, integral_rad_per_s: f64) -> Vec<f64> {
    let profile = steps_profile(&model.params);
    let settings =
        LawSettings { mpc: MpcSettings { integral_rad_per_s, ..MpcSettings::default() }, ..LawSettings::default() };
    let config = ObserverConfig {
        measurement_var_n2: 7.0,
        accel_noise_n_per_s2: 10.0,
        disturbance_drift_n_per_s2: 1.5,
        ..ObserverConfig::default()
    };
    let metrics = observed_run(truth, model, (kind, &settings), config, &profile, 7);
    metrics.holds[1..].iter().map(|h| h.steady_state_error_pct).collect()
}

/// A model that is off leaves the MPC without its integral an offset on every hold (about
/// `Δa/ω²`); the integral (the default) learns the acceleration the model lacks and takes
/// the offset out, as the observer's disturbance does for FBL. A gain error's acceleration
/// changes with the throttle, so after a full step both relearn it over a second or two:
/// on the 21.5 N hold after 81.9 N both are 2.3 % off in this draw, so the worst hold is
/// held to FBL's.
#[test]
fn the_mpcs_integral_holds_a_model_that_is_off_on_the_reference() {
    let mean = |e: &[f64]| e.iter().map(|x| x.abs()).sum::<f64>() / e.len() as f64;
    let worst = |e: &[f64]| e.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    let truth = p100();
    let mut params = truth.params;
    params.b_u *= 0.9;
    let model = Plant::new(params, Effects::none());
    let holds = |kind, integral| holds_off_model(&truth, &model, kind, integral);
    let (without, with) =
        (holds(Controller::Mpc, 0.0), holds(Controller::Mpc, MpcSettings::default().integral_rad_per_s));
    let fbl = holds(Controller::Fbl, 0.0);
    assert_eq!((without.len(), with.len(), fbl.len()), (10, 10, 10));
    assert!(without.iter().all(|e| *e < -2.0), "a low gain leaves the thrust low: {without:.2?} %");
    assert!(mean(&with) < 1.0, "with the integral: hold errors {with:.2?} %");
    assert!(worst(&with) < worst(&fbl) + 0.25, "worst hold: MPC {with:.2?} %, FBL {fbl:.2?} %");
}

/// A ten-parameter model `jetbench identify` wrote from a 300 s campaign of the turbojet
/// plant (`sim-record --plant turbojet-p100 --seed 7`, scripts/turbojet-closed-loop.sh):
/// bounded, 1.2× the noise floor on held-out data, and stiff (`∂T̈/∂T` about −165/s² at
/// 20 N, against the correction's ω² = 10).
const TURBOJET_IDENTIFIED: &str = "
[model]
K_T = -81.21432187476843
K_TT = -5.375524875703246
K_D = 6.2893715593542545
K_DD = 0.09613806326258148
K_TD = 1.3961712704506108
c = -149.74813576254255
B_U = 1.2265077605185746
B_T = 0.20274026304671314
B_D = -0.05993556175491519
B_UU = 0.27916478014457485

[effects.rate_limit]
up_pct_per_s = 250.0
down_pct_per_s = 250.0

[effects.discrepancy]
B_DD = -3.294357708611699e-6
";

/// The turbojet under the MPC with the model identified from it. Without the integral the
/// correction, which sets the model-to-engine error to `(s + ω)²` whatever the model's own
/// stiffness, cancels most of this model's stiffness, and the corrected model settles in a
/// state of its own: 3.6 N above the estimate and rising at 7 N/s, held there by the
/// correction, the plan content with it. The MPC then holds 21.5 N 15 % low. With the
/// integral no state but the estimate's can hold (its input, the innovation, must vanish).
#[test]
fn on_the_turbojet_with_its_identified_model_the_mpcs_integral_holds_every_step() {
    let truth = Plant::with_turbojet(TurbojetParams::p100(), Effects::none());
    let model = ModelFile::from_toml_str(TURBOJET_IDENTIFIED).unwrap().plant();
    let worst = |e: &[f64]| e.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    let without = holds_off_model(&truth, &model, Controller::Mpc, 0.0);
    let with = holds_off_model(&truth, &model, Controller::Mpc, MpcSettings::default().integral_rad_per_s);
    assert!(worst(&without) > 10.0, "without the integral: hold errors {without:.2?} %");
    assert!(worst(&with) < 2.0, "with the integral: hold errors {with:.2?} %");
}
