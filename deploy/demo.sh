#!/usr/bin/env bash
# The main job (README's first line), runnable without ../shared: generates a sample
# volume (the paper's Pillow Box, 128^3 float32) and extracts + simplifies it in tandem
# with the local CLI. Leaves out/pillowbox.ply and out/pillowbox.metrics.json.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=build/bin
mkdir -p out
"$bin/tandem" generate pillowbox --size 128 --out out/pillowbox.json
"$bin/tandem" extract --input out/pillowbox.json --error 0.1 --schedule tandem-lag \
  --out out/pillowbox.ply --metrics out/pillowbox.metrics.json --reference
echo "wrote out/pillowbox.ply and out/pillowbox.metrics.json:"
grep -E '"(triangles_extracted|triangles_final|peak_triangles|error_max)"' out/pillowbox.metrics.json
