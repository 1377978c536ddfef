//! Observer accuracy, input rejection, fallbacks and determinism.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

mod common;

use common::{rms, simulate_plant_run, simulate_run, Run, NOISE_VAR_N2};
use jetbench_estim::{EstimError, Estimate, Gated, ObserverConfig, ThrustObserver, Verdict, MAX_SETTLING_STEPS};
use jetbench_model::{Effects, Params, Plant, Preset, STEP_S};

/// Skip the first second, while the filter converges from its initial guess.
const SKIP: usize = 100;

fn observe(run: &Run, params: Params, config: ObserverConfig) -> (Vec<Estimate>, u64) {
    let mut observer = ThrustObserver::new(params, config);
    let estimates =
        run.thrust_meas_n.iter().zip(&run.throttle_pct).map(|(&y, &u)| observer.step(y, u).unwrap()).collect();
    (estimates, observer.fallbacks())
}

fn errors(run: &Run, estimates: &[Estimate]) -> (f64, f64, f64) {
    let n = run.truth.len();
    let thrust = rms((SKIP..n).map(|k| estimates[k].thrust_n - run.truth[k].thrust_n));
    let rate = rms((SKIP..n).map(|k| estimates[k].thrust_rate_n_per_s - run.truth[k].thrust_rate_n_per_s));
    let first_difference = rms((SKIP..n)
        .map(|k| (run.thrust_meas_n[k] - run.thrust_meas_n[k - 1]) / STEP_S - run.truth[k].thrust_rate_n_per_s));
    (thrust, rate, first_difference)
}

#[test]
fn matched_model_beats_the_noise_and_a_first_difference() {
    let params = Preset::P100Diesel.params();
    let run = simulate_run(params, 60.0, 7);
    let (estimates, fallbacks) = observe(&run, params, ObserverConfig::default());
    let (thrust_rms, rate_rms, fd_rms) = errors(&run, &estimates);
    assert_eq!(fallbacks, 0);
    assert!(thrust_rms < NOISE_VAR_N2.sqrt(), "thrust rms {thrust_rms} N");
    assert!(thrust_rms < 1.0, "thrust rms {thrust_rms} N");
    assert!(rate_rms < fd_rms / 3.0, "rate rms {rate_rms} vs first difference {fd_rms} N/s");
    assert!(rate_rms < 10.0, "rate rms {rate_rms} N/s");
}

#[test]
fn mismatched_study_models_still_track() {
    // The default process noise is chosen for this case: a model that is off by a few N.
    let run = simulate_run(Preset::P100Diesel.params(), 60.0, 11);
    for preset in [Preset::P100Ekf, Preset::P100Ls] {
        let (estimates, _) = observe(&run, preset.params(), ObserverConfig::default());
        let (thrust_rms, rate_rms, fd_rms) = errors(&run, &estimates);
        assert!(thrust_rms < NOISE_VAR_N2.sqrt(), "{preset}: thrust rms {thrust_rms} N");
        assert!(rate_rms < fd_rms / 3.0, "{preset}: rate rms {rate_rms} N/s");
        let worst_n =
            (SKIP..run.truth.len()).map(|k| (estimates[k].thrust_n - run.truth[k].thrust_n).abs()).fold(0.0, f64::max);
        assert!(worst_n < 8.0, "{preset}: worst thrust error {worst_n} N");
    }
}

#[test]
fn first_call_initialises_from_the_measurement() {
    let mut observer = ThrustObserver::new(Preset::P100Diesel.params(), ObserverConfig::default());
    let e = observer.step(31.5, 60.0).unwrap();
    assert_eq!(e.thrust_n, 31.5);
    assert_eq!(e.thrust_rate_n_per_s, 0.0);
    assert_eq!(e.innovation_n, 0.0);
    assert_eq!(e.thrust_var_n2, ObserverConfig::default().initial_thrust_var_n2);
    let params = Preset::P100Diesel.params();
    assert_eq!(e.thrust_accel_n_per_s2, params.accel(31.5, 0.0, 60.0));
}

#[test]
fn non_finite_inputs_are_rejected_without_corrupting_state() {
    let params = Preset::P100Diesel.params();
    let run = simulate_run(params, 3.0, 3);
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    for k in 0..150 {
        observer.step(run.thrust_meas_n[k], run.throttle_pct[k]).unwrap();
    }
    let mut untouched = observer.clone();
    for (y, u) in [(f64::NAN, 50.0), (f64::INFINITY, 50.0), (30.0, f64::NAN)] {
        assert!(matches!(observer.step(y, u), Err(EstimError::NonFiniteInput { .. })));
    }
    for k in 150..run.truth.len() {
        let (y, u) = (run.thrust_meas_n[k], run.throttle_pct[k]);
        assert_eq!(observer.step(y, u).unwrap(), untouched.step(y, u).unwrap());
    }
}

#[test]
fn same_inputs_give_bit_identical_outputs() {
    let params = Preset::P100Diesel.params();
    let run = simulate_run(params, 20.0, 5);
    let (a, _) = observe(&run, params, ObserverConfig::default());
    let (b, _) = observe(&run, params, ObserverConfig::default());
    let bits = |e: &Estimate| {
        [e.thrust_n, e.thrust_rate_n_per_s, e.thrust_accel_n_per_s2, e.innovation_n, e.thrust_var_n2, e.thrust_rate_var]
            .map(f64::to_bits)
    };
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(bits(x), bits(y));
    }
}

#[test]
fn a_diverging_model_falls_back_and_never_returns_nan() {
    // Acceleration far beyond anything physical: every model prediction is unusable.
    let mut params = Preset::P100Diesel.params();
    params.c = 1e300;
    let run = simulate_run(Preset::P100Diesel.params(), 5.0, 9);
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    for (k, (&y, &u)) in run.thrust_meas_n.iter().zip(&run.throttle_pct).enumerate() {
        let e = observer.step(y, u).unwrap();
        for value in [e.thrust_n, e.thrust_rate_n_per_s, e.thrust_accel_n_per_s2, e.thrust_var_n2] {
            assert!(value.is_finite(), "sample {k}: {e:?}");
        }
        assert!((e.thrust_n - run.truth[k].thrust_n).abs() < 15.0, "sample {k}: {e:?}");
    }
    assert_eq!(observer.fallbacks(), run.truth.len() as u64 - 1);
}

#[test]
fn the_study_ekf_model_on_its_diverging_step_stays_finite() {
    // p100-ekf diverges on 70 -> 100 %; fed measurements of a real (bounded) step it must
    // still produce finite estimates.
    let run = simulate_run(Preset::P100Diesel.params(), 50.0, 13);
    let mut observer = ThrustObserver::new(Preset::P100Ekf.params(), ObserverConfig::default());
    for (&y, _) in run.thrust_meas_n.iter().zip(&run.throttle_pct) {
        let e = observer.step(y, 100.0).unwrap();
        assert!(e.thrust_n.is_finite() && e.thrust_rate_n_per_s.is_finite());
    }
}

#[test]
fn invalid_settings_are_reported_on_every_step() {
    let config = ObserverConfig { measurement_var_n2: 0.0, ..ObserverConfig::default() };
    assert!(config.validate().is_err());
    let mut observer = ThrustObserver::new(Preset::P100Diesel.params(), config);
    for _ in 0..2 {
        assert!(matches!(observer.step(20.0, 50.0), Err(EstimError::InvalidConfig { name: "measurement_var_n2", .. })));
    }
    let mut params = Preset::P100Diesel.params();
    params.k_d = f64::NAN;
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    let err = observer.step(20.0, 50.0).unwrap_err();
    assert!(matches!(err, EstimError::InvalidParams { name: "K_D", .. }), "{err}");
}

#[test]
fn reset_starts_over() {
    let params = Preset::P100Diesel.params();
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    let first = observer.step(20.0, 50.0).unwrap();
    observer.step(22.0, 50.0).unwrap();
    observer.reset();
    assert_eq!(observer.step(20.0, 50.0).unwrap(), first);
    assert_eq!(observer.fallbacks(), 0);
}

#[test]
fn honest_noise_passes_the_gate_on_a_whole_run() {
    // 60 s of steps, a sine and full steps, with the P100's noise: nothing is gated,
    // with the matched model and with the study's mismatched ones.
    let run = simulate_run(Preset::P100Diesel.params(), 60.0, 17);
    for preset in [Preset::P100Diesel, Preset::P100Ekf, Preset::P100Ls] {
        let mut observer = ThrustObserver::new(preset.params(), ObserverConfig::default());
        for (&y, &u) in run.thrust_meas_n.iter().zip(&run.throttle_pct) {
            observer.step(y, u).unwrap();
        }
        assert_eq!(observer.gated(), Gated::default(), "{preset}");
    }
}

#[test]
fn a_spike_is_rejected_and_leaves_the_estimate_where_the_prediction_was() {
    let params = Preset::P100Diesel.params();
    let run = simulate_run(params, 8.0, 19);
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    let at = 520; // mid-step from 40 to 80 %
    for k in 0..at {
        observer.step(run.thrust_meas_n[k], run.throttle_pct[k]).unwrap();
    }
    let (y, u) = (run.thrust_meas_n[at], run.throttle_pct[at]);
    let clean = observer.clone().step(y, u).unwrap();
    assert_eq!(clean.verdict, Verdict::Accepted);
    let spiked: Vec<(ThrustObserver, Estimate)> = [30.0, -30.0, 25.0]
        .iter()
        .map(|spike_n| {
            let mut o = observer.clone();
            let e = o.step(y + spike_n, u).unwrap();
            assert_eq!(e.verdict, Verdict::Rejected, "{spike_n} N spike");
            assert_eq!(o.gated().rejected, 1);
            assert!((e.innovation_n - spike_n - clean.innovation_n).abs() < 1e-9, "the innovation reports the spike");
            (o, e)
        })
        .collect();
    // Not used: whatever the spike, the estimate is the prediction, bit for bit.
    for (_, e) in &spiked[1..] {
        assert_eq!((e.thrust_n, e.thrust_rate_n_per_s), (spiked[0].1.thrust_n, spiked[0].1.thrust_rate_n_per_s));
    }
    // And the next clean measurements are used again.
    let (mut after, _) = spiked.into_iter().next().unwrap();
    for k in at + 1..at + 50 {
        assert_eq!(after.step(run.thrust_meas_n[k], run.throttle_pct[k]).unwrap().verdict, Verdict::Accepted);
    }
}

#[test]
fn a_stuck_sensor_is_flagged_after_ten_identical_readings_and_a_real_jump_restarts_the_filter() {
    let params = Preset::P100Diesel.params();
    let run = simulate_run(params, 12.0, 23);
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    for k in 0..300 {
        observer.step(run.thrust_meas_n[k], run.throttle_pct[k]).unwrap();
    }
    let frozen = run.thrust_meas_n[299];
    let verdicts: Vec<Verdict> =
        (300..450).map(|k| observer.step(frozen, run.throttle_pct[k]).unwrap().verdict).collect();
    let first_stuck = verdicts.iter().position(|v| *v == Verdict::Stuck).expect("flagged stuck");
    assert_eq!(first_stuck, 8, "the tenth identical reading (the 9th repeat) is the first flagged");
    assert!(verdicts[first_stuck..].iter().all(|v| *v == Verdict::Stuck));
    // Fresh readings are used again at once; the estimate followed the model meanwhile.
    let back = observer.step(run.thrust_meas_n[450], run.throttle_pct[450]).unwrap();
    assert_ne!(back.verdict, Verdict::Stuck);
    assert!((back.thrust_n - run.truth[450].thrust_n).abs() < 8.0, "{back:?} vs {:?}", run.truth[450]);

    // A filter started 40 N off (a bad first sample) does not lock itself out.
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    observer.step(run.thrust_meas_n[0] + 40.0, run.throttle_pct[0]).unwrap();
    let verdicts: Vec<Verdict> =
        (1..10).map(|k| observer.step(run.thrust_meas_n[k], run.throttle_pct[k]).unwrap().verdict).collect();
    assert_eq!(
        verdicts[..6],
        [
            Verdict::Rejected,
            Verdict::Rejected,
            Verdict::Rejected,
            Verdict::Rejected,
            Verdict::Rejected,
            Verdict::Restarted
        ]
    );
    assert_eq!(observer.gated().restarts, 1);
    assert!(verdicts[6..].iter().all(|v| *v == Verdict::Accepted), "{verdicts:?}");
}

#[test]
fn the_disturbance_state_takes_up_a_constant_model_error_and_is_exactly_zero_when_off() {
    let truth = Preset::P100Diesel.params();
    let run = simulate_run(truth, 60.0, 23);
    // The model's constant acceleration is 5 N/s² too high: the disturbance learns -5.
    let mut model = truth;
    model.c += 5.0;
    let on =
        ObserverConfig { accel_noise_n_per_s2: 10.0, disturbance_drift_n_per_s2: 1.5, ..ObserverConfig::default() };
    let (estimates, _) = observe(&run, model, on);
    let late: Vec<f64> = estimates[3000..].iter().map(|e| e.disturbance_n_per_s2).collect();
    let mean = late.iter().sum::<f64>() / late.len() as f64;
    assert!((mean + 5.0).abs() < 1.5, "disturbance {mean:.2} N/s² for a model 5 N/s² off");
    // Off, the disturbance is 0 at every step and the acceleration is the model's alone.
    let (off, _) = observe(&run, model, ObserverConfig::default());
    assert!(off.iter().all(|e| e.disturbance_n_per_s2 == 0.0));
}

#[test]
fn an_observer_that_knows_the_input_delay_tracks_a_delayed_engine_and_one_that_does_not_lags() {
    let params = Preset::P100Diesel.params();
    // 115 ms: eleven and a half cycles, so the fraction is used too.
    let plant = Plant::new(params, Effects::new(["input_delay:delay_s=0.115".parse().unwrap()]).unwrap());
    let run = simulate_plant_run(&plant, 60.0, 29);
    let calm =
        ObserverConfig { accel_noise_n_per_s2: 10.0, disturbance_drift_n_per_s2: 1.5, ..ObserverConfig::default() };
    let (knows, _) = observe(&run, params, ObserverConfig { input_delay_s: 0.115, ..calm });
    let (ignores, _) = observe(&run, params, calm);
    let (knows_rms, knows_rate, fd_rms) = errors(&run, &knows);
    let (ignores_rms, ignores_rate, _) = errors(&run, &ignores);
    println!("thrust rms: knows the delay {knows_rms:.2} N, ignores it {ignores_rms:.2} N; rate {knows_rate:.1} / {ignores_rate:.1} N/s");
    assert!(knows_rms < 1.0, "thrust rms {knows_rms} N with the delay modelled");
    assert!(knows_rate < fd_rms / 3.0, "rate rms {knows_rate} N/s");
    assert!(knows_rms < 0.6 * ignores_rms, "{knows_rms} N against {ignores_rms} N without the delay");
    assert!(knows_rate < 0.6 * ignores_rate, "{knows_rate} N/s against {ignores_rate} N/s without the delay");
    // The throttle the prediction assumed is the one applied 11.5 cycles back.
    let k = 1000;
    let expected = 0.5 * run.throttle_pct[k - 11] + 0.5 * run.throttle_pct[k - 12];
    assert_eq!(knows[k].engine_throttle_pct, expected);
    assert!(ignores.iter().zip(&run.throttle_pct).all(|(e, &u)| e.engine_throttle_pct == u));
}

#[test]
fn an_input_delay_out_of_range_is_a_config_error() {
    for delay_s in [-0.01, 2.5, f64::NAN] {
        let config = ObserverConfig { input_delay_s: delay_s, ..ObserverConfig::default() };
        let mut observer = ThrustObserver::new(Preset::P100Diesel.params(), config);
        match observer.step(30.0, 50.0) {
            Err(EstimError::InvalidConfig { name: "input_delay_s", .. }) => {}
            other => panic!("delay {delay_s}: {other:?}"),
        }
    }
}

#[test]
fn an_observer_that_knows_the_acceleration_schedule_tracks_a_paced_engine_and_one_that_does_not_runs_ahead() {
    let params = Preset::P100Diesel.params();
    let effects =
        Effects::new(["accel_schedule:up_n_per_s=60,down_n_per_s=80,exponent=1.5,offset_n=5".parse().unwrap()])
            .unwrap();
    let plant = Plant::new(params, effects.clone());
    let run = simulate_plant_run(&plant, 60.0, 31);
    // The schedule binds on the run's large steps, or this test shows nothing.
    let schedule = effects.rate_schedule().unwrap();
    let paced = run
        .truth
        .iter()
        .filter(|s| schedule.bound(s.thrust_n, s.thrust_rate_n_per_s * 1.05) != s.thrust_rate_n_per_s * 1.05)
        .count();
    assert!(paced > 300, "the rate is on the schedule for {paced} cycles");
    let calm =
        ObserverConfig { accel_noise_n_per_s2: 10.0, disturbance_drift_n_per_s2: 1.5, ..ObserverConfig::default() };
    let (knows, knows_fallbacks) = observe(&run, params, ObserverConfig { rate_schedule: Some(schedule), ..calm });
    let (ignores, _) = observe(&run, params, calm);
    let (knows_rms, knows_rate, fd_rms) = errors(&run, &knows);
    let (ignores_rms, ignores_rate, _) = errors(&run, &ignores);
    println!("thrust rms: knows the schedule {knows_rms:.2} N, ignores it {ignores_rms:.2} N; rate {knows_rate:.1} / {ignores_rate:.1} N/s");
    assert_eq!(knows_fallbacks, 0);
    assert!(knows_rms < 1.0, "thrust rms {knows_rms} N with the schedule modelled");
    assert!(knows_rate < fd_rms / 3.0, "rate rms {knows_rate} N/s");
    assert!(knows_rms < 0.6 * ignores_rms, "{knows_rms} N against {ignores_rms} N without the schedule");
    assert!(knows_rate < 0.6 * ignores_rate, "{knows_rate} N/s against {ignores_rate} N/s without the schedule");
    // Off the schedule (no effect), the prediction is the ten parameters' bit for bit.
    let unpaced = simulate_run(params, 20.0, 37);
    let (with, _) = observe(&unpaced, params, ObserverConfig { rate_schedule: None, ..calm });
    let (plain, _) = observe(&unpaced, params, calm);
    assert_eq!(with, plain);
}

#[test]
fn the_rate_settles_after_a_start_and_after_a_restart_and_stays_settled_through_a_stuck_sensor() {
    let params = Preset::P100Diesel.params();
    let run = simulate_run(params, 12.0, 29);
    // The default (trusting the model little) and the bench's calm tuning.
    let calm = ObserverConfig { accel_noise_n_per_s2: 10.0, disturbance_drift_n_per_s2: 1.5, ..Default::default() };
    for config in [ObserverConfig::default(), calm] {
        let mut observer = ThrustObserver::new(params, config);
        assert!(!observer.settling(), "nothing settles before the first measurement");
        let mut settled_at = None;
        let mut rate_errors = Vec::new();
        for k in 0..400 {
            let e = observer.step(run.thrust_meas_n[k], run.throttle_pct[k]).unwrap();
            rate_errors.push(e.thrust_rate_n_per_s - run.truth[k].thrust_rate_n_per_s);
            match settled_at {
                None if !observer.settling() => settled_at = Some(k),
                Some(_) => assert!(!observer.settling(), "settled, then settling again at {k} without a restart"),
                None => {}
            }
        }
        let at = settled_at.expect("the rate settles");
        // By its variance, not by the cap: a few measurements at least, well inside a second.
        assert!((3..MAX_SETTLING_STEPS as usize).contains(&at), "{config:?}: settled at measurement {at}");
        // While it settled the rate was far noisier than after.
        let before = rms(rate_errors[1..at].iter().copied());
        let after = rms(rate_errors[at..].iter().copied());
        assert!(after < before / 3.0, "{config:?}: rate error {before} N/s settling, {after} N/s after");
        // A stuck sensor widens the variance without making the rate a first difference.
        let frozen = run.thrust_meas_n[399];
        for k in 400..520 {
            assert!(observer.step(frozen, run.throttle_pct[k]).unwrap().thrust_n.is_finite());
            assert!(!observer.settling(), "{config:?}: stuck at {k}");
        }
    }
    // A filter restarted at a real jump settles afresh.
    let mut observer = ThrustObserver::new(params, ObserverConfig::default());
    for k in 0..200 {
        observer.step(run.thrust_meas_n[k], run.throttle_pct[k]).unwrap();
    }
    assert!(!observer.settling());
    let mut restarted = None;
    for k in 200..400 {
        let e = observer.step(run.thrust_meas_n[k] + 40.0, run.throttle_pct[k]).unwrap();
        if e.verdict == Verdict::Restarted {
            restarted = Some(k);
            assert!(observer.settling(), "restarted at {k}: its rate is a first difference again");
        }
    }
    let restarted = restarted.expect("a 40 N jump restarts the filter");
    assert!(restarted < 220 && !observer.settling(), "restarted at {restarted}, settled since");
}
