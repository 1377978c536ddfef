#!/usr/bin/env bash
# The shipped Foxglove layout checked the way a person sees it: a built
# Lichtblick (the open-source fork of Foxglove Studio) served on loopback with
# docs/foxglove/jetbench-layout.json as its default layout, opened in headless
# Chromium against a live `jetbench up --sim --foxglove`; a screenshot of the
# live layout, then the layout's STOP button clicked in the browser, and the
# run's recording read back: the STOP from the Foxglove view on bench/operator,
# and how long after it the throttle command was at idle.
#
#   scripts/browser-check.sh LICHTBLICK_WEB_DIR [SCREENSHOT.png]
#
# LICHTBLICK_WEB_DIR is Lichtblick's production web build (its `web/.webpack`
# after `yarn run web:build:prod`; docs/control-room/BROWSER.md says how it was
# built here). Installs Debian's chromium and puppeteer-core (under
# target/browserenv) when missing. Not part of the test suite: building
# Lichtblick takes a long time and needs a patched lockfile on this machine.
source "$(dirname "$0")/common.sh"
web=${1:?usage: scripts/browser-check.sh LICHTBLICK_WEB_DIR [SCREENSHOT.png]}
shot=${2:-$root/docs/control-room/lichtblick-live.png}
[[ -f "$web/index.html" ]] || { echo "$web has no index.html: not a Lichtblick web build" >&2; exit 2; }
if ! command -v chromium >/dev/null 2>&1; then
  echo "chromium not found; installing Debian's" >&2
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >&2
fi
env_dir="$root/target/browserenv"
mkdir -p "$env_dir"
if [[ ! -d "$env_dir/node_modules/puppeteer-core" ]]; then
  cp "$root/tests/browser/package.json" "$env_dir/"
  (cd "$env_dir" && npm install --no-audit --no-fund --loglevel=error) >&2
fi
cp "$root/tests/browser/lichtblick_check.mjs" "$env_dir/"
py=$("$root/scripts/pyenv.sh")

work=$(mktemp -d)
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT
export JETBENCH_BUS="browser$$"
ws_port=${JETBENCH_BROWSER_WS_PORT:-28765}
app_port=${JETBENCH_BROWSER_APP_PORT:-28080}

# Lichtblick, served on loopback, with the layout put where its index.html
# keeps a place for a default layout (as its own container image does).
"$py" - "$web" "$root/docs/foxglove/jetbench-layout.json" "$app_port" > "$work/serve.log" 2>&1 <<'PY' &
import functools, http.server, json, os, sys
web, layout, port = sys.argv[1], sys.argv[2], int(sys.argv[3])
index = open(os.path.join(web, "index.html")).read()
placeholder = "/*LICHTBLICK_SUITE_DEFAULT_LAYOUT_PLACEHOLDER*/"
if placeholder not in index:
    sys.exit("this Lichtblick build has no default-layout placeholder in index.html")
index = index.replace(placeholder, json.dumps(json.load(open(layout)))).encode()
class Handler(http.server.SimpleHTTPRequestHandler):
    def do_GET(self):
        if self.path.split("?")[0] in ("/", "/index.html"):
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(index)))
            self.end_headers()
            self.wfile.write(index)
        else:
            super().do_GET()
http.server.ThreadingHTTPServer(("127.0.0.1", port), functools.partial(Handler, directory=web)).serve_forever()
PY
pids+=($!)

echo "== jetbench up --sim --foxglove 127.0.0.1:$ws_port (steps profile, recorded)" >&2
"$jb" up --sim --quiet --profile steps --duration 600 --foxglove "127.0.0.1:$ws_port" \
  --record "$work/run.mcap" > "$work/up.log" 2>&1 &
up=$!
pids+=($up)
sleep 5

echo "== Chromium: Lichtblick at http://127.0.0.1:$app_port/, layout, screenshot, STOP" >&2
result=$(node "$env_dir/lichtblick_check.mjs" "http://127.0.0.1:$app_port/" "ws://127.0.0.1:$ws_port" "$shot" STOP \
  "$(command -v chromium)") || { echo "the browser check failed; the run's log:" >&2; tail -30 "$work/up.log" >&2; exit 1; }
echo "$result" >&2
sleep 5
kill -INT "$up" 2>/dev/null || true
wait "$up" || true

"$py" - "$work/run.mcap" "$result" <<'PY'
import json, sys
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
path, result = sys.argv[1], json.loads(sys.argv[2])
STOP, FOXGLOVE, IDLE_PCT = 2, 3, 25.0
stops, commands = [], []
with open(path, "rb") as f:
    for _, channel, message, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=["/bench/operator", "/bench/command"]):
        if channel.topic == "/bench/operator" and m.command == STOP and m.origin == FOXGLOVE:
            stops.append(m.stamp_ns)
        elif channel.topic == "/bench/command":
            commands.append((m.stamp_ns, m.throttle_pct))
if not stops:
    sys.exit("FAIL: no STOP from the Foxglove view on bench/operator: the click did not reach the bench")
at = stops[0]
before = [t for s, t in commands if s < at][-1:]
after = [(s, t) for s, t in commands if s >= at and t <= IDLE_PCT + 1e-6]
if not after:
    sys.exit("FAIL: the throttle never reached idle after the STOP")
print(f"STOP from the Foxglove view recorded on bench/operator; throttle {before[0] if before else float('nan'):.1f} % "
      f"before it, idle ({after[0][1]:.1f} %) {(after[0][0] - at) / 1e6:.0f} ms after it; "
      f"the panel showed: {result['answer']}; page errors: {len(result['errors'])}")
PY
echo "screenshot: $shot" >&2
