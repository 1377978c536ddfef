//! Replay speed: 30 000 recorded cycles (5 minutes at 100 Hz) through the
//! estimator, the comparison with the recorded states included.
//!
//! ```sh
//! cargo bench -p jetbench-stack --bench replay
//! ```
//!
//! The input is built once, in memory, by simulating the closed loop with the
//! live step structs ([`synthetic_recording`]); only [`replay`] is measured.
//! Criterion reports the throughput in samples (elements) per second.
#![allow(missing_docs, reason = "criterion_group! defines a public function it cannot document")]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use jetbench_stack::config::BenchConfig;
use jetbench_stack::replay::{replay, EstimatorSource, InputRule};
use jetbench_stack::synthetic::synthetic_recording;

const CYCLES: usize = 30_000;

fn bench_replay(c: &mut Criterion) {
    let config = BenchConfig::default_sim().expect("the built-in config is valid");
    let recording = synthetic_recording(&config, CYCLES).expect("simulate the closed loop");
    let mut group = c.benchmark_group("replay");
    group.throughput(Throughput::Elements(CYCLES as u64));
    for (name, rule) in [("recorded_state", InputRule::RecordedState), ("actuation", InputRule::Actuation)] {
        // Check once that the bench measures a complete, bit-exact replay.
        let report = replay(&recording, EstimatorSource::Recorded, rule).expect("replay").report;
        assert_eq!((report.replayed, report.compared, report.identical), (CYCLES, CYCLES, CYCLES), "{name}");
        group.bench_function(name, |b| {
            b.iter(|| replay(black_box(&recording), EstimatorSource::Recorded, rule).expect("replay"))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    // Numbers only: this machine has neither gnuplot nor fonts for charts.
    config = Criterion::default().without_plots();
    targets = bench_replay
}
criterion_main!(benches);
