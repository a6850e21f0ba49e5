#!/usr/bin/env bash
# What previews and sealed chunks cost a stream (issue 19): the wall time of one stream
# through the server with no previews, with a preview asked for every slice (the server's
# floor, --min-preview-interval-ms 250, still applies), each without and with --seal, and
# the bytes each sent. Median of --repeats runs (default 3) per row; a fresh server per run.
#   tests/bench/cadence.sh [--bin DIR] [--repeats N]
# Volumes are generated into /dev/shm: a 256³ Link and a 192²×384 periodic gyroid (dense).
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=build/bin
repeats=3
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin="$2"; shift 2;;
    --repeats) repeats="$2"; shift 2;;
    *) echo "cadence: unknown argument $1" >&2; exit 2;;
  esac
done
source tests/bench/bench_lib.sh  # mib, timed, status_kib, start_server, stop_server
bench_start cadence

"$bin/tandem" generate link --size 256 --out "$work/link.json" > /dev/null
/usr/bin/python3 - "$work/gyroid" <<'PY'
import json, sys
import numpy as np
path, n, nz = sys.argv[1], 192, 384
w = 2 * np.pi / 32
x, y = np.meshgrid(np.arange(n), np.arange(n))
border = np.minimum(np.minimum(x, y), np.minimum(n - 1 - x, n - 1 - y)) < 2
with open(path + ".raw", "wb") as f:
    for k in range(nz):
        g = np.sin(w * x) * np.cos(w * y) + np.sin(w * y) * np.cos(w * k) + np.sin(w * k) * np.cos(w * x)
        f.write(((np.where(border, 1.5, g) + 1.5) * 20000).astype("<u2").tobytes())
json.dump({"dims": [n, n, nz], "dtype": "uint16", "spacing": [1, 1, 1],
           "raw_file": path.split("/")[-1] + ".raw", "suggested_isovalues": [30000]},
          open(path + ".json", "w"))
PY

median() { sort -g | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
json_field() { /usr/bin/python3 -c "import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])" "$@"; }
echo "| input | run | wall s (median of $repeats) | × no previews | bytes sent |"
echo "|---|---|---|---|---|"
for input in link:0:0.1 gyroid:30000:0.2; do
  IFS=: read -r name iso e0 <<< "$input"
  base=""
  for mode in "plain" "plain, preview every slice" "seal" "seal, preview every slice"; do
    flags=()
    case "$mode" in *seal*) flags+=(--seal);; esac
    case "$mode" in *preview*) flags+=(--preview-every 1);; esac
    walls=()
    for _ in $(seq 1 "$repeats"); do
      start_server
      t0=$(date +%s.%N)
      "$bin/tandem-client" stream --server "$address" --input "$work/$name.json" --iso "$iso" \
        --error "$e0" --out "$work/o.drc" --metrics "$work/m.json" --timeout 900 "${flags[@]}" \
        > /dev/null 2> "$work/client.err" || { cat "$work/client.err" >&2; exit 1; }
      walls+=("$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.3f", b - a }')")
      stop_server
    done
    wall=$(printf '%s\n' "${walls[@]}" | median)
    [ -z "$base" ] && base=$wall
    [ "$mode" = seal ] && seal_base=$wall
    ref=$base
    case "$mode" in seal*) ref=$seal_base;; esac
    echo "| $name | $mode | $wall | $(awk -v a="$ref" -v b="$wall" 'BEGIN { printf "%.2f", b / a }') | $(json_field "$work/m.json" bytes_sent) |"
  done
done
