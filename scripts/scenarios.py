#!/usr/bin/env python3
"""Runs `jetbench diagnose` blind on every case of recordings/scenarios/scenarios.toml and
writes recordings/scenarios/REPORT.md: truth, what was found, the cause, parameters, MAE before
and after, and the time each case took. With --record, first re-records every case (closed-loop
cases, 5 minutes each in real time, only with --closed-loop too).

Standard library only (the closed-loop recordings are trimmed with Python's `mcap`, set up by
scripts/pyenv.sh). Exit status 1 when a case misses the suite's criteria (the same ones
tests/scenarios.rs asserts): the right effect names (none where none, only `discrepancy` for
physics outside the catalogue), parameters within 20 %, the right cause, and validation MAE
after within 10 % of the noise floor. `--jetbench` runs another build, e.g. main's, on the same
cases (to measure a before), and `--out` writes the report elsewhere.
"""

import argparse
import concurrent.futures
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

from diagnose_campaign import disclosed
from outside_catalogue import parse_spec

ROOT = Path(__file__).resolve().parent.parent
SUITE = ROOT / "recordings" / "scenarios"
PARAM_TOLERANCE = 0.20
# A parameter the fit gives a standard error under this share of its value passes within two
# standard errors of the truth too: the data resolve it no finer than that.
RESOLVED = 0.25
FLOOR_TOLERANCE = 0.10
# Channels a closed-loop case keeps: what a diagnosis reads.
CLOSED_LOOP_TOPICS = {"/bench/thrust", "/bench/actuation"}


def model_arg(model):
    path = SUITE / model
    return str(path) if model.endswith(".toml") else model


def recording(case):
    return SUITE / f"{case['name']}.{'mcap' if 'closed_loop' in case else 'csv'}"


def expected_cause(case):
    if "cause" in case:
        return case["cause"]
    return "missing_physics" if case.get("effects") or "outside" in case else "none"


def noise_var(suite, case):
    return case.get("noise_var_n2", suite["noise_var_n2"])


def record_drawn(suite, case):
    """A case simulated by scripts/diagnose_campaign.py's own engine (its noise kinds, spikes, lost
    rows, jitter, a clipping sensor, a slow periodic force on the stand, and its physics outside the
    catalogue: play in the throttle path, spool-down slower than spool-up, ...): the classes the randomised
    campaign draws that `jetbench sim-record` and outside_catalogue.py do not make."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import diagnose_campaign

    plant = case.get("plant", case["model"])
    path = SUITE / plant if plant.endswith(".toml") else SUITE / "plants" / f"{plant}.toml"
    with open(path, "rb") as f:
        params = {k: float(v) for k, v in tomllib.load(f)["model"].items() if k in diagnose_campaign.KEYS}
    drawn = case["drawn"]
    effects = dict(parse_spec(e) for e in case.get("effects", []))
    if "outside" in case:
        name, values = parse_spec(case["outside"])
        effects[name] = values
    artefact = None
    if "clipping" in drawn:
        artefact = "clipping"
        effects["clipping"] = {"quantile": float(drawn["clipping"])}
    if "periodic_force" in drawn:
        # A slow periodic force on the stand, added to what the sensor reads: `key=value,...`.
        artefact = "periodic_force"
        effects["periodic_force"] = parse_spec("periodic_force:" + drawn["periodic_force"])[1]
    draw = {
        "index": 0, "plant": plant, "params": params, "given": params, "effects": effects, "params_off": False,
        "artefact": artefact, "duration_s": case.get("duration_s", suite["duration_s"]),
        "noise": drawn.get("noise", "white"), "noise_var": noise_var(suite, case), "ar": float(drawn.get("ar", 0.0)),
        "spikes": bool(drawn.get("spikes", False)), "drops": bool(drawn.get("drops", False)),
        "jitter": bool(drawn.get("jitter", False)), "seed": case["seed"],
    }
    diagnose_campaign.simulate(draw, recording(case))


def record(jetbench, suite, case):
    out = recording(case)
    plant = model_arg(case.get("plant", case["model"]))
    if "drawn" in case:
        record_drawn(suite, case)
        return
    if "outside" in case:
        with tempfile.TemporaryDirectory() as tmp:
            profile = Path(tmp) / "profile.csv"
            subprocess.run([jetbench, "excite", "--duration", str(suite["duration_s"]), "--seed", str(case["seed"]),
                            "--out", str(profile)], check=True, stdout=subprocess.DEVNULL)
            subprocess.run([sys.executable, str(ROOT / "scripts" / "outside_catalogue.py"), "--plant", plant,
                            "--profile", str(profile), "--physics", case["outside"], "--noise-var",
                            str(noise_var(suite, case)), "--seed", str(case["seed"]), "--out", str(out)], check=True)
        return
    cmd = [jetbench, "sim-record", "--model", plant, "--seed", str(case["seed"]), "--duration",
           str(case.get("duration_s", suite["duration_s"])), "--noise-var", str(noise_var(suite, case)), "--out", str(out)]
    for effect in case.get("effects", []):
        cmd += ["--effect", effect]
    if case.get("noise_ar"):
        cmd += ["--noise-ar", ",".join(str(x) for x in case["noise_ar"])]
    for key in ("spikes", "drop"):
        if key in case:
            cmd += [f"--{key}", str(case[key])]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def record_closed_loop(jetbench, suite, case):
    """Runs the live simulated bench in closed loop and keeps the channels a diagnosis reads."""
    python = subprocess.run([str(ROOT / "scripts" / "pyenv.sh")], check=True, capture_output=True,
                            text=True).stdout.strip()
    config = (ROOT / "config" / "sim.toml").read_text()
    config = config.replace("seed = 1\n", f"seed = {case['seed']}\n", 1)
    config = config.replace(f"noise_var_n2 = {suite['noise_var_n2']}\n", f"noise_var_n2 = {noise_var(suite, case)}\n", 1)
    with tempfile.TemporaryDirectory() as tmp:
        config_path, full = Path(tmp) / "bench.toml", Path(tmp) / "full.mcap"
        config_path.write_text(config)
        subprocess.run([jetbench, "up", "--sim", "--config", str(config_path), "--quiet", "--plant",
                        model_arg(case["plant"]), "--model", model_arg(case["model"]), "--controller",
                        case["closed_loop"], "--profile", "campaign", "--duration",
                        str(case.get("duration_s", suite["duration_s"])),
                        "--record", str(full)], check=True, stdout=subprocess.DEVNULL)
        trim = (
            "import sys\n"
            "from mcap.reader import make_reader\n"
            "from mcap.writer import Writer, CompressionType\n"
            "keep = set(sys.argv[3].split(','))\n"
            "with open(sys.argv[1], 'rb') as src, open(sys.argv[2], 'wb') as dst:\n"
            "    reader = make_reader(src)\n"
            "    w = Writer(dst, compression=CompressionType.ZSTD)\n"
            "    w.start(profile='', library='jetbench scenarios.py')\n"
            "    schemas, channels = {}, {}\n"
            "    for schema, channel, message in reader.iter_messages():\n"
            "        if channel.topic not in keep:\n"
            "            continue\n"
            "        if schema.id not in schemas:\n"
            "            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)\n"
            "        if channel.id not in channels:\n"
            "            channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,\n"
            "                                                      schemas[schema.id], channel.metadata)\n"
            "        w.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,\n"
            "                      message.sequence)\n"
            "    w.finish()\n"
        )
        subprocess.run([python, "-c", trim, str(full), str(recording(case)), ",".join(sorted(CLOSED_LOOP_TOPICS))],
                       check=True)


def diagnose(jetbench, case):
    cmd = [jetbench, "diagnose", "--model", model_arg(case["model"]), str(recording(case)), "--json"]
    start = time.monotonic()
    out = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.monotonic() - start
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"exit {out.returncode}"}, seconds
    return json.loads(out.stdout), seconds


def judge(case, result):
    """Problems with a result, as text (empty when the case passes), and whether it claims physics
    that is not there."""
    if "error" in result:
        return [f"error: {result['error']}"], False
    truth = dict(parse_spec(e) for e in case.get("effects", []))
    # `hidden`: effects of the truth this recording cannot show beside the rest; the probes must
    # say they could hide (tests/scenarios.rs alike).
    hidden = set(case.get("hidden", []))
    expected = (set(truth) - hidden) | ({"discrepancy"} if "outside" in case else set())
    found = {e["name"]: e["params"] for e in result["effects"]}
    uncertainty = {e["name"]: e.get("uncertainty", {}) for e in result["effects"]}
    problems = []
    # Only a claim can be false: `ambiguous`, `unexplained` and `insufficient_data` name what the
    # search found without claiming it.
    claimed = result.get("cause") in ("none", "parameters", "missing_physics")
    false_claim = claimed and bool(set(found) - expected)
    if (expected_cause(case) == "ambiguous" and expected) or "rival" in case:
        # Honestly ambiguous: the truth must be among the rivals, with its weight.
        rivals = [set(r["effects"]) for r in result.get("rivals", []) if r.get("weight") is not None]
        # `rival`: the explanation that must be among them, where the library cannot write the truth.
        wanted = set(case.get("rival", expected))
        if wanted not in rivals and not (claimed and set(found) == expected):
            problems.append(f"the truth {sorted(wanted)} is not among the rivals {[sorted(r) for r in rivals]}")
    elif set(found) != expected:
        problems.append(f"found {sorted(found) or 'nothing'}, expected {sorted(expected) or 'nothing'}")
    for name, params in truth.items():
        for key, value in params.items():
            got = found.get(name, {}).get(key)
            error = uncertainty.get(name, {}).get(key)
            error = error if error is not None and error <= RESOLVED * abs(got or 0.0) else 0.0
            if got is not None and abs(got - value) > max(PARAM_TOLERANCE * abs(value), 2.0 * error):
                problems.append(f"{name}.{key} = {got:.4g}, truth {value:.4g}")
    for h in sorted(hidden):
        # A probe of that class that would not show must say the truth's values could hide too
        # (every value within its `could_hide` range: the campaign's grader alike).
        hidden_probes = [p for p in result.get("detectability", []) if p.get("would_show") is False]
        if not disclosed(h, truth[h], hidden_probes):
            problems.append(f"{h} is in the truth but no probe says it could hide at its size")
    if "periodic_s" in case:
        period = (result.get("periodic") or {}).get("period_s")
        if period is None or abs(period - case["periodic_s"]) > 0.1 * case["periodic_s"]:
            problems.append(f"a periodic force of period {case['periodic_s']} s, reported: {result.get('periodic')}")
    cause = result.get("cause", "n/a")
    # Where nothing (or only the parameters) is off, `insufficient_data` naming a class of effect
    # this recording could not have shown is as honest as the claim (tests/scenarios.rs alike).
    not_shown = sum(1 for p in result.get("detectability", []) if p.get("would_show") is False)
    honest_not_shown = expected_cause(case) in ("none", "parameters") and cause == "insufficient_data" and not_shown
    if cause != expected_cause(case) and not honest_not_shown:
        problems.append(f"cause {cause}, expected {expected_cause(case)}")
    # A claim must reach the floor; an honest refusal (`ambiguous`, `unexplained`) need not.
    claim_expected = expected_cause(case) in ("none", "parameters", "missing_physics")
    if claim_expected and result["mae_after_n"] > (1 + FLOOR_TOLERANCE) * result["noise_floor_n"]:
        problems.append(f"MAE after {result['mae_after_n']:.3f} N above 1.1 x floor {result['noise_floor_n']:.3f} N")
    return problems, false_claim


def fmt_truth(case):
    parts = []
    for name, params in (parse_spec(e) for e in case.get("effects", [])):
        parts.append(f"{name}: " + ", ".join(f"{k} = {v:.4g}" for k, v in params.items()))
    if "outside" in case:
        name, params = parse_spec(case["outside"])
        parts.append(f"*{name}* (outside): " + ", ".join(f"{k} = {v:.4g}" for k, v in params.items()))
    if "plant" in case and case["plant"].startswith("plants/") and "params" in case["plant"]:
        parts.append(f"parameters off ({case['plant']})")
    return "<br>".join(parts) or "none"


def fmt_found(result):
    if "error" in result:
        return "error"
    parts = []
    for e in result["effects"]:
        values = ", ".join(f"{k} = {v:.4g} ± {e['uncertainty'].get(k, float('nan')):.2g}" for k, v in e["params"].items())
        parts.append(f"{e['name']}: {values}")
    if result.get("refit"):
        changes = sorted(result["refit"]["change_pct"].items(), key=lambda kv: -abs(kv[1]))[:2]
        parts.append("refit: " + ", ".join(f"{k} {v:+.1f} %" for k, v in changes))
    return "<br>".join(parts) or "none"


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--record", action="store_true", help="re-record every case first (not closed-loop ones)")
    parser.add_argument("--closed-loop", action="store_true", help="with --record: the closed-loop cases too")
    parser.add_argument("--jetbench", default=str(ROOT / "target" / "release" / "jetbench"))
    parser.add_argument("--jobs", type=int, default=max(1, min(2, os.cpu_count() or 1)))
    parser.add_argument("--only", help="comma-separated case names")
    parser.add_argument("--out", default=str(SUITE / "REPORT.md"))
    args = parser.parse_args()

    suite = tomllib.loads((SUITE / "scenarios.toml").read_text())
    cases = [c for c in suite["case"] if not args.only or c["name"] in args.only.split(",")]
    if args.record:
        offline = [c for c in cases if "closed_loop" not in c]
        with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
            list(pool.map(lambda c: record(args.jetbench, suite, c), offline))
        if args.closed_loop:
            for case in (c for c in cases if "closed_loop" in c):
                record_closed_loop(args.jetbench, suite, case)
        print(f"recorded {len(cases)} cases into {SUITE}", file=sys.stderr)

    results = {}
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
        futures = {pool.submit(diagnose, args.jetbench, c): c["name"] for c in cases}
        for future in concurrent.futures.as_completed(futures):
            name = futures[future]
            results[name] = future.result()
            print(f"  {name}: {results[name][1]:.1f} s", file=sys.stderr)

    rows, failures, false_claims, without_physics = [], 0, 0, 0
    for case in cases:
        result, seconds = results[case["name"]]
        problems, false_claim = judge(case, result)
        failures += bool(problems)
        if expected_cause(case) in ("none", "parameters"):
            without_physics += 1
            false_claims += false_claim
        if "error" in result:
            rows.append(f"| {case['name']} | {case['model']} | {fmt_truth(case)} | error | | | | | | | {seconds:.1f} | "
                        f"NO: {'; '.join(problems)} |")
            continue
        before, after, floor = result["mae_before_n"], result["mae_after_n"], result["noise_floor_n"]
        rows.append(
            f"| {case['name']} | {case['model']} | {fmt_truth(case)} | {fmt_found(result)} | "
            f"{result.get('cause', 'n/a')} | "
            f"{before:.3f} ({100 * (before / floor - 1):+.0f} %) | {after:.3f} ({100 * (after / floor - 1):+.1f} %) | "
            f"{floor:.3f} | {result['before']['whiteness']['p_value']:.1g} → {result['after']['whiteness']['p_value']:.2f} | "
            f"{result.get('noise', {}).get('model', 'n/a')} | "
            f"{seconds:.1f} | {'yes' if not problems else 'NO: ' + '; '.join(problems)} |"
        )
    jobs = f"{args.jobs} cases at a time" if args.jobs > 1 else "one case at a time"
    report = f"""# Concealed-effect scenarios: `jetbench diagnose` blind

Generated by `scripts/scenarios.sh` from [scenarios.toml](scenarios.toml); do not edit by hand.
Each case is a {suite['duration_s']:.0f} s recording (a campaign recorded with `jetbench sim-record`, physics
outside the catalogue simulated by `scripts/outside_catalogue.py`, or the live simulated bench in
closed loop), diagnosed with only the plant's ten-parameter model (the truth column is never shown
to it). Truth in *italics* is physics outside the catalogue, for which only `discrepancy` may be
named. MAE is on the held-out last 30 % of the recording; the percentages are relative to the noise
floor (the MAE of the noise alone, from the noise model the diagnosis estimates from the data).
Whiteness is the Ljung–Box p-value of the residual prewhitened by that noise model, before → after.
Time is the wall time of one `jetbench diagnose` run in release mode on this machine
({os.cpu_count()} cores, {jobs}).

Pass: the effect names are the truth (none where there is none, only `discrepancy` outside the
catalogue), every parameter within {PARAM_TOLERANCE:.0%} of the truth (or two of its standard errors,
when the fit resolves it to {RESOLVED:.0%} or better), the cause right, and
validation MAE after within {FLOOR_TOLERANCE:.0%} of the noise floor.

| case | model | truth | found (± 1 standard error) | cause | MAE before, N | MAE after, N | floor, N | whiteness p | noise model | time, s | pass |
|---|---|---|---|---|---|---|---|---|---|---|---|
""" + "\n".join(rows) + f"""

{len(cases) - failures} of {len(cases)} cases pass; {false_claims} false claim(s) over the {without_physics} cases without
missing physics.
"""
    Path(args.out).write_text(report)
    print(f"wrote {args.out}: {len(cases) - failures} of {len(cases)} cases pass, {false_claims} false claim(s)",
          file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
