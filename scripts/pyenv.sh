#!/usr/bin/env bash
# Creates (once) the Python environment with the independent MCAP reader
# (mcap + mcap-ros2-support) that the tests use to check recordings, and the
# Zenoh client (eclipse-zenoh, the version of the bridge's zenoh crate) that
# reads a live bridge, and prints the path of its python. Set JETBENCH_PYENV
# to put it elsewhere.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
venv="${JETBENCH_PYENV:-$root/target/pyenv}"
if ! "$venv/bin/python" -c "import mcap, mcap_ros2.decoder, zenoh" >/dev/null 2>&1; then
  echo "setting up the Python MCAP reader in $venv ..." >&2
  if ! python3 -m venv "$venv" >&2; then
    echo "python3 -m venv failed; installing python3-venv" >&2
    (apt-get update -qq && apt-get install -y -qq python3-venv) >&2
    python3 -m venv "$venv" >&2
  fi
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "mcap>=1.1" "mcap-ros2-support>=0.5" \
    "eclipse-zenoh==1.10.2" >&2
fi
echo "$venv/bin/python"
