// Small helpers shared by the test suites.
#ifndef TANDEM_TESTS_TESTUTIL_H_
#define TANDEM_TESTS_TESTUTIL_H_

#include <cstdint>
#include <cstring>
#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"

namespace tandem::testing {

// Full path of a file in ../shared/data, or "" when that folder is absent (a user's clone).
std::string SharedDataPath(const std::string& name);

// A fresh empty directory under the system temp dir, unique per call.
std::string MakeTempDir();

// The bytes of a file ("" when it cannot be read).
std::string FileBytes(const std::string& path);

// Path of a built executable (build/bin/NAME).
std::string BinPath(const std::string& name);
// A shell command line's exit status (-1 when it did not exit) and its stdout and stderr
// together.
struct CommandOutput {
  int code = -1;
  std::string text;
};
CommandOutput RunCommand(const std::string& command);

// VmRSS of a process in bytes (/proc/PID/status), or -1.
int64_t ResidentBytes(int pid);

// Built with ASan or TSan: resident sizes and page-fault counts say nothing there (freed
// memory sits in the quarantine, shadow memory grows), so bounds on them are checked in
// normal builds only.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
inline constexpr bool kSanitized = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif
#else
inline constexpr bool kSanitized = false;
#endif

// Voxel (i, j, k) of the readers' test pattern: uses both bytes of 16-bit types, negatives
// for int16 and fractions for float32, so byte-order, sign and placement mistakes show
// (int16 stays in range up to 37 x 21 x 25 voxels). The wider integers hold values a
// double holds exactly (below 2^53).
double PatternValue(DType t, int64_t i, int64_t j, int64_t k);

// Stores v as one voxel of type t (host byte order) at dst.
void StoreValue(DType t, double v, uint8_t* dst);

// The voxel of type t (host byte order) at p, as float.
double LoadValue(DType t, const uint8_t* p);

// A multi-page uint8 TIFF written by libtiff with no resolution tags and no ImageJ
// description (as many microscopes and converters write them): a ball of radius 0.35 x
// the smallest extent, 200 inside and 0 outside. The file gives no spacing.
void WriteBareTiffStack(const std::string& path, int nx, int ny, int nz);

// Slices of PatternValue for a writer.
io::SliceFn PatternSlices(const VolumeInfo& info);

// Writes a localizer series into dir (which must exist), as a CT takes one before its
// stack: a front and a side image across info's volume (LocalizerGrid, zeros), description
// "Scout", ImageType LOCALIZER unless `flagged` is false. Returns its SeriesInstanceUID.
std::string WriteLocalizer(const std::string& dir, const VolumeInfo& info, bool flagged = true);

// Writes a DICOM object with no image (a radiation dose report, as CTs store beside their
// series) to path: a Part 10 file holding only its series UID and a few identifiers.
void WriteDoseReport(const std::string& path, const std::string& series_uid);

// A float32 volume from a formula, slice by slice: surfaces cut by the grid's box.
class FieldSource : public SliceSource {
 public:
  FieldSource(int64_t nx, int64_t ny, int64_t nz, std::function<double(double, double, double)> f)
      : f_(std::move(f)) {
    info_.nx = nx;
    info_.ny = ny;
    info_.nz = nz;
    info_.dtype = DType::kFloat32;
  }
  const VolumeInfo& info() const override { return info_; }
  int64_t next_slice() const override { return k_; }
  absl::Status ReadSlice(std::vector<uint8_t>* bytes) override {
    if (k_ >= info_.nz) return absl::OutOfRangeError("end of volume");
    std::vector<float> v(static_cast<size_t>(info_.nx * info_.ny));
    for (int64_t j = 0; j < info_.ny; ++j) {
      for (int64_t i = 0; i < info_.nx; ++i) {
        v[static_cast<size_t>(j * info_.nx + i)] = static_cast<float>(f_(
            static_cast<double>(i), static_cast<double>(j), static_cast<double>(k_)));
      }
    }
    bytes->resize(v.size() * sizeof(float));
    std::memcpy(bytes->data(), v.data(), bytes->size());
    ++k_;
    return absl::OkStatus();
  }

 private:
  VolumeInfo info_;
  std::function<double(double, double, double)> f_;
  int64_t k_ = 0;
};

// A gyroid filling the whole box: its boundary runs over all six faces.
inline std::unique_ptr<SliceSource> BoxCutGyroid(int64_t nx, int64_t ny, int64_t nz) {
  return std::make_unique<FieldSource>(nx, ny, nz, [](double x, double y, double z) {
    const double w = 0.45;
    return std::sin(w * x) * std::cos(w * y) + std::sin(w * y) * std::cos(w * z) +
           std::sin(w * z) * std::cos(w * x) + 0.1;
  });
}

}  // namespace tandem::testing

// Skips the current test with a message when the shared data file is missing.
#define TANDEM_SHARED_OR_SKIP(var, name)                                              \
  const std::string var = ::tandem::testing::SharedDataPath(name);                    \
  if (var.empty()) GTEST_SKIP() << "../shared/data/" << (name)                        \
                                << " is absent (only CI and developers have it)"

#endif  // TANDEM_TESTS_TESTUTIL_H_
