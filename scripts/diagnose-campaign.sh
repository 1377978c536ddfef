#!/usr/bin/env bash
# A randomised diagnosis campaign: N cases from broad distributions, simulated independently of
# jetbench's models, diagnosed blind with the release binary, graded per class and overall.
#   scripts/diagnose-campaign.sh N SEED [--jobs 2] [--out docs/diagnose/CAMPAIGN.md] [--json results.json]
#       [--discriminate] [--truth-given] [--deadline-s S] [--from-case I] [--merge A.json B.json ...]
#   (python3 scripts/diagnose_campaign.py --help says what each does)
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet --workspace --all-targets
exec python3 scripts/diagnose_campaign.py "$@"
