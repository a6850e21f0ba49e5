#!/usr/bin/env bash
# Runs the libFuzzer targets (clang + libFuzzer + ASan + UBSan) for a bounded time each:
# every volume reader, and the server's request handling (fuzz_request: request_validation
# + ExtractJob, no gRPC; needs the service). They are built in tests/sanitize.sh's build
# folder (build-san) with its configuration, so after `bash tests/sanitize.sh` nothing is
# compiled again. Fails if any target finds a crash, a leak, undefined behaviour, a
# contract violation or a timeout; the input is kept in tests/fuzz/crashes/<target>/ (for
# the report) and replayed first on every later run, so a fixed bug shows as fixed and a
# regression fails at once.
#   bash tests/fuzz/run.sh                 all targets, 20 s each
#   bash tests/fuzz/run.sh --time 300      longer runs
#   bash tests/fuzz/run.sh fuzz_tiff       one target
#   bash tests/fuzz/run.sh --seeds         regenerate tests/fuzz/corpus/ (fuzz_make_seeds for
#                                          the readers, TANDEM_FUZZ_WRITE_SEEDS for requests)
# Environment: SAN_BUILD_DIR (default build-san), SAN_JOBS (build parallelism and how many
# targets fuzz at once, 2), TANDEM_BUILD_SERVICE=OFF (readers only).
#
# Targets: fuzz_raw_json (raw + JSON sidecar; input = 2-byte raw size + sidecar text),
# fuzz_nrrd, fuzz_nifti (.nii and .nii.gz), fuzz_tiff, fuzz_metaimage (.mha), fuzz_zarr (a
# mode byte, a 2-byte metadata length, the array metadata or an OME group's attributes, one
# chunk; see fuzz_zarr.cc), fuzz_dicom (a series folder of two slice files: a 4-byte
# length, file a, file b; GDCM runs in the DICOM reader process), fuzz_session (whole
# sessions with extreme geometry and options; see fuzz_session.cc), fuzz_request (one
# option byte, then length-delimited ExtractRequest messages; see fuzz_request.cc).
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
    -h|--help) sed -n '2,24p' "$0"; exit 0 ;;
    fuzz_*) targets+=("$1"); shift ;;
    *) echo "fuzz/run.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
all=(fuzz_raw_json fuzz_nrrd fuzz_nifti fuzz_tiff fuzz_metaimage fuzz_zarr fuzz_dicom fuzz_session)
if [ "${TANDEM_BUILD_SERVICE:-ON}" != OFF ]; then all+=(fuzz_request); fi
if [ ${#targets[@]} -eq 0 ]; then targets=("${all[@]}"); fi

build="${SAN_BUILD_DIR:-build-san}"
start=$(date +%s)
bash tests/sanitize.sh --build-only "${targets[@]}" fuzz_make_seeds

if [ "$seeds" = 1 ]; then
  # Only the generated corpora: fuzz_session's seeds are written by hand.
  for t in "${all[@]}"; do
    [ "$t" = fuzz_session ] || rm -rf "tests/fuzz/corpus/$t"
  done
  "$build/bin/fuzz_make_seeds" tests/fuzz/corpus
  if [ -x "$build/bin/fuzz_request" ]; then
    mkdir -p tests/fuzz/corpus/fuzz_request
    TANDEM_FUZZ_WRITE_SEEDS=tests/fuzz/corpus/fuzz_request "$build/bin/fuzz_request"
  fi
  exit 0
fi

export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:symbolize=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
if command -v llvm-symbolizer >/dev/null; then
  export ASAN_SYMBOLIZER_PATH="$(command -v llvm-symbolizer)"
fi

# One target: its verdict lines go to $build/fuzz-work/$t.result, "FAIL" first when it failed.
fuzz_one() {
  local t="$1"
  local bin="$build/bin/$t"
  local work="$build/fuzz-work/$t"        # grows with the inputs the fuzzer finds (not checked in)
  local artifacts="$build/fuzz-artifacts/$t/"
  local kept="tests/fuzz/crashes/$t"
  local log="$build/fuzz-work/$t.log"
  rm -rf "$artifacts"
  mkdir -p "$work" "$artifacts"

  # 1. Known crashing inputs first: each is run once.
  if compgen -G "$kept/*" >/dev/null; then
    if ! "$bin" -runs=1 "$kept"/* </dev/null >"$log.replay" 2>&1; then
      echo "FAIL $t: an input in $kept/ still crashes:"
      grep -E "^fuzz_[a-z_]+: |ERROR|SUMMARY|violation|Running:" "$log.replay" | head -n 8
      return
    fi
    echo "ok   $t: the inputs in $kept/ no longer crash"
  fi

  # 2. Fuzz for a bounded time, from the checked-in seeds plus what earlier runs found.
  # stdin is /dev/null: a header naming /dev/stdin as its data file must not block.
  local max_len=8192
  if [ "$t" = fuzz_request ]; then max_len=20000; fi  # whole request streams: seeds to 17 KB
  local rc=0
  timeout $((seconds + 120)) "$bin" -max_total_time="$seconds" \
    -timeout=20 -rss_limit_mb=2048 \
    -max_len="$max_len" -print_final_stats=1 -artifact_prefix="$artifacts" \
    "$work" "tests/fuzz/corpus/$t" </dev/null >"$log" 2>&1 || rc=$?
  local runs
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
  if [ $rc -ne 0 ]; then
    echo "FAIL $t (exit $rc after ${runs:-?} runs); log: $log"
    grep -E "^fuzz_[a-z_]+: |ERROR|SUMMARY|violation|#[0-9]+ 0x.* in " "$log" | head -n 20
    mkdir -p "$kept"
    for a in "$artifacts"*; do
      [ -f "$a" ] && cp "$a" "$kept/" && echo "     kept $kept/$(basename "$a")"
    done
  else
    echo "ok   $t: ${runs:-?} runs in ${seconds} s, no crash"
  fi
}

# libFuzzer runs one process on one core: SAN_JOBS targets fuzz side by side, each for its
# full time, and their verdicts print in the targets' order.
jobs="${SAN_JOBS:-2}"
mkdir -p "$build/fuzz-work"
running=0
for t in "${targets[@]}"; do
  if [ "$running" -ge "$jobs" ]; then wait -n || true; running=$((running - 1)); fi
  fuzz_one "$t" > "$build/fuzz-work/$t.result" 2>&1 &
  running=$((running + 1))
done
wait
failed=()
for t in "${targets[@]}"; do
  cat "$build/fuzz-work/$t.result"
  if grep -q '^FAIL' "$build/fuzz-work/$t.result"; then failed+=("$t"); fi
done

echo "fuzz/run.sh: $(( $(date +%s) - start )) s in all"
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz/run.sh: FAILED: ${failed[*]} (inputs in tests/fuzz/crashes/, stacks in the logs)"
  exit 1
fi
