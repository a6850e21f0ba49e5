#!/usr/bin/env bash
# Regenerates the experiments of the paper (Tables 1-2, Figs. 6-9) with our tandem CLI.
#   bash tests/experiments/run.sh [--quick] [--repeats N] [--jobs N]
# Full mode writes tests/experiments/REPORT.md, results.json and fig*.png; --quick writes them
# to $TANDEM_EXPERIMENTS_SCRATCH/report (default ${TMPDIR:-/tmp}/tandem-experiments/report).
# Programs: $TANDEM_BIN (the tandem CLI; bench_run beside it is used when present) if set,
# else tandem and bench_run are built in $TANDEM_BENCH_BUILD (default <repo>/build-bench-peers,
# shared with tests/bench/run.sh; needs no peer library). Plots need python3-matplotlib
# (Debian); without it the report is written without figures.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
python=/usr/bin/python3  # Debian's (python3-matplotlib lives there), not a pyenv shim
[[ -x $python ]] || python=python3

tandem="${TANDEM_BIN:-}"
if [[ -z $tandem ]]; then
  build="${TANDEM_BENCH_BUILD:-$root/build-bench-peers}"
  mkdir -p "$build"
  echo "building tandem in $build"
  werror=OFF
  if [ "${CI:-}" = "true" ]; then werror=ON; fi  # as tests/run.sh: the main build's flags, one cache
  if ! { cmake -S "$root/tests/bench" -B "$build" -DCMAKE_BUILD_TYPE=Release -DTANDEM_WERROR="$werror" &&
         cmake --build "$build" -j"$(nproc)" --target tandem bench_run; } \
       >"$build/experiments-build.log" 2>&1; then
    tail -n 40 "$build/experiments-build.log"
    echo "experiments: build failed (full log: $build/experiments-build.log)" >&2
    exit 1
  fi
  tandem="$build/bin/tandem"
fi
launcher=()
if [[ -x "$(dirname "$tandem")/bench_run" ]]; then
  launcher=(--launcher "$(dirname "$tandem")/bench_run")
fi
exec "$python" "$here/experiments.py" --tandem "$tandem" "${launcher[@]}" "$@"
