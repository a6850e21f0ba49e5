// tandem simulate: an instrument for demos and tests, writing a volume slice by slice at a
// rate as a DICOM series, numbered TIFFs or a growing Zarr store.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "apps/common/cli_util.h"
#include "apps/common/flags.h"
#include "command.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/series.h"
#include "tandem/status_macros.h"
#include "tandem/volume.h"
#include "tandem/io/zarr.h"

namespace tandem::app {

namespace {

constexpr char kSimulateUsage[] =
    R"(usage: tandem simulate --input FILE --out DIR --as dicom|tiff|zarr [flags]
Plays an instrument for demos and tests: writes the volume FILE (any format tandem reads)
into DIR slice by slice at R slices per second, as a scanner or microscope would while
`tandem extract --follow` or `tandem-client stream --follow` meshes it:
  dicom   a CT series (GDCM; float volumes quantized to int16 with a rescale), written in
          bursts of N slices (default 8) whose files appear in shuffled order under names
          that say nothing about position, as a C-STORE receiver stores them; --numbering,
          --scout and --temp-names play what other scanners, reconstructions and transfer
          tools do
  tiff    numbered single-page TIFFs slice_00000.tif, ... in order (a reconstruction)
  zarr    an OME-Zarr v2 image whose array grows along z (chunks 4 x 256 x 256,
          blosc-lz4), each chunk row appearing whole (a light-sheet microscope))";

// `tandem simulate --numbering`: the InstanceNumber of slice k of nz.
absl::StatusOr<std::vector<int64_t>> InstanceNumbers(const std::string& how, int64_t nz,
                                                     int64_t burst, uint32_t seed) {
  std::vector<int64_t> n(static_cast<size_t>(nz));
  for (int64_t k = 0; k < nz; ++k) {
    int64_t& v = n[static_cast<size_t>(k)];
    if (how == "ordered" || how == "random") {
      v = k + 1;
    } else if (how == "reversed") {
      v = nz - k;
    } else if (how == "restarted") {
      v = k % burst + 1;
    } else if (how == "equal") {
      v = 1;
    } else if (how == "absent") {
      v = io::DicomSliceWriter::kNoInstanceNumber;
    } else {
      return absl::InvalidArgumentError(
          absl::StrCat("--numbering '", how,
                       "': expected ordered, random, restarted, reversed, equal or absent"));
    }
  }
  if (how == "random") std::shuffle(n.begin(), n.end(), std::mt19937(seed));
  return n;
}

// The localizer a CT takes before its stack: a front and a side projection (maxima along y
// and along x, head up), in the volume's frame and voxel type; one pass over the volume.
absl::Status WriteScout(
    const std::string& input, const VolumeInfo& info, const io::DicomWriteOptions& stack_opts,
    const std::function<absl::Status(const std::string&, const io::DicomSliceWriter&, int64_t,
                                     const std::vector<uint8_t>&)>& put) {
  TANDEM_ASSIGN_OR_RETURN(auto src, io::OpenVolume(input));
  const int64_t nx = info.nx, ny = info.ny, nz = info.nz;
  const float none = -std::numeric_limits<float>::infinity();
  std::vector<float> front(static_cast<size_t>(nx * nz), none),
      side(static_cast<size_t>(ny * nz), none);
  std::vector<uint8_t> b;
  std::vector<float> v(static_cast<size_t>(nx * ny));
  for (int64_t z = 0; z < nz; ++z) {
    TANDEM_RETURN_IF_ERROR(src->ReadSlice(&b));
    ConvertToFloat(info.dtype, b.data(), v.size(), v.data());
    const int64_t row = nz - 1 - z;  // head up
    for (int64_t y = 0; y < ny; ++y) {
      for (int64_t x = 0; x < nx; ++x) {
        const float f = v[static_cast<size_t>(y * nx + x)];
        float& a = front[static_cast<size_t>(row * nx + x)];
        float& c = side[static_cast<size_t>(row * ny + y)];
        a = std::max(a, f);
        c = std::max(c, f);
      }
    }
  }
  io::DicomWriteOptions o = stack_opts;
  o.series_description = "Scout";
  o.image_type = "ORIGINAL\\PRIMARY\\LOCALIZER";
  o.series_uid = "1.2.826.0.1.3680043.2.1125.7.1";
  for (int image = 0; image < 2; ++image) {
    const VolumeInfo si = io::LocalizerGrid(info, image);
    const std::vector<float>& values = image == 0 ? front : side;
    std::vector<uint8_t> bytes(values.size() * DTypeSize(info.dtype));
    for (size_t i = 0; i < values.size(); ++i) {
      const float f = values[i];
      switch (info.dtype) {
        case DType::kUInt8:
          bytes[i] = static_cast<uint8_t>(f);
          break;
        case DType::kUInt16: {
          const uint16_t u = static_cast<uint16_t>(f);
          std::memcpy(&bytes[2 * i], &u, 2);
          break;
        }
        case DType::kInt16: {
          const int16_t u = static_cast<int16_t>(f);
          std::memcpy(&bytes[2 * i], &u, 2);
          break;
        }
        case DType::kFloat32:
          std::memcpy(&bytes[4 * i], &f, 4);
          break;
        case DType::kInt8:
        case DType::kUInt32:
        case DType::kInt32:
        case DType::kUInt64:
        case DType::kInt64:  // DicomSliceWriter::Create refused the stack already
          return absl::InvalidArgumentError(
              absl::StrCat("a DICOM scout of ", std::string(DTypeName(info.dtype)), " voxels"));
      }
    }
    TANDEM_ASSIGN_OR_RETURN(auto w, io::DicomSliceWriter::Create(si, o));
    if (absl::Status st = put(absl::StrCat("1.2.826.0.1.3680043.2.1125.7.", image + 1, ".dcm"), w,
                              image + 1, bytes);
        !st.ok()) {
      return st;
    }
  }
  return absl::OkStatus();
}

}  // namespace

int SimulateCommand(int argc, char** argv) {
  std::string input, out, as, done_file, numbering = "ordered", temp_names = "none";
  double rate = 20;
  int64_t burst = 8, seed = 1;
  bool scout = false, descending = false;
  cli::FlagSet flags(kSimulateUsage);
  flags.AddString("input", &input, "FILE", "the volume to play (any format tandem reads)",
                  /*required=*/true);
  flags.AddString("out", &out, "DIR", "the folder (or .zarr store) to write into",
                  /*required=*/true);
  flags.AddString("as", &as, "dicom|tiff|zarr", "what the instrument writes (see above)",
                  /*required=*/true);
  flags.AddDouble("rate", &rate, "slices per second (0 = as fast as possible)", false, "R");
  flags.AddInt("burst", &burst, "dicom: slices per burst");
  flags.AddString("done-file", &done_file, "NAME",
                  "create DIR/NAME (an empty file) after the last slice");
  flags.AddInt("seed", &seed, "shuffle seed for dicom bursts (and --numbering random)", "S");
  flags.AddString("numbering", &numbering, "HOW",
                  "dicom: InstanceNumbers: ordered (1 at the first slice acquired, the bottom "
                  "of the stack, 2 above it, ...), random, restarted (from 1 in every burst), "
                  "reversed (1 at the last acquired, the top), equal (all 1) or absent, as "
                  "reconstructions and anonymizers leave them");
  flags.AddBool("descending", &descending,
                "dicom: acquire the stack from its last slice down to its first (head to feet "
                "for the usual axial CT: positions decreasing along the slice normal); "
                "InstanceNumbers then count in that order (ordered: 1 at the top). The whole "
                "volume is read first");
  flags.AddBool("scout", &scout,
                "dicom: first write a localizer series (a front and a side projection, "
                "ImageType LOCALIZER) into the folder, as a CT does before its stack");
  flags.AddString("temp-names", &temp_names, "HOW",
                  "dicom: write each file under a temporary name, then rename it into place: "
                  "none, suffix (NAME.part) or hidden (.NAME.tmp), as transfer tools do");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (as != "dicom" && as != "tiff" && as != "zarr") {
    return Usage(
        absl::InvalidArgumentError(absl::StrCat("--as '", as, "': expected dicom, tiff or zarr")));
  }
  if (as != "dicom" &&
      (flags.IsSet("numbering") || scout || flags.IsSet("temp-names") || descending)) {
    return Usage(absl::InvalidArgumentError(
        "--numbering, --scout, --temp-names and --descending go with --as dicom"));
  }
  if (temp_names != "none" && temp_names != "suffix" && temp_names != "hidden") {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--temp-names '", temp_names, "': expected none, suffix or hidden")));
  }
  if (rate < 0 || burst < 1) {
    return Usage(absl::InvalidArgumentError("--rate must be >= 0 and --burst >= 1"));
  }
  auto src = io::OpenVolume(input);
  if (!src.ok()) return Fail(src.status());
  const VolumeInfo info = (*src)->info();
  auto numbers = InstanceNumbers(numbering, info.nz, burst, static_cast<uint32_t>(seed) + 1);
  if (!numbers.ok()) return Usage(numbers.status());
  std::error_code ec;
  if (std::filesystem::exists(out, ec)) {
    return Fail(absl::AlreadyExistsError(absl::StrCat(out,
                                                      ": already exists (the simulator "
                                                      "writes a fresh acquisition)")));
  }
  // Slices are read as they are written (one burst in memory for DICOM).
  io::DicomWriteOptions dopt;
  std::unique_ptr<io::ZarrAppender> zarr;
  std::optional<io::DicomSliceWriter> dicom;
  if (as == "dicom") {
    if (info.dtype == DType::kFloat32) {  // the quantization needs the range: one pass first
      auto scan = io::OpenVolume(input);
      if (!scan.ok()) return Fail(scan.status());
      std::vector<uint8_t> b;
      float lo = std::numeric_limits<float>::infinity(), hi = -lo;
      for (int64_t z = 0; z < info.nz; ++z) {
        if (absl::Status st = (*scan)->ReadSlice(&b); !st.ok()) return Fail(st);
        for (size_t i = 0; i + 4 <= b.size(); i += 4) {
          float v;
          std::memcpy(&v, b.data() + i, 4);
          if (std::isfinite(v)) lo = std::min(lo, v), hi = std::max(hi, v);
        }
      }
      dopt.float_min = std::isfinite(lo) ? lo : 0.0f;
      dopt.float_max = std::isfinite(hi) ? hi : 0.0f;
    }
    auto w = io::DicomSliceWriter::Create(info, dopt);
    if (!w.ok()) return Fail(w.status());
    dicom.emplace(*std::move(w));
  } else if (as == "zarr") {
    io::ZarrWriteOptions zo;
    zo.chunks = {4, 256, 256};
    auto w = io::ZarrAppender::Create(out, info, zo);
    if (!w.ok()) return Fail(w.status());
    zarr = *std::move(w);
  }
  if (as != "zarr") std::filesystem::create_directories(out, ec);
  if (ec) return Fail(absl::InternalError(absl::StrCat(out, ": ", ec.message())));
  // A DICOM file goes in under its name, or through a temporary one (--temp-names).
  auto put = [&](const std::string& name, const io::DicomSliceWriter& writer, int64_t z,
                 const std::vector<uint8_t>& bytes, int64_t instance) -> absl::Status {
    const std::filesystem::path dir(out), path = dir / name;
    if (temp_names == "none") return writer.Write(path.string(), z, bytes, instance);
    const std::filesystem::path temp =
        dir / (temp_names == "suffix" ? name + ".part" : "." + name + ".tmp");
    TANDEM_RETURN_IF_ERROR(writer.Write(temp.string(), z, bytes, instance));
    std::error_code rename_ec;
    std::filesystem::rename(temp, path, rename_ec);
    if (rename_ec) {
      return absl::InternalError(
          absl::StrCat(temp.string(), ": cannot rename it to ", name, ": ", rename_ec.message()));
    }
    return absl::OkStatus();
  };
  if (scout) {
    absl::Status st = WriteScout(
        input, info, dopt,
        [&](const std::string& name, const io::DicomSliceWriter& w, int64_t instance,
            const std::vector<uint8_t>& bytes) { return put(name, w, 0, bytes, instance); });
    if (!st.ok()) return Fail(st);
  }

  const auto start = std::chrono::steady_clock::now();
  auto pace = [&](int64_t written) {  // slice `written` may not go before written / rate s
    if (rate <= 0) return;
    std::this_thread::sleep_until(start +
                                  std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                      std::chrono::duration<double>(written / rate)));
  };
  std::mt19937 rng(static_cast<uint32_t>(seed));
  cli::Progress progress("slices written");
  std::vector<std::vector<uint8_t>> held;
  // --descending: the slices in acquisition order, the last of the volume first.
  std::vector<std::vector<uint8_t>> volume;
  if (descending) {
    volume.resize(static_cast<size_t>(info.nz));
    for (auto it = volume.rbegin(); it != volume.rend(); ++it) {
      if (absl::Status st = (*src)->ReadSlice(&*it); !st.ok()) return Fail(st);
    }
  }
  // Acquisition index a -> the slice of the volume it is.
  auto slice_of = [&](int64_t a) { return descending ? info.nz - 1 - a : a; };
  int64_t written = 0;
  for (int64_t z = 0; z < info.nz; ++z) {  // z: the acquisition index
    std::vector<uint8_t> bytes;
    if (descending) {
      bytes = std::move(volume[static_cast<size_t>(z)]);
    } else if (absl::Status st = (*src)->ReadSlice(&bytes); !st.ok()) {
      return Fail(st);
    }
    absl::Status st;
    if (as == "tiff") {
      char name[32];
      std::snprintf(name, sizeof(name), "slice_%05lld.tif", static_cast<long long>(z));
      pace(written);
      st = io::WriteTiffSlice((std::filesystem::path(out) / name).string(), info, z, bytes);
      ++written;
    } else if (as == "zarr") {
      pace(written);
      st = zarr->Append(bytes.data());
      ++written;
    } else {
      held.push_back(std::move(bytes));
      if (static_cast<int64_t>(held.size()) == burst || z + 1 == info.nz) {
        const int64_t first = z + 1 - static_cast<int64_t>(held.size());
        std::vector<int64_t> order(held.size());
        for (size_t i = 0; i < order.size(); ++i) order[i] = first + static_cast<int64_t>(i);
        std::shuffle(order.begin(), order.end(), rng);
        for (int64_t k : order) {
          pace(written);
          // Names carry no position: a hash of the slice index.
          const int64_t slice = slice_of(k);
          const std::string name =
              absl::StrCat("1.2.826.0.1.3680043.2.1125.", (slice * 2654435761u) % 1000003u, ".dcm");
          st = put(name, *dicom, slice, held[static_cast<size_t>(k - first)],
                   (*numbers)[static_cast<size_t>(k)]);
          if (!st.ok()) break;
          ++written;
        }
        held.clear();
      }
    }
    if (!st.ok()) return Fail(st);
    progress.Update(written, info.nz);
  }
  if (zarr) {
    if (absl::Status st = zarr->Finish(); !st.ok()) return Fail(st);
  }
  progress.Done();
  if (!done_file.empty()) {
    std::ofstream((std::filesystem::path(out) / done_file).string());
  }
  std::fprintf(stderr, "simulated %lld slices into %s (%s)\n", static_cast<long long>(written),
               out.c_str(), as.c_str());
  return 0;
}

}  // namespace tandem::app
