#!/bin/bash
# Instructions a contraction (callgrind), the measure of issue 65's contraction loop:
#
#   bash tests/bench/contraction_cost.sh BUILD/bin/tandem [WORKDIR] [-- extra extract flags]
#
# Generates the closed period-32 256² x 16 gyroid of the dense family (dense_volume, compiled
# here on its own: it needs no library), runs `tandem extract --error 0.2` once for its metrics
# and once under callgrind, and prints the instructions of the schedule's ACTIVATE + SIMPLIFY
# steps (SimplifyLayer and FinishSlab, inclusive, less DELAY) and of the whole run, each over
# the contractions, with the evaluations, Q pushes and W pushes a contraction (the metrics'
# counters). Counts are repeatable on a loaded machine; about a minute. Needs valgrind and a
# C++ compiler.
set -euo pipefail
[ $# -ge 1 ] || { sed -n '2,12p' "$0"; exit 2; }
tandem=$(readlink -f "$1")
shift
work=${1:-}
[ -n "$work" ] && [ "$work" != "--" ] && shift || work=$(mktemp -d /tmp/contraction_cost.XXXXXX)
[ "${1:-}" = "--" ] && shift
extra=("$@")
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$work"
command -v valgrind >/dev/null || { echo "valgrind not found (apt-get install valgrind)" >&2; exit 2; }
if [ ! -x "$work/dense_volume" ]; then
  c++ -O2 -std=c++20 -o "$work/dense_volume" "$here/dense_volume.cc"
fi
vol="$work/gyroid-p32-256x16.json"
[ -f "$vol" ] || "$work/dense_volume" gyroid --period 32 --size 256 --slices 16 --out "$vol"
run=(extract --input "$vol" --iso 30000 --error 0.2 --quiet "${extra[@]}")
"$tandem" "${run[@]}" --out "$work/out.ply" --metrics "$work/out.json"
valgrind --tool=callgrind --callgrind-out-file="$work/callgrind.out" \
  "$tandem" "${run[@]}" --out "$work/cg.ply" >/dev/null 2>"$work/valgrind.log"
callgrind_annotate --inclusive=yes "$work/callgrind.out" >"$work/inclusive.txt"
python3 - "$work" <<'EOF'
import json, re, sys
work = sys.argv[1]
m = json.load(open(f"{work}/out.json"))
text = open(f"{work}/inclusive.txt").read()
total = int(re.search(r"([\d,]+) \(100\.0%\)\s+PROGRAM TOTALS", text).group(1).replace(",", ""))
def inclusive(name):  # a function's inclusive count (0 if it never ran or was inlined)
    for line in text.splitlines():
        if name in line:
            return int(line.split()[0].replace(",", ""))
    return 0
# The schedule's steps, which call Activate and Simplify (or, in older builds, their one
# ActivateAndSimplify), less the DELAY they start with: stable across how those are split.
loop = (inclusive("tandem::(anonymous namespace)::SimplifyLayer(tandem::Slab&)") +
        inclusive("tandem::FinishSlab(tandem::Slab&, tandem::Schedule)") -
        inclusive("tandem::Simplifier::Delay("))
c = m["contractions"]
print(f"contractions {c}, triangles {m['triangles_final']}, Error(K) {m['error_max']:.4g}")
print(f"instructions: ACTIVATE + SIMPLIFY {loop / 1e9:.3f} G = {loop / c / 1e3:.2f} k a contraction;"
      f" whole run {total / 1e9:.3f} G = {total / c / 1e3:.2f} k")
print(f"a contraction: {m['evaluations'] / c:.2f} evaluations, {m['q_pushes'] / c:.2f} Q pushes,"
      f" {m['w_pushes'] / c:.2f} W pushes")
EOF
echo "(callgrind profile: $work/callgrind.out)"
