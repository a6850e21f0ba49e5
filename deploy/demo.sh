#!/usr/bin/env bash
# The main job (README's first line), runnable without ../shared: generates a sample
# volume (the paper's Pillow Box, 128^3), starts tandem-server on 127.0.0.1 (a port the OS
# picks), lets `tandem simulate` play a CT scanner writing it as a DICOM series into
# out/acquisition (100 slices/s, in shuffled bursts, then a DONE marker) while
# `tandem-client stream --follow` sends each slice to the server as soon as it is complete,
# and stops the server with SIGTERM (it drains and exits 0).
# Leaves in out/: pillowbox.ply (final mesh), pillowbox.metrics.json, previews/*.drc
# (the growing partial meshes), acquisition/ (the series) and server.log.
#   bash deploy/demo.sh --view [HOST:PORT]   the same, watched in a browser: a slower scan
#       (10 slices/s) with sealed chunks, the viewer page on HOST:PORT (127.0.0.1:8080 by
#       default) printed as it starts; it stays up after the end until Ctrl-C.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=build/bin
view=()
server_extra=()
rate=100
stream_extra=(--preview-every 16 --partials out/previews)
if [ "${1:-}" = "--view" ]; then
  view=(--view "${2:-127.0.0.1:8080}")
  server_extra=(--max-band-bytes-share 4)  # a fresh band to watch (docs/guide.md: Watching in a browser)
  rate=10
  stream_extra=(--seal --preview-every 2)
fi
# The viewer's page needs three.js from npm, so that `tandem view out/pillowbox.ply` works
# after this first command too (tests/run.sh installs the test packages as well).
[ -f node_modules/three/package.json ] || bash deploy/install-web.sh --omit=dev
mkdir -p out
rm -rf out/previews out/acquisition out/pillowbox.ply
"$bin/tandem" generate pillowbox --size 128 --out out/pillowbox.json

# Emptied here, not by the server's redirection: that runs in the background child, so the
# loop below could look before the file exists (sed's error ends the script under set -e; it
# did on a loaded machine) or read a previous run's address.
: >out/server.stdout
"$bin/tandem-server" --listen 127.0.0.1:0 ${server_extra[@]+"${server_extra[@]}"} \
  >out/server.stdout 2>out/server.log &
server=$!
trap 'kill -TERM "$server" 2>/dev/null || true' EXIT
addr=""
for _ in $(seq 100); do
  addr=$(sed -n 's/^listening on //p' out/server.stdout)
  [ -n "$addr" ] && break
  sleep 0.1
done
[ -n "$addr" ] || { echo "demo: tandem-server did not start; see out/server.log" >&2; exit 1; }

"$bin/tandem" simulate --input out/pillowbox.json --out out/acquisition --as dicom --rate "$rate" \
  --done-file DONE &
scanner=$!
"$bin/tandem-client" stream --server "$addr" --input out/acquisition --follow --done-file DONE \
  --iso 0 --error 0.1 "${stream_extra[@]}" --reference \
  --out out/pillowbox.ply --metrics out/pillowbox.metrics.json ${view[@]+"${view[@]}"}
wait "$scanner"

kill -TERM "$server" 2>/dev/null || true  # (Ctrl-C on --view stopped it already)
wait "$server" || true
trap - EXIT
echo "demo: wrote out/pillowbox.ply, out/pillowbox.metrics.json and $(ls out/previews 2>/dev/null | wc -l) previews in out/previews"
grep -E '"(triangles_extracted|triangles_final|peak_triangles|error_max)"' out/pillowbox.metrics.json
