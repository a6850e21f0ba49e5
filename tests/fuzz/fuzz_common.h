// Shared by the reader fuzz targets: a private scratch folder (in /dev/shm when it exists,
// so no disk I/O per input), file writing, and ReadAllSlices, which opens a volume through
// the public OpenVolume and drains it while checking the SliceSource contract. Contract
// violations abort with a message, so libFuzzer records them like crashes.
#ifndef TANDEM_TESTS_FUZZ_FUZZ_COMMON_H_
#define TANDEM_TESTS_FUZZ_FUZZ_COMMON_H_

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "tandem/io/open_volume.h"
#include "tandem/volume.h"

namespace tandem::fuzz {

// Declared volumes above these are opened (header parsing is what is fuzzed) but read
// only up to the caps, so huge declared dims with a tiny gzip stream cannot make one input
// allocate gigabytes or run for minutes.
inline constexpr uint64_t kMaxSliceBytes = uint64_t{16} << 20;
inline constexpr uint64_t kMaxReadBytes = uint64_t{64} << 20;

[[noreturn]] inline void Violation(const std::string& what) {
  std::fprintf(stderr, "SliceSource contract violation: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

// A folder of this process's own (libFuzzer -jobs/-fork run several processes).
inline const std::string& ScratchDir() {
  static const std::string dir = [] {
    const char* base = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
    std::string d = std::string(base) + "/tandem-fuzz-" + std::to_string(getpid());
    std::string cmd = "mkdir -p '" + d + "'";
    if (std::system(cmd.c_str()) != 0) {
      std::fprintf(stderr, "cannot create %s\n", d.c_str());
      std::abort();
    }
    // Best effort removal at exit (libFuzzer exits through exit()).
    static std::string to_remove = d;
    std::atexit([] { std::system(("rm -rf '" + to_remove + "'").c_str()); });
    return d;
  }();
  return dir;
}

inline void WriteFileOrDie(const std::string& path, const uint8_t* data, size_t size) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr || (size > 0 && std::fwrite(data, 1, size, f) != size) || std::fclose(f) != 0) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    std::abort();
  }
}

// Opens path with OpenVolume and reads every slice (up to the caps; the even ones through
// ViewSlice where offered). Checks: the info of an opened volume passes ValidateVolumeInfo;
// nz is known; every successful read returns exactly slice_bytes() bytes and advances
// next_slice(); a ViewSlice that offers nothing consumes nothing; OutOfRange comes only after
// nz slices; no slice past nz.
inline void ReadAllSlices(const std::string& path) {
  absl::StatusOr<std::unique_ptr<SliceSource>> opened = io::OpenVolume(path);
  if (!opened.ok()) {
    if (opened.status().message().empty()) Violation("error status without a message");
    return;
  }
  SliceSource& src = **opened;
  const VolumeInfo& info = src.info();
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) {
    Violation("opened volume has invalid info: " + std::string(st.message()));
  }
  if (info.nz < 2) Violation("opened file volume has nz = " + std::to_string(info.nz));
  const uint64_t slice_bytes = info.slice_bytes();
  if (slice_bytes > kMaxSliceBytes) return;

  std::vector<uint8_t> bytes;
  std::vector<float> values;
  uint64_t read = 0;
  for (int64_t z = 0;; ++z) {
    if (src.next_slice() != z) {
      Violation("next_slice() is " + std::to_string(src.next_slice()) + ", expected " +
                std::to_string(z));
    }
    if (read + slice_bytes > kMaxReadBytes) return;
    // Even slices through the zero-copy path where the source offers it (a mapped file; the
    // odd ones are then copied from the mapping by ReadSlice): the view is copied out, so
    // ASan sees every byte of it read.
    absl::Status st;
    const uint8_t* view = nullptr;
    if (z % 2 == 0) {
      st = src.ViewSlice(&view);
      if (st.ok() && view == nullptr && src.next_slice() != z) {
        Violation("ViewSlice offered nothing but consumed a slice");
      }
      if (st.ok() && view != nullptr) bytes.assign(view, view + slice_bytes);
    }
    if (st.ok() && view == nullptr) st = src.ReadSlice(&bytes);
    if (absl::IsOutOfRange(st)) {
      if (z != info.nz) {
        Violation("OutOfRange after " + std::to_string(z) + " of " + std::to_string(info.nz) +
                  " slices: " + std::string(st.message()));
      }
      return;
    }
    if (!st.ok()) {
      if (st.message().empty()) Violation("error status without a message");
      return;
    }
    if (z >= info.nz) Violation("slice " + std::to_string(z) + " delivered past nz");
    if (bytes.size() != slice_bytes) {
      Violation("slice " + std::to_string(z) + " has " + std::to_string(bytes.size()) +
                " bytes, expected " + std::to_string(slice_bytes));
    }
    read += slice_bytes;
    values.resize(static_cast<size_t>(info.slice_voxels()));
    ConvertToFloat(info.dtype, bytes.data(), values.size(), values.data());
  }
}

}  // namespace tandem::fuzz

#endif  // TANDEM_TESTS_FUZZ_FUZZ_COMMON_H_
