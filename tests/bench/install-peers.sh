#!/usr/bin/env bash
# Installs the benchmark's peer libraries and the plotting package from Debian 12 (bookworm).
#   bash tests/bench/install-peers.sh            # everything (about 1.1 GB installed)
#   bash tests/bench/install-peers.sh --light    # meshoptimizer + matplotlib only (~365 MB)
# Sizes measured with `apt-get install --assume-no --no-install-recommends` on Debian 12:
#   libvtk9-dev 787 MB (VTK 9.1, with its dependencies), libcgal-dev 215 MB (CGAL 5.5, GPL:
#   benchmark only), libmeshoptimizer-dev 0.2 MB (0.18), python3-matplotlib 363 MB.
# The benchmark and the experiments skip, with a message, any peer that is not installed.
set -euo pipefail

packages=(libmeshoptimizer-dev python3-matplotlib)
if [[ "${1:-}" != "--light" ]]; then
  packages+=(libvtk9-dev libcgal-dev)
fi

SUDO=""
if [[ $(id -u) -ne 0 ]]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update
$SUDO apt-get install -y --no-install-recommends "${packages[@]}"
