// tandem generate: a synthetic volume (raw + JSON sidecar, another volume format, OME-Zarr,
// or a DICOM / TIFF series).
#include <array>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "apps/common/cli_util.h"
#include "apps/common/flags.h"
#include "command.h"
#include "tandem/io/series.h"
#include "tandem/eval/synthetic.h"
#include "tandem/volume.h"
#include "tandem/io/volume_writers.h"
#include "tandem/io/zarr.h"

namespace tandem::app {

namespace {

// "X,Y,Z" as three numbers; errors name `what`.
absl::StatusOr<std::array<double, 3>> ParseTriple(const std::string& s, const char* what) {
  std::vector<std::string> parts = absl::StrSplit(s, ',');
  if (parts.size() != 3) {
    return absl::InvalidArgumentError(
        absl::StrCat(what, ": expected three comma-separated numbers, got '", s, "'"));
  }
  std::array<double, 3> v{};
  for (int i = 0; i < 3; ++i) {
    char* end = nullptr;
    v[i] = std::strtod(parts[i].c_str(), &end);
    if (parts[i].empty() || *end != '\0') {
      return absl::InvalidArgumentError(absl::StrCat(what, ": '", parts[i], "' is not a number"));
    }
  }
  return v;
}

// A string flag left empty unless given; the help shows `shown_default`, what empty stands for.
void AddStringShowingDefault(cli::FlagSet& flags, const std::string& name, std::string* var,
                             const std::string& value_name, const std::string& help,
                             const std::string& shown_default) {
  flags.AddString(name, var, value_name, help);
  flags.SetDefaultText(name, shown_default);
}

}  // namespace

int GenerateCommand(int argc, char** argv) {
  std::string out, dims_text, spacing_text, origin_text, directions_text, zarr_codec, zarr_chunks;
  std::string series, dicom_syntax;
  int64_t size = 0, zarr_version = 2;
  cli::FlagSet flags(
      "usage: tandem generate SHAPE --size N --out FILE [flags]\n"
      "Writes a synthetic float32 volume in the format of FILE's extension, every one the readers\n"
      "read: .json (FILE.raw beside it plus the JSON sidecar, whose \"suggested_isovalues\" holds\n"
      "the shape's iso-value, 0), .nrrd, .nhdr (+ .raw), .nii, .nii.gz, .tif/.tiff, .mha, .mhd\n"
      "(+ .raw), or .zarr (an "
      "OME-Zarr image: one level, array \"0\", axes z/y/x with the spacing as scale).\n"
      "SHAPE: sphere, pillowbox (the paper's Pillow Box), link (two interlocked tori),\n"
      "gyroid (a solid gyroid clipped to a ball: closed, high genus).");
  flags.AddString("out", &out, "FILE", "the volume to write (its extension says the format)",
                  /*required=*/true);
  flags.AddInt("size", &size, "N x N x N grid vertices (or --dims)");
  flags.AddString("dims", &dims_text, "NX,NY,NZ", "grid vertices per axis");
  AddStringShowingDefault(flags, "spacing", &spacing_text, "SX,SY,SZ",
                          "physical voxel size per axis", "1,1,1");
  AddStringShowingDefault(flags, "origin", &origin_text, "X,Y,Z", "world position of voxel (0,0,0)",
                          "0,0,0");
  AddStringShowingDefault(flags, "directions", &directions_text, "9 NUMBERS",
                          "world unit vectors of the x, y and z axes (stored by --series dicom and "
                          ".json sidecars, refused by the others)",
                          "identity");
  flags.AddInt("zarr-version", &zarr_version, ".zarr: 2 or 3", "V");
  AddStringShowingDefault(flags, "zarr-codec", &zarr_codec, "C",
                          ".zarr: none, gzip, zstd, blosc-lz4, blosc-zstd", "blosc-lz4");
  AddStringShowingDefault(flags, "zarr-chunks", &zarr_chunks, "Z,Y,X",
                          ".zarr: chunk shape (0 = the whole axis)", "1,256,256");
  flags.AddString("series", &series, "dicom|tiff",
                  "write FILE as a folder of one file per slice instead: a DICOM CT series "
                  "(IM00001.dcm, ...; values quantized to int16 with a rescale slope and "
                  "intercept) or numbered single-page TIFFs (slice_00000.tif, ...)");
  AddStringShowingDefault(
      flags, "dicom-syntax", &dicom_syntax, "S",
      "--series dicom: explicit, implicit, jpeg-lossless, jpeg-ls, jpeg2000 or rle", "explicit");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (flags.positional().size() != 1) {
    return Usage(
        absl::InvalidArgumentError("expected one shape: sphere, pillowbox, link or gyroid"));
  }
  auto shape = eval::ParseShape(flags.positional()[0]);
  if (!shape.ok()) return Usage(shape.status());
  io::ZarrWriteOptions zarr;
  zarr.version = static_cast<int>(zarr_version);
  if (!zarr_codec.empty()) {
    auto codec = io::ParseZarrCompressor(zarr_codec);
    if (!codec.ok()) return Usage(codec.status());
    zarr.compressor = *codec;
  }
  if (!zarr_chunks.empty()) {
    auto t = ParseTriple(zarr_chunks, "--zarr-chunks");
    if (!t.ok()) return Usage(t.status());
    zarr.chunks = {int64_t((*t)[0]), int64_t((*t)[1]), int64_t((*t)[2])};
  }
  std::array<double, 3> dims{};
  if (!dims_text.empty()) {
    auto t = ParseTriple(dims_text, "--dims");
    if (!t.ok()) return Usage(t.status());
    dims = *t;
  } else {
    if (!flags.IsSet("size")) {
      return Usage(absl::InvalidArgumentError("--size N (or --dims NX,NY,NZ) is required"));
    }
    dims = {double(size), double(size), double(size)};
  }
  std::array<double, 3> spacing{1, 1, 1};
  if (!spacing_text.empty()) {
    auto t = ParseTriple(spacing_text, "--spacing");
    if (!t.ok()) return Usage(t.status());
    spacing = *t;
  }
  if (!series.empty() && series != "dicom" && series != "tiff") {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--series must be dicom or tiff, not '", series, "'")));
  }
  io::DicomWriteOptions dicom;
  if (!dicom_syntax.empty()) {
    auto syntax = io::ParseDicomSyntax(dicom_syntax);
    if (!syntax.ok()) return Usage(syntax.status());
    dicom.syntax = *syntax;
  }
  auto make = [&] {
    return eval::MakeSyntheticSource(*shape, int64_t(dims[0]), int64_t(dims[1]), int64_t(dims[2]),
                                     spacing);
  };
  auto src = make();
  // The shape is drawn on the grid; --origin and --directions only place the grid in the
  // world (what a scanner's header says), so every format holds the same voxels.
  VolumeInfo info = src->info();
  if (!origin_text.empty()) {
    auto t = ParseTriple(origin_text, "--origin");
    if (!t.ok()) return Usage(t.status());
    info.origin = *t;
  }
  if (!directions_text.empty()) {
    std::vector<double> v;
    bool numbers = true;
    for (absl::string_view part : absl::StrSplit(directions_text, ',')) {
      double x = 0;
      numbers = numbers && absl::SimpleAtod(part, &x);
      v.push_back(x);
    }
    if (!numbers || v.size() != 9) {
      return Usage(absl::InvalidArgumentError(
          "--directions needs 9 numbers: the world directions of the x, y and z axes"));
    }
    for (int a = 0; a < 3; ++a) info.directions[a] = {v[3 * a], v[3 * a + 1], v[3 * a + 2]};
  }
  if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) return Usage(st);
  cli::Progress progress("slices");
  const int64_t nz = info.nz;
  const io::SliceFn next = [&](int64_t z, std::vector<uint8_t>* bytes) {
    progress.Update(z + 1, nz);
    if (z < src->next_slice()) src = make();  // a second pass (the DICOM writer's range scan)
    return src->ReadSlice(bytes);
  };
  absl::Status st = series == "dicom"        ? io::WriteDicomSeries(out, info, next, dicom)
                    : series == "tiff"       ? io::WriteTiffSequence(out, info, next)
                    : out.ends_with(".zarr") ? io::WriteZarr(out, info, next, zarr)
                                             : io::WriteVolume(out, info, next);
  progress.Done();
  if (!st.ok()) return FailWriting(st);
  std::fprintf(stderr, "wrote %s (%lld x %lld x %lld float32, iso-value 0)\n", out.c_str(),
               static_cast<long long>(dims[0]), static_cast<long long>(dims[1]),
               static_cast<long long>(dims[2]));
  return 0;
}

}  // namespace tandem::app
