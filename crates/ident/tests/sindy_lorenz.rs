//! Peer check against PySINDy's documented Lorenz result, and the no-allocation promise of
//! the evaluation paths used in hot loops.

#![allow(clippy::unwrap_used)] // not library code: a failed unwrap fails the test

use jetbench_ident::sindy::{finite_difference, fit, PolynomialLibrary, SindyModel, StlsqOptions};
use jetbench_ident::SavitzkyGolay;

const DT_S: f64 = 0.002;

/// The Lorenz system (σ 10, ρ 28, β 8/3) from `[-8, 8, 27]`, sampled every 2 ms over
/// `[0, 2)` s, integrated by RK4 with 10 substeps per sample: PySINDy's README example
/// (which uses `odeint`), to well below the regression's sensitivity.
fn lorenz() -> [Vec<f64>; 3] {
    let f = |s: [f64; 3]| [10.0 * (s[1] - s[0]), s[0] * (28.0 - s[2]) - s[1], s[0] * s[1] - 8.0 / 3.0 * s[2]];
    let axpy = |s: [f64; 3], h: f64, k: [f64; 3]| [s[0] + h * k[0], s[1] + h * k[1], s[2] + h * k[2]];
    let h = DT_S / 10.0;
    let mut s = [-8.0, 8.0, 27.0];
    let mut out = [Vec::new(), Vec::new(), Vec::new()];
    for _ in 0..1000 {
        for (o, v) in out.iter_mut().zip(s) {
            o.push(v);
        }
        for _ in 0..10 {
            let k1 = f(s);
            let k2 = f(axpy(s, h / 2.0, k1));
            let k3 = f(axpy(s, h / 2.0, k2));
            let k4 = f(axpy(s, h, k3));
            s = std::array::from_fn(|i| s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]));
        }
    }
    out
}

fn fit_lorenz() -> SindyModel {
    let [x, y, z] = lorenz();
    let rates: Vec<Vec<f64>> = [&x, &y, &z].iter().map(|s| finite_difference(s, DT_S).unwrap()).collect();
    let targets = [("x", rates[0].as_slice()), ("y", rates[1].as_slice()), ("z", rates[2].as_slice())];
    fit(PolynomialLibrary::new(&["x", "y", "z"], 2), &[&x, &y, &z], &targets, &StlsqOptions::default()).unwrap()
}

#[test]
fn lorenz_matches_pysindy_documented_result() {
    // PySINDy README, degree-2 library, STLSQ(threshold=0.1), finite differences:
    //   x' = -10.000 x + 10.000 y
    //   y' = 27.993 x - 0.999 y - 1.000 x z
    //   z' = -2.666 z + 1.000 x y
    // (PySINDy 2.1.0 on this RK4 data: -9.999701 x + 9.999619 y; 27.993739 x - 0.999143 y
    //  - 0.999810 x z; -2.666459 z + 0.999902 x y.)
    let documented: [&[(&str, f64)]; 3] = [
        &[("x", -10.000), ("y", 10.000)],
        &[("x", 27.993), ("y", -0.999), ("x*z", -1.000)],
        &[("z", -2.666), ("x*y", 1.000)],
    ];
    let model = fit_lorenz();
    let names = model.library().term_names();
    for (target, want) in documented.iter().enumerate() {
        for (term, &c) in names.iter().zip(model.coefficients(target)) {
            match want.iter().find(|(name, _)| name == term) {
                Some(&(_, w)) => {
                    assert!((c - w).abs() <= 0.01, "{}' term {term}: {c} vs {w}", model.target_names()[target])
                }
                None => assert_eq!(c, 0.0, "{}' term {term} must be eliminated", model.target_names()[target]),
            }
        }
        assert!(model.converged(target));
    }
    assert_eq!(model.equation(0), "-10.000 x + 10.000 y");
    assert_eq!(model.equation(2), "-2.666 z + 1.000 x*y");
}

#[test]
fn evaluation_paths_do_not_allocate() {
    let model = fit_lorenz();
    let library = PolynomialLibrary::new(&["T", "Tdot", "u"], 5);
    let sg = SavitzkyGolay::new(31, 3).unwrap();
    let signal: Vec<f64> = (0..500).map(|k| (k as f64 * 0.01).sin()).collect();
    let mut terms = vec![0.0; library.len()];
    let mut rhs = [0.0; 3];
    let mut smoothed = vec![0.0; signal.len()];

    // This thread's allocations only: tests run in parallel.
    let allocations = allocation_counter::measure(|| {
        for k in 0..100 {
            let p = [k as f64 * 0.1, 1.0, -2.0];
            model.eval_into(&p, &mut rhs);
            library.eval_into(&p, &mut terms);
            sg.apply_into(&signal, k % 3, 0.01, &mut smoothed).unwrap();
        }
    });
    assert_eq!(allocations.count_total, 0, "allocations in eval_into / apply_into");
    // x' = σ(y − x) at the last point.
    assert!((rhs[0] - 10.0 * (1.0 - 9.9)).abs() < 0.01, "{rhs:?}");
    assert!(terms.iter().all(|t| t.is_finite()) && smoothed.iter().all(|s| s.is_finite()));
}
