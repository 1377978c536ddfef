#!/usr/bin/env bash
# Is this build's control loop as fast as a previous one's? Runs `jetbench latency` of the
# two builds in alternation (A B B A ..., so the host's drift over the run does not decide)
# under the same load and real-time settings, and prints one table: per build, the median
# over its runs of the end-to-end p50 and p99, the hops' p99, the eventfd floor's p99 (the
# machine as each build saw it), and the deadline misses and lost samples summed.
#
#   scripts/latency-against.sh OLD                 # OLD: a git revision, or a folder of built binaries
#   JETBENCH_AGAINST_PAIRS=4 JETBENCH_AGAINST_SECONDS=15 scripts/latency-against.sh main~3
#   JETBENCH_AGAINST_KEEP=runs/ scripts/latency-against.sh OLD   # keep each run's JSON report there
#
# The machine's own speed drifts from run to run on a shared host (its floor's p99 moved by a
# third between consecutive runs here), so the table also gives each run's end-to-end latency
# over that run's floor: the build's cost with the machine taken out.
#
# A revision is built (release, binaries only) in a git worktree under target/against/, so
# the first run takes as long as a clean build.
source "$(dirname "$0")/common.sh"
old=${1:?usage: scripts/latency-against.sh OLD_REVISION_OR_BIN_DIR}
pairs=${JETBENCH_AGAINST_PAIRS:-3}
seconds=${JETBENCH_AGAINST_SECONDS:-10}
load=${JETBENCH_AGAINST_LOAD:-cpu}

if [[ -x "$old/jetbench" ]]; then
    old_bin=$(cd "$old" && pwd)
    old_name="$old_bin"
else
    rev=$(git rev-parse --short=10 "$old^{commit}") || { echo "$old is neither a folder with a jetbench binary nor a git revision" >&2; exit 2; }
    tree="$root/target/against/$rev"
    if [[ ! -d "$tree" ]]; then
        git worktree add --detach "$tree" "$rev" >&2
    fi
    echo "== building $rev in $tree (release binaries)" >&2
    (cd "$tree" && CARGO_TARGET_DIR="$root/target/against/target-$rev" cargo build --release --quiet --bins)
    old_bin="$root/target/against/target-$rev/release"
    old_name="$rev"
fi
new_bin="$root/target/release"
if [[ -n "${JETBENCH_AGAINST_KEEP:-}" ]]; then
    out=$JETBENCH_AGAINST_KEEP
    mkdir -p "$out"
else
    out=$(mktemp -d)
    trap 'rm -rf "$out"' EXIT
fi

run() { # build-dir label index
    echo "== $2 run $3: jetbench latency --duration $seconds --rounds 1 --load $load --rt" >&2
    "$1/jetbench" latency --duration "$seconds" --rounds 1 --load "$load" --rt --json > "$out/$2-$3.json"
}
for ((k = 1; k <= pairs; k++)); do
    if ((k % 2)); then run "$old_bin" old "$k"; run "$new_bin" new "$k"; else run "$new_bin" new "$k"; run "$old_bin" old "$k"; fi
done

python3 - "$out" "$old_name" "$(git rev-parse --short=10 HEAD)" "$pairs" "$seconds" "$load" <<'PY'
import glob, json, statistics, sys
out, old_name, new_name, pairs, seconds, load = sys.argv[1:]
def runs(label):
    return [json.load(open(f)) for f in sorted(glob.glob(f"{out}/{label}-*.json"))]
rows = [("e2e p50, us", lambda d: d["e2e_us"]["p50"]), ("e2e p99, us", lambda d: d["e2e_us"]["p99"])]
hops = sorted(runs("new")[0]["hops_us"].keys())
rows += [(f"{h} hop p99, us", (lambda h: lambda d: d["hops_us"][h]["p99"])(h)) for h in hops]
rows += [("floor p99, us (the machine)", lambda d: d["floor_us"]["p99"])]
rows += [("e2e p99 / floor p99, each run", lambda d: d["e2e_us"]["p99"] / d["floor_us"]["p99"]),
         ("e2e p50 / floor p50, each run", lambda d: d["e2e_us"]["p50"] / d["floor_us"]["p50"])]
old, new = runs("old"), runs("new")
print(f"jetbench latency, {pairs} runs of {seconds} s per build in alternation, load {load}, --rt")
print(f"old: {old_name}   new: {new_name}   (medians over the runs; ratio new/old)\n")
print(f"| {'figure':32} | {'old':>9} | {'new':>9} | {'new/old':>7} |")
print(f"|{'-'*34}|{'-'*11}|{'-'*11}|{'-'*9}|")
for name, get in rows:
    a, b = statistics.median(map(get, old)), statistics.median(map(get, new))
    digits = 2 if "/" in name else 1
    print(f"| {name:32} | {a:9.{digits}f} | {b:9.{digits}f} | {b / a if a else float('nan'):7.2f} |")
for name, key in [("deadline misses (sum)", "deadline_misses"), ("samples lost (sum)", "lost")]:
    a, b = sum(d[key] for d in old), sum(d[key] for d in new)
    print(f"| {name:32} | {a:9d} | {b:9d} | {'':7} |")
PY
