#!/usr/bin/env python3
"""What the diagnosis's restraint costs and buys, read from stored campaign results.

Two of the campaign's bars pull against the first one (precision of claims): the share of
`ambiguous` answers and the recall. This script asks the stored results (the JSON files
`scripts/diagnose-campaign.sh --json` writes) what each way of answering more often would
have cost in false claims, without running anything again:

- claiming the leader of every `ambiguous` answer (the explanation that won most of the
  held-out resamples), by how often it won;
- claiming the explanation the search found where the answer was `unexplained` only because
  the residual it leaves fails the whiteness test ("what it leaves is not noise"), for
  Ljung-Box p-values down to a given floor instead of 0.01.

Each answer is graded as the campaign grades a claim (diagnose_campaign.grade). The files
may come from different builds; the counts are what those builds answered.

    scripts/campaign_tradeoff.py [FILE.json ...]     # default: docs/diagnose/campaign-*.json
"""

import glob
import json
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import diagnose_campaign as dc  # noqa: E402

UNMODELLED = {"periodic", "slow_history", "throttle_play"}
WEIGHT_BANDS = [(0.8, 1.01, "won >= 80 % of the resamples"), (0.5, 0.8, "won 50-80 %"), (0.0, 0.5, "won < 50 %")]
P_FLOORS = [1e-3, 1e-4]
INCOMPLETE = re.compile(r"leaves is not noise \(Ljung–Box p ([0-9.e+-]+) under the noise model")


def leader_claim(r):
    """The claim the leader of an ambiguous answer would make, or None when it cannot be
    claimed (an explanation jetbench weighs but cannot model)."""
    effects, refit, _ = r["rivals"][0]
    if UNMODELLED & set(effects):
        return None
    claim = dict(r)
    claim["found"] = list(effects)
    claim["cause"] = "missing_physics" if effects else ("parameters" if refit else "none")
    return claim


def tally(paths):
    leaders = {band[2]: [0, 0] for band in WEIGHT_BANDS}
    unclaimable = 0
    relaxed = {p: [0, 0] for p in P_FLOORS}
    cases = ambiguous = claims = false_claims = 0
    for path in paths:
        for r in json.load(open(path))["results"]:
            if "error" in r or "cause" not in r:
                continue
            cases += 1
            claimed, true = dc.grade(r)
            claims += claimed
            false_claims += claimed and not true
            if r["cause"] == "ambiguous" and r.get("rivals"):
                ambiguous += 1
                claim = leader_claim(r)
                if claim is None:
                    unclaimable += 1
                    continue
                weight = r["rivals"][0][2]
                band = next(b[2] for b in WEIGHT_BANDS if b[0] <= weight < b[1])
                leaders[band][dc.grade(claim)[1]] += 1
            elif r["cause"] == "unexplained":
                m = INCOMPLETE.search(r.get("verdict", ""))
                if not m:
                    continue
                claim = dict(r, cause="missing_physics")
                for floor in P_FLOORS:
                    if float(m.group(1)) >= floor:
                        relaxed[floor][dc.grade(claim)[1]] += 1
    return cases, claims, false_claims, ambiguous, leaders, unclaimable, relaxed


def main():
    paths = sys.argv[1:] or sorted(glob.glob(os.path.join(os.path.dirname(__file__), "..", "docs", "diagnose", "campaign-*.json")))
    cases, claims, false_claims, ambiguous, leaders, unclaimable, relaxed = tally(paths)
    print(f"{len(paths)} campaign file(s), {cases} cases: {claims} claims ({false_claims} false), {ambiguous} ambiguous")
    print()
    print("Claiming the leader of each ambiguous answer:")
    print()
    print("| leader | would be true | would be false |")
    print("|---|---|---|")
    for _, _, band in WEIGHT_BANDS:
        false, true = leaders[band]
        print(f"| {band} | {true} | {false} |")
    print(f"| outside what jetbench models (never claimed) | {unclaimable} | – |")
    print()
    print("Claiming what the search found where only the whiteness test stood in the way:")
    print()
    print("| claims allowed down to Ljung-Box p | new claims true | new claims false |")
    print("|---|---|---|")
    for floor in P_FLOORS:
        false, true = relaxed[floor]
        print(f"| {floor:g} | {true} | {false} |")


if __name__ == "__main__":
    main()
