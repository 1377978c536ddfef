//! One throttle path (`jetbench_model::ThrottlePath`: input delay, rate limit, actuator
//! lag) and one rule for splitting a delay (`jetbench_model::DelaySplit`), and their
//! three users agree on them for any path a model file may hold: the plant (the
//! throttle its engine follows, tick by tick), the estimator (the throttle it predicts
//! with, the mean over each cycle) and the controllers (the coarse model their
//! predictors roll forward, and how far ahead they look).

use jetbench_control::{Controller, Law, LawSettings};
use jetbench_estim::{ObserverConfig, ThrustObserver};
use jetbench_model::{
    DelaySplit, Effects, Plant, Preset, ThrottlePath, MAX_INPUT_DELAY_S, STEP_S, SUBSTEPS, THROTTLE_MAX_PCT,
    THROTTLE_MIN_PCT,
};
use proptest::prelude::*;

/// A throttle path as a model file may hold it: each effect present or not.
#[derive(Clone, Debug)]
struct PathSpec {
    delay_s: Option<f64>,
    rate_limit_pct_per_s: Option<(f64, f64)>,
    lag_s: Option<f64>,
}

impl PathSpec {
    fn effects(&self) -> Effects {
        let mut specs = Vec::new();
        if let Some(d) = self.delay_s {
            specs.push(format!("input_delay:delay_s={d}"));
        }
        if let Some((up, down)) = self.rate_limit_pct_per_s {
            specs.push(format!("rate_limit:up_pct_per_s={up},down_pct_per_s={down}"));
        }
        if let Some(tau) = self.lag_s {
            specs.push(format!("actuator_lag:time_constant_s={tau}"));
        }
        Effects::new(specs.iter().map(|s| s.parse().expect("an effect"))).expect("effects")
    }
}

fn path_spec() -> impl Strategy<Value = PathSpec> {
    (
        proptest::option::of(0.001f64..MAX_INPUT_DELAY_S),
        proptest::option::of((2.0f64..1000.0, 2.0f64..1000.0)),
        proptest::option::of(0.02f64..2.0),
    )
        .prop_map(|(delay_s, rate_limit_pct_per_s, lag_s)| PathSpec { delay_s, rate_limit_pct_per_s, lag_s })
}

/// Commanded throttles: held levels of random length across the ECU's range.
fn commands() -> impl Strategy<Value = Vec<f64>> {
    proptest::collection::vec((THROTTLE_MIN_PCT..THROTTLE_MAX_PCT, 1usize..60), 3..12)
        .prop_map(|levels| levels.into_iter().flat_map(|(u, n)| std::iter::repeat_n(u, n)).collect())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Cycle by cycle over the same commands: the plant's engine follows exactly the
    /// throttle of the path stepped tick by tick; the estimator predicts with the mean of
    /// those ticks; the controllers' coarse model (1, 2 or 5 substeps) follows the same
    /// throttle and the same thrust.
    #[test]
    fn plant_estimator_and_controllers_follow_one_throttle_path(spec in path_spec(), u in commands()) {
        let effects = spec.effects();
        let params = Preset::P100Diesel.params();
        let plant = Plant::new(params, effects.clone());
        let mut path = ThrottlePath::new(&effects);
        path.start_at(u[0]);
        let mut fine = plant.at_equilibrium(u[0]);
        let mut coarse: Vec<_> =
            [1, 2, 5].into_iter().map(|s| (s, plant.coarse_engine(fine.state(), u[0], 0.0, s))).collect();
        let config = ObserverConfig { input_delay_s: effects.input_delay_s(), ..ObserverConfig::default() };
        let mut observer = ThrustObserver::new(params, config).with_throttle_path(ThrottlePath::new(&effects));
        let mut delay_only = ThrustObserver::new(params, config);
        let pure_delay = spec.rate_limit_pct_per_s.is_none() && spec.lag_s.is_none();
        let largest_move = u.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
        for (k, &uk) in u.iter().enumerate() {
            path.push(uk);
            let ticks: Vec<f64> = (0..SUBSTEPS).map(|j| path.tick(j)).collect();
            let mean = ticks.iter().sum::<f64>() / SUBSTEPS as f64;
            let now = fine.step(uk).expect("the plant runs");
            prop_assert_eq!(now.engine_throttle_pct.to_bits(), ticks[SUBSTEPS - 1].to_bits(), "the plant, cycle {}", k);

            let estimate = observer.step(now.measured_n, uk).expect("the observer runs");
            prop_assert!((estimate.engine_throttle_pct - mean).abs() < 1e-9,
                "the estimator, cycle {}: {} vs {}", k, estimate.engine_throttle_pct, mean);
            if pure_delay {
                let alone = delay_only.step(now.measured_n, uk).expect("the observer runs");
                prop_assert_eq!(alone.engine_throttle_pct.to_bits(), estimate.engine_throttle_pct.to_bits(),
                    "a delay in the config is the path of that delay, cycle {}", k);
            }

            for (substeps, model) in coarse.iter_mut() {
                let predicted = model.step(uk).expect("the controllers' model runs");
                let gap_n = (predicted.state.thrust_n - now.state.thrust_n).abs();
                prop_assert!(gap_n < 0.05, "{} substeps, cycle {}: {} N off", substeps, k, gap_n);
                if pure_delay {
                    // A held row stands for the last tick, which may straddle two rows.
                    prop_assert!((predicted.engine_throttle_pct - now.engine_throttle_pct).abs() <= largest_move + 1e-9);
                } else {
                    prop_assert_eq!(predicted.engine_throttle_pct.to_bits(), now.engine_throttle_pct.to_bits(),
                        "{} substeps, cycle {}", substeps, k);
                }
            }
        }
    }

    /// A step commanded at `step_at` reaches the plant's engine and the estimator's
    /// throttle after the delay's whole cycles, in full one cycle later when the delay
    /// has a fraction, and the controllers' predictors look that far ahead.
    #[test]
    fn plant_estimator_and_predictor_split_a_delay_alike(delay_s in 0.001f64..MAX_INPUT_DELAY_S, step_at in 1usize..30) {
        let split = DelaySplit::of(delay_s);
        prop_assert!((0.0..1.0).contains(&split.fraction));
        prop_assert!(((split.cycles as f64 + split.fraction) * STEP_S - delay_s).abs() < 1e-9);
        let (plant_first, estimator_first, estimator_full) = first_responses(delay_s, step_at);
        prop_assert_eq!(plant_first, Some(step_at + split.cycles), "the plant");
        prop_assert_eq!(estimator_first, Some(step_at + split.cycles), "the estimator's path");
        prop_assert_eq!(estimator_full, Some(step_at + split.cycles_to_full_effect()), "the estimator's path, in full");
        let plant = Plant::new(
            Preset::P100Diesel.params(),
            Effects::new([format!("input_delay:delay_s={delay_s}").parse().expect("an effect")]).expect("effects"),
        );
        for kind in [Controller::Fbl, Controller::Smc] {
            let law = Law::new(kind, &plant, &LawSettings::default()).expect("a law");
            prop_assert_eq!(law.prediction_lead_s(), split.cycles_to_full_effect() as f64 * STEP_S, "{}", kind);
        }
    }
}

/// A throttle step from idle to 80 % commanded at cycle `step_at`: the first cycle the
/// plant's engine follows more than idle, and the first the estimator's path does,
/// and the first the path has the step in full.
fn first_responses(delay_s: f64, step_at: usize) -> (Option<usize>, Option<usize>, Option<usize>) {
    let effects =
        Effects::new([format!("input_delay:delay_s={delay_s}").parse().expect("an effect")]).expect("effects");
    let plant = Plant::new(Preset::P100Diesel.params(), effects);
    let mut engine = plant.at_equilibrium(25.0);
    let mut path = ThrottlePath::delay_only(delay_s);
    let (mut plant_first, mut path_first, mut path_full) = (None, None, None);
    for k in 0..step_at + 2 + (MAX_INPUT_DELAY_S / STEP_S) as usize {
        let u = if k >= step_at { 80.0 } else { 25.0 };
        let followed = engine.step(u).expect("the plant runs").engine_throttle_pct;
        let predicted_with = path.cycle_mean(u);
        if plant_first.is_none() && followed > 25.0 {
            plant_first = Some(k);
        }
        if path_first.is_none() && predicted_with > 25.0 {
            path_first = Some(k);
        }
        if path_full.is_none() && predicted_with >= 80.0 {
            path_full = Some(k);
        }
    }
    (plant_first, path_first, path_full)
}

#[test]
fn whole_delays_in_binary_are_whole() {
    for (delay_s, cycles) in [(0.12, 12), (0.07, 7), (0.3, 30), (2.0, 200)] {
        assert_eq!(DelaySplit::of(delay_s), DelaySplit { cycles, fraction: 0.0 }, "{delay_s} s");
    }
    assert_eq!(DelaySplit::of(0.0125).cycles_to_full_effect(), 2);
}
