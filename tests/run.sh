#!/usr/bin/env bash
# The test command (README's second line, and what CI runs): installs the dependencies,
# builds everything and runs every test suite through ctest. Tests that need
# ../shared/data skip with a message when it is absent.
#   bash tests/run.sh              install, build, test
#   bash tests/run.sh --build-only install and build (CI starts other work beside the tests)
set -euo pipefail
cd "$(dirname "$0")/.."
build_only=0
if [ "${1:-}" = "--build-only" ]; then build_only=1; fi
bash deploy/install-deps.sh
bash deploy/install-web.sh
werror=OFF
if [ "${CI:-}" = "true" ]; then werror=ON; fi  # warnings are errors in CI
cmake -S . -B build -DTANDEM_WERROR="$werror"
cmake --build build -j2
[ "$build_only" = 1 ] && exit 0
ctest --test-dir build --output-on-failure -j2 --timeout 900
