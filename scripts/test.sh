#!/usr/bin/env bash
# The whole test suite, as CI runs it: formatting, lints, then every test in
# release mode (the end-to-end tests start the real service processes and
# check recordings with Python's mcap reader, set up by scripts/pyenv.sh).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
export IOX2_LOG_LEVEL="${IOX2_LOG_LEVEL:-Error}"

echo "== cargo fmt --check"
cargo fmt --all --check

echo "== cargo clippy (warnings are errors)"
cargo clippy --workspace --all-targets --quiet -- -D warnings

echo "== Python MCAP reader for the recording checks"
scripts/pyenv.sh >/dev/null

echo "== cargo test --release"
cargo test --release --workspace
