# Sourced by the scripts that run the bench: strict mode, the repository root
# as the working folder, a release build of every binary, and `$jb`, the
# jetbench binary.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
cargo build --release --quiet --bins
jb="$root/target/release/jetbench"
