#!/usr/bin/env bash
# Checks that two builds of `tandem` give identical results: the same mesh bytes and the same
# metrics (timings, memory and the input path aside) on generated volumes and, when present,
# the shared CT/MRI volumes, over every schedule, slabs on and off, sealing, isotropy and a
# target count. For refactoring steps that must not change behaviour:
#   bash tests/bench/same_outputs.sh OLD/bin/tandem NEW/bin/tandem
# Exit 0 when every case matches; the first difference is printed.
set -euo pipefail
ref=$1 new=$2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
data=$(cd "$(dirname "$0")/../.." && pwd)/../shared/data
inputs=()
"$ref" generate link --size 96 --out "$work/link.nrrd" >/dev/null 2>&1
"$ref" generate pillowbox --size 80 --out "$work/box.nrrd" >/dev/null 2>&1
"$ref" generate gyroid --dims 300,280,48 --out "$work/gyroid.nrrd" >/dev/null 2>&1  # 4 slabs
inputs+=("$work/link.nrrd" "$work/box.nrrd" "$work/gyroid.nrrd")
for f in ct_engine_256x256x128_uint8 ct_head_headsq_64x64x93_int16 mr_head_48x62x42_uint8 \
         mri_avg152T1_91x109x91_uint8; do
  [[ -f $data/$f.json ]] && inputs+=("$data/$f.json")
done
cases=(
  ""
  "--parts 1"
  "--parts 4"
  "--schedule classical"
  "--schedule tandem"
  "--no-simplify"
  "--alpha 0.5"
  "--seal"
  "--target-triangles 3000"
  "--distance-guard 0 --sag-correction 0"
)
strip() {  # the metrics that may differ between two identical runs
  /usr/bin/python3 -c '
import json, sys
def clean(r):
    for k in ("time_s", "peak_rss_bytes", "input", "output", "peak_session_bytes", "memory_bytes"):
        r.pop(k, None)
    return r
r = json.load(open(sys.argv[1]))
print(json.dumps([clean(x) for x in r] if isinstance(r, list) else clean(r), sort_keys=True))' "$1"
}
n=0
for in in "${inputs[@]}"; do
  iso=()
  case $in in *.nrrd) iso=(--iso 0) ;; esac
  for c in "${cases[@]}"; do
    # shellcheck disable=SC2086
    for bin in ref new; do
      b=$ref; [[ $bin == new ]] && b=$new
      "$b" extract --input "$in" "${iso[@]}" $c --out "$work/$bin.ply" \
        --metrics "$work/$bin.json" --quiet >/dev/null
    done
    if ! cmp -s "$work/ref.ply" "$work/new.ply"; then
      echo "DIFFERENT MESH: $in $c"; exit 1
    fi
    if [[ "$(strip "$work/ref.json")" != "$(strip "$work/new.json")" ]]; then
      echo "DIFFERENT METRICS: $in $c"
      diff <(strip "$work/ref.json" | tr ',' '\n') <(strip "$work/new.json" | tr ',' '\n') | head
      exit 1
    fi
    n=$((n + 1))
  done
done
echo "same outputs: $n cases on ${#inputs[@]} volumes"
