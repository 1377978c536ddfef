#!/usr/bin/env python3
"""Runs `jetbench diagnose` blind on every case of recordings/scenarios/scenarios.toml and
writes recordings/scenarios/REPORT.md: truth, what was found, parameters, MAE before and
after, and the time each case took. With --record, first re-records every case with
`jetbench sim-record`.

Standard library only. Exit status 1 when a case misses the suite's criteria (the same
ones tests/scenarios.rs asserts): the right effect names, parameters within 20 %, and
validation MAE after within 10 % of the noise floor.
"""

import argparse
import concurrent.futures
import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SUITE = ROOT / "recordings" / "scenarios"
PARAM_TOLERANCE = 0.20
FLOOR_TOLERANCE = 0.10


def parse_effect(spec):
    name, _, rest = spec.partition(":")
    params = {}
    for pair in filter(None, rest.split(",")):
        key, _, value = pair.partition("=")
        params[key.strip()] = float(value)
    return name.strip(), params


def model_arg(model):
    path = SUITE / model
    return str(path) if model.endswith(".toml") else model


def record(jetbench, suite, case):
    cmd = [jetbench, "sim-record", "--model", model_arg(case["model"]), "--seed", str(case["seed"]),
           "--duration", str(suite["duration_s"]), "--noise-var", str(suite["noise_var_n2"]),
           "--out", str(SUITE / f"{case['name']}.csv")]
    for effect in case["effects"]:
        cmd += ["--effect", effect]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def diagnose(jetbench, case):
    cmd = [jetbench, "diagnose", "--model", model_arg(case["model"]), str(SUITE / f"{case['name']}.csv"), "--json"]
    start = time.monotonic()
    out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(out.stdout), time.monotonic() - start


def judge(case, result):
    """Problems with a result, as text (empty when the case passes)."""
    problems = []
    truth = dict(parse_effect(e) for e in case["effects"])
    found = {e["name"]: e["params"] for e in result["effects"]}
    if set(truth) != set(found):
        problems.append(f"found {sorted(found) or 'nothing'}, truth {sorted(truth) or 'nothing'}")
    for name, params in truth.items():
        for key, value in params.items():
            got = found.get(name, {}).get(key)
            if got is not None and abs(got - value) > PARAM_TOLERANCE * abs(value):
                problems.append(f"{name}.{key} = {got:.4g}, truth {value:.4g}")
    if result["mae_after_n"] > (1 + FLOOR_TOLERANCE) * result["noise_floor_n"]:
        problems.append(f"MAE after {result['mae_after_n']:.3f} N above 1.1 x floor {result['noise_floor_n']:.3f} N")
    return problems


def fmt_effects(effects):
    if not effects:
        return "none"
    return "<br>".join(
        f"{name}: " + ", ".join(f"{k} = {v:.4g}" for k, v in params.items()) for name, params in effects
    )


def fmt_found(result):
    if not result["effects"]:
        return "none"
    parts = []
    for e in result["effects"]:
        values = ", ".join(f"{k} = {v:.4g} ± {e['uncertainty'].get(k, float('nan')):.2g}" for k, v in e["params"].items())
        parts.append(f"{e['name']}: {values}")
    return "<br>".join(parts)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--record", action="store_true", help="re-record every case first")
    parser.add_argument("--jetbench", default=str(ROOT / "target" / "release" / "jetbench"))
    parser.add_argument("--jobs", type=int, default=max(1, min(2, os.cpu_count() or 1)))
    args = parser.parse_args()

    suite = tomllib.loads((SUITE / "scenarios.toml").read_text())
    cases = suite["case"]
    if args.record:
        with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
            list(pool.map(lambda c: record(args.jetbench, suite, c), cases))
        print(f"recorded {len(cases)} cases into {SUITE}", file=sys.stderr)

    results = {}
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        futures = {pool.submit(diagnose, args.jetbench, c): c["name"] for c in cases}
        for future in concurrent.futures.as_completed(futures):
            name = futures[future]
            results[name] = future.result()
            print(f"  {name}: {results[name][1]:.1f} s", file=sys.stderr)

    rows, failures = [], 0
    for case in cases:
        result, seconds = results[case["name"]]
        problems = judge(case, result)
        failures += bool(problems)
        before, after, floor = result["mae_before_n"], result["mae_after_n"], result["noise_floor_n"]
        truth = [parse_effect(e) for e in case["effects"]]
        rows.append(
            f"| {case['name']} | {case['model']} | {fmt_effects(truth)} | {fmt_found(result)} | "
            f"{before:.3f} ({100 * (before / floor - 1):+.0f} %) | {after:.3f} ({100 * (after / floor - 1):+.1f} %) | "
            f"{floor:.3f} | {result['before']['whiteness']['p_value']:.1g} → {result['after']['whiteness']['p_value']:.2f} | "
            f"{seconds:.1f} | {'yes' if not problems else 'NO: ' + '; '.join(problems)} |"
        )
    jobs = f"{args.jobs} cases at a time" if args.jobs > 1 else "one case at a time"
    report = f"""# Concealed-effect scenarios: `jetbench diagnose` blind

Generated by `scripts/scenarios.sh` from [scenarios.toml](scenarios.toml); do not edit by hand.
Each case is a {suite['duration_s']:.0f} s campaign recorded with `jetbench sim-record` at noise
variance {suite['noise_var_n2']} N², diagnosed with only the plant's ten-parameter model (the truth
column is never shown to it). MAE is on the held-out last 30 % of the recording; the
percentages are relative to the noise floor (the MAE of the noise alone, estimated from
the data). Whiteness is the Ljung–Box p-value of the residual before → after. Time is
the wall time of one `jetbench diagnose` run in release mode on this machine ({os.cpu_count()} cores,
{jobs}).

Pass: the effect names are the truth (none where there is none), every parameter within
{PARAM_TOLERANCE:.0%} of the truth, and validation MAE after within {FLOOR_TOLERANCE:.0%} of the noise floor.

| case | model | truth | found (± 1 standard error) | MAE before, N | MAE after, N | floor, N | whiteness p | time, s | pass |
|---|---|---|---|---|---|---|---|---|---|
""" + "\n".join(rows) + f"""

{len(cases) - failures} of {len(cases)} cases pass.
"""
    (SUITE / "REPORT.md").write_text(report)
    print(f"wrote {SUITE / 'REPORT.md'}: {len(cases) - failures} of {len(cases)} cases pass", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
