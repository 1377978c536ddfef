#!/usr/bin/env bash
# Compares FBL, SMC and MPC on the simulated bench (real processes, real bus) and writes
# docs/control/REPORT.md with plots. About 20 minutes: every run is real time.
#
#   scripts/control-report.sh            # all of it
#   JETBENCH_REPORT_QUICK=1 scripts/...  # 20 s steps only, for trying the script
#
# 1. The same profiles for every law on the nominal P100 plant: steps (full-range steps
#    that saturate the throttle, and small ones), ramps, sines, chirp. SMC twice: with
#    the study's gains and with gains tuned for the bench's noise.
# 2. A plant with an input delay the nominal model lacks: `jetbench diagnose` finds it in
#    an open-loop recording, and each law runs once with the nominal model and once with
#    the diagnosed one.
source "$(dirname "$0")/common.sh"
out="$root/docs/control"
work="$root/target/control-report"
rm -rf "$work" && mkdir -p "$work" "$out/plots"
rm -f "$out"/plots/*

quick=${JETBENCH_REPORT_QUICK:-}
declare -A duration=([steps]=56 [ramps]=15 [sines]=13 [chirp]=21)
profiles=(steps ramps sines chirp)
if [[ -n "$quick" ]]; then duration=([steps]=20); profiles=(steps); fi

# config/sim.toml ships SMC gains tuned for the simulated bench's noise; the study's
# (a1 20, beta 900, k 0.15) run from a copy with those put back.
sed 's/^a1 = 10.0$/a1 = 20.0/; s/^beta = 100.0$/beta = 900.0/; s/^k = 0.05$/k = 0.15/' config/sim.toml > "$work/smc-study.toml"
grep -q '^beta = 900.0$' "$work/smc-study.toml"

run() { # name, then arguments of `jetbench up`
  local name=$1; shift
  echo "== $name: jetbench up --sim $*" >&2
  "$jb" up --sim --quiet --record "$work/$name.mcap" "$@" > "$work/$name.log" 2>&1
}

for profile in "${profiles[@]}"; do
  d=${duration[$profile]}
  run "fbl-$profile" --controller fbl --profile "$profile" --duration "$d"
  run "smc-$profile" --controller smc --config "$work/smc-study.toml" --profile "$profile" --duration "$d"
  run "smc-tuned-$profile" --controller smc --profile "$profile" --duration "$d"
  run "mpc-$profile" --controller mpc --profile "$profile" --duration "$d"
done

# FBL against MPC on steps with two more sensor-noise seeds: one run's settling times
# move by a few cycles with the noise, so the comparison is made over three.
if [[ -z "$quick" ]]; then
  for seed in 2 3; do
    sed "s/^seed = 1$/seed = $seed/" config/sim.toml > "$work/seed$seed.toml"
    grep -q "^seed = $seed$" "$work/seed$seed.toml"
    for law in fbl mpc; do
      run "$law-steps-seed$seed" --controller $law --config "$work/seed$seed.toml" --profile steps --duration "${duration[steps]}"
    done
  done
fi

# The delayed plant, and what diagnosis makes of an open-loop recording of it.
cat > "$work/p100-delay.toml" <<'TOML'
# p100-diesel with a 120 ms input delay (ECU processing and fuel transport).
[model]
K_T = -1.49676
K_TT = -0.045206
K_D = -2.43303
K_DD = 0.020352
K_TD = 0.064188
c = -19.926756
B_U = 0.589177
B_T = 0.016715
B_D = -0.021258
B_UU = 0.013878

[effects.input_delay]
delay_s = 0.12
TOML
"$jb" sim-record --model "$work/p100-delay.toml" --seed 11 --duration 300 --out "$work/delay-campaign.csv"
"$jb" diagnose --model p100-diesel "$work/delay-campaign.csv" --out "$work/diagnosed.toml" --json > "$work/diagnosis.json"
d=${duration[steps]}
for law in fbl smc mpc; do
  run "delay-nominal-$law" --controller $law --plant "$work/p100-delay.toml" --model p100-diesel --profile steps --duration "$d"
  run "delay-diagnosed-$law" --controller $law --plant "$work/p100-delay.toml" --model "$work/diagnosed.toml" --profile steps --duration "$d"
done

for f in "$work"/*.mcap; do
  "$jb" metrics --json --skip 1 "$f" > "${f%.mcap}.json"
done
"$jb" metrics --skip 1 --plot "$out/plots" "$work"/fbl-steps.mcap "$work"/smc-steps.mcap "$work"/smc-tuned-steps.mcap \
  "$work"/mpc-steps.mcap "$work"/delay-nominal-mpc.mcap "$work"/delay-diagnosed-mpc.mcap > /dev/null
rm -f "$out"/plots/*.svg
cargo bench --quiet -p jetbench-control --bench mpc > "$work/mpc-bench.txt" 2>/dev/null
python3 "$root/scripts/control_report.py" "$work" "$out/REPORT.md"
echo "wrote $out/REPORT.md" >&2
