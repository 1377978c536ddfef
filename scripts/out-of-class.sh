#!/usr/bin/env bash
# Out-of-class identification, the acceptance figure: N campaigns of the turbojet plant (an
# engine that is not the ten-parameter model), identified as `jetbench identify` does; per seed
# whether a bounded model is written, its held-out MAE and its MAE on a second run of the same
# engine over the noise floor, as a Markdown table (crates/ident/examples/out_of_class.rs).
#   scripts/out-of-class.sh [N=20] [FIRST_SEED=1] [DURATION_S=300]
set -euo pipefail
cd "$(dirname "$0")/.."
exec cargo run --release --quiet -p jetbench-ident --example out_of_class -- "$@"
