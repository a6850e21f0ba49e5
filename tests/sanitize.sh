#!/usr/bin/env bash
# AddressSanitizer + UndefinedBehaviorSanitizer (+ LeakSanitizer) build of the whole test
# suite (core and service) with clang, in its own build folder, then ctest. Any sanitizer
# report fails the test that hit it (UBSan does not recover; ASan aborts), and the report
# with its stack is in ctest's output. The same build holds the libFuzzer targets
# (-DTANDEM_FUZZ=ON): tests/fuzz/run.sh reuses it, so CI compiles the instrumented code once.
#   bash tests/sanitize.sh                        build, then every test under the sanitizers
#                                                 but the packaging, browser and deep-memory tests
#   bash tests/sanitize.sh -R readers             extra arguments go to ctest (and replace
#                                                 the default exclusion)
#   bash tests/sanitize.sh --build-only [TARGET...]   configure + build (all, or the targets)
#   TANDEM_BUILD_SERVICE=OFF bash tests/sanitize.sh   core only (no gRPC; no fuzz_request)
# Environment: SAN_BUILD_DIR (default build-san), SAN_JOBS (build parallelism, 2),
# SAN_TEST_JOBS (tests at a time, 3: about a fifth of these tests' time is spent waiting on
# servers, clients and timeouts, so three keep two cores busy).
# -O1 with line tables only: the quickest build whose tests still run in reasonable time. The
# test programs' own files at -O0 (SAN_TEST_CXX_FLAGS; those that compute much in their own
# code say OPTIMISED in CMake and keep -O1), and so are the components that pass data on
# rather than compute (SAN_GLUE_CXX_FLAGS: RPC, HTTP, the viewer, the programs; the top
# CMakeLists.txt lists them): under ASan that halves their compile.
set -euo pipefail
cd "$(dirname "$0")/.."

build_only=0
targets=()
if [ "${1:-}" = "--build-only" ]; then
  build_only=1
  shift
  targets=("$@")
  set --
fi

bash deploy/install-deps.sh --fuzz  # clang, libFuzzer and the sanitizer runtimes

build="${SAN_BUILD_DIR:-build-san}"
jobs="${SAN_JOBS:-2}"
test_jobs="${SAN_TEST_JOBS:-3}"
service="${TANDEM_BUILD_SERVICE:-}"
if [ -z "$service" ]; then
  if [ -f server/CMakeLists.txt ] && [ -f client/CMakeLists.txt ]; then service=ON; else service=OFF; fi
fi
flags="-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined"

start=$(date +%s)
CXX=clang++ cmake -S . -B "$build" -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -gline-tables-only" -DCMAKE_CXX_FLAGS="$flags" \
  -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" \
  -DTANDEM_TEST_CXX_FLAGS="${SAN_TEST_CXX_FLAGS:--O0}" \
  -DTANDEM_GLUE_CXX_FLAGS="${SAN_GLUE_CXX_FLAGS:--O0}" \
  -DTANDEM_BUILD_SERVICE="$service" -DTANDEM_BUILD_TESTS=ON -DTANDEM_FUZZ=ON >/dev/null
if [ ${#targets[@]} -gt 0 ]; then
  cmake --build "$build" -j"$jobs" --target "${targets[@]}"
else
  cmake --build "$build" -j"$jobs"
fi
built=$(date +%s)
echo "sanitize.sh: built (TANDEM_BUILD_SERVICE=$service) in $((built - start)) s"
[ "$build_only" = 1 ] && exit 0

# halt/abort on the first report, symbolized stacks; LSan runs at exit of every test binary.
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1:check_initialization_order=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
# LeakSanitizer suppressions, for leaks in Debian's own libraries only (each with its proof):
# - c-ares 1.18.1 (libc-ares2) leaks the 10-byte copy of "localhost" in ares_gethostbyname
#   <- gRPC's c-ares resolver when a client dials localhost:PORT (stack: tandem-client
#   info --server localhost:PORT, TlsTest.StreamHealthAndInfoWorkWithTheCa).
# - what GDCM had allocated when one of its assertions fired on a corrupt file: the guard in
#   core/io/dicom_codec.cc longjmps out of GDCM (documented there), so those objects are
#   never freed. That happens in the DICOM reader process, tandem-dicom-worker, which then
#   exits without a leak check; kept for GDCM in any process. Stacks through GDCM stop at
#   its frames (built without frame pointers), hence the module names too.
# - OpenSSL 3.0 (libssl3) leaks a thread's error queue (ERR_STATE, 904 bytes from
#   CRYPTO_zalloc: 16 slots of 7 fields + top/bottom) when a gRPC thread that recorded a
#   failed handshake outlives OpenSSL's atexit cleanup: only the thread-exit handler frees
#   it. Stack: malloc <- CRYPTO_zalloc, nothing deeper (libcrypto has no frame pointers);
#   tandem-client in TlsTest.WrongCaFails, 1 run in 6. The project calls libcrypto only in
#   server/tls_check.cc (owned pointers) and server/resume.cc (RAND_bytes, CRYPTO_memcmp).
supp="$(cd "$build" && pwd)/lsan.supp"
printf '%s\n' "leak:libcares.so" "leak:GdcmGuarded" "leak:libgdcmDSED.so" \
  "leak:libgdcmMSFF.so" "leak:libgdcmCommon.so" "leak:libcrypto.so" > "$supp"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$supp:print_suppressions=0}"
if command -v llvm-symbolizer >/dev/null; then
  export ASAN_SYMBOLIZER_PATH="$(command -v llvm-symbolizer)"
fi
# Packaging checks (label deploy, engine_only) test files and installs, and the browser tests
# test JavaScript on C++ the ViewServer and service tests cover: the plain build runs them.
# The depth tests run the shallow case's code again on a stack eight times deeper to bound
# memory: the shallow runs of the same paths are what the sanitizers need, the plain build
# checks the bounds.
# More run in the plain build only: each takes 10-40 s here, and a smaller test of the same
# file runs the same code under the sanitizers:
#   VoronoiCellsFillingTheBoxAreOpenThereOrClosed   (SplitFullResolutionIsOnePartsComplex...:
#   VoronoiCellsInABallAreClosedManifolds            Voronoi cells open and closed at the box;
#                                                    IsotropyATargetCount...: a smaller ball)
#   AStatusLineWithAnEstimateWhileTheSessionFinishes  (a 224³ classical run for its timing; the
#                                                    status lines print in every CliParity run)
#   AnisotropicCubesKeepTheirAreasAsWritten          (EveryCubeOfValuesAtTheIsoKeepsItsPointsApart...)
#   KeepsTheSurfaceCloserForAFewMoreTriangles        (the guard runs in every Simplifier test)
#   SlabsHoldTheirSeamsUpToABoundedDepth             (a depth test: SettledSeamsAreCoarsenedFirst)
#   SeamCoarseningKeepsTheTopologyOfQuantisedTangles (SettledSeamsAreCoarsenedFirst; the quantised
#                                                    tangles in QuadricsKeptAsMatricesAreTheFullSums)
#   SealedLabelSessionsSendAboutTheUnsealedBytes     (SealedChunksCarryTheirLabelBeforeEnd)
#   ManyScatteredUint64IdsEachGetTheirOwnSurface     (thousands of labels for their names; the label
#                                                    mode runs in every other CliLabels test)
#   FiftyKilledClientsLeaveNothingBehind             (CancelledStreamLeavesNothingBehind and
#                                                    AKilledClientsSlotComesFreeAtOnce...: one each)
#   EveryModeKeepsSheetsApartWhereValuesEqualTheIso  (EveryCubeOfValuesAtTheIso...: values at the
#                                                    iso; QuadricsKeptAsMatrices...: sealed parts)
#   ErrorBoundAndTopologyOnSyntheticFields           (PipelinedRunIsIdenticalToSequential: two shapes
#                                                    in every schedule with the isotropy term,
#                                                    whole and in parts)
# and the Simplifier's statistics over whole runs (a peak, an anisotropy, a bias, distances, a
# count), whose schedules, isotropy term and finishing pass every other Simplifier test runs:
#   TandemLagHoldsAQuarterOfClassicalsPeak, AnisotropyFallsAsAlphaRises,
#   MeanAndRmsDistanceStayBelowE0OnThePillowBox, TheFinishingPassTakesTheCoarsestContractions...,
#   TimeLagRemovesDirectionalBiasAndMatchesClassicalCount, TimeLagCountStaysNearClassicalOn...
if [ $# -eq 0 ]; then
  heavy='VoronoiCellsFillingTheBoxAreOpenThereOrClosed|VoronoiCellsInABallAreClosedManifolds'
  heavy+='|AStatusLineWithAnEstimateWhileTheSessionFinishes|AnisotropicCubesKeepTheirAreasAsWritten'
  heavy+='|KeepsTheSurfaceCloserForAFewMoreTriangles|SlabsHoldTheirSeamsUpToABoundedDepth'
  heavy+='|SeamCoarseningKeepsTheTopologyOfQuantisedTangles|SealedLabelSessionsSendAboutTheUnsealedBytes'
  heavy+='|ManyScatteredUint64IdsEachGetTheirOwnSurface|FiftyKilledClientsLeaveNothingBehind'
  heavy+='|EveryModeKeepsSheetsApartWhereValuesEqualTheIso|ErrorBoundAndTopologyOnSyntheticFields'
  heavy+='|TandemLagHoldsAQuarterOfClassicalsPeak|AnisotropyFallsAsAlphaRises'
  heavy+='|MeanAndRmsDistanceStayBelowE0OnThePillowBox|TheFinishingPassTakesTheCoarsestContractions'
  heavy+='|TimeLagRemovesDirectionalBiasAndMatchesClassicalCount|TimeLagCountStaysNearClassicalOn'
  set -- -LE deploy -E "_browser|^engine_only\$|MemoryIsFlatInDepth|MemoryFollowsTheFront|$heavy"
fi
set +e
ctest --test-dir "$build" --output-on-failure -j"$test_jobs" --timeout 1800 "$@"
rc=$?
set -e
echo "sanitize.sh: ctest took $(( $(date +%s) - built )) s (total $(( $(date +%s) - start )) s), exit $rc"
exit $rc
