#!/usr/bin/env bash
# scaling.sh: how `tandem extract` scales past two cores (issue 65 item 3), measured with
# quantities a loaded machine does not change, and the wall time they predict on 1-16 cores.
#
#   bash tests/bench/scaling.sh [--tandem BIN] [--parts "1 2 4 8 16"] [--inputs LIST]
#                               [--repeats N] [--pairs N] [--balance] [--quick] [--work DIR]
#                               [--data DIR]
#
# For each input and each part count P, one run `taskset -c 0 tandem extract --parts P` under
# `perf record --call-graph dwarf` (cpu-clock samples: on-CPU time only, whatever else the
# machine runs) splits the process's user + sys by what may run side by side: the slabs' own
# chains of steps (extraction and SIMPLIFY, one core a slab at most), the final sag correction
# (ranges on every core), and the serial rest (start-up, the merge, SIMPLIFY at the seams, the
# write). Parts are not threads, so 16 parts run on this 2-core machine. --balance also runs
# each slab of the P-part split as a volume of its own (its columns cropped) for the longest
# slab's share by its contractions (the edge slabs hold the volume's x walls); without it the
# slabs count as equal. --repeats N: N runs of each (the model takes medians: CPU time on a
# loaded machine moves by about 10 %).
# The model (scaling.py): wall(C cores, P = C) = serial + max(longest slab, reading, (slabs +
# reading) / C) + sag / C, the slices read by one thread beside the slabs. Not modelled:
# memory bandwidth and caches shared by 16 cores, the hand-off between threads.
# --pairs N: N interleaved pairs of `taskset -c 0` and `taskset -c 0,1` runs at the default
# parts (wall time, /usr/bin/time), the median ratio against the model's 1-vs-2-core ratio.
# Inputs (--inputs, comma-separated): closed32 (the dense family's closed period-32 gyroid
# 512² × 64), open256 (the open period-256 gyroid 2048² × 16), iso 30000 and E0 0.2 for both;
# ct (the engine CT, iso 100, E0 0.2, when --data DIR, default ../shared/data beside the
# checkout, has it; 255 cube columns give at most 15 slabs of 16). --quick: 256² × 32 and
# 1024² × 16, parts 1 2 4 8, one pair. Needs perf (linux-perf), taskset and a C++ compiler.
# Prints the tables (markdown) and keeps the raw figures in DIR/work.jsonl, DIR/pairs.jsonl.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
root=$(cd "$here/../.." && pwd)
tandem=$root/build/bin/tandem
parts="1 2 4 8 16"
inputs=closed32,open256
pairs=0
repeats=1
balance=0
quick=0
work=${TMPDIR:-/tmp}/tandem-scaling
data=$root/../shared/data
while [ $# -gt 0 ]; do
  case $1 in
    --tandem) tandem=$2; shift 2 ;;
    --parts) parts=$2; shift 2 ;;
    --inputs) inputs=$2; shift 2 ;;
    --pairs) pairs=$2; shift 2 ;;
    --repeats) repeats=$2; shift 2 ;;
    --balance) balance=1; shift ;;
    --quick) quick=1; shift ;;
    --work) work=$2; shift 2 ;;
    --data) data=$2; shift 2 ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
    *) echo "scaling.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ $quick = 1 ]; then
  [ "$parts" = "1 2 4 8 16" ] && parts="1 2 4 8"
  [ "$pairs" = 0 ] && pairs=1
fi
for tool in perf taskset /usr/bin/time; do
  command -v $tool >/dev/null || { echo "scaling.sh: needs $tool" >&2; exit 2; }
done
[ -x "$tandem" ] || { echo "scaling.sh: no tandem at $tandem (--tandem BIN)" >&2; exit 2; }
mkdir -p "$work"
: > "$work/work.jsonl"
: > "$work/pairs.jsonl"

c++ -O2 -std=c++20 -o "$work/dense_volume" "$here/dense_volume.cc"
declare -A volume iso error
size32=512; slices32=64; size256=2048
[ $quick = 1 ] && { size32=256; slices32=32; size256=1024; }
for name in ${inputs//,/ }; do
  case $name in
    closed32)
      volume[$name]=$work/closed32.json
      [ -f "${volume[$name]}" ] || "$work/dense_volume" gyroid --period 32 --size $size32 \
        --slices $slices32 --out "${volume[$name]}"
      iso[$name]=30000; error[$name]=0.2 ;;
    open256)
      volume[$name]=$work/open256.json
      [ -f "${volume[$name]}" ] || "$work/dense_volume" gyroid --period 256 --size $size256 \
        --slices 16 --open-ends --out "${volume[$name]}"
      iso[$name]=30000; error[$name]=0.2 ;;
    ct)
      volume[$name]=$data/ct_engine_256x256x128_uint8.json
      [ -f "${volume[$name]}" ] || { echo "scaling.sh: no engine CT, skipped" >&2; continue; }
      iso[$name]=100; error[$name]=0.2 ;;
    *) echo "scaling.sh: unknown input $name" >&2; exit 2 ;;
  esac
done

extract() {  # extract NAME VOLUME PARTS [more flags]: the command line of one run
  local name=$1 vol=$2 p=$3
  shift 3
  echo "$tandem" extract --input "$vol" --iso "${iso[$name]}" --error "${error[$name]}" \
    --parts "$p" --out "$work/out.ply" --quiet "$@"
}

for name in "${!volume[@]}"; do
  for p in $parts; do
    for ((rep = 0; rep < repeats; rep++)); do
      echo "scaling.sh: $name, --parts $p on one core (run $((rep + 1)) of $repeats)" >&2
      # shellcheck disable=SC2046
      perf record -q -e cpu-clock -F 250 --call-graph dwarf,16384 -o "$work/perf.data" -- \
        taskset -c 0 /usr/bin/time -f "%U %S %e" -o "$work/time.txt" \
        $(extract "$name" "${volume[$name]}" "$p" --metrics "$work/m.json") 2>/dev/null
      perf script -i "$work/perf.data" -F comm,pid,tid,time,ip,sym --no-inline 2>/dev/null \
        > "$work/perf.txt"
      python3 "$here/scaling.py" classify "$work/perf.txt" "$work/time.txt" "$work/m.json" \
        --input "$name" --parts "$p" >> "$work/work.jsonl"
      rm -f "$work/perf.data" "$work/perf.txt"
    done
    if [ $balance = 1 ] && [ "$p" -gt 1 ]; then
      python3 "$here/scaling.py" crop "${volume[$name]}" --parts "$p" --out "$work/slabs"
      for ((s = 0; s < p; s++)); do
        # shellcheck disable=SC2046
        taskset -c 0 $(extract "$name" "$work/slabs/slab$s.json" 1 --metrics "$work/s.json")
        python3 - "$work/s.json" "$name" "$p" "$s" >> "$work/work.jsonl" <<'EOF'
import json, sys
m = json.load(open(sys.argv[1]))
print(json.dumps({"kind": "slab", "input": sys.argv[2], "parts": int(sys.argv[3]),
                  "slab": int(sys.argv[4]), "contractions": m["contractions"],
                  "evaluations": m["evaluations"], "extracted": m["triangles_extracted"],
                  "session_cpu_s": m["time_s"]["extract"] + m["time_s"]["simplify"]}))
EOF
      done
      rm -rf "$work/slabs"
    fi
  done
  if [ "$pairs" -gt 0 ]; then
    default_parts=$(python3 -c "import json,sys; nx=json.load(open(sys.argv[1]))['dims'][0]; \
print(4 if nx >= 256 else 2 if nx >= 81 else 1)" "${volume[$name]}")
    one=() two=()
    for ((k = 0; k < pairs; k++)); do
      echo "scaling.sh: $name, pair $((k + 1)) of $pairs (one core, then two)" >&2
      for cpus in 0 0,1; do
        # shellcheck disable=SC2046
        /usr/bin/time -f "%e" -o "$work/wall.txt" taskset -c $cpus \
          $(extract "$name" "${volume[$name]}" "$default_parts")
        if [ $cpus = 0 ]; then one+=("$(cat "$work/wall.txt")"); else two+=("$(cat "$work/wall.txt")"); fi
      done
    done
    python3 - "$name" "$default_parts" "${one[*]}" "${two[*]}" >> "$work/pairs.jsonl" <<'EOF'
import json, statistics, sys
one = [float(x) for x in sys.argv[3].split()]
two = [float(x) for x in sys.argv[4].split()]
r = [a / b for a, b in zip(one, two)]
print(json.dumps({"input": sys.argv[1], "parts": int(sys.argv[2]), "n": len(r),
                  "one": statistics.median(one), "two": statistics.median(two),
                  "ratio": statistics.median(r), "ratio_min": min(r), "ratio_max": max(r)}))
EOF
  fi
done
python3 "$here/scaling.py" model "$work/work.jsonl" --pairs "$work/pairs.jsonl"
