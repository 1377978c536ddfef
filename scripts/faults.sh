#!/usr/bin/env bash
# The fault campaign, and docs/faults/REPORT.md with its figures: each service
# and the launcher killed (SIGKILL) 10 times at random moments, the recorder
# killed mid-run and recovered 10 times, the disk filled (a small tmpfs: run
# as root) with both [recorder] on_error settings, bad sensor data injected
# into the live loop, a second set in a namespace in use, another user
# against a running set's files, and a healthy engine with every limit on
# (10 runs of 60 s on the campaign and the steps profiles: no false trips).
# About 50 minutes; exits non-zero if a bound broke (the report lists it).
#
#   scripts/faults.sh              # the whole campaign, 10 times each
#   scripts/faults.sh 3            # 3 times each, a quicker look
#   scripts/faults.sh 10 --only limits   # one part again; the report keeps the other sections
source "$(dirname "$0")/common.sh"
repeat=${1:-10}
shift || true
python=$(scripts/pyenv.sh)
mkdir -p docs/faults
exec "$jb" faults --repeat "$repeat" --python "$python" --report docs/faults/REPORT.md "$@"
