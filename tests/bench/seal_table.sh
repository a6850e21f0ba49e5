#!/usr/bin/env bash
# The table "what sealing costs" (tests/bench/README.md): each input at two E0, `tandem extract --parts 1`
# without and with --seal (default margin 2), distances by --reference; the volume's
# default iso-value (its first suggested one) unless given as VOLUME@ISO. One run at a time.
# Prints: input  E0  triangles plain/seal (change)  RMS plain/seal (change)  Hausdorff (change)
# usage: tests/bench/seal_table.sh TANDEM "E0 E0" VOLUME[@ISO]... 
set -euo pipefail
bin=$1 e0s=$2; shift 2
work=$(mktemp -d); trap 'rm -rf "$work"' EXIT
printf 'input\te0\ttri_plain\ttri_seal\ttri_pct\trms_plain\trms_seal\trms_pct\thd_plain\thd_seal\thd_pct\n'
for spec in "$@"; do
  vol=${spec%@*} iso=()
  [[ $spec == *@* ]] && iso=(--iso "${spec##*@}")
  for e in $e0s; do
    for mode in plain seal; do
      flags=(); [[ $mode == seal ]] && flags=(--seal)
      "$bin" extract --input "$vol" "${iso[@]}" --error "$e" --parts 1 "${flags[@]}" \
        --reference --metrics "$work/$mode.json" --out "$work/out.ply" --quiet
    done
    python3 - "$work" "$(basename "$spec")" "$e" <<'PY'
import json, sys
w, name, e = sys.argv[1:]
p, s = (json.load(open(f"{w}/{m}.json")) for m in ("plain", "seal"))
def row(a, b, fmt):
    return [fmt % a, fmt % b, "%+.1f" % (100.0 * (b / a - 1.0))]
out = [name, e]
out += row(p["triangles_final"], s["triangles_final"], "%d")
out += row(p["distance"]["L2"]["max"], s["distance"]["L2"]["max"], "%.4f")
out += row(p["distance"]["Linf"]["max"], s["distance"]["Linf"]["max"], "%.3f")
print("\t".join(out), flush=True)
PY
  done
done
