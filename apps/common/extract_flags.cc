#include "apps/common/extract_flags.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <memory>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_replace.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "absl/strings/strip.h"
#include "tandem/io/open_volume.h"
#include "tandem/status_macros.h"
#ifdef TANDEM_HAVE_DRACO
#include "tandem/codec/draco_codec.h"
#endif

namespace tandem::cli {

namespace {
// SessionOptions' member names, '_' written '-', are the flags' names.
std::string FlagName(const std::string& field) {
  return absl::StrCat("--", absl::StrReplaceAll(field, {{"_", "-"}}));
}
}  // namespace

absl::Status NameOptionFlag(const absl::Status& status) {
  return NameOptionError(status, FlagName, " ");
}

#ifdef TANDEM_HAVE_DRACO
absl::Status CheckDracoFlags(int64_t bits, int64_t level) {
  // Saturated, so a value past int's range is refused rather than wrapped into the range.
  const auto to_int = [](int64_t v) {
    return static_cast<int>(std::clamp<int64_t>(v, std::numeric_limits<int>::min(),
                                                std::numeric_limits<int>::max()));
  };
  codec::DracoOptions options;
  options.quantization_bits = to_int(bits);
  options.compression_level = to_int(level);
  absl::Status st = codec::ValidateDracoOptions(options);
  if (st.ok()) return st;
  // The codec's refusal starts with the field's name; the flag is that name, dashed.
  const absl::string_view message = st.message();
  const size_t space = std::min(message.find(' '), message.size());
  return absl::InvalidArgumentError(
      absl::StrCat(FlagName(std::string(message.substr(0, space))), message.substr(space)));
}
#endif

void ExtractFlags::Add(FlagSet* flags, const std::string& out_help) {
  flags->AddString(
      "input", &input, "FILE",
      "volume: .json (raw + JSON sidecar), .nrrd, .nhdr, .nii, .nii.gz, .tif, "
      ".tiff, .mha, .mhd, a Zarr / OME-Zarr store, or a folder holding a DICOM series or "
      "numbered single-page TIFFs",
      /*required=*/true);
  flags->AddString("zarr-array", &zarr_array, "SEL",
                   "Zarr group: the multiscale level (a number) or the array path to read "
                   "(same as --input X.zarr#SEL); none = level 0");
  flags->AddString("series", &series, "UID",
                   "a folder holding several DICOM series: read (or follow) the one with this "
                   "SeriesInstanceUID; without it, localizers and scouts are skipped with a note "
                   "and two slice stacks are refused, listing each");
  flags->AddString("spacing", &spacing, "SX,SY,SZ",
                   "voxel size along x, y and z for an input that carries none (a TIFF stack "
                   "without resolution tags or ImageJ description, a plain Zarr array, a NRRD "
                   "or MetaImage header without spacing): the mesh's extent follows it. A "
                   "file's own spacing, when it differs, is replaced with a warning");
  flags->AddString("frame", &frame, "lps|ras|voxel",
                   "the frame of the output's vertices: lps or ras (patient frames: DICOM and "
                   "MetaImage are LPS, NIfTI RAS, NRRD and a raw sidecar say theirs; the two "
                   "differ by the sign of x and y), or voxel (grid indices i, j, k: --error, "
                   "the metrics' distances and E0's default 0.2 are then in voxels). Written "
                   "into the mesh file as SPACE=LPS or SPACE=RAS, as 3D Slicer reads it");
  flags->SetDefaultText("frame", "the input's own");
  flags->AddBool("follow", &follow,
                 "the input is still being written (a folder of numbered TIFF slices or of a "
                 "DICOM series, or a Zarr array growing along z): take each slice as soon as "
                 "it is complete and in order, until --expect-slices, --done-file or --settle "
                 "says the scan is over");
  flags->AddInt("expect-slices", &expect_slices, "--follow: the scan has this many slices");
  flags->AddDouble("settle", &settle,
                   "--follow: the scan is over after this many seconds without a new slice",
                   false, "S");
  flags->AddString("done-file", &done_file, "NAME",
                   "--follow: the scan is over when a file NAME appears in the folder");
  flags->AddString("out", &out, "MESH",
                   absl::StrCat(out_help, "; with several iso-values, a pattern holding {iso} "
                                          "(head_{iso}.ply)"),
                   /*required=*/true);
  flags->AddBool("glb-draco", &glb_draco,
                 ".glb output: compress the mesh with Draco (glTF's KHR_draco_mesh_compression, "
                 "which three.js, Blender and most glTF viewers read)");
#ifdef TANDEM_HAVE_DRACO
  quantization_bits = codec::kDefaultQuantizationBits;
  compression_level = codec::kDefaultCompressionLevel;
  flags->AddInt("quantization-bits", &quantization_bits,
                "Draco position quantization, 1..30 (meshes the server sends; --glb-draco)");
  flags->AddInt("compression-level", &compression_level,
                "Draco level 0..10 (0 keeps vertex order; higher = smaller, slower)");
#endif
  flags->AddString("iso", &iso, "C0[,C1,...]",
                   "iso-value, required when the file suggests none. Several (up to 8, e.g. "
                   "skin and bone: --iso 60,120) give one surface each from one read of the "
                   "slices, run side by side: name the outputs with {iso}; one summary per "
                   "surface, and --metrics writes a JSON array (or one file per surface with "
                   "{iso} in its name)");
  flags->SetDefaultText("iso", "the file's first suggested iso-value");
  flags->AddDouble("error", &error,
                   "E0 in the volume's physical units: every vertex stays within RMS distance "
                   "E0 of the planes it replaces",
                   false, "E0");
  flags->SetDefaultText("error", "0.2 x the smallest spacing");
  flags->AddDouble("alpha", &alpha,
                   "isotropy in [0, 1]: trades accuracy for better-shaped triangles (never "
                   "beyond E0); below E0 = A x spacing / 5 it keeps most triangles",
                   false, "A");
  flags->AddString("schedule", &schedule, "S",
                   "tandem-lag: simplify behind the sweep with the paper's time-lag; tandem: "
                   "no lag; classical: extract all, then simplify (holds the full-resolution "
                   "mesh); none: no simplification (= --no-simplify)");
  flags->AddBool("no-simplify", &no_simplify, "the full-resolution marching-cubes surface");
  flags->AddDouble("distance-guard", &distance_guard,
                   "refuse contractions that would put a vertex farther than K x E0 from the "
                   "plane of a triangle it reshapes: keeps thin features close (lower "
                   "Hausdorff distance) for a few more triangles; 0 = off (the paper's rules "
                   "only)",
                   false, "K");
  flags->AddDouble("sag-correction", &sag_correction,
                   "at the end, move each vertex along its normal by F x the mean chordal sag "
                   "of its triangles (not at creases, never past E0): removes the coarse "
                   "mesh's bias toward the concave side; 0 = off (the paper's placement), at "
                   "most 1",
                   false, "F");
  flags->AddDouble("lockstep-error", &lockstep_error,
                   "the finishing pass for an --error above the default: the lock-step "
                   "simplifies to F x E0 only (not below the default E0), and when the "
                   "stream ends the whole mesh comes down to E0 in one cost order (closer to "
                   "the full-resolution surface for its triangle count; holds more triangles "
                   "until then); not with --seal or --target-triangles; 1 = off (the paper's "
                   "lock-step at E0 throughout)",
                   false, "F");
  flags->AddInt("target-triangles", &target_triangles,
                "simplify to N triangles: E0 starts at --error or 1/1000 of the smallest "
                "spacing, whichever is smaller, and rises as the mesh grows, so N is reached "
                "whatever --error is (unless the surface's components need more); the summary "
                "and --metrics (error_reached) give the E0 reached; 0 = off");
  flags->AddInt("parts", &parts,
                "split the grid along x into N slabs, simplified side by side on their own "
                "threads and merged at the end (their seams simplified last); 1 = the paper's "
                "algorithm unchanged; 0 = automatic: 4 on grids at least 256 wide, 2 on grids "
                "at least 81 wide, else 1");
  flags->AddBool("seal", &seal,
                 "seal the mesh behind the sweep: vertices whose reach lies --seal-margin "
                 "slices below the front never change again and their triangles leave the "
                 "session, so its memory follows the front, not the depth (a grid split into "
                 "parts keeps the triangles at their seams for up to 512 slices; not with "
                 "--target-triangles)");
  flags->AddDouble("seal-margin", &seal_margin,
                   "--seal: slices between the front and the sealed mesh", false, "N");
  flags->AddString("metrics", &metrics, "FILE.json",
                   "write the run's figures as JSON (one report; several iso-values: a JSON "
                   "array, or one file each with {iso} in the name)");
  flags->AddBool("reference", &reference,
                 "also extract the unsimplified surface (kept only for this) and report "
                 "L1/L2/Linf distances to it");
  flags->AddBool("strict", &strict,
                 "exit 3 (after writing the mesh) when an iso-value lies outside the data's "
                 "value range, so the surface is empty (a warning otherwise)");
  flags->AddBool("quiet", &quiet, "no summary, no progress and no notes on stderr");
  flags->AddBool("labels", &labels,
                 "the volume is a label map (a segmentation: integer voxels, each value a "
                 "label id): every label's surface from one sweep, touching labels sharing "
                 "their interface. --out DIR/ writes DIR/<id or name>.<--format> per label and "
                 "DIR/labels.glb (a node per label, a colour each); --out X.glb that GLB alone. "
                 "With --seal the session holds the front only and the outputs come from its "
                 "chunks. Not with --iso or --reference");
  flags->AddString("background", &background, "ID",
                   "--labels: the label with no surface of its own (what surrounds the others)");
  flags->AddString("label-ids", &label_ids, "A,B,...",
                   "--labels: mesh these labels only; every other label counts as background");
  flags->SetDefaultText("label-ids", "every label");
  flags->AddString("label-names", &label_names, "FILE",
                   "--labels: names (and colours) of the labels, for the file names and the "
                   "GLB's nodes: a CSV of id,name lines (a header line allowed; 3D Slicer's CSV "
                   "colour tables too) or a 3D Slicer colour table (.ctbl, .txt: \"id name r g "
                   "b a\" lines, # comments)");
  flags->AddBool("close", &close,
                 "--labels: close the surfaces where labels touch the volume's border (as if "
                 "it were surrounded by background); else they are open there");
  flags->AddString("format", &format, "ply|obj|stl|glb",
                   "--labels --out DIR/: the format of the per-label files");
}

namespace {

// "--label-ids 3,x": each a whole number in [0, 2^64).
absl::StatusOr<LabelId> ParseLabelId(const std::string& flag, const std::string& text,
                                     const std::string& item) {
  LabelId id = 0;
  if (item.empty() || !absl::ascii_isdigit(static_cast<unsigned char>(item[0])) ||
      !absl::SimpleAtoi(item, &id)) {
    return absl::InvalidArgumentError(absl::StrCat(
        flag, " ", text, ": '", item, "' is not a label id (a whole number in [0, 2^64))"));
  }
  return id;
}

}  // namespace

bool ExtractFlags::LabelsToFolder() const {
  std::error_code ec;
  return absl::EndsWith(out, "/") || std::filesystem::is_directory(out, ec);
}

absl::StatusOr<LabelOptions> ExtractFlags::Labels() const {
  LabelOptions o;
  o.enabled = labels;
  o.close = close;
  TANDEM_ASSIGN_OR_RETURN(o.background, ParseLabelId("--background", background, background));
  if (!label_ids.empty()) {
    for (absl::string_view item : absl::StrSplit(label_ids, ',')) {
      TANDEM_ASSIGN_OR_RETURN(
          LabelId id,
          ParseLabelId("--label-ids", label_ids, std::string(absl::StripAsciiWhitespace(item))));
      if (id == o.background) {
        return absl::InvalidArgumentError(absl::StrCat("--label-ids ", label_ids, ": ", id,
                                                       " is the background (--background ",
                                                       background, "), which has no surface"));
      }
      o.only.push_back(id);
    }
    std::sort(o.only.begin(), o.only.end());
    o.only.erase(std::unique(o.only.begin(), o.only.end()), o.only.end());
  }
  return o;
}

absl::Status ExtractFlags::CheckLabelInput(const VolumeInfo& info) const {
  if (labels && !IsIntegerDType(info.dtype)) {
    return absl::InvalidArgumentError(absl::StrCat("--labels needs integer voxels; ", InputPath(),
                                                   " holds ", std::string(DTypeName(info.dtype))));
  }
  return absl::OkStatus();
}

namespace {

absl::StatusOr<std::array<double, 3>> ParseSpacing(const std::string& text) {
  std::vector<std::string> parts = absl::StrSplit(text, ',');
  std::array<double, 3> s{};
  bool ok = parts.size() == 3;
  for (size_t i = 0; ok && i < 3; ++i) {
    ok = absl::SimpleAtod(parts[i], &s[i]) && std::isfinite(s[i]) && s[i] > 0;
  }
  if (!ok) {
    return absl::InvalidArgumentError(absl::StrCat(
        "--spacing ", text, ": expected three positive numbers SX,SY,SZ (e.g. 0.5,0.5,2)"));
  }
  return s;
}

// --frame: lps, ras or voxel (the input's own frame is the default, not a value).
absl::StatusOr<Space> FrameFlag(const std::string& text) {
  absl::StatusOr<Space> s = ParseSpace(text);
  if (!s.ok() || *s == Space::kGrid) {
    return absl::InvalidArgumentError(
        absl::StrCat("--frame ", text, ": expected lps, ras or voxel"));
  }
  return s;
}

std::string Triple(const std::array<double, 3>& v) { return absl::StrJoin(v, ","); }

}  // namespace

absl::StatusOr<std::string> ExtractFlags::ApplyGeometry(std::unique_ptr<SliceSource>* source) const {
  VolumeInfo info = (*source)->info();
  std::string warning;
  if (!spacing.empty()) {
    TANDEM_ASSIGN_OR_RETURN(auto s, ParseSpacing(spacing));
    if (info.spacing_known && info.spacing != s) {
      warning = absl::StrCat("--spacing ", Triple(s), " replaces the spacing ",
                             Triple(info.spacing), " that ", InputPath(), " carries");
    }
    info.spacing = s;
    info.spacing_known = true;
    if (absl::Status st = ValidateVolumeInfo(info); !st.ok()) {
      return absl::InvalidArgumentError(absl::StrCat("--spacing ", spacing, ": ", st.message()));
    }
  }
  if (!frame.empty()) {
    TANDEM_ASSIGN_OR_RETURN(Space to, FrameFlag(frame));
    absl::StatusOr<VolumeInfo> moved = InFrame(info, to);
    if (!moved.ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("--frame ", frame, ": ", moved.status().message()));
    }
    info = *std::move(moved);
  }
  if (!spacing.empty() || !frame.empty()) *source = Regrid(std::move(*source), std::move(info));
  return warning;
}

std::string ExtractFlags::InputPath() const {
  return zarr_array.empty() ? input : absl::StrCat(input, "#", zarr_array);
}

io::OpenOptions ExtractFlags::Open(std::function<void(const std::string&)> note) const {
  return io::OpenOptions{.dicom_series = series, .note = std::move(note)};
}

io::FollowOptions ExtractFlags::Follow(std::function<void(const std::string&)> note) const {
  io::FollowOptions fo;
  fo.expect_slices = expect_slices;
  fo.settle_s = settle;
  fo.done_file = done_file;
  fo.dicom_series = series;
  fo.note = std::move(note);
  return fo;
}

absl::Status ExtractFlags::Check(const FlagSet& flags) const {
  if (!follow && (flags.IsSet("expect-slices") || flags.IsSet("settle") || flags.IsSet("done-file"))) {
    return absl::InvalidArgumentError("--expect-slices, --settle and --done-file go with --follow");
  }
  if (!spacing.empty()) {
    if (absl::StatusOr<std::array<double, 3>> s = ParseSpacing(spacing); !s.ok()) {
      return s.status();
    }
  }
  if (!frame.empty()) {
    if (absl::StatusOr<Space> s = FrameFlag(frame); !s.ok()) return s.status();
  }
#ifdef TANDEM_HAVE_DRACO
  TANDEM_RETURN_IF_ERROR(CheckDracoFlags(quantization_bits, compression_level));
#endif
  if (!labels) {
    for (const char* flag : {"background", "label-ids", "label-names", "close", "format"}) {
      if (flags.IsSet(flag)) {
        return absl::InvalidArgumentError(
            absl::StrCat("--", flag, " goes with --labels (the volume as a label map)"));
      }
    }
  } else {
    if (flags.IsSet("iso")) {
      return absl::InvalidArgumentError(
          "--iso does not go with --labels: a label map's surfaces lie between its labels");
    }
    if (reference) {
      return absl::InvalidArgumentError(
          "--reference does not go with --labels (it measures an iso-surface)");
    }
    TANDEM_RETURN_IF_ERROR(Labels().status());
    if (format != "ply" && format != "obj" && format != "stl" && format != "glb") {
      return absl::InvalidArgumentError(
          absl::StrCat("--format ", format, ": expected ply, obj, stl or glb"));
    }
    if (!LabelsToFolder() && !absl::EndsWith(absl::AsciiStrToLower(out), ".glb")) {
      return absl::InvalidArgumentError(
          absl::StrCat("--labels writes one mesh per label: --out ", out,
                       " must be a folder (end it with /) or one .glb (a node per label)"));
    }
    if (flags.IsSet("format") && !LabelsToFolder()) {
      return absl::InvalidArgumentError(
          absl::StrCat("--format is the per-label files' format, for --out DIR/; --out is ", out));
    }
  }
  if (glb_draco && labels && !(LabelsToFolder() && format == "glb")) {
    return absl::InvalidArgumentError(
        "--glb-draco with --labels compresses the per-label files of --out DIR/ --format glb "
        "(labels.glb and --out X.glb hold every label uncompressed)");
  }
  if (glb_draco && !labels && !absl::EndsWith(out, ".glb")) {
    return absl::InvalidArgumentError(
        absl::StrCat("--glb-draco compresses a .glb output; --out is ", out));
  }
  auto sched = ParseSchedule(schedule);
  if (!sched.ok()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "--schedule '", schedule, "': expected none, classical, tandem or tandem-lag"));
  }
  if (flags.IsSet("iso")) {
    TANDEM_ASSIGN_OR_RETURN(auto isos, ParseIsoList(iso));
    for (const IsoValue& v : isos) {
      if (auto name = NameForIso("out", out, v, isos.size()); !name.ok()) return name.status();
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<IsoValue>> ExtractFlags::Isos(const FlagSet& flags,
                                                         const VolumeInfo& info) const {
  if (flags.IsSet("iso")) return ParseIsoList(iso);
  if (info.suggested_isovalues.empty()) {
    return absl::InvalidArgumentError(
        absl::StrCat("--iso C0 is required: ", InputPath(), " suggests no iso-value"));
  }
  const double v = info.suggested_isovalues[0];
  return std::vector<IsoValue>{{v, absl::StrCat(v)}};
}

namespace {
// The default E0 and the isotropy warning both scale with the finest axis.
double MinSpacing(const VolumeInfo& info) {
  return std::min({info.spacing[0], info.spacing[1], info.spacing[2]});
}
}  // namespace

absl::StatusOr<SessionOptions> ExtractFlags::Options(const FlagSet& flags,
                                                     const VolumeInfo& info) const {
  SessionOptions o;
  const double min_spacing = MinSpacing(info);
  o.error = flags.IsSet("error") ? error : SessionOptions::kDefaultErrorVoxels * min_spacing;
  o.alpha = alpha;
  o.distance_guard = distance_guard;
  o.sag_correction = sag_correction;
  o.lockstep_error = lockstep_error;
  o.target_triangles = target_triangles;
  o.seal = seal;
  o.seal_margin = seal_margin;
  // Clamped to int: a count out of range stays out of range for Validate().
  o.parts = static_cast<int>(std::clamp<int64_t>(parts, std::numeric_limits<int>::min(),
                                                 std::numeric_limits<int>::max()));
  TANDEM_ASSIGN_OR_RETURN(auto sched, ParseSchedule(schedule));
  o.schedule = no_simplify ? Schedule::kNone : sched;
  if (absl::Status st = o.ValidateFor(info); !st.ok()) return NameOptionFlag(st);
  return o;
}

std::string OptionsWarning(const SessionOptions& o, const VolumeInfo& info) {
  if (o.alpha <= 0.0 || o.schedule == Schedule::kNone) return "";
  const double min_spacing = MinSpacing(info);
  const double limit = o.alpha * min_spacing / 5.0;
  if (!(o.error < limit)) return "";
  return absl::StrCat("--alpha ", o.alpha, " at --error ", o.error,
                      " keeps most triangles: below E0 = alpha x spacing / 5 (here ", limit,
                      ") the isotropy term alone costs more than E0 for a triangle a voxel "
                      "wide; lower --alpha or raise --error");
}

}  // namespace tandem::cli
