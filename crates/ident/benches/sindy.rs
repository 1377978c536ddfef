//! Jet-sized SINDy: 30 000 samples (5 min at 100 Hz, an identification campaign's size), the
//! 56-term degree-5 library in `(T, Tdot, u)`, one target `T''`.
//!
//! ```sh
//! cargo bench -p jetbench-ident --bench sindy
//! ```
#![allow(missing_docs, reason = "criterion_group! defines a public function it cannot document")]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use jetbench_ident::sindy::{fit, PolynomialLibrary, StlsqOptions};
use jetbench_ident::SavitzkyGolay;
use jetbench_model::Preset;

const SAMPLES: usize = 30_000;
const DT_S: f64 = 0.01;

/// Smooth thrust, rate and throttle signals, the P100 diesel model's acceleration as the
/// target, and a slightly perturbed thrust record to differentiate.
struct JetData {
    thrust_n: Vec<f64>,
    rate_n_per_s: Vec<f64>,
    throttle_pct: Vec<f64>,
    accel_n_per_s2: Vec<f64>,
    measured_n: Vec<f64>,
}

fn jet_data() -> JetData {
    let params = Preset::P100Diesel.params();
    let t = |k: usize| k as f64 * DT_S;
    let thrust_n: Vec<f64> =
        (0..SAMPLES).map(|k| 50.0 + 30.0 * (0.3 * t(k)).sin() + 8.0 * (1.7 * t(k)).sin()).collect();
    let rate_n_per_s: Vec<f64> = (0..SAMPLES).map(|k| 9.0 * (0.3 * t(k)).cos() + 13.6 * (1.7 * t(k)).cos()).collect();
    let throttle_pct: Vec<f64> = (0..SAMPLES).map(|k| 62.5 + 37.5 * (0.21 * t(k) + 1.0).sin()).collect();
    let accel_n_per_s2 = (0..SAMPLES).map(|k| params.accel(thrust_n[k], rate_n_per_s[k], throttle_pct[k])).collect();
    let measured_n = thrust_n.iter().enumerate().map(|(k, y)| y + 0.5 * (k as f64 * 2.3).sin()).collect();
    JetData { thrust_n, rate_n_per_s, throttle_pct, accel_n_per_s2, measured_n }
}

fn benches(c: &mut Criterion) {
    let data = jet_data();
    let options = StlsqOptions::default();
    let library = PolynomialLibrary::new(&["T", "Tdot", "u"], 5);
    assert_eq!(library.len(), 56);

    c.bench_function("sindy_fit_30k_samples_56_terms", |b| {
        b.iter(|| {
            let states = [data.thrust_n.as_slice(), &data.rate_n_per_s, &data.throttle_pct];
            fit(library.clone(), black_box(&states), &[("Tdot", &data.accel_n_per_s2)], &options)
                .expect("the synthetic data set is well posed")
        })
    });

    let sg = SavitzkyGolay::new(31, 3).expect("valid window and order");
    let mut out = vec![0.0; SAMPLES];
    c.bench_function("savgol_31_3_30k_samples_second_derivative", |b| {
        b.iter(|| sg.apply_into(black_box(&data.measured_n), 2, DT_S, &mut out).expect("30 000 samples > window"))
    });

    // What sindy_csv's fit_seconds measures for the jet: three Savitzky-Golay passes, the
    // library and STLSQ.
    c.bench_function("jet_pipeline_savgol_and_sindy_30k", |b| {
        b.iter(|| {
            let y = black_box(&data.measured_n);
            let apply = |deriv| sg.apply(y, deriv, DT_S).expect("30 000 samples > window");
            let (thrust, rate, accel) = (apply(0), apply(1), apply(2));
            let states = [thrust.as_slice(), &rate, &data.throttle_pct];
            fit(library.clone(), &states, &[("Tdot", &accel)], &options).expect("well posed")
        })
    });
}

criterion_group!(sindy_benches, benches);
criterion_main!(sindy_benches);
