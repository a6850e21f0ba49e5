#!/usr/bin/env bash
# The tandem benchmark (issue 6): builds tests/bench (our CLI, mesh_check and the peer
# programs whose libraries are installed) and runs bench.py.
#   bash tests/bench/run.sh [--quick] [--repeats N] [--only NAME] [--calibrate] [--keep]
# With --dense (first argument) it runs the dense family instead (dense.py, issue 25:
# tests/bench/DENSE.md), which also needs tandem-server and tandem-client: it brings them up
# to date in the main build ($TANDEM_BENCH_SERVER_BUILD, default <repo>/build) when that is
# configured, else the server rows are skipped.
#   bash tests/bench/run.sh --dense [--quick] [--repeats N] [--only NAME] [--keep]
# With --sweep (first argument) it runs the reduction sweep instead (sweep.py, issues 24 and
# 66: tests/bench/SWEEP.md): every schedule and the CGAL / VTK peers from ~10 % down to ~0.1 %
# of the triangles, on generated shapes, fields not made with the paper's formulas
# (field_volume) and the shared scans; the field generator's own test runs first.
#   bash tests/bench/run.sh --sweep [--quick] [--inputs LIST] [--tandem BIN] [--e0-from JSON]
#                                   [--lean] [--points N] [--keep]
# With --target (first argument) it runs --target-triangles N against the E0 run that gives N
# (target.py, issue 24: tests/bench/TARGET.md).
#   bash tests/bench/run.sh --target [--quick] [--only NAME] [--repeats N] [--keep]
# With --labels (first argument) it runs the segmentation benchmark instead (labels.py, issue
# 64: tests/bench/LABELS.md): label volumes meshed by tandem's label mode and by VTK's
# discrete flying edges + per-label decimation, with the gaps between touching labels.
#   bash tests/bench/run.sh --labels [--quick] [--repeats N] [--keep]
# With --build-only (first argument) it only builds (CI builds the programs beside its
# sanitizer tests, then runs each benchmark).
# Full mode writes tests/bench/REPORT.md and tests/bench/results.json; --quick writes them to
# the scratch directory ($TANDEM_BENCH_SCRATCH, default ${TMPDIR:-/tmp}/tandem-bench), which
# also holds the generated volumes (never committed). Peers: bash tests/bench/install-peers.sh
# Environment: TANDEM_BENCH_BUILD (build directory, default <repo>/build-bench-peers).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
build="${TANDEM_BENCH_BUILD:-$root/build-bench-peers}"
script="$here/bench.py"
dense=false
labels=false
sweep=false
build_only=false
if [[ "${1:-}" == "--build-only" ]]; then
  shift
  build_only=true
elif [[ "${1:-}" == "--dense" ]]; then
  shift
  dense=true
  script="$here/dense.py"
elif [[ "${1:-}" == "--sweep" ]]; then
  shift
  script="$here/sweep.py"
  sweep=true
elif [[ "${1:-}" == "--target" ]]; then
  shift
  script="$here/target.py"
elif [[ "${1:-}" == "--labels" ]]; then
  shift
  script="$here/labels.py"
  labels=true
fi
python=/usr/bin/python3  # Debian's (python3-matplotlib lives there), not a pyenv shim
[[ -x $python ]] || python=python3

mkdir -p "$build"
echo "building tests/bench in $build"
werror=OFF
if [ "${CI:-}" = "true" ]; then werror=ON; fi  # as tests/run.sh: the main build's flags, one cache
if ! { cmake -S "$here" -B "$build" -DCMAKE_BUILD_TYPE=Release -DTANDEM_WERROR="$werror" &&
       cmake --build "$build" -j"$(nproc)"; } >"$build/bench-build.log" 2>&1; then
  tail -n 40 "$build/bench-build.log"
  echo "bench: build failed (full log: $build/bench-build.log)" >&2
  exit 1
fi
grep -E '^-- bench:' "$build/bench-build.log" || true
if $build_only; then exit 0; fi
if $labels && [[ -x "$build/bin/labels_lib_test" ]]; then
  # The measures the report rests on check themselves first.
  ctest --test-dir "$build" -R labels_lib_test --output-on-failure
fi
if $sweep && [[ -x "$build/bin/fields_lib_test" ]]; then
  ctest --test-dir "$build" -R fields_lib_test --output-on-failure
fi
if $dense; then
  server_build="${TANDEM_BENCH_SERVER_BUILD:-$root/build}"
  if [[ -f "$server_build/CMakeCache.txt" ]]; then
    echo "building tandem-server and tandem-client in $server_build"
    if ! cmake --build "$server_build" --target tandem-server tandem-client -j"$(nproc)" \
        >"$build/server-build.log" 2>&1; then
      tail -n 40 "$build/server-build.log"
      echo "bench: building the server failed (full log: $build/server-build.log)" >&2
      exit 1
    fi
  fi
  set -- --server-bin "$server_build/bin" "$@"
fi
exec "$python" "$script" --bin "$build/bin" "$@"
