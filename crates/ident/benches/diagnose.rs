//! `jetbench diagnose` on scenario-sized cases, 300 s (30 000 samples) each: the
//! default plant with a concealed input delay at 7 N²; and a bench-grade recording of
//! the P220 at 9 N² (two parameters off, AR(1) noise, CAN spikes, 1 % of rows lost),
//! where both searches run (physics, and the ten parameters refitted with physics on
//! top). Plus the simulations every fit is made of: the reference plant (RK4 at
//! 1 kHz) and the one a diagnosis uses (one RK4 step per 10 ms).
//!
//! ```sh
//! cargo bench -p jetbench-ident --bench diagnose
//! ```
#![allow(missing_docs, reason = "criterion_group! defines a public function it cannot document")]

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use jetbench_ident::diagnose::{diagnose, Options};
use jetbench_ident::{excite, synth};
use jetbench_model::{Effects, ModelFile, Params, Plant, Preset, State};

fn cases(c: &mut Criterion) {
    let params = Preset::P100Diesel.params();
    let delayed =
        Plant::new(params, Effects::new(["input_delay:delay_s=0.15".parse().expect("effect")]).expect("effects"));
    let profile = excite::campaign(300.0, 3).profile;
    let recording = synth::record_plant(&delayed, &profile, 7.0, 4).expect("simulated recording");
    let data = std::slice::from_ref(&recording);
    let model = ModelFile::new(params);

    let mut group = c.benchmark_group("diagnose_30k");
    group.sample_size(10).measurement_time(Duration::from_secs(60));
    group.bench_function("plant_free_run_30k", |b| {
        let mut out = Vec::new();
        let initial = State { thrust_n: 0.0, thrust_rate_n_per_s: 0.0 };
        b.iter(|| delayed.free_run(0.0, initial, black_box(&profile.u_pct), &mut out))
    });
    group.bench_function("plant_free_run_30k_one_substep", |b| {
        let mut out = Vec::new();
        let initial = State { thrust_n: 0.0, thrust_rate_n_per_s: 0.0 };
        b.iter(|| delayed.free_run_with(1, 0.0, initial, black_box(&profile.u_pct), &mut out))
    });
    group.bench_function("diagnose_input_delay_case", |b| {
        b.iter(|| diagnose(&model, black_box(data), &Options::default(), &mut |_| {}).expect("diagnosis"))
    });

    let given = Preset::P220Kerosene.params();
    let mut off = given.to_array();
    off[7] *= 1.02; // B_T
    off[2] *= 0.95; // K_D
    let plant = Plant::new(Params::from_array(off), Effects::none());
    let bench = synth::Bench {
        noise_var_n2: 9.0,
        noise_ar: vec![0.6],
        spike_fraction: 0.002,
        drop_fraction: 0.01,
        resolution: true,
        ..synth::Bench::default()
    };
    let messy = synth::record_bench(&plant, &excite::campaign(300.0, 5).profile, &bench, 6).expect("recording");
    let messy = std::slice::from_ref(&messy);
    let given = ModelFile::new(given);
    group.bench_function("diagnose_bench_grade_parameter_case", |b| {
        b.iter(|| diagnose(&given, black_box(messy), &Options::default(), &mut |_| {}).expect("diagnosis"))
    });
    group.finish();
}

criterion_group!(benches, cases);
criterion_main!(benches);
