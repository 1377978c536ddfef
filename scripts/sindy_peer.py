#!/usr/bin/env python3
"""Peer check: PySINDy itself against our Rust SINDy (crates/ident, example sindy_csv).

Run it through scripts/sindy-peer.sh, which sets up the Python environment (numpy,
scipy, pysindy) and builds the example:

    scripts/sindy-peer.sh                 # Lorenz only
    scripts/sindy-peer.sh jet.csv         # Lorenz and a jet recording (time_s,throttle_pct,thrust_n)

Two cases, each fitted by both sides from the same numbers, printed side by side with
both run times (best of 3) and the speed ratio:

1. Lorenz (sigma 10, rho 28, beta 8/3) from [-8, 8, 27], dt 2 ms over [0, 2) s, RK4
   with 10 substeps per sample; degree-2 library, STLSQ(threshold=0.1), PySINDy's
   default finite differences on both sides. Timed: PySINDy's model.fit(...) and our
   fit_seconds (differentiation, library, STLSQ).
2. A jet recording: T, Tdot and T'' from scipy's savgol_filter (window 31, order 3,
   mode interp) on the PySINDy side, from our Savitzky-Golay (same settings) on ours
   (--second-order); degree-5 library over (T, Tdot, u), 56 terms, target T''.
   PySINDy's SINDy API wants a derivative per state, so its model.fit also fits the
   trivial T' = Tdot; its single-target cost (library transform + STLSQ.fit) is
   timed as well, for fairness.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pysindy as ps
from scipy.signal import savgol_filter

REPEATS = 3


def lorenz(dt=0.002, n=1000, substeps=10):
    """Lorenz samples by RK4, as crates/ident/tests/sindy_lorenz.rs generates them."""

    def f(s):
        return np.array([10.0 * (s[1] - s[0]), s[0] * (28.0 - s[2]) - s[1], s[0] * s[1] - 8.0 / 3.0 * s[2]])

    h = dt / substeps
    s = np.array([-8.0, 8.0, 27.0])
    out = np.empty((n, 3))
    for k in range(n):
        out[k] = s
        for _ in range(substeps):
            k1 = f(s)
            k2 = f(s + h / 2 * k1)
            k3 = f(s + h / 2 * k2)
            k4 = f(s + h * k3)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return np.arange(n) * dt, out


def write_csv(path, names, columns):
    # repr() round-trips, so both sides read bit-identical doubles.
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for row in zip(*columns):
            f.write(",".join(repr(float(v)) for v in row) + "\n")


def best_time(fn):
    best, result = float("inf"), None
    for _ in range(REPEATS):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


def run_ours(binary, args):
    best, out = float("inf"), None
    for _ in range(REPEATS):
        proc = subprocess.run([binary, *args], capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"sindy_csv failed: {proc.stderr.strip()}")
        out = json.loads(proc.stdout)
        best = min(best, out["fit_seconds"])
    return best, out


def side_by_side(title, feature_names, py_coefs, py_equations, ours, targets):
    """Prints both equations and every term either side kept, with the difference."""
    names = [n.replace(" ", "*") for n in feature_names]
    worst = 0.0
    same_support = True
    print(f"\n== {title}")
    for row, target in targets:
        our_terms = ours["coefficients"][target]
        print(f"  {target}'")
        print(f"    PySINDy: {py_equations[row]}")
        print(f"    ours:    {ours['equations'][target]}")
        print(f"    {'term':<16} {'PySINDy':>16} {'ours':>16} {'|diff|':>10}")
        for j, name in enumerate(names):
            p, o = float(py_coefs[row, j]), our_terms.get(name, 0.0)
            if p == 0.0 and o == 0.0:
                continue
            same_support &= (p != 0.0) == (o != 0.0)
            worst = max(worst, abs(p - o))
            print(f"    {name:<16} {p:>16.9g} {o:>16.9g} {abs(p - o):>10.2e}")
    print(f"  same terms selected: {'yes' if same_support else 'NO'}; largest coefficient difference {worst:.2e}")


def times(py_s, ours_s, extra=None):
    print(f"  PySINDy model.fit: {py_s * 1e3:9.2f} ms (best of {REPEATS})")
    if extra:
        label, s = extra
        print(f"  {label}: {s * 1e3:9.2f} ms (best of {REPEATS})")
    print(f"  ours fit_seconds:  {ours_s * 1e3:9.2f} ms (best of {REPEATS})")
    single = f" (single target: {extra[1] / ours_s:.1f}x)" if extra else ""
    print(f"  speed ratio PySINDy/ours: {py_s / ours_s:.1f}x{single}")


def lorenz_case(binary, tmp):
    t, x = lorenz()
    dt = t[1] - t[0]
    path = tmp / "lorenz.csv"
    write_csv(path, ["t", "x", "y", "z"], [t, x[:, 0], x[:, 1], x[:, 2]])

    def fit():
        model = ps.SINDy(feature_library=ps.PolynomialLibrary(degree=2), optimizer=ps.STLSQ(threshold=0.1))
        model.fit(x, t=dt, feature_names=["x", "y", "z"])
        return model

    py_s, model = best_time(fit)
    ours_s, ours = run_ours(binary, [str(path), "--vars", "x,y,z", "--degree", "2", "--threshold", "0.1"])
    side_by_side(
        "Lorenz, degree 2, STLSQ threshold 0.1, finite differences (1000 samples)",
        model.get_feature_names(),
        model.coefficients(),
        model.equations(precision=3),
        ours,
        [(0, "x"), (1, "y"), (2, "z")],
    )
    times(py_s, ours_s)


def jet_case(binary, tmp, csv, threshold, normalize):
    data = np.genfromtxt(csv, delimiter=",", names=True)
    missing = {"time_s", "throttle_pct", "thrust_n"} - set(data.dtype.names)
    if missing:
        sys.exit(f"{csv}: missing columns {', '.join(sorted(missing))}")
    t, u, y = data["time_s"], data["throttle_pct"], data["thrust_n"]
    dt = (t[-1] - t[0]) / (len(t) - 1)
    # Same numbers for our side, columns renamed so both libraries name terms alike.
    path = tmp / "jet.csv"
    write_csv(path, ["time_s", "T", "u"], [t, y, u])

    sg = dict(window_length=31, polyorder=3, delta=dt, mode="interp")
    thrust, rate, accel = (savgol_filter(y, deriv=d, **sg) for d in range(3))
    states = np.column_stack([thrust, rate])
    optimizer = dict(threshold=threshold, normalize_columns=normalize)

    def fit():
        model = ps.SINDy(feature_library=ps.PolynomialLibrary(degree=5), optimizer=ps.STLSQ(**optimizer))
        model.fit(states, t=dt, x_dot=np.column_stack([rate, accel]), u=u, feature_names=["T", "Tdot", "u"])
        return model

    def fit_single_target():
        theta = ps.PolynomialLibrary(degree=5).fit_transform(np.column_stack([thrust, rate, u]))
        return ps.STLSQ(**optimizer).fit(np.asarray(theta), accel)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # PySINDy warns when STLSQ eliminates every term
        py_s, model = best_time(fit)
        single_s, _ = best_time(fit_single_target)
    args = [str(path), "--vars", "T", "--inputs", "u", "--second-order", "T:Tdot", "--degree", "5"]
    args += ["--threshold", str(threshold)] + (["--normalize"] if normalize else [])
    ours_s, ours = run_ours(binary, args)
    side_by_side(
        f"jet {csv}: T'' over (T, Tdot, u), degree 5 ({len(model.get_feature_names())} terms), "
        f"STLSQ threshold {threshold}{', normalized columns' if normalize else ''} ({len(t)} samples)",
        model.get_feature_names(),
        model.coefficients(),
        model.equations(precision=5),
        ours,
        [(1, "Tdot")],
    )
    times(py_s, ours_s, ("PySINDy single target (library + STLSQ.fit)", single_s))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("jet_csv", nargs="?", help="jet recording with columns time_s,throttle_pct,thrust_n")
    parser.add_argument("--bin", required=True, help="path to the built sindy_csv example")
    parser.add_argument("--jet-threshold", type=float, default=0.1, help="STLSQ threshold for the jet (0.1)")
    parser.add_argument("--jet-normalize", action="store_true", help="normalize library columns for the jet")
    args = parser.parse_args()
    print(f"PySINDy {ps.__version__}, numpy {np.__version__}; ours: {args.bin}")
    with tempfile.TemporaryDirectory() as tmp:
        lorenz_case(args.bin, Path(tmp))
        if args.jet_csv:
            jet_case(args.bin, Path(tmp), args.jet_csv, args.jet_threshold, args.jet_normalize)
        else:
            print("\n== jet: skipped (no recording given; pass a CSV with time_s,throttle_pct,thrust_n)")


if __name__ == "__main__":
    main()
