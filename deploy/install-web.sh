#!/usr/bin/env bash
# Installs the npm side of tandem from package-lock.json (npm ci): three.js and its Draco
# decoder (the browser viewer's page loads them), and for the tests the Khronos glTF
# validator, playwright-core (drives Debian's Chromium), pngjs (reads its screenshots), and
# Neuroglancer with esbuild (bundles it for the export's browser test).
# Installs Debian's nodejs and npm first when node or npm is missing. Non-interactive; run
# from anywhere (as root or with sudo for the packages).
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
  echo "install-web: installing Debian's nodejs and npm"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
fi
# Extra arguments go to npm ci (the container build passes --omit=dev: three.js only).
npm ci --no-audit --no-fund --loglevel=error "$@"
echo "install-web: done"
