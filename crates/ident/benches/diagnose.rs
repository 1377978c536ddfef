//! `jetbench diagnose` on one scenario-sized case: 300 s (30 000 samples) of the
//! default plant with a concealed input delay, noise variance 7 N², the whole
//! catalogue tried until nothing is left; and the simulation every hypothesis
//! fit is made of.
//!
//! ```sh
//! cargo bench -p jetbench-ident --bench diagnose
//! ```

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use jetbench_ident::diagnose::{diagnose, Options};
use jetbench_ident::{excite, synth};
use jetbench_model::{Effects, ModelFile, Plant, Preset, State};

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
    group.bench_function("diagnose_input_delay_case", |b| {
        b.iter(|| diagnose(&model, black_box(data), &Options::default(), &mut |_| {}).expect("diagnosis"))
    });
    group.finish();
}

criterion_group!(benches, cases);
criterion_main!(benches);
