#!/usr/bin/env bash
# What sealing costs in quality, around one E0: `tandem extract --parts 1` without and with
# --seal (margins 2, 4, 8) at each E0 of a sweep, distances to the full-resolution surface
# by --reference. One run at a time (2 shared cores). Prints one TSV row per run:
#   E0  mode  triangles  RMS(L2 max)  Hausdorff(Linf max)  Linf forward  Linf backward
# usage: tests/bench/seal_sweep.sh TANDEM VOLUME ISO "E0 E0 ..." [WORKDIR]
set -euo pipefail
bin=$1 vol=$2 iso=$3 e0s=$4 work=${5:-$(mktemp -d)}
mkdir -p "$work"
printf 'e0\tmode\ttriangles\trms\thausdorff\tlinf_fwd\tlinf_bwd\n'
for e in $e0s; do
  for mode in plain seal2 seal4 seal8; do
    flags=()
    [[ $mode == seal* ]] && flags=(--seal --seal-margin "${mode#seal}")
    "$bin" extract --input "$vol" --iso "$iso" --error "$e" --parts 1 "${flags[@]}" \
      --reference --metrics "$work/m.json" --out "$work/out.ply" --quiet
    python3 - "$work/m.json" "$e" "$mode" <<'PY'
import json, sys
m = json.load(open(sys.argv[1])); d = m["distance"]
print("\t".join([sys.argv[2], sys.argv[3], str(m["triangles_final"]),
                 "%.4f" % d["L2"]["max"], "%.3f" % d["Linf"]["max"],
                 "%.3f" % d["Linf"]["forward"], "%.3f" % d["Linf"]["backward"]]))
PY
  done
done
