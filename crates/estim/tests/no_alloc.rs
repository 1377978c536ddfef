//! A step must not touch the heap: the observer runs in a 100 Hz loop.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use jetbench_estim::{ObserverConfig, ThrustObserver};
use jetbench_model::Preset;

struct Counting;

thread_local! {
    /// Allocations made by this thread: the test harness's own threads allocate
    /// when they please (a waiting channel, a timer), and those are not the filter's.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: forwards to the system allocator unchanged, only counting calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // `try_with`: the allocator also runs while thread-locals are torn down.
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn step_does_not_allocate() {
    // Without a delay, and with one that keeps throttles in flight (built outside the count).
    let delayed = ObserverConfig { input_delay_s: 0.115, disturbance_drift_n_per_s2: 1.5, ..ObserverConfig::default() };
    for config in [ObserverConfig::default(), delayed] {
        let mut observer = ThrustObserver::new(Preset::P100Diesel.params(), config);
        let mut checksum = 0.0;
        let before = ALLOCATIONS.with(Cell::get);
        for k in 0..1000 {
            let y = 20.0 + (f64::from(k) * 0.05).sin();
            let u = if k % 200 < 100 { 50.0 } else { 80.0 };
            if let Ok(e) = observer.step(y, u) {
                checksum += e.thrust_n;
            }
            let _ = observer.step(f64::NAN, u);
        }
        let after = ALLOCATIONS.with(Cell::get);
        assert!(checksum.is_finite());
        assert_eq!(after - before, 0, "allocations during steps ({config:?})");
    }
}
