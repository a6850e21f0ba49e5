#!/usr/bin/env bash
# The tandem benchmark (issue 6): builds tests/bench (our CLI, mesh_check and the peer
# programs whose libraries are installed) and runs bench.py.
#   bash tests/bench/run.sh [--quick] [--repeats N] [--only NAME] [--calibrate] [--keep]
# Full mode writes tests/bench/REPORT.md and tests/bench/results.json; --quick writes them to
# the scratch directory ($TANDEM_BENCH_SCRATCH, default ${TMPDIR:-/tmp}/tandem-bench), which
# also holds the generated volumes (never committed). Peers: bash tests/bench/install-peers.sh
# Environment: TANDEM_BENCH_BUILD (build directory, default <repo>/build-bench-peers).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
build="${TANDEM_BENCH_BUILD:-$root/build-bench-peers}"
python=/usr/bin/python3  # Debian's (python3-matplotlib lives there), not a pyenv shim
[[ -x $python ]] || python=python3

mkdir -p "$build"
echo "building tests/bench in $build"
if ! { cmake -S "$here" -B "$build" -DCMAKE_BUILD_TYPE=Release &&
       cmake --build "$build" -j"$(nproc)"; } >"$build/bench-build.log" 2>&1; then
  tail -n 40 "$build/bench-build.log"
  echo "bench: build failed (full log: $build/bench-build.log)" >&2
  exit 1
fi
grep -E '^-- bench:' "$build/bench-build.log" || true
exec "$python" "$here/bench.py" --bin "$build/bin" "$@"
