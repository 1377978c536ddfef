//! Heap allocations in a control cycle: none after start-up, but for the one Clarabel
//! makes in each QP solve.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use jetbench_control::{Controller, Law, LawSettings, Profile};
use jetbench_model::{Effects, Plant, Preset, STEP_S};

/// Counts the allocations the current thread makes while counting is on.
struct Counting;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

// SAFETY: forwards every call to the system allocator unchanged; the counters are
// thread-local cells with const initialisers, which never allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            ALLOCATIONS.with(|n| n.set(n.get() + 1));
        }
        // SAFETY: the caller's contract is passed on as it is.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.with(Cell::get) {
            ALLOCATIONS.with(|n| n.set(n.get() + 1));
        }
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Allocations in cycles 100..1100 of `kind` tracking the built-in steps on `plant`, per
/// cycle; the first 100 cycles are start-up (the MPC builds its model copies and solver).
fn allocations_per_cycle(kind: Controller, plant: &Plant) -> f64 {
    let params = plant.params;
    let profile =
        Profile::builtin("steps", params.stable_equilibrium(25.0).unwrap(), params.stable_equilibrium(100.0).unwrap())
            .unwrap();
    let mut law = Law::new(kind, plant, &LawSettings::default()).expect("a feedback law");
    let mut engine = plant.at_equilibrium(25.0);
    for k in 0..1100 {
        let state = engine.state();
        COUNTING.with(|c| c.set(k >= 100));
        let out = law.step(state, k as f64 * STEP_S, &profile).unwrap();
        COUNTING.with(|c| c.set(false));
        assert!(!out.fallback, "{kind} fell back at cycle {k}");
        engine.step(out.command.throttle_pct).unwrap();
    }
    ALLOCATIONS.with(|n| n.replace(0)) as f64 / 1000.0
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
