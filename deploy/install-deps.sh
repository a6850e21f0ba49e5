#!/usr/bin/env bash
# Installs every Debian 12 package tandem needs to build, test and run (core, service,
# tests). Non-interactive: safe for CI and container builds. Run as root (or via sudo).
#   deploy/install-deps.sh            build + test dependencies
#   deploy/install-deps.sh --product  only what building the programs needs (the container's
#                                     build stage: no tests, no browser)
#   deploy/install-deps.sh --runtime  only the shared libraries the binaries need
#   deploy/install-deps.sh --fuzz     build + test dependencies, plus clang and the
#                                     libFuzzer/sanitizer runtimes (tests/sanitize.sh,
#                                     tests/fuzz/run.sh)
#   deploy/install-deps.sh --image    only what deploy/image-test.sh needs (podman, ...)
set -euo pipefail

PRODUCT_PKGS=(
  build-essential cmake pkg-config git ca-certificates
  libabsl-dev libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev libdraco-dev
  nlohmann-json3-dev libeigen3-dev libtiff-dev zlib1g-dev python3
  libblosc-dev libzstd-dev
  libgdcm-dev libniftiio-dev libznz-dev libnifti2-dev libcpp-httplib-dev libcli11-dev
  libssl-dev help2man
)
TEST_PKGS=(
  libgtest-dev libgmock-dev python3-yaml openssl assimp-utils
  python3-zarr python3-numcodecs python3-grpcio python3-protobuf python3-numpy draco
  chromium libinsighttoolkit5-dev lld
)
BUILD_PKGS=("${PRODUCT_PKGS[@]}" "${TEST_PKGS[@]}")
# (libznz-dev and libnifti2-dev: niftiio's I/O layer and its nifti1.h, which
# libniftiio-dev does not pull in; found missing when deploy/image-test.sh first built
# the image on a bare Debian 12.)
# (chromium: the headless browser the viewer's test loads the page in, tests/viewer.)
# (lld: the linker CMake picks when it is there, CMakeLists.txt; it links the test programs
# several times faster than GNU ld.)
# (libinsighttoolkit5-dev: ITK, whose own MetaImageIO writes and reads the .mha / .mhd files
# tests/core/readers_metaimage_test.cc cross-checks the MetaImage reader and writer against;
# test-only, those tests skip without it.)
# (python3-zarr / python3-numcodecs: the independent Zarr writer and reader the Zarr tests
# cross-check against. python3-grpcio, python3-protobuf, python3-numpy: the Python client
# in client/python and its test; draco: draco_decoder, which it decodes meshes with.)
# What tandem-server and tandem-client link (their DT_NEEDED entries, checked with
# `objdump -p` / `ldd` on the Release binaries): gRPC++ (libgrpc++, libgrpc++_reflection),
# gRPC core (libgrpc, libgpr, libupb, libaddress_sorting), Abseil, Protobuf, Draco,
# libtiff, zlib, libblosc and libzstd (Zarr codecs), GDCM (DICOM, with its JPEG / JPEG-LS /
# JPEG 2000 codecs; linked by the DICOM module, lib/tandem/libtandem_dicom.so, which the
# client loads when it reads a DICOM series), nifticlib's niftiio (NIfTI orientation), cpp-httplib (the server's
# metrics endpoint), OpenSSL's libcrypto (the server's TLS key check), and the C++ runtime. The rest (c-ares,
# re2, OpenSSL, libtiff's codecs) comes in through these packages' own dependencies.
RUNTIME_PKGS=(
  libgrpc++1.51 libgrpc29 libabsl20220623 libprotobuf32 libdraco7 libtiff6 zlib1g
  libstdc++6 libgcc-s1
  libblosc1 libzstd1 libgdcm3.0 libniftiio2 libznz3 libcpp-httplib0.11 libssl3
)
# Fuzzing and sanitizer builds: clang, its runtimes (libFuzzer, ASan, UBSan: a
# Recommends of clang that --no-install-recommends would skip), llvm-symbolizer for stacks.
FUZZ_PKGS=(clang libclang-rt-14-dev llvm)
# Building and running the container image here (deploy/image-test.sh): podman, runc (crun,
# podman's default, refuses the hybrid cgroup hierarchies of nested CI machines), and
# mmdebstrap to make the debian:12 base without a registry.
IMAGE_PKGS=(podman runc uidmap mmdebstrap)

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive

pkgs=("${BUILD_PKGS[@]}")
case "${1:-}" in
  "") ;;
  --product) pkgs=("${PRODUCT_PKGS[@]}") ;;
  --runtime) pkgs=("${RUNTIME_PKGS[@]}") ;;
  --fuzz) pkgs+=("${FUZZ_PKGS[@]}") ;;
  --image) pkgs=("${IMAGE_PKGS[@]}") ;;
  *)
    echo "install-deps: unknown option '$1' (use --product, --runtime, --fuzz or --image, or nothing)" >&2
    exit 2
    ;;
esac

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
