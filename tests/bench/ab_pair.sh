#!/usr/bin/env bash
# A/B of two `tandem` builds on a noisy shared machine: the two binaries run side by side, one
# core each (taskset), `--parts 1`, so that both see the same load; every round is four runs,
# each binary on each core and each started first (on a shared VM one core and the binary
# started second can each run several % faster: a single ordering hides, or makes up,
# changes of that size). Prints each run's B/A user time and their
# geometric mean; outputs are not compared (tests/bench/same_outputs.sh does that).
#   bash tests/bench/ab_pair.sh OLD/tandem NEW/tandem VOLUME [ROUNDS [extract flags...]]
# Default 2 rounds (8 runs), `--error 0.2`. Needs two free cores; the machine otherwise idle.
set -euo pipefail
if [[ $# -lt 3 ]]; then
  sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
fi
a=$1 b=$2 vol=$3 rounds=${4:-2}
shift $(($# < 4 ? $# : 4))
flags=("$@")
[[ ${#flags[@]} -gt 0 ]] || flags=(--error 0.2)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
one() {  # FIRST SECOND CORE_OF_FIRST: both at once; prints the user times of FIRST and SECOND
  local c1=$3 c2=$((1 - $3))
  /usr/bin/time -f %U -o "$work/t1" taskset -c "$c1" "$1" extract --input "$vol" \
    --out "$work/1.ply" --quiet --parts 1 "${flags[@]}" > /dev/null 2>&1 &
  local p1=$!
  /usr/bin/time -f %U -o "$work/t2" taskset -c "$c2" "$2" extract --input "$vol" \
    --out "$work/2.ply" --quiet --parts 1 "${flags[@]}" > /dev/null 2>&1 &
  local p2=$!
  wait "$p1" "$p2"
  echo "$(tail -1 "$work/t1") $(tail -1 "$work/t2")"
}
for ((i = 0; i < rounds; ++i)); do
  for c in 0 1; do
    one "$a" "$b" "$c"                       # A first
    one "$b" "$a" "$c" | awk '{print $2, $1}'  # B first; printed as A B
  done
done | awk '{r = $2 / $1; printf "A %.2f s  B %.2f s  B/A %.3f\n", $1, $2, r; s += log(r); n++}
            END {printf "geometric mean B/A %.3f over %d runs\n", exp(s / n), n}'
