#!/usr/bin/env bash
# Measures the figures of deploy/README.md's "Sizing" table on this machine and prints the
# table's rows (markdown): peak resident size of the local CLI, of the client, and of the
# server (VmHWM from /proc, a fresh server per row) for simplified and full-resolution
# streams, one and four at a time, and at the pod's flags. Volumes are generated into
# /dev/shm (no ../shared needed; the engine CT row runs when ../shared/data has it).
#   tests/bench/sizing.sh [--bin DIR]      (default: build/bin, a Release build)
# About 2 minutes on 2 cores. Nothing is asserted: tests/service/service_sizing_test.cc
# checks the bounds; this script regenerates the documented figures.
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=build/bin
[ "${1:-}" = --bin ] && bin="$2"
source tests/bench/bench_lib.sh  # mib, timed, status_kib, start_server, stop_server
bench_start sizing

# stream N VOLUME ISO E0 [client flags...]: N concurrent clients into the running server;
# prints "wall_s client_peak_kib".
stream() {
  local n=$1 vol=$2 iso=$3 e0=$4
  shift 4
  local t0 pids=() i
  t0=$(date +%s.%N)
  for i in $(seq 1 "$n"); do
    /usr/bin/time -v "$bin/tandem-client" stream --server "$address" --input "$vol" --iso "$iso" \
      --error "$e0" --out "$work/out$i.drc" --timeout 600 "$@" > /dev/null 2> "$work/client$i.txt" &
    pids+=($!)
  done
  for i in "${!pids[@]}"; do
    wait "${pids[$i]}" || { cat "$work/client$((i + 1)).txt" >&2; exit 1; }
  done
  local wall client
  wall=$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.2f", b - a }')
  client=$(awk -F': ' '/Maximum resident set size/ { if ($2 > m) m = $2 } END { print m }' \
    "$work"/client*.txt)
  rm -f "$work"/client*.txt
  echo "$wall $client"
}
row() { printf '| %s | %s | %s |\n' "$1" "$2" "$3"; }
server_row() {  # label n volume iso e0 [client flags]
  local label=$1 n=$2
  shift 2
  read -r wall client < <(stream "$n" "$@")
  local peak
  peak=$(status_kib "$server_pid" VmHWM)
  local per=$(( (peak - idle_kib) / n ))
  row "$label" "$(mib "$peak") (+$(mib "$per")$([ "$n" -gt 1 ] && echo " per session"))" "${wall} s"
  client_max=$(( client > ${client_max:-0} ? client : ${client_max:-0} ))
}

echo "sizing: generating volumes in $work" >&2
"$bin/tandem" generate pillowbox --size 512 --out "$work/pb512.json" > /dev/null
"$bin/tandem" generate gyroid --size 192 --out "$work/gyroid192.json" > /dev/null
"$bin/tandem" generate pillowbox --dims 1024,1024,64 --out "$work/pb1024x64.json" > /dev/null
engine=../shared/data/ct_engine_256x256x128_uint8.json

echo "| run | peak RSS | wall |"
echo "|---|---|---|"
if [ -f "$engine" ]; then
  read -r k s < <(timed "$bin/tandem" extract --input "$engine" --iso 120 --error 0.5 --out "$work/e.ply")
  row '`tandem extract` engine CT 256×256×128 uint8, `--iso 120 --error 0.5`' "$(mib "$k")" "$s s"
fi
read -r k s < <(timed "$bin/tandem" extract --input "$work/pb512.json" --error 0.2 --out "$work/p.ply")
row '`tandem extract` Pillow Box 512³ float32, `--error 0.2` (default)' "$(mib "$k")" "$s s"
read -r k s < <(timed "$bin/tandem" extract --input "$work/pb512.json" --error 0.1 --out "$work/p.ply")
row 'same, `--error 0.1`' "$(mib "$k")" "$s s"
read -r k s < <(timed "$bin/tandem" extract --input "$work/gyroid192.json" --iso 0 --no-simplify --out "$work/g.ply")
row '`tandem extract` gyroid 192³ at full resolution (`--no-simplify`)' "$(mib "$k")" "$s s"

start_server
row '`tandem-server` idle' "$(mib "$idle_kib")" ""
stop_server
if [ -f "$engine" ]; then
  start_server
  server_row "server, one engine CT stream" 1 "$engine" 120 0.5
  stop_server
fi
start_server
server_row "server, one 512³ Pillow Box stream" 1 "$work/pb512.json" 0 0.2
stop_server
start_server --max-sessions 4
server_row "server, 4 concurrent 512³ Pillow Box streams" 4 "$work/pb512.json" 0 0.2
stop_server
start_server
server_row "server, one 1024×1024×64 Pillow Box stream (4 MiB slices)" 1 "$work/pb1024x64.json" 0 0.2
stop_server
start_server
server_row "server, one full-resolution 192³ gyroid stream (\`--schedule none\`)" 1 "$work/gyroid192.json" 0 0.2 --schedule none
stop_server
start_server --max-sessions 4
server_row "server, 4 concurrent full-resolution 192³ gyroid streams" 4 "$work/gyroid192.json" 0 0.2 --schedule none
stop_server
row '`tandem-client stream` (largest of the runs above)' "$(mib "$client_max")" ""
