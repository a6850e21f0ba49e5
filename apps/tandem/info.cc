// tandem info: what a volume file holds (grid, voxel type, frame) and its values' range.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "apps/common/cli_util.h"
#include "apps/common/flags.h"
#include "command.h"
#include "tandem/io/open_volume.h"
#include "tandem/status_macros.h"
#include "tandem/volume.h"

namespace tandem::app {

namespace {

// Value range, mean and a 10-bin histogram of every voxel (two passes, one slice in memory):
// what a user looks at to pick an iso-value.
struct ValueStats {
  double lo = 0, hi = 0, mean = 0;
  int64_t count = 0, nonfinite = 0;
  std::array<int64_t, 10> bins{};
};

absl::StatusOr<ValueStats> ScanValues(SliceSource& src, const std::string& path,
                                      const io::OpenOptions& open) {
  const VolumeInfo& info = src.info();
  std::vector<uint8_t> bytes;
  std::vector<float> values(static_cast<size_t>(info.slice_voxels()));
  ValueStats s;
  s.lo = std::numeric_limits<double>::infinity();
  s.hi = -s.lo;
  double sum = 0;
  cli::Progress progress("scanning values");
  // Pass 1: range and mean; pass 2 (the volume reopened): the histogram over that range.
  for (int64_t z = 0; z < info.nz; ++z) {
    TANDEM_RETURN_IF_ERROR(src.ReadSlice(&bytes));
    ConvertToFloat(info.dtype, bytes.data(), values.size(), values.data());
    for (float v : values) {
      if (!std::isfinite(v)) {
        ++s.nonfinite;
        continue;
      }
      s.lo = std::min(s.lo, double{v});
      s.hi = std::max(s.hi, double{v});
      sum += v;
      ++s.count;
    }
    progress.Update(z + 1, info.nz);
  }
  if (s.count == 0) return s;
  s.mean = sum / static_cast<double>(s.count);
  TANDEM_ASSIGN_OR_RETURN(auto again, io::OpenVolume(path, open));
  const double width = (s.hi - s.lo) / 10.0;
  for (int64_t z = 0; z < info.nz; ++z) {
    TANDEM_RETURN_IF_ERROR(again->ReadSlice(&bytes));
    ConvertToFloat(info.dtype, bytes.data(), values.size(), values.data());
    for (float v : values) {
      if (!std::isfinite(v)) continue;
      const int b = width > 0 ? std::min(9, static_cast<int>((v - s.lo) / width)) : 0;
      ++s.bins[b];
    }
  }
  progress.Done();
  return s;
}

}  // namespace

int InfoCommand(int argc, char** argv) {
  std::string input_flag, zarr_array, series;
  bool no_values = false;
  cli::FlagSet flags(
      "usage: tandem info --input FILE|DIR [flags]\n"
      "Prints the grid, voxel type, spacing, origin, axis directions (when not the identity),\n"
      "suggested iso-values, then reads every voxel once for the value range, the mean and a\n"
      "10-bin histogram (an iso-value between two populated ranges separates them).");
  flags.AddString("input", &input_flag, "FILE", "the volume (any format tandem reads)",
                  /*required=*/true);
  flags.AddString("zarr-array", &zarr_array, "SEL",
                  "Zarr group: the multiscale level (a number) or the array path to read");
  flags.AddString("series", &series, "UID",
                  "a folder holding several DICOM series: the one to describe (without it, "
                  "localizers and scouts are skipped with a note, two slice stacks refused)");
  flags.AddBool("no-values", &no_values, "skip the value scan (header only)");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  const std::string input =
      zarr_array.empty() ? input_flag : absl::StrCat(input_flag, "#", zarr_array);
  auto src = io::OpenVolume(
      input, io::OpenOptions{.dicom_series = series, .note = [](const std::string& line) {
                               std::fprintf(stderr, "tandem info: %s\n", line.c_str());
                             }});
  if (!src.ok()) return Fail(src.status());
  const VolumeInfo& i = (*src)->info();
  std::printf("grid     %lld x %lld x %lld\n", static_cast<long long>(i.nx),
              static_cast<long long>(i.ny), static_cast<long long>(i.nz));
  std::printf("dtype    %s\n", std::string(DTypeName(i.dtype)).c_str());
  std::printf("spacing  %g %g %g\n", i.spacing[0], i.spacing[1], i.spacing[2]);
  std::printf("origin   %g %g %g\n", i.origin[0], i.origin[1], i.origin[2]);
  std::printf("frame    %s\n", i.frame.c_str());
  if (!i.axis_aligned()) {
    const auto& d = i.directions;
    std::printf("axes     x (%g %g %g)  y (%g %g %g)  z (%g %g %g)\n", d[0][0], d[0][1], d[0][2],
                d[1][0], d[1][1], d[1][2], d[2][0], d[2][1], d[2][2]);
  }
  std::string isos;
  for (double v : i.suggested_isovalues) absl::StrAppend(&isos, isos.empty() ? "" : " ", v);
  std::printf("isovalues %s\n", isos.empty() ? "(none suggested)" : isos.c_str());
  if (!i.description.empty()) std::printf("about    %s\n", i.description.c_str());
  if (no_values || i.nz == 0) return 0;
  auto stats = ScanValues(**src, input, io::OpenOptions{.dicom_series = series});
  if (!stats.ok()) return Fail(stats.status());
  if (stats->count == 0) {
    std::printf("values   none finite\n");
    return 0;
  }
  std::printf("values   %g .. %g, mean %g%s\n", stats->lo, stats->hi, stats->mean,
              stats->nonfinite ? absl::StrCat(" (", stats->nonfinite, " NaN/inf)").c_str() : "");
  const int64_t peak = *std::max_element(stats->bins.begin(), stats->bins.end());
  const double width = (stats->hi - stats->lo) / 10.0;
  for (int b = 0; b < 10; ++b) {
    const int bar = peak > 0 ? static_cast<int>(std::lround(40.0 * stats->bins[b] / peak)) : 0;
    std::printf("  %12.6g .. %-12.6g %12lld %s\n", stats->lo + b * width,
                stats->lo + (b + 1) * width, static_cast<long long>(stats->bins[b]),
                std::string(static_cast<size_t>(bar), '#').c_str());
  }
  return 0;
}

}  // namespace tandem::app
