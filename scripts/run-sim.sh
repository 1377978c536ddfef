#!/usr/bin/env bash
# The main job on the simulated bench: build, launch the whole service set
# (simulated engine, sensing, estimation, control, actuation, recorder) for
# 30 s, and record every channel to recordings/sim-run.mcap.
# Extra arguments go to `jetbench up`, e.g. scripts/run-sim.sh --duration 60.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
cargo build --release --quiet --bins
mkdir -p recordings
exec target/release/jetbench up --sim --duration 30 --record recordings/sim-run.mcap "$@"
