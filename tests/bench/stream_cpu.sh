#!/usr/bin/env bash
# CPU a stream costs the server against the CLI on the same volume (issue 65 item 2): the
# server's user + sys (from /proc/PID/stat, a fresh server per row) for 1, 2 and 4 concurrent
# streams of one generated volume, over the streams, against `tandem extract`'s user + sys
# (/usr/bin/time; it writes PLY, the streams Draco). Timings: noisy on a shared machine; compare rows of one run.
#   tests/bench/stream_cpu.sh [--bin DIR] [--input VOLUME --iso V] [--dims X,Y,Z] [--error E0]
# (default: a generated gyroid of --dims; the dense family's volumes come from dense_volume.cc)
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=build/bin dims=256,256,64 e0=0.5 input="" iso=0
while [ $# -gt 0 ]; do
  case $1 in
    --bin) bin=$2; shift 2 ;;
    --dims) dims=$2; shift 2 ;;
    --error) e0=$2; shift 2 ;;
    --input) input=$(readlink -f "$2"); shift 2 ;;
    --iso) iso=$2; shift 2 ;;
    *) echo "unknown flag $1" >&2; exit 2 ;;
  esac
done
source tests/bench/bench_lib.sh  # start_server, stop_server
bench_start stream_cpu
vol=$input
if [ -z "$vol" ]; then
  vol="$work/gyroid.nrrd"
  "$bin/tandem" generate gyroid --dims "$dims" --out "$vol" > /dev/null
fi
cpu_s() {  # user + sys seconds of PID so far
  awk -v hz="$(getconf CLK_TCK)" '{ printf "%.3f", ($14 + $15) / hz }' "/proc/$1/stat"
}
/usr/bin/time -f "%U %S" "$bin/tandem" extract --input "$vol" --iso "$iso" --error "$e0" \
  --out "$work/cli.ply" --quiet 2> "$work/cli.time" > /dev/null
cli=$(awk 'END { printf "%.3f", $1 + $2 }' "$work/cli.time")
echo "| streams | server CPU s | a stream, s | a stream / CLI |"
echo "|---:|---:|---:|---:|"
echo "| CLI | $cli | $cli | 1.00 |"
for n in 1 2 4; do
  start_server
  before=$(cpu_s "$server_pid")
  pids=()
  for i in $(seq 1 "$n"); do
    "$bin/tandem-client" stream --server "$address" --input "$vol" --iso "$iso" --error "$e0" \
      --out "$work/out$i.drc" --timeout 600 > /dev/null 2> "$work/client$i.err" &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p"; done
  after=$(cpu_s "$server_pid")
  stop_server
  awk -v n="$n" -v b="$before" -v a="$after" -v c="$cli" \
    'BEGIN { s = a - b; printf "| %d | %.3f | %.3f | %.2f |\n", n, s, s / n, s / n / c }'
done
