//! A step must not touch the heap: the observer runs in a 100 Hz loop.

use jetbench_estim::{ObserverConfig, ThrustObserver};
use jetbench_model::Preset;

#[test]
fn step_does_not_allocate() {
    // Without a delay, and with one that keeps throttles in flight (built outside the count).
    let delayed = ObserverConfig { input_delay_s: 0.115, disturbance_drift_n_per_s2: 1.5, ..ObserverConfig::default() };
    for config in [ObserverConfig::default(), delayed] {
        let mut observer = ThrustObserver::new(Preset::P100Diesel.params(), config);
        let mut checksum = 0.0;
        // Counts this thread's allocations only: the harness's own threads allocate when
        // they please (a waiting channel, a timer), and those are not the filter's.
        let allocations = allocation_counter::measure(|| {
            for k in 0..1000 {
                let y = 20.0 + (f64::from(k) * 0.05).sin();
                let u = if k % 200 < 100 { 50.0 } else { 80.0 };
                if let Ok(e) = observer.step(y, u) {
                    checksum += e.thrust_n;
                }
                let _ = observer.step(f64::NAN, u);
            }
        });
        assert!(checksum.is_finite());
        assert_eq!(allocations.count_total, 0, "allocations during steps ({config:?})");
    }
}
