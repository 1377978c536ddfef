//! Heap allocations in a control cycle: none after start-up, but for the one Clarabel
//! makes in each QP solve.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_control::{Controller, Law, LawSettings, Profile};
use jetbench_model::{Effects, Plant, Preset, STEP_S};

/// Allocations in cycles 100..1100 of `kind` tracking the built-in steps on `plant`, per
/// cycle; the first 100 cycles are start-up (the MPC builds its model copies and solver).
fn allocations_per_cycle(kind: Controller, plant: &Plant) -> f64 {
    let params = plant.params;
    let profile =
        Profile::builtin("steps", params.stable_equilibrium(25.0).unwrap(), params.stable_equilibrium(100.0).unwrap())
            .unwrap();
    let mut law = Law::new(kind, plant, &LawSettings::default()).expect("a feedback law");
    let mut engine = plant.at_equilibrium(25.0);
    let mut allocations = 0;
    for k in 0..1100 {
        let state = engine.state();
        let mut out = None;
        // This thread's allocations only.
        let counted = allocation_counter::measure(|| out = Some(law.step(state, k as f64 * STEP_S, &profile)));
        let out = out.expect("the law ran").unwrap();
        if k >= 100 {
            allocations += counted.count_total;
        }
        assert!(!out.fallback, "{kind} fell back at cycle {k}");
        engine.step(out.command.throttle_pct).unwrap();
    }
    allocations as f64 / 1000.0
}

#[test]
fn a_control_cycle_allocates_nothing_but_inside_the_qp_solver() {
    let nominal = Plant::new(Preset::P100Diesel.params(), Effects::none());
    let delayed = Plant::new(
        Preset::P100Diesel.params(),
        Effects::new([
            "input_delay:delay_s=0.12".parse().unwrap(),
            "rate_limit:up_pct_per_s=200,down_pct_per_s=300".parse().unwrap(),
        ])
        .unwrap(),
    );
    for plant in [&nominal, &delayed] {
        for kind in [Controller::Fbl, Controller::Smc] {
            assert_eq!(allocations_per_cycle(kind, plant), 0.0, "{kind} with effects {}", plant.effects);
        }
        // Clarabel 0.11 allocates once per solve: `DefaultSolver::solve` resets its timers,
        // which drops the nested "IP iteration" timer's map, and re-creates it on its first
        // sub-timer. The MPC solves one QP per Gauss-Newton pass; everything else it does
        // in a cycle (model copies, rollouts, sensitivities, QP data) reuses its buffers.
        let passes = LawSettings::default().mpc.iterations as f64;
        let mpc = allocations_per_cycle(Controller::Mpc, plant);
        assert!(mpc <= passes, "MPC: {mpc} allocations per cycle with effects {}", plant.effects);
    }
}
