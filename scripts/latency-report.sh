#!/usr/bin/env bash
# Measures the control loop's latency under load and writes docs/latency/REPORT.md
# with the histogram plots and the raw JSON. About 15 minutes: `jetbench latency`
# measures the service set over iceoryx2, the same set over Unix sockets and the
# eventfd floor for 60 s each under --rt; then, 30 s each, the normal scheduler;
# then the two priority orders in alternating runs (A B A B, 15 s each), so that
# the host's drift does not decide between them.
#
#   scripts/latency-report.sh              # the acceptance run and both contrasts
#   JETBENCH_LATENCY_SECONDS=10 JETBENCH_LATENCY_CONTRAST_SECONDS=6 scripts/latency-report.sh   # a quick try
source "$(dirname "$0")/common.sh"
out="$root/docs/latency"
seconds=${JETBENCH_LATENCY_SECONDS:-60}
contrast=${JETBENCH_LATENCY_CONTRAST_SECONDS:-30}
mkdir -p "$out"

# The same bench with the sensor side first (sensing > estimation > control > actuation).
feeder_first=$(mktemp --suffix=.toml)
trap 'rm -f "$feeder_first"' EXIT
sed 's/^priority = .*/priority = { sim-bench = 90, sensing = 80, estimation = 70, control = 60, actuation = 50, recorder = 40 }/' \
    config/sim.toml > "$feeder_first"
grep -q '^priority = { sim-bench = 90, sensing = 80' "$feeder_first" || { echo "cannot derive the contrast config" >&2; exit 1; }

echo "== jetbench latency --duration $seconds --load cpu --rt --control-room" >&2
"$jb" latency --duration "$seconds" --load cpu --rt --control-room --json --plot "$out/latency-cpu-rt.png" > "$out/latency-cpu-rt.json"
echo "== jetbench latency --duration $contrast --load cpu (normal scheduler)" >&2
"$jb" latency --duration "$contrast" --load cpu --json --plot "$out/latency-cpu.png" > "$out/latency-cpu.json"
pair=$(( contrast / 2 > 2 ? contrast / 2 : 2 ))
rm -f "$out"/latency-cpu-rt-sensor-first.json
for run in 1 2; do
  echo "== pair $run: jetbench latency --duration $pair --load cpu --rt, each stage above its feeder, then sensor side first" >&2
  "$jb" latency --duration "$pair" --load cpu --rt --json > "$out/latency-order-$run-feeder.json"
  "$jb" latency --duration "$pair" --load cpu --rt --config "$feeder_first" --json > "$out/latency-order-$run-sensor.json"
done

python3 - "$out" "$seconds" "$contrast" "$pair" <<'EOF'
import json, platform, subprocess, sys
out, seconds, contrast, pair = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
rt = json.load(open(f"{out}/latency-cpu-rt.json"))
plain = json.load(open(f"{out}/latency-cpu.json"))
orders = [(run, order, json.load(open(f"{out}/latency-order-{run}-{order}.json")))
          for run in (1, 2) for order in ("feeder", "sensor")]
HOPS = ["sensing", "estimation", "control", "actuation"]

def row(name, p):
    return f"| {name} | {p['p50']:.1f} | {p['p90']:.1f} | {p['p99']:.1f} | {p['p999']:.1f} | {p['max']:.1f} |"

def table(r):
    lines = ["| µs | p50 | p90 | p99 | p99.9 | max |", "|---|---|---|---|---|---|",
             row("**service set over iceoryx2: sensor frame → board write**", r["e2e_us"])]
    lines += [row(f"&nbsp;&nbsp;hop: {hop}", r["hops_us"][hop]) for hop in HOPS]
    lines += [row("&nbsp;&nbsp;sensing period jitter", r["period_jitter_us"]),
              row("**the same service set over Unix sockets**", r["uds_us"])]
    lines += [row(f"&nbsp;&nbsp;hop: {hop}", r["uds"]["hops_us"][hop]) for hop in HOPS]
    lines += [row("**floor: eventfd ping through 4 processes (3 hops)**", r["floor_us"])]
    lines += [row(f"&nbsp;&nbsp;floor hop {h + 1}", p) for h, p in enumerate(r["floor_hops_us"])]
    return "\n".join(lines)

def counts(r):
    gaps = sum(r["seq_gaps"].values())
    steal = ", ".join(f"cpu{i} {ms:.0f} ms" for i, ms in enumerate(r["steal_ms"])) if r["steal_ms"] else "not reported"
    rt_note = ("asked for" if r["rt_requested"] else "off") + (
        f", refused: {'; '.join(r['rt_refused'])}" if r["rt_refused"] else (", all set" if r["rt_requested"] else ""))
    return (f"- iceoryx2: cycles judged {r['cycles']}, completed {r['completed']}; deadline misses **{r['deadline_misses']}** "
            f"(commands written > 10 ms after their frame {r['late_e2e']}, sensor cycles > 1 period late {r['late_periods']}, "
            f"commands superseded before they were written {r['superseded']}); lost **{r['lost']}** (sensor frames "
            f"{r['frames_lost']}, bus/recorder seq gaps {gaps}, unfinished cycles {r['unfinished']})\n"
            f"- Unix sockets: cycles judged {r['uds']['cycles']}, completed {r['uds']['completed']}; deadline misses "
            f"{r['uds']['deadline_misses']}; lost {r['uds']['lost']}. Floor chain: lost {r['floor_lost']}\n"
            f"- deadline misses the services counted themselves (iceoryx2 runs): {r['service_deadline_misses']}\n"
            f"- hypervisor steal while measuring: {steal} (a stolen virtual CPU stalls every process on it, SCHED_FIFO or not); "
            f"of the iceoryx2 deadline misses, {r['misses_during_steal']} came within 40 ms before to 20 ms after the host took a CPU\n"
            f"- real-time settings: {rt_note}")

def control_room(r):
    room = r.get("control_room")
    if not room:
        return "(not measured: run with --control-room)"
    c = room["clients"]
    errors = [e for x in c for e in x["errors"]]
    return "\n".join([
        "| µs | p50 | p90 | p99 | p99.9 | max |", "|---|---|---|---|---|---|",
        row("service set over iceoryx2, no control room", r["e2e_us"]),
        row("**the same set, control room attached**", room["e2e_us"]), "",
        f"- with the control room: cycles {room['cycles']}, deadline misses **{room['deadline_misses']}** "
        f"({room['misses_per_1000']:.2f} per 1000 cycles; without it {room['misses_per_1000_without']:.2f}), lost **{room['lost']}**; "
        f"e2e p50 {room['e2e_p50_ratio']:.2f}×, p99 {room['e2e_p99_ratio']:.2f}× the set without it",
        f"- deadline misses the services counted themselves: {room['service_deadline_misses']}",
        f"- the clients, per round: Foxglove reader {[x['foxglove_read'] for x in c]} messages; stalled client connected "
        f"{[x['foxglove_stalled'] for x in c]}; the dropping client read {[x['foxglove_dropped_after'] for x in c]} messages "
        f"before it cut its connection; Zenoh subscriber {[x['zenoh_received'] for x in c]} samples, "
        f"{sum(x['zenoh_gaps'] for x in c)} lost" + (f"; errors: {errors}" if errors else ""),
        commands(c),
    ])

def commands(c):
    k = [x["commands"] for x in c if "commands" in x]
    if not k:
        return "- (no operator's client: a build before the commanding client)"
    s = lambda key: sum(x[key] for x in k)
    return (f"- the operator's client, over TLS: control taken in {sum(x['took_control'] for x in k)} of {len(k)} rounds; "
            f"{s('sent')} heartbeats sent every 100 ms, {s('accepted')} accepted, {s('refused')} refused, "
            f"{s('unanswered')} unanswered while the set ran; answered in p50 {max(x['answer_ms_p50'] for x in k):.1f} ms, "
            f"p99 {max(x['answer_ms_p99'] for x in k):.1f} ms (worst round); in the recordings {s('recorded')} commands on "
            f"bench/operator, {s('recorded_accepted')} accepted, {s('deadman_events')} DEADMAN events")

def per_hop(r):
    lines = ["| hand-over | floor p50 | service set p50 | its own cost p50 | floor p99 | service set p99 |", "|---|---|---|---|---|---|"]
    for h, hop in enumerate(HOPS[1:]):
        f, p = r["floor_hops_us"][h], r["hops_us"][hop]
        lines.append(f"| to {hop} | {f['p50']:.1f} | {p['p50']:.1f} | {p['p50'] - f['p50']:.1f} | {f['p99']:.1f} | {p['p99']:.1f} |")
    return "\n".join(lines)

def order_rows():
    name = {"feeder": "each stage above its feeder", "sensor": "sensor side first"}
    rows = []
    for run, order, r in orders:
        e, u, f, q = r["e2e_us"], r["uds_us"], r["floor_us"], r["ratios"]
        rows.append(f"| {run} | {name[order]} | {e['p50']:.1f} / {e['p99']:.1f} | {u['p50']:.1f} / {u['p99']:.1f} | "
                    f"{q['e2e_p50_over_uds_p50']:.2f} / {q['e2e_p99_over_uds_p99']:.2f} | {f['p50']:.1f} / {f['p99']:.1f} | "
                    f"{r['deadline_misses']}, {r['lost']} |")
    return "\n".join(rows)

q = rt["ratios"]
def verdict(ok):
    return "holds" if ok else "**fails**"
kernel = platform.release()
cpu = subprocess.run(["sh", "-c", "grep -m1 'model name' /proc/cpuinfo | cut -d: -f2"], capture_output=True, text=True).stdout.strip()
budget = 0.5 * rt["floor_us"]["p99"]
doc = f"""# Latency under load on two cores

Generated by `scripts/latency-report.sh`. Machine: {cpu or 'unknown CPU'}, 2 virtual cores, kernel {kernel}
(not PREEMPT_RT). Load: `{rt['load']}` on every core at the normal scheduler priority, through every measurement.

`jetbench latency --duration {seconds} --load cpu --rt` measures three things, each for {seconds} s split into
{rt['rounds']} rounds (each round measures all three in turn, in alternating order, so that the host's drift
favours none; the rounds' HDR histograms are merged):

1. the service set on the simulated bench over iceoryx2: real processes, recorded, every cycle rebuilt from the
   samples' own stamps (sensor frame received → `bench/thrust` → `bench/state` → `bench/command` → frame written
   to the throttle board), after a 2 s warm-up per run;
2. the same service set with every sample copied through Unix domain sockets (`jetbench up --transport uds`),
   measured the same way: the copying baseline;
3. the floor: a bare eventfd ping through four processes (the same three hand-overs) at the same priorities and CPUs.

## Acceptance run: `--load cpu --rt`

{table(rt)}

{counts(rt)}

| acceptance line | measured | |
|---|---|---|
| zero deadline misses, zero lost samples, the recorder never drops | misses {rt['deadline_misses']}, lost {rt['lost']}, recorder gaps {sum(rt['seq_gaps'].values())} | {verdict(rt['deadline_misses'] == 0 and rt['lost'] == 0)} |
| end-to-end p99 within 1.5× the floor's p99 (3 hops) | {rt['e2e_us']['p99']:.1f} / {rt['floor_us']['p99']:.1f} µs = **{q['e2e_p99_over_floor_p99']:.2f}×** | {verdict(q['e2e_p99_over_floor_p99'] <= 1.5)} |
| iceoryx2 pipeline no slower than the Unix-socket baseline at p50 and p99 | p50 {q['e2e_p50_over_uds_p50']:.2f}×, p99 {q['e2e_p99_over_uds_p99']:.2f}× | {verdict(q['e2e_p50_over_uds_p50'] <= 1 and q['e2e_p99_over_uds_p99'] <= 1)} |
| runs without real-time permission, saying what it could not set | `tests/latency.rs` (`without_real_time_permission_…`): with CAP_SYS_NICE and CAP_IPC_LOCK dropped, every measurement completes and the refused SCHED_FIFO priorities and memory lock are named, in the JSON and as warnings | holds |

![latency histograms under --load cpu --rt](latency-cpu-rt.png)

### Where the time goes

Each hand-over of the service set against the same hand-over of the floor (a hop runs from one stage's publish to
the next stage's publish, so it holds the wake-up and the next stage's whole step: receive, compute, publish):

{per_hop(rt)}

The floor's p99 leaves {budget:.1f} µs, over all four stages, for everything the service set does beyond waking
processes: reading two CAN frames and calibrating them, the EKF, the control law, the tty write to the throttle
board, and three receives and three publishes on the bus. Its hops cost several times that on their own.

## The control room attached

`--control-room` measures, in the same rounds, the iceoryx2 set with the Foxglove viewer (`--foxglove`) and the
Zenoh bridge (`--zenoh`) running, and four clients attached: a Foxglove client reading every channel, one that
subscribes to every channel and never reads again, one that reads and tears its connection down mid-stream, and a
Zenoh subscriber of every channel; and an operator's client that takes control over Zenoh with TLS and a client
certificate (an `[operator]` section and a PKI the run makes) and sends a heartbeat every 100 ms, each one going
the whole command path: the gateway, `bench/operator`, the control service's decision and event, the answer.
Both services read the bus through polled subscribers on their own 10 ms clock.
Under `--rt` the viewer and the bridge run on the core of the simulated devices and the recorder (`[rt] cpus`), off
the control chain's core, and so do the clients, which stand for another computer (pinned by `jetbench latency`).
Before that placement, with the viewer, the bridge and the clients free to run on the control core, the same
measurement counted 4 deadline misses in 6034 cycles (0 without the control room): their threads and their network
work on that core delayed the chain.

{control_room(rt)}

## Contrast: the same load on the normal scheduler (no `--rt`, {contrast} s each)

{table(plain)}

{counts(plain)}

- iceoryx2 to the floor at p99: {plain['ratios']['e2e_p99_over_floor_p99']:.2f}×; to Unix sockets: p50 {plain['ratios']['e2e_p50_over_uds_p50']:.2f}×, p99 {plain['ratios']['e2e_p99_over_uds_p99']:.2f}×

![latency histograms under --load cpu](latency-cpu.png)

## History: the bus's doorbell

The bus wakes consumers with its own futex doorbells instead of iceoryx2's event services
(why: crates/bus/README.md, "Why a doorbell, not iceoryx2's event services"). Not
regenerated by this script: measured once, at the change, with `jetbench latency
--duration 5 --load cpu --rt` on this two-core VM. The service set's end-to-end latency
went from p50 266 µs / p99 518 µs with iceoryx2's events to p50 158 µs / p99 243 µs with
the doorbells. Later changes to the path moved both; the figures above are today's.

## Contrast: the priority order along the control path

`config/sim.toml` puts each stage of the control path above the stage that feeds it
(`actuation > control > estimation > sensing`). The order first specified was the sensor side first
(`sensing > estimation > control > actuation`). Both, under `--load cpu --rt`, in alternating runs of {pair} s
(each a whole `jetbench latency` run: the order applies to the floor chain and the socket baseline too):

| run | order | service set over iceoryx2 p50 / p99 µs | over Unix sockets p50 / p99 | iceoryx2 ÷ sockets p50 / p99 | floor p50 / p99 | misses, lost |
|---|---|---|---|---|---|---|
{order_rows()}

With the sensor side first, a stage that publishes keeps the CPU until its own cycle is over (its heartbeat, the next
read), and only then does the stage it woke run: every stage's bookkeeping lies on the control path. With each
stage above its feeder, the publish itself hands the CPU over, and the floor's own hand-overs get shorter too. The
order also moves the transport comparison: with each stage above its feeder, a socket publisher is preempted at its
first send, the consumer's, so its copy to the recorder leaves the control path for free; an iceoryx2 publisher
delivers to every subscriber's queue before it rings.

Raw results: [`latency-cpu-rt.json`](latency-cpu-rt.json), [`latency-cpu.json`](latency-cpu.json),
`latency-order-<run>-<feeder|sensor>.json`.
"""
open(f"{out}/REPORT.md", "w").write(doc)
print(f"wrote {out}/REPORT.md")
EOF
