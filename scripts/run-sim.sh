#!/usr/bin/env bash
# The main job on the simulated bench: build, launch the whole service set
# (simulated engine, sensing, estimation, control, actuation, recorder) for
# 30 s, and record every channel to recordings/sim-run.mcap.
# Extra arguments go to `jetbench up`, e.g. scripts/run-sim.sh --duration 60.
source "$(dirname "$0")/common.sh"
mkdir -p recordings
exec "$jb" up --sim --duration 30 --record recordings/sim-run.mcap "$@"
