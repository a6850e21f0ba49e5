#!/usr/bin/env bash
# Builds deploy/Dockerfile with podman, runs the image, streams a generated volume into it
# from the host, and stops it with SIGTERM while a stream is running. Everything comes
# from Debian's packages: no registry is needed (the debian:12 base is made locally with
# mmdebstrap when podman has none). Run from anywhere, as root, after the host build
# (the host's tandem and tandem-client generate and stream the volume):
#   deploy/image-test.sh [--bin DIR] [--image NAME] [--require]
#     --bin DIR     host binaries (default: build/bin)
#     --image NAME  tag to build (default: localhost/tandem:image-test)
#     --require     fail, rather than skip, when podman or mmdebstrap is missing
# What it checks (each failure names itself and exits 1):
#   1. the image builds (its own RUN step checks that no runtime library is missing);
#   2. the container runs as uid 10001, answers the health check from the host and the
#      image's HEALTHCHECK from inside, and `tandem-client info` inside it works;
#   3. a volume streamed from the host gives the mesh `tandem extract` gives on the host,
#      and so does a DICOM series streamed by the image's own client (its DICOM module)
#      (same triangle count);
#   4. SIGTERM (podman stop) during a paced stream: health turns NOT_SERVING at once, the
#      running stream still finishes OK within the grace period, the container exits 0 and
#      its log says it drained and stopped.
set -euo pipefail
cd "$(dirname "$0")/.."

bin=build/bin
image=localhost/tandem:image-test
require=0
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin="$2"; shift 2 ;;
    --image) image="$2"; shift 2 ;;
    --require) require=1; shift ;;
    -h|--help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "image-test: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done

t0=$(date +%s)
say() { echo "== image-test: $* (at $(( $(date +%s) - t0 )) s)"; }
fail() { echo "image-test: FAILED: $*" >&2; exit 1; }
skip() {
  if [ "$require" = 1 ]; then fail "$*"; fi
  echo "image-test: skipped: $*"
  exit 0
}

command -v podman > /dev/null || skip "podman is not installed (apt-get install podman)"
for b in tandem tandem-client; do
  [ -x "$bin/$b" ] || fail "$bin/$b not found: build first (or pass --bin DIR)"
done
work=$(mktemp -d /tmp/tandem-image-test.XXXXXX)
container="tandem-image-test-$$"
cleanup() {
  podman rm -f "$container" > /dev/null 2>&1 || true
  rm -rf "$work"
}
trap cleanup EXIT

# --- the base image ---------------------------------------------------------------------
base=localhost/debian:12
if ! podman image exists "$base"; then
  if podman image exists docker.io/library/debian:12; then
    base=docker.io/library/debian:12
  else
    command -v mmdebstrap > /dev/null || skip "no debian:12 image and no mmdebstrap to make one"
    say "making $base with mmdebstrap (Debian 12, apt variant)"
    # An explicit mirror: without one mmdebstrap reads sources from a non-terminal stdin.
    mmdebstrap --variant=apt --quiet bookworm - http://deb.debian.org/debian < /dev/null \
      | podman import - "$base" > /dev/null
  fi
fi

# --- how containers can run here ----------------------------------------------------------
# Inside CI containers (nested, hybrid cgroups, capped rlimits) podman's defaults can fail:
# crun refuses hybrid cgroup hierarchies, and the default rlimits may exceed what this
# process may set. Try the defaults first, then runc, then lower rlimits; keep the first
# that runs a container.
nofile_hard=$(ulimit -Hn)
[ "$nofile_hard" = unlimited ] && nofile_hard=1048576
low_limits=(--ulimit "nofile=1024:$nofile_hard" --ulimit nproc=4096:4096)
runtime=()
limits=()
found=0
for rt in "" runc; do
  for lim in 0 1; do
    r=(); [ -n "$rt" ] && r=(--runtime "$rt")
    l=(); [ "$lim" = 1 ] && l=("${low_limits[@]}")
    if podman "${r[@]}" run --rm --network host "${l[@]}" "$base" true > /dev/null 2>&1; then
      runtime=("${r[@]}"); limits=("${l[@]}"); found=1; break 2
    fi
  done
done
[ "$found" = 1 ] || fail "podman cannot run a container here (tried crun and runc, default and lower rlimits): $(podman run --rm --network host "$base" true 2>&1 | tail -1)"
say "containers run with: podman ${runtime[*]:-(default runtime)} ${limits[*]:-(default rlimits)}"

# --- 1. build -----------------------------------------------------------------------------
say "building $image from deploy/Dockerfile"
# --format docker keeps HEALTHCHECK (the OCI format has no such field); --network host so
# that apt inside the build reaches the mirror without a CNI setup.
# A host that trusts an extra CA for npm (NODE_EXTRA_CA_CERTS: a network that intercepts
# TLS) lends it to the build's npm ci, read-only.
lent=()
if [ -n "${NODE_EXTRA_CA_CERTS:-}" ] && [ -f "$NODE_EXTRA_CA_CERTS" ]; then
  lent=(--volume "$(dirname "$NODE_EXTRA_CA_CERTS"):/tandem-host-ca:ro"
        --build-arg "NODE_EXTRA_CA_CERTS=/tandem-host-ca/$(basename "$NODE_EXTRA_CA_CERTS")")
fi
# A compiler cache in CCACHE_DIR (CI's, which its host build filled) is lent to the build: the
# Dockerfile then compiles only what the host did not. CI's -Werror and the host's generator
# (CMAKE_GENERATOR=Ninja in CI) go along, since the objects' command lines must match.
if [ -n "${CCACHE_DIR:-}" ] && [ -d "$CCACHE_DIR" ]; then
  lent+=(--volume "$CCACHE_DIR:/ccache")
  cmake_args=""
  if [ "${CI:-}" = "true" ]; then cmake_args="-DTANDEM_WERROR=ON"; fi
  if [ "${CMAKE_GENERATOR:-}" = "Ninja" ]; then cmake_args="$cmake_args -G Ninja"; fi
  if [ -n "$cmake_args" ]; then lent+=(--build-arg "TANDEM_CMAKE_ARGS=${cmake_args# }"); fi
fi
podman "${runtime[@]}" build --format docker --network host "${limits[@]}" ${lent[@]+"${lent[@]}"} \
  --build-arg "DEBIAN_IMAGE=$base" -f deploy/Dockerfile -t "$image" . \
  > "$work/build.log" 2>&1 || { tail -40 "$work/build.log" >&2; fail "podman build"; }
say "built: $(podman image inspect --format '{{.Size}}' "$image" | awk '{printf "%.0f MiB", $1/1048576}')"

# --- 2. run -------------------------------------------------------------------------------
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
server="127.0.0.1:$port"
# The image's CMD with a longer grace period and a drain delay (flags after the image
# replace CMD); the address through the image's own variable.
podman "${runtime[@]}" run -d --name "$container" --network host "${limits[@]}" \
  -e "TANDEM_LISTEN=$server" "$image" \
  --max-sessions 4 --grace-seconds 60 --drain-delay-seconds 2 > "$work/run.log" 2>&1 \
  || { cat "$work/run.log" >&2; fail "podman run"; }
# (Without systemd, podman logs that it cannot schedule the HEALTHCHECK timer: the
# check is run by hand below instead.)
healthy=0
for _ in $(seq 1 60); do
  if "$bin/tandem-client" health --server "$server" --timeout 2 > /dev/null 2>&1; then
    healthy=1; break
  fi
  [ "$(podman inspect --format '{{.State.Running}}' "$container")" = true ] \
    || { podman logs "$container" >&2; fail "the container exited at start"; }
  sleep 1
done
[ "$healthy" = 1 ] || { podman logs "$container" >&2; fail "no SERVING health answer in 60 s"; }
say "serving on $server"
uid=$(podman exec "$container" id -u)
[ "$uid" = 10001 ] || fail "the server runs as uid $uid, not 10001"
# The browser viewer's page and three.js, where tandem-client --view looks for them.
for f in viewer/index.html viewer/viewer.js three/build/three.module.js \
         three/examples/jsm/libs/draco/draco_decoder.wasm; do
  podman exec "$container" test -s "/usr/local/share/tandem/$f" \
    || fail "the image lacks /usr/local/share/tandem/$f (the viewer's assets)"
done
podman healthcheck run "$container" > /dev/null 2>&1 \
  || fail "the image's HEALTHCHECK failed: $(podman inspect --format '{{.Config.Healthcheck}}' "$container")"
podman exec "$container" tandem-client info --server "$server" > "$work/info.txt" 2>&1 \
  || { cat "$work/info.txt" >&2; fail "tandem-client info inside the container"; }
grep -q "max sessions *4" "$work/info.txt" \
  || { cat "$work/info.txt" >&2; fail "info does not show --max-sessions 4"; }

# --- 3. a stream from the host --------------------------------------------------------------
"$bin/tandem" generate pillowbox --size 96 --out "$work/pb.json" > /dev/null
"$bin/tandem" extract --input "$work/pb.json" --iso 0 --error 0.2 --out "$work/local.ply" \
  --metrics "$work/local.json" > /dev/null
"$bin/tandem-client" stream --server "$server" --input "$work/pb.json" --iso 0 --error 0.2 \
  --out "$work/remote.ply" --metrics "$work/remote.json" > "$work/stream.log" 2>&1 \
  || { cat "$work/stream.log" >&2; fail "streaming into the container"; }
triangles() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["triangles_final"])' "$1"; }
[ "$(triangles "$work/local.json")" = "$(triangles "$work/remote.json")" ] \
  || fail "the container's mesh has $(triangles "$work/remote.json") triangles, tandem extract's $(triangles "$work/local.json")"
say "streamed: $(triangles "$work/remote.json") triangles, as tandem extract"
# The image's client reads a DICOM series (its DICOM reader, lib/tandem/tandem-dicom-worker, runs GDCM).
"$bin/tandem" generate link --size 24 --series dicom --out "$work/dcm" > /dev/null
"$bin/tandem" extract --input "$work/dcm" --iso 0 --error 0.2 --out "$work/dcm.ply" \
  --metrics "$work/dcm-local.json" > /dev/null
podman cp "$work/dcm" "$container:/data/dcm" \
  && podman exec "$container" tandem-client stream --server "$server" --input /data/dcm \
       --iso 0 --error 0.2 --out /data/dcm.drc --metrics /data/dcm.json > "$work/dcm.log" 2>&1 \
  && podman cp "$container:/data/dcm.json" "$work/dcm-remote.json" \
  || { cat "$work/dcm.log" >&2; fail "tandem-client inside the container streaming a DICOM series"; }
[ "$(triangles "$work/dcm-local.json")" = "$(triangles "$work/dcm-remote.json")" ] \
  || fail "the container's DICOM mesh has $(triangles "$work/dcm-remote.json") triangles, tandem extract's $(triangles "$work/dcm-local.json")"
say "a DICOM series streamed from inside the container: $(triangles "$work/dcm-remote.json") triangles"
# ... and shows it in the browser viewer (its viewer module, lib/tandem, loads cpp-httplib).
podman exec "$container" tandem-client stream --server "$server" --input /data/dcm --iso 0 \
     --error 0.2 --out /data/dcm-view.drc --view 127.0.0.1:0 --view-linger 0 \
     > "$work/view.log" 2>&1 \
  || { cat "$work/view.log" >&2; fail "tandem-client --view inside the container"; }
grep -q "viewer at http://127.0.0.1:" "$work/view.log" \
  || { cat "$work/view.log" >&2; fail "tandem-client --view in the container printed no address"; }

# --- 4. SIGTERM during a stream ---------------------------------------------------------
# 96 slices at 16 a second: about 6 s, longer than the drain delay, well within the grace.
"$bin/tandem-client" stream --server "$server" --input "$work/pb.json" --iso 0 --error 0.2 \
  --rate 16 --out "$work/paced.ply" > "$work/paced.log" 2>&1 &
paced=$!
sleep 1.5
podman stop --time 90 "$container" > "$work/stop.log" 2>&1 &  # SIGTERM (the image's STOPSIGNAL)
stopper=$!
not_serving=0
for _ in $(seq 1 100); do  # podman stop takes a moment to deliver the signal
  answer=$("$bin/tandem-client" health --server "$server" --timeout 1 2>/dev/null || true)
  if [ "$answer" = NOT_SERVING ]; then
    not_serving=1; break
  fi
  sleep 0.1
done
wait "$paced" || { cat "$work/paced.log" >&2; fail "the stream running at SIGTERM did not finish OK"; }
wait "$stopper" || fail "podman stop"
code=$(podman inspect --format '{{.State.ExitCode}}' "$container" 2>/dev/null)
podman logs "$container" > "$work/server.log" 2>&1
[ "$not_serving" = 1 ] || { cat "$work/server.log" >&2; fail "health never answered NOT_SERVING after SIGTERM"; }
[ "$code" = 0 ] || { cat "$work/server.log" >&2; fail "the server exited with $code after SIGTERM"; }
for want in "NOT_SERVING" "draining" "stopped"; do
  grep -q "$want" "$work/server.log" || { cat "$work/server.log" >&2; fail "the log lacks '$want'"; }
done
say "SIGTERM: NOT_SERVING at once, the running stream finished OK, exit 0"
say "passed"
