#!/usr/bin/env bash
# Regenerates recordings/scenarios/REPORT.md: `jetbench diagnose` run blind on every
# case of the concealed-effect suite. With --record, first re-records the cases.
#   scripts/scenarios.sh [--record] [--jobs N]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet --workspace --all-targets
exec python3 scripts/scenarios.py "$@"
