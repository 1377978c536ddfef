//! The identification methods on the study's data-set size: 30 000 samples
//! (300 s at 100 Hz) of the default plant driven by a `jetbench excite`
//! campaign, noise variance 7 N², 70 % calibration and 30 % validation.
//!
//! ```sh
//! cargo bench -p jetbench-ident --bench identify
//! ```
#![allow(missing_docs, reason = "criterion_group! defines a public function it cannot document")]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use jetbench_ident::identify::{fit_sindy, hold_out, SindyOptions};
use jetbench_ident::{ekf, excite, ls, synth, validate};
use jetbench_model::Preset;

fn methods(c: &mut Criterion) {
    let profile = excite::campaign(300.0, 1).profile;
    let recording = synth::record(&Preset::P100Diesel.params(), &profile, 7.0, 2).expect("simulated recording");
    let all = std::slice::from_ref(&recording);
    let (cal, val) = hold_out(all, 0.3);
    let noise = validate::noise_floor(all).expect("noise floor");
    let start = ls::fit(all, &ls::LsOptions::default()).expect("least squares").params;

    let mut group = c.benchmark_group("identify_30k");
    group.sample_size(10);
    group.bench_function("ls_fit_30k", |b| b.iter(|| ls::fit(black_box(all), &ls::LsOptions::default())));
    group.bench_function("sindy_fit_30k", |b| b.iter(|| fit_sindy(black_box(all), &SindyOptions::default())));
    // The whole EKF identification as `identify` runs it: passes over the
    // calibration data from the LS estimate, each validated by a free run.
    group.bench_function("ekf_identification_30k", |b| {
        b.iter(|| ekf::fit(black_box(&cal), &val, start, noise, &ekf::EkfOptions::default(), |_| {}))
    });
    group.bench_function("free_run_validation_9k", |b| b.iter(|| validate::simulate(&start, black_box(&val))));
    group.finish();
}

criterion_group!(benches, methods);
criterion_main!(benches);
