#!/usr/bin/env bash
# The engine as an outside project sees it: `cmake --install --component dev` into a temporary
# prefix, then this folder configured on its own with find_package(tandem) against that prefix
# (and nothing of the build tree), built and run.   installed_test.sh BUILD_DIR EXAMPLES_DIR
set -euo pipefail
build=$1 examples=$2
tmp=$(mktemp -d /tmp/tandem-package.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }
cmake --install "$build" --component dev --prefix "$tmp/prefix" > /dev/null
for f in include/tandem/tandem.h include/tandem/executor.h lib/cmake/tandem/tandemConfig.cmake \
         lib/cmake/tandem/tandemConfigVersion.cmake; do
  [ -f "$tmp/prefix/$f" ] || fail "$f not installed"
done
ls "$tmp"/prefix/lib*/libtandem_core.a > /dev/null 2>&1 || fail "libtandem_core.a not installed"
# Only the contract's headers: the engine's (core/src) stay inside.
[ ! -e "$tmp/prefix/include/tandem/session_impl.h" ] || fail "an engine header was installed"
compiler=$(sed -n 's/^CMAKE_CXX_COMPILER:[A-Z]*=//p' "$build/CMakeCache.txt")
cmake -S "$examples" -B "$tmp/out" -DCMAKE_PREFIX_PATH="$tmp/prefix" \
      -DCMAKE_CXX_COMPILER="$compiler" -DCMAKE_BUILD_TYPE=Release > "$tmp/configure.log" 2>&1 \
  || { cat "$tmp/configure.log" >&2; fail "configuring the example against the prefix"; }
grep -q "tandem_DIR:PATH=$tmp/prefix/" "$tmp/out/CMakeCache.txt" \
  || fail "find_package(tandem) did not find the installed package"
cmake --build "$tmp/out" > "$tmp/build.log" 2>&1 \
  || { cat "$tmp/build.log" >&2; fail "building the example against the prefix"; }
"$tmp/out/tandem_example_sphere"
