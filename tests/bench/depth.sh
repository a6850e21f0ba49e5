#!/usr/bin/env bash
# Memory and bytes against depth, with and without sealed chunks (issue 19): a volume made
# of the same slices repeated 8x deeper (a gyroid periodic in z, closed at the x/y borders,
# uint16) through the local CLI (peak RSS) and through the server (VmHWM over the idle
# server, a fresh server per row; bytes the server sent). Prints a markdown table. The server
# runs with --max-inflight-bytes 2 MiB: with the default 16 MiB, a deep volume's slices
# queued ahead of the session (a shallow one is smaller than that) weigh more than the mesh.
#   tests/bench/depth.sh [--bin DIR] [--size N] [--depth Z] [--repeat R] [--modes "plain seal"]
#                        [--server-flag FLAG]...
# (defaults build/bin, 192, 48, 1, both): with --repeat, each peak is the median of R runs
# (the machine is shared); --modes seal measures the sealed rows only; --server-flag adds a
# flag to every server (e.g. --watch-retain-mb=0: no chunks kept for late watchers).
# Nothing is asserted (tests/core/sealer_test.cc checks the bound on MemoryBytes); this
# script gives the figures of tests/bench/SEALING.md.
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=build/bin
size=192
depth=48
repeat=1
modes="plain seal"
server_flags=()
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin="$2"; shift 2;;
    --size) size="$2"; shift 2;;
    --depth) depth="$2"; shift 2;;
    --repeat) repeat="$2"; shift 2;;
    --modes) modes="$2"; shift 2;;
    --server-flag) server_flags+=("$2"); shift 2;;
    *) echo "depth: unknown argument $1" >&2; exit 2;;
  esac
done
source tests/bench/bench_lib.sh  # mib, timed, status_kib, start_server, stop_server
bench_start depth

# gyroid N NZ FILE: the volume and its sidecar.
gyroid() {
  /usr/bin/python3 - "$1" "$2" "$3" <<'PY'
import json, sys
import numpy as np
n, nz, path = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
w = 2 * np.pi / 32  # period: 32 voxels
i = np.arange(n)
x, y = np.meshgrid(i, i)  # y rows, x columns
border = (np.minimum(np.minimum(x, y), np.minimum(n - 1 - x, n - 1 - y)) < 2)
with open(path + ".raw", "wb") as f:
    for k in range(nz):
        g = np.sin(w * x) * np.cos(w * y) + np.sin(w * y) * np.cos(w * k) + np.sin(w * k) * np.cos(w * x)
        g = np.where(border, 1.5, g)
        f.write(((g + 1.5) * 20000).astype("<u2").tobytes())
json.dump({"dims": [n, n, nz], "dtype": "uint16", "spacing": [1, 1, 1],
           "raw_file": path.split("/")[-1] + ".raw", "suggested_isovalues": [30000],
           "description": "gyroid periodic in z (tests/bench/depth.sh)"}, open(path + ".json", "w"))
PY
}
echo "depth: generating ${size}x${size}x${depth} and x$((8 * depth)) in $work" >&2
gyroid "$size" "$depth" "$work/shallow"
gyroid "$size" "$((8 * depth))" "$work/deep"

declare -A final_bytes
json_field() { /usr/bin/python3 -c "import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])" "$@"; }
echo "| run | ${depth} slices | $((8 * depth)) slices | ratio |"
echo "|---|---|---|---|"
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.2f", b / a }'; }
median() { printf '%s\n' "$@" | sort -n | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
for mode in $modes; do
  flags=()
  [ "$mode" = seal ] && flags=(--seal)
  declare -A peak tris
  for vol in shallow deep; do
    runs=()
    for _ in $(seq 1 "$repeat"); do
      read -r k _ < <(timed "$bin/tandem" extract --input "$work/$vol.json" --error 0.2 \
        --metrics "$work/m.json" --out "$work/o.ply" "${flags[@]}")
      runs+=("$k")
    done
    peak[$vol]=$(median "${runs[@]}")
    tris[$vol]=$(json_field "$work/m.json" triangles_final)
  done
  echo "| \`tandem extract\` $mode: peak RSS | $(mib "${peak[shallow]}") | $(mib "${peak[deep]}") | $(ratio "${peak[shallow]}" "${peak[deep]}") |"
  echo "| (final triangles) | ${tris[shallow]} | ${tris[deep]} | $(ratio "${tris[shallow]}" "${tris[deep]}") |"
done
for mode in $modes; do
  flags=()
  [ "$mode" = seal ] && flags=(--seal)
  declare -A peak sent
  for vol in shallow deep; do
    runs=()
    for _ in $(seq 1 "$repeat"); do
      start_server --max-inflight-bytes 2097152 "${server_flags[@]}"
      "$bin/tandem-client" stream --server "$address" --input "$work/$vol.json" --iso 30000 \
        --error 0.2 --out "$work/o.drc" --metrics "$work/m.json" --timeout 900 "${flags[@]}" \
        > /dev/null 2> "$work/client.err" || { cat "$work/client.err" >&2; exit 1; }
      runs+=($(( $(status_kib "$server_pid" VmHWM) - idle_kib )))
      stop_server
    done
    peak[$vol]=$(median "${runs[@]}")
    sent[$vol]=$(json_field "$work/m.json" bytes_sent)
    [ "$mode" = plain ] && final_bytes[$vol]=$(stat -c %s "$work/o.drc")
  done
  echo "| server, $mode: peak over idle | $(mib "${peak[shallow]}") | $(mib "${peak[deep]}") | $(ratio "${peak[shallow]}" "${peak[deep]}") |"
  echo "| server, $mode: bytes sent | ${sent[shallow]} | ${sent[deep]} | $(ratio "${sent[shallow]}" "${sent[deep]}") |"
done
if [ -n "${final_bytes[shallow]:-}" ]; then
  echo "| (the final mesh as one Draco buffer) | ${final_bytes[shallow]} | ${final_bytes[deep]} | $(ratio "${final_bytes[shallow]}" "${final_bytes[deep]}") |"
fi
