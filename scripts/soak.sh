#!/usr/bin/env bash
# The soak test: the whole service set recording for MINUTES (default 30)
# under background load on every core (computation, memory traffic and file
# I/O: `--load all`), at its real-time settings, with every process's resident
# memory sampled every 10 s. Prints per-process RSS settled and at the end with
# its slope (flat: no leak), the samples lost, the deadline misses and the
# recording's size. CI runs a short one (tests/faults.rs).
#
#   scripts/soak.sh          # 30 minutes
#   scripts/soak.sh 2        # 2 minutes
source "$(dirname "$0")/common.sh"
minutes=${1:-30}
exec "$jb" soak --minutes "$minutes" --load all --rt --every 10
