#!/usr/bin/env bash
# Installs every Debian 12 package tandem needs to build, test and run (core, service,
# tests). Non-interactive: safe for CI and container builds. Run as root (or via sudo).
#   deploy/install-deps.sh            build + test dependencies
#   deploy/install-deps.sh --runtime  only the shared libraries the binaries need
set -euo pipefail

BUILD_PKGS=(
  build-essential cmake pkg-config git ca-certificates
  libabsl-dev libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev libdraco-dev
  libgtest-dev libgmock-dev nlohmann-json3-dev libeigen3-dev libtiff-dev zlib1g-dev
  python3
)
RUNTIME_PKGS=(libgrpc++1.51 libprotobuf32 libtiff6 zlib1g libdraco7)

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive

pkgs=("${BUILD_PKGS[@]}")
if [ "${1:-}" = "--runtime" ]; then pkgs=("${RUNTIME_PKGS[@]}"); fi

# Skip the network when everything is already there (fast re-runs, offline machines).
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -eq 0 ]; then
  echo "install-deps: all ${#pkgs[@]} packages already installed"
  exit 0
fi
echo "install-deps: installing ${missing[*]}"
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "install-deps: done"
