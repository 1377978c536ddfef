#!/usr/bin/env python3
"""Do two scenario reports give the same rows? Compares two reports written by
scripts/scenarios.py (for example one build's against another's on the same cases, with
`--jetbench OTHER --out B.md`), cell by cell, leaving out the wall time. Prints the rows that
differ; exit status 1 when any does, or when a case is in one report only.

    python3 scripts/scenario_rows_same.py before.md after.md
"""

import sys

TIME_COLUMN = "time, s"


def rows(path):
    header, out = None, {}
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError as e:
        sys.exit(f"{path}: cannot read it ({e.strerror}); give two reports written by scripts/scenarios.py")
    for line in lines:
        if not line.startswith("| "):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[0] == "case":
            header = cells
            continue
        if header and len(cells) == len(header):
            out[cells[0]] = {h: c for h, c in zip(header, cells) if h != TIME_COLUMN}
    if header is None:
        sys.exit(f"{path}: no scenario table (a report of scripts/scenarios.py has a `| case | ...` header)")
    return out


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    a, b = rows(sys.argv[1]), rows(sys.argv[2])
    differ = 0
    for case in a.keys() | b.keys():
        if case not in a or case not in b:
            differ += 1
            print(f"{case}: only in {sys.argv[1] if case in a else sys.argv[2]}")
        elif a[case] != b[case]:
            differ += 1
            cells = [f"{k}: {a[case][k]} -> {b[case].get(k)}" for k in a[case] if a[case][k] != b[case].get(k)]
            print(f"{case}: " + "; ".join(cells))
    same = len(a.keys() & b.keys()) - sum(a[c] != b[c] for c in a.keys() & b.keys())
    print(f"{same} of {len(a.keys() | b.keys())} cases give the same row (wall time left out)")
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
