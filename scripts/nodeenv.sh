#!/usr/bin/env bash
# Installs (once) the independent Foxglove WebSocket client of the tests
# (tests/clients/package.json: @foxglove/ws-protocol, ws, @foxglove/rosmsg,
# @foxglove/rosmsg2-serialization, versions locked) under target/nodeenv, and
# prints that folder. Needs node and npm; installs Debian's when missing.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
env_dir="${JETBENCH_NODEENV:-$root/target/nodeenv}"
if ! command -v npm >/dev/null 2>&1; then
  echo "npm not found; installing Debian's nodejs and npm" >&2
  (apt-get update -qq && apt-get install -y -qq nodejs npm) >&2
fi
mkdir -p "$env_dir"
if ! cmp -s "$root/tests/clients/package-lock.json" "$env_dir/package-lock.json" || [ ! -d "$env_dir/node_modules" ]; then
  echo "setting up the Foxglove test client in $env_dir ..." >&2
  cp "$root/tests/clients/package.json" "$root/tests/clients/package-lock.json" "$env_dir/"
  (cd "$env_dir" && npm ci --no-audit --no-fund --loglevel=error) >&2
fi
cp "$root/tests/clients/foxglove_client.mjs" "$env_dir/"
echo "$env_dir"
