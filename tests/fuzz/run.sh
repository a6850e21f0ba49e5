#!/usr/bin/env bash
# Builds the volume-reader fuzz targets with clang + libFuzzer + ASan + UBSan in build-fuzz/
# and runs each for a bounded time. Fails if any target finds a crash, a leak, undefined
# behaviour, a SliceSource contract violation or a timeout; the input is kept in
# tests/fuzz/crashes/<target>/ (for the report) and replayed first on every later run, so
# a fixed reader shows as fixed and a regression fails at once.
#   bash tests/fuzz/run.sh                 all targets, 20 s each
#   bash tests/fuzz/run.sh --time 300      longer runs
#   bash tests/fuzz/run.sh fuzz_tiff       one target
#   bash tests/fuzz/run.sh --seeds         regenerate tests/fuzz/corpus/ with fuzz_make_seeds
# Environment: FUZZ_BUILD_DIR (default build-fuzz), FUZZ_JOBS (build parallelism, 2).
#
# Targets: fuzz_raw_json (raw + JSON sidecar; input = 2-byte raw size + sidecar text),
# fuzz_nrrd, fuzz_nifti (.nii and .nii.gz), fuzz_tiff.
# TODO(request validation): add fuzz_request (tests/fuzz/fuzz_request.cc + request.cmake,
# being written: server/request_validation.h + ExtractJob fed with parsed requests) to
# `all` below, include request.cmake at the end of tests/fuzz/CMakeLists.txt, and configure
# with -DTANDEM_BUILD_SERVICE=ON when it is selected (the service libraries are then
# instrumented like tandem_core; the build takes longer).
set -euo pipefail
cd "$(dirname "$0")/../.."

seconds=20
seeds=0
targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --time) seconds="$2"; shift 2 ;;
    --time=*) seconds="${1#--time=}"; shift ;;
    --seeds) seeds=1; shift ;;
    -h|--help) sed -n '2,19p' "$0"; exit 0 ;;
    fuzz_*) targets+=("$1"); shift ;;
    *) echo "fuzz/run.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
all=(fuzz_raw_json fuzz_nrrd fuzz_nifti fuzz_tiff)
if [ ${#targets[@]} -eq 0 ]; then targets=("${all[@]}"); fi

build="${FUZZ_BUILD_DIR:-build-fuzz}"
bash deploy/install-deps.sh --fuzz
start=$(date +%s)
CXX=clang++ cmake -S . -B "$build" -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DTANDEM_FUZZ=ON -DTANDEM_BUILD_SERVICE=OFF -DTANDEM_BUILD_TESTS=OFF >/dev/null
cmake --build "$build" -j"${FUZZ_JOBS:-2}" --target "${targets[@]}" fuzz_make_seeds
echo "fuzz/run.sh: built in $(( $(date +%s) - start )) s"

if [ "$seeds" = 1 ]; then
  rm -rf tests/fuzz/corpus
  "$build/bin/fuzz_make_seeds" tests/fuzz/corpus
  exit 0
fi

export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:symbolize=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
if command -v llvm-symbolizer >/dev/null; then
  export ASAN_SYMBOLIZER_PATH="$(command -v llvm-symbolizer)"
fi

failed=()
for t in "${targets[@]}"; do
  bin="$build/bin/$t"
  work="$build/fuzz-work/$t"        # grows with the inputs the fuzzer finds (not checked in)
  artifacts="$build/fuzz-artifacts/$t/"
  kept="tests/fuzz/crashes/$t"
  rm -rf "$artifacts"
  mkdir -p "$work" "$artifacts"
  log="$build/fuzz-work/$t.log"

  # 1. Known crashing inputs first: each is run once.
  if compgen -G "$kept/*" >/dev/null; then
    if ! "$bin" -runs=1 "$kept"/* </dev/null >"$log.replay" 2>&1; then
      echo "FAIL $t: an input in $kept/ still crashes:"
      grep -E "ERROR|SUMMARY|violation|Running:" "$log.replay" | head -n 8
      failed+=("$t")
      continue
    fi
    echo "ok   $t: the inputs in $kept/ no longer crash"
  fi

  # 2. Fuzz for a bounded time, from the checked-in seeds plus what earlier runs found.
  # stdin is /dev/null: a header naming /dev/stdin as its data file must not block.
  set +e
  timeout $((seconds + 120)) "$bin" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
    -max_len=8192 -print_final_stats=1 -artifact_prefix="$artifacts" \
    "$work" "tests/fuzz/corpus/$t" </dev/null >"$log" 2>&1
  rc=$?
  set -e
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
  if [ $rc -ne 0 ]; then
    echo "FAIL $t (exit $rc after ${runs:-?} runs); log: $log"
    grep -E "ERROR|SUMMARY|violation|#[0-9]+ 0x.* in " "$log" | head -n 20
    mkdir -p "$kept"
    for a in "$artifacts"*; do
      [ -f "$a" ] && cp "$a" "$kept/" && echo "     kept $kept/$(basename "$a")"
    done
    failed+=("$t")
  else
    echo "ok   $t: ${runs:-?} runs in ${seconds} s, no crash"
  fi
done

echo "fuzz/run.sh: $(( $(date +%s) - start )) s in all"
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz/run.sh: FAILED: ${failed[*]} (inputs in tests/fuzz/crashes/, stacks in the logs)"
  exit 1
fi
