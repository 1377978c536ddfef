#!/usr/bin/env bash
# Out-of-class identification, the acceptance figure: N campaigns of the turbojet plant (an
# engine that is not the ten-parameter model), identified as `jetbench identify` does; per seed
# whether a bounded model is written, its held-out MAE and its MAE on a second run of the same
# engine over the noise floor, as a Markdown table (crates/ident/examples/out_of_class.rs).
#   scripts/out-of-class.sh [N=20] [FIRST_SEED=1] [DURATION_S=300]
# It builds the workspace's examples (the whole workspace, so the release build's feature set
# stays the one every other build uses) and runs the example at low priority.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet --workspace --examples
exec nice -n 10 target/release/examples/out_of_class "$@"
