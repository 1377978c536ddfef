#!/usr/bin/env bash
# Peer check of our SINDy against PySINDy (scripts/sindy_peer.py): adds numpy, scipy and
# pysindy to the Python environment of scripts/pyenv.sh (target/pyenv, or JETBENCH_PYENV),
# builds the sindy_csv example in release mode and runs the comparison.
#
#   scripts/sindy-peer.sh                 # Lorenz only
#   scripts/sindy-peer.sh jet.csv         # plus a jet recording (time_s,throttle_pct,thrust_n)
#   scripts/sindy-peer.sh jet.csv --jet-threshold 0.01 --jet-normalize
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
python=$(scripts/pyenv.sh)
if ! "$python" -c "import numpy, scipy, pysindy" >/dev/null 2>&1; then
  echo "adding numpy, scipy and pysindy to $("$python" -c 'import sys; print(sys.prefix)') ..." >&2
  "$python" -m pip install --quiet --disable-pip-version-check numpy scipy "pysindy>=2" >&2
fi
cargo build --release --quiet -p jetbench-ident --example sindy_csv
exec "$python" scripts/sindy_peer.py --bin "${CARGO_TARGET_DIR:-$root/target}/release/examples/sindy_csv" "$@"
