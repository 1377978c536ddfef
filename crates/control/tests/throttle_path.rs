//! One rule splits an input delay into whole cycles and a fraction
//! (`jetbench_model::DelaySplit`), and its three users agree on it for any delay a
//! model file may hold: the plant (the throttle its engine follows), the estimator's
//! throttle history (the throttle it predicts with) and the controllers' predictor
//! (how far ahead it looks).

use jetbench_control::{Controller, Law, LawSettings};
use jetbench_model::{DelaySplit, Effects, Plant, Preset, ThrottleHistory, MAX_INPUT_DELAY_S, STEP_S};
use proptest::prelude::*;

/// A throttle step from idle to 80 % commanded at cycle `step_at`: the first cycle the
/// plant's engine follows more than idle, and the first the estimator's history does,
/// and the first the history has the step in full.
fn first_responses(delay_s: f64, step_at: usize) -> (Option<usize>, Option<usize>, Option<usize>) {
    let effects =
        Effects::new([format!("input_delay:delay_s={delay_s}").parse().expect("an effect")]).expect("effects");
    let plant = Plant::new(Preset::P100Diesel.params(), effects);
    let mut engine = plant.at_equilibrium(25.0);
    let mut history = ThrottleHistory::new(delay_s);
    let (mut plant_first, mut history_first, mut history_full) = (None, None, None);
    for k in 0..step_at + 2 + (MAX_INPUT_DELAY_S / STEP_S) as usize {
        let u = if k >= step_at { 80.0 } else { 25.0 };
        let followed = engine.step(u).expect("the plant runs").engine_throttle_pct;
        let predicted_with = history.push(u);
        if plant_first.is_none() && followed > 25.0 {
            plant_first = Some(k);
        }
        if history_first.is_none() && predicted_with > 25.0 {
            history_first = Some(k);
        }
        if history_full.is_none() && predicted_with >= 80.0 {
            history_full = Some(k);
        }
    }
    (plant_first, history_first, history_full)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn plant_estimator_and_predictor_split_a_delay_alike(delay_s in 0.001f64..MAX_INPUT_DELAY_S, step_at in 1usize..30) {
        let split = DelaySplit::of(delay_s);
        prop_assert!((0.0..1.0).contains(&split.fraction));
        prop_assert!(((split.cycles as f64 + split.fraction) * STEP_S - delay_s).abs() < 1e-9);
        let (plant_first, history_first, history_full) = first_responses(delay_s, step_at);
        prop_assert_eq!(plant_first, Some(step_at + split.cycles), "the plant");
        prop_assert_eq!(history_first, Some(step_at + split.cycles), "the estimator's history");
        prop_assert_eq!(history_full, Some(step_at + split.cycles_to_full_effect()), "the estimator's history, in full");
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

#[test]
fn whole_delays_in_binary_are_whole() {
    for (delay_s, cycles) in [(0.12, 12), (0.07, 7), (0.3, 30), (2.0, 200)] {
        assert_eq!(DelaySplit::of(delay_s), DelaySplit { cycles, fraction: 0.0 }, "{delay_s} s");
    }
    assert_eq!(DelaySplit::of(0.0125).cycles_to_full_effect(), 2);
}
