// tandem: the local command-line interface of the core library.
//   tandem extract   volume -> (simplified) iso-surface mesh, with metrics
//   tandem generate  synthetic volume (raw + JSON sidecar, or OME-Zarr)
//   tandem measure   Metro-style distances between two meshes
//   tandem info      what a volume file holds
#include <unistd.h>

#include <algorithm>
#include <thread>
#include <random>
#include <optional>
#include <filesystem>
#include <cstring>
#include <chrono>
#include <atomic>
#include <cmath>
#include <limits>
#include <cstdio>
#include <fstream>
#include <future>
#include <csignal>
#include <sstream>
#include <string>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "apps/common/cli_util.h"
#include "apps/common/extract_flags.h"
#include "apps/common/flags.h"
#include "apps/common/version.h"
#ifdef TANDEM_HAVE_DRACO
#include "codec/draco_codec.h"
#endif
#include "tandem/distance.h"
#include "tandem/follow.h"
#include "tandem/mesh_io.h"
#include "tandem/metrics.h"
#include "tandem/report.h"
#include "tandem/series.h"
#include "tandem/synthetic.h"
#include "tandem/run_session.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"
#include "tandem/volume_writers.h"
#include "tandem/zarr.h"
#include "viewer/view_server.h"

namespace tandem {
namespace {

constexpr char kUsage[] =
    R"(tandem: extract and simplify iso-surfaces of volumes, one slice at a time
(Attali, Cohen-Steiner, Edelsbrunner, "Extraction and Simplification of Iso-surfaces in
Tandem", SGP 2005).

Usage:
  tandem extract  --input FILE --out MESH.{ply,obj,stl,glb} [--iso C0[,C1,...]] [flags]
  tandem generate {sphere,pillowbox,link,gyroid} --size N --out FILE [--series dicom|tiff]
  tandem measure  A.{ply,obj,stl} B.{ply,obj,stl} [--samples N] [--json]
  tandem info     --input FILE
  tandem simulate --input FILE --out DIR --as dicom|tiff|zarr --rate R   (an instrument)
  tandem view     MESH.{ply,obj,stl,glb,drc} | DIR_OF_CHUNKS [--view HOST:PORT]   (browser)
  tandem --version
Every subcommand's --help lists its flags with their defaults.

Volume files: .json (raw + JSON sidecar), .nrrd/.nhdr (raw or gzip), .nii/.nii.gz,
.tif/.tiff (multi-page stack), .mha/.mhd (ITK MetaImage), Zarr v2/v3 and OME-Zarr stores
(X.zarr; X.zarr#N reads
multiscale level N, X.zarr#PATH the array PATH inside the group), or a folder of one
file per slice: a DICOM series (any names and order; vertices in the patient frame) or
numbered single-page TIFFs. Voxel types uint8, uint16, int16, float32.
)";

// A failure met while running (a file, a device, a session): exit status 1 (cli_util.h).
int Fail(const absl::Status& st) {
  std::fprintf(stderr, "tandem: %s\n", std::string(st.message()).c_str());
  return cli::kExitFailure;
}

// A mistake in the command line itself: exit status 2.
int Usage(const absl::Status& st) {
  std::fprintf(stderr, "tandem: %s\n", std::string(st.message()).c_str());
  return cli::kExitUsage;
}

// A writer's refusal of what the flags ask for (a format that cannot hold it: Invalid
// argument or Unimplemented) is the command line's; anything else happened while writing.
int FailWriting(const absl::Status& st) {
  return st.code() == absl::StatusCode::kInvalidArgument ||
                 st.code() == absl::StatusCode::kUnimplemented
             ? Usage(st)
             : Fail(st);
}

// Parses a subcommand's flags (argv[2..]): -1 to go on, else the exit status (0 after
// printing --help).
int ParseOrExit(cli::FlagSet& flags, int argc, char** argv) {
  absl::Status st = flags.Parse(argc, argv, 2);
  if (flags.help_requested()) {
    std::fputs(flags.Help().c_str(), stdout);
    return 0;
  }
  if (!st.ok()) return Usage(st);
  return -1;
}

absl::Status WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
  out.close();
  if (!out) return absl::InternalError(absl::StrCat(path, ": cannot write"));
  return absl::OkStatus();
}

absl::StatusOr<std::array<double, 3>> ParseTriple(const std::string& s, const char* what) {
  std::vector<std::string> parts = absl::StrSplit(s, ',');
  if (parts.size() != 3) {
    return absl::InvalidArgumentError(absl::StrCat(what, ": expected three comma-separated numbers, got '", s, "'"));
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

std::string DistanceTable(const Distances& d) {
  std::string s = absl::StrFormat("%-6s %14s %14s %14s\n", "", "forward(A->B)", "backward(B->A)", "max");
  absl::StrAppend(&s, absl::StrFormat("%-6s %14.6g %14.6g %14.6g\n", "L1", d.forward.l1, d.backward.l1, d.l1_max));
  absl::StrAppend(&s, absl::StrFormat("%-6s %14.6g %14.6g %14.6g\n", "L2", d.forward.l2, d.backward.l2, d.l2_max));
  absl::StrAppend(&s, absl::StrFormat("%-6s %14.6g %14.6g %14.6g\n", "Linf", d.forward.linf, d.backward.linf, d.linf_max));
  return s;
}

int Extract(int argc, char** argv) {
  cli::ExtractFlags f;
  int64_t samples = 0;
  cli::FlagSet flags(
      "usage: tandem extract --input FILE --out MESH [flags]\n"
      "Reads the volume one slice at a time, extracts the iso-surface F = C0 layer by layer\n"
      "(marching cubes) and simplifies it in tandem by quadric-error edge contraction.");
  f.Add(&flags, "output mesh: binary PLY (.ply) or OBJ (.obj), both with vertex normals, "
                "binary STL (.stl), or glTF binary (.glb)");
  flags.AddInt("samples", &samples,
               "surface samples per direction for --reference (0 = automatic)");
  flags.SetEpilog(
      "Progress (slices done / total) is shown on stderr when it is a terminal. Exit status: 0\n"
      "done, 1 a failure while running (the input, a file, the session), 2 a mistake in the\n"
      "command line, 3 with --strict: the iso-value is outside the data (a warning on stderr\n"
      "otherwise).\n");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (!flags.positional().empty()) {
    return Usage(absl::InvalidArgumentError(absl::StrCat("unexpected argument '", flags.positional()[0], "'")));
  }
  if (absl::Status st = f.Check(flags); !st.ok()) return Usage(st);
  const std::string& out = f.out;
  if (!IsMeshOutputPath(out)) {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--out ", out, ": the extension must be ", kMeshExtensions)));
  }
  const std::string input_path = f.InputPath();
  const bool follow = f.follow, quiet = f.quiet, reference = f.reference;
  const std::string& metrics = f.metrics;
  // --follow: an acquisition still being written (tandem/follow.h). One status line on a
  // terminal: slices complete on disk, read, meshed.
  std::atomic<int64_t> seen{0}, read{0};
  const bool tty = isatty(2) && !quiet;
  std::atomic<bool> status_shown{false};  // a status line without its newline is on stderr
  auto status_line = [&](int64_t meshed) {
    if (tty) {
      status_shown = true;
      std::fprintf(stderr, "\rfollowing: %lld on disk, %lld read, %lld meshed   ",
                   static_cast<long long>(seen.load()), static_cast<long long>(read.load()),
                   static_cast<long long>(meshed));
    }
  };
  // What the readers set aside (a series, a file) or find odd, unless --quiet.
  auto note = [&](const std::string& line) {
    if (quiet) return;
    std::fprintf(stderr, "%standem extract: %s\n", status_shown.exchange(false) ? "\n" : "",
                 line.c_str());
  };
  absl::StatusOr<std::unique_ptr<SliceSource>> source;
  if (follow) {
    FollowOptions fo = f.Follow(note);
    fo.progress = [&](int64_t s, int64_t r) {
      seen = s;
      read = r;
    };
    source = FollowVolume(input_path, fo);
  } else {
    source = OpenVolume(input_path, f.Open(note));
  }
  if (!source.ok()) return Fail(source.status());
  if (absl::StatusOr<std::string> warn = f.ApplyGeometry(&*source); !warn.ok()) {
    return Usage(warn.status());
  } else if (!warn->empty()) {
    std::fprintf(stderr, "tandem extract: warning: %s\n", warn->c_str());
  }
  const VolumeInfo info = (*source)->info();

  MeshWriteOptions write;
  write.space = info.space;
  if (f.glb_draco) {
#ifdef TANDEM_HAVE_DRACO
    codec::DracoOptions draco;
    draco.quantization_bits = static_cast<int>(f.quantization_bits);
    draco.compression_level = static_cast<int>(f.compression_level);
    write.glb_draco = codec::GlbCompressor(draco);
#else
    return Usage(absl::InvalidArgumentError(
        "--glb-draco: this tandem was built without Draco (-DTANDEM_BUILD_SERVICE=OFF)"));
#endif
  }
  auto parsed_opt = f.Options(flags, info);
  if (!parsed_opt.ok()) return Usage(parsed_opt.status());
  SessionOptions opt = *parsed_opt;
  // --iso A,B,...: one surface per value, from one read of the slices.
  auto parsed_isos = f.Isos(flags, info);
  if (!parsed_isos.ok()) return Usage(parsed_isos.status());
  const std::vector<cli::IsoValue> isos = *std::move(parsed_isos);
  std::vector<std::string> outs;
  for (const cli::IsoValue& iso : isos) {
    auto name = cli::NameForIso("out", out, iso, isos.size());
    if (!name.ok()) return Usage(name.status());
    outs.push_back(*std::move(name));
  }
  opt.iso = isos[0].value;

  cli::Progress progress("slices");
  ValueRangeSource range(source->get());
  // One surface per iso-value. Sealed, to .ply or .obj and without --reference: the chunks
  // go to the file as they come (memory follows the front, not the mesh); otherwise they are
  // kept and welded at the end.
  struct Surface {
    SessionOptions opt;
    std::string out;
    std::vector<SealedChunk> chunks;
    std::unique_ptr<ChunkedMeshWriter> writer;
    ShapeSums shape;
    IndexedMesh mesh;
    MetricsReport report;
  };
  std::vector<Surface> surfaces(isos.size());
  std::vector<SessionOptions> options;
  for (size_t i = 0; i < isos.size(); ++i) {
    Surface& s = surfaces[i];
    s.opt = opt;
    s.opt.iso = isos[i].value;
    s.out = outs[i];
    options.push_back(s.opt);
    if (opt.seal && ChunkedMeshWriter::Supports(s.out) && !reference) {
      auto w = ChunkedMeshWriter::Open(s.out, write);
      if (!w.ok()) return Fail(w.status());
      s.writer = *std::move(w);
    }
  }
  auto on_chunk = [&](size_t i, SealedChunk c) -> absl::Status {
    Surface& s = surfaces[i];
    if (!s.writer) {
      s.chunks.push_back(std::move(c));
      return absl::OkStatus();
    }
    absl::Status st = s.writer->Add(c);
    IndexedMesh piece;
    piece.positions = std::move(c.positions);
    piece.indices = std::move(c.indices);
    s.shape.Add(piece);
    return st;
  };
  // After the last slice: what the finish is doing, with an estimate of the time left.
  cli::FinishingStatus finishing("tandem extract: ", quiet);
  bool slices_done = false;  // the slices' line was ended
  auto sessions = RunSessions(
      range, options,
      [&](int64_t d, int64_t t) {
        if (follow) {
          status_line(d);
        } else {
          if (!quiet) progress.Update(d, t);
        }
      },
      on_chunk, nullptr, [&](const std::vector<TandemSession::Finishing>& f) {
        if (!slices_done) {
          slices_done = true;
          if (follow && tty) std::fprintf(stderr, "\n");
          progress.Done();
          status_shown = false;
        }
        finishing.Show(f);
      });
  if (!slices_done) {
    if (follow && tty) std::fprintf(stderr, "\n");
    progress.Done();
  }
  finishing.Done();
  if (!sessions.ok()) return Fail(absl::Status(sessions.status().code(),
                                               absl::StrCat(input_path, ": ", std::string(sessions.status().message()))));
  for (size_t i = 0; i < surfaces.size(); ++i) {
    Surface& s = surfaces[i];
    const TandemSession& session = *(*sessions)[i];
    if (s.writer) {
      if (absl::Status st = s.writer->Finish(); !st.ok()) return Fail(st);
      s.report = MakeReport(session, s.writer->triangles(), s.writer->vertices(), s.shape);
    } else {
      s.mesh = s.opt.seal ? WeldChunks(s.chunks) : session.Snapshot();
      s.chunks = {};
      // The report's measures (Error(K), anisotropy, bias) only read the mesh and the
      // finished session: work them out on another core while the mesh is written.
      // (async | deferred: runs here, later, when no thread can be had.)
      std::future<MetricsReport> measured = std::async(std::launch::async | std::launch::deferred, [&] {
        return MakeReport(session, s.mesh);
      });
      if (absl::Status st = WriteMesh(s.out, s.mesh, write); !st.ok()) return Fail(st);
      s.report = measured.get();
    }
    s.report.input = input_path;
  }
  if (reference) {
    auto ref_source = OpenVolume(input_path, f.Open(nullptr));
    if (!ref_source.ok()) return Fail(ref_source.status());
    if (absl::Status st = f.ApplyGeometry(&*ref_source).status(); !st.ok()) return Usage(st);
    std::vector<SessionOptions> ref_options = options;
    for (SessionOptions& o : ref_options) {
      o.schedule = Schedule::kNone;
      o.seal = false;
    }
    cli::Progress ref_progress("reference slices");
    auto refs = RunSessions(**ref_source, ref_options,
                            [&](int64_t d, int64_t t) {
                              if (!quiet) ref_progress.Update(d, t);
                            });
    ref_progress.Done();
    if (!refs.ok()) return Fail(refs.status());
    DistanceOptions dopt;
    dopt.samples = static_cast<size_t>(samples);
    for (size_t i = 0; i < surfaces.size(); ++i) {
      surfaces[i].report.distance = MeasureDistances((*refs)[i]->Snapshot(), surfaces[i].mesh, dopt);
    }
  }
  bool outside = false;
  std::vector<std::string> json;
  for (size_t i = 0; i < surfaces.size(); ++i) {
    Surface& s = surfaces[i];
    s.report.peak_rss_bytes = PeakRssBytes();  // the process's, as /usr/bin/time reports it
    if (!metrics.empty()) {
      if (metrics.find("{iso}") != std::string::npos) {
        auto name = cli::NameForIso("metrics", metrics, isos[i], isos.size());
        if (!name.ok()) return Usage(name.status());
        if (absl::Status st = WriteText(*name, ReportToJson(s.report)); !st.ok()) return Fail(st);
      } else {
        json.push_back(ReportToJson(s.report));
      }
    } else if (!quiet) {
      const std::string which = isos.size() > 1 ? absl::StrCat(" (iso ", isos[i].text, ")") : "";
      std::fprintf(stderr, "%s -> %s%s\n%s", input_path.c_str(), s.out.c_str(), which.c_str(),
                   ReportSummary(s.report).c_str());
    }
    // An iso-value the data never crosses gives an empty mesh: say so, never silently.
    if (range.Outside(s.opt.iso)) {
      outside = true;
      std::fprintf(stderr, "tandem extract: warning: %s\n",
                   range.lo() > range.hi()
                       ? absl::StrCat("the volume holds no finite value: no surface at iso ", s.opt.iso).c_str()
                       : absl::StrCat("iso ", s.opt.iso, " is outside the data's value range [",
                                      range.lo(), ", ", range.hi(),
                                      "]: the surface is empty (see tandem info)").c_str());
    }
  }
  if (!json.empty()) {
    // One surface: its report; several into one file: a JSON array of them, in --iso order.
    std::string text = json.size() == 1 ? json[0] : absl::StrCat("[\n", absl::StrJoin(json, ",\n"), "]\n");
    if (absl::Status st = WriteText(metrics, text); !st.ok()) return Fail(st);
  }
  if (outside && f.strict) return 3;
  return 0;
}

int Generate(int argc, char** argv) {
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
  flags.AddString("spacing", &spacing_text, "SX,SY,SZ", "physical voxel size per axis");
  flags.SetDefaultText("spacing", "1,1,1");
  flags.AddString("origin", &origin_text, "X,Y,Z", "world position of voxel (0,0,0)");
  flags.SetDefaultText("origin", "0,0,0");
  flags.AddString("directions", &directions_text, "9 NUMBERS",
                  "world unit vectors of the x, y and z axes (stored by --series dicom and "
                  ".json sidecars, refused by the others)");
  flags.SetDefaultText("directions", "identity");
  flags.AddInt("zarr-version", &zarr_version, ".zarr: 2 or 3", "V");
  flags.AddString("zarr-codec", &zarr_codec, "C", ".zarr: none, gzip, zstd, blosc-lz4, blosc-zstd");
  flags.SetDefaultText("zarr-codec", "blosc-lz4");
  flags.AddString("zarr-chunks", &zarr_chunks, "Z,Y,X", ".zarr: chunk shape (0 = the whole axis)");
  flags.SetDefaultText("zarr-chunks", "1,256,256");
  flags.AddString("series", &series, "dicom|tiff",
                  "write FILE as a folder of one file per slice instead: a DICOM CT series "
                  "(IM00001.dcm, ...; values quantized to int16 with a rescale slope and "
                  "intercept) or numbered single-page TIFFs (slice_00000.tif, ...)");
  flags.AddString("dicom-syntax", &dicom_syntax, "S",
                  "--series dicom: explicit, implicit, jpeg-lossless, jpeg-ls, jpeg2000 or rle");
  flags.SetDefaultText("dicom-syntax", "explicit");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (flags.positional().size() != 1) {
    return Usage(absl::InvalidArgumentError("expected one shape: sphere, pillowbox, link or gyroid"));
  }
  auto shape = ParseShape(flags.positional()[0]);
  if (!shape.ok()) return Usage(shape.status());
  ZarrWriteOptions zarr;
  zarr.version = static_cast<int>(zarr_version);
  if (!zarr_codec.empty()) {
    auto codec = ParseZarrCompressor(zarr_codec);
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
  DicomWriteOptions dicom;
  if (!dicom_syntax.empty()) {
    auto syntax = ParseDicomSyntax(dicom_syntax);
    if (!syntax.ok()) return Usage(syntax.status());
    dicom.syntax = *syntax;
  }
  auto make = [&] {
    return MakeSyntheticSource(*shape, int64_t(dims[0]), int64_t(dims[1]), int64_t(dims[2]),
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
  const SliceFn next = [&](int64_t z, std::vector<uint8_t>* bytes) {
    progress.Update(z + 1, nz);
    if (z < src->next_slice()) src = make();  // a second pass (the DICOM writer's range scan)
    return src->ReadSlice(bytes);
  };
  absl::Status st = series == "dicom"         ? WriteDicomSeries(out, info, next, dicom)
                    : series == "tiff"        ? WriteTiffSequence(out, info, next)
                    : out.ends_with(".zarr") ? WriteZarr(out, info, next, zarr)
                                              : WriteVolume(out, info, next);
  progress.Done();
  if (!st.ok()) return FailWriting(st);
  std::fprintf(stderr, "wrote %s (%lld x %lld x %lld float32, iso-value 0)\n", out.c_str(),
               static_cast<long long>(dims[0]), static_cast<long long>(dims[1]),
               static_cast<long long>(dims[2]));
  return 0;
}

int Measure(int argc, char** argv) {
  int64_t samples = 0;
  bool json = false;
  cli::FlagSet flags(
      "usage: tandem measure A.{ply,obj,stl} B.{ply,obj,stl} [flags]\n"
      "Metro-style distances between two meshes by area-uniform sampling and exact\n"
      "point-to-triangle distance: L1 (mean), L2 (RMS) and Linf (Hausdorff), A->B (forward),\n"
      "B->A (backward) and the larger of the two (max). Units are the meshes' own.");
  flags.AddInt("samples", &samples, "surface samples per direction (0 = automatic)");
  flags.AddBool("json", &json, "print the distances as JSON instead of a table");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (flags.positional().size() != 2) return Usage(absl::InvalidArgumentError("expected two meshes: A B"));
  for (const std::string& path : flags.positional()) {
    const std::string ext = absl::AsciiStrToLower(std::filesystem::path(path).extension().string());
    if (ext != ".ply" && ext != ".obj" && ext != ".stl") {
      return Usage(absl::InvalidArgumentError(
          absl::StrCat(path, ": expected a .ply, .obj or .stl mesh")));
    }
  }
  auto a = ReadMesh(flags.positional()[0]);
  if (!a.ok()) return Fail(a.status());
  auto b = ReadMesh(flags.positional()[1]);
  if (!b.ok()) return Fail(b.status());
  if (a->num_triangles() == 0 || b->num_triangles() == 0) {
    return Fail(absl::InvalidArgumentError("both meshes need at least one triangle"));
  }
  DistanceOptions dopt;
  dopt.samples = static_cast<size_t>(samples);
  const Distances d = MeasureDistances(*a, *b, dopt);
  if (json) {
    std::fputs(DistancesToJson(d).c_str(), stdout);
  } else {
    std::fputs(DistanceTable(d).c_str(), stdout);
  }
  return 0;
}

// Value range, mean and a 10-bin histogram of every voxel (two passes, one slice in memory):
// what a user looks at to pick an iso-value.
struct ValueStats {
  double lo = 0, hi = 0, mean = 0;
  int64_t count = 0, nonfinite = 0;
  std::array<int64_t, 10> bins{};
};

absl::StatusOr<ValueStats> ScanValues(SliceSource& src, const std::string& path,
                                      const OpenOptions& open) {
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
    if (absl::Status st = src.ReadSlice(&bytes); !st.ok()) return st;
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
  auto again = OpenVolume(path, open);
  if (!again.ok()) return again.status();
  const double width = (s.hi - s.lo) / 10.0;
  for (int64_t z = 0; z < info.nz; ++z) {
    if (absl::Status st = (*again)->ReadSlice(&bytes); !st.ok()) return st;
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

int Info(int argc, char** argv) {
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
  auto src =
      OpenVolume(input, OpenOptions{.dicom_series = series, .note = [](const std::string& line) {
                                      std::fprintf(stderr, "tandem info: %s\n", line.c_str());
                                    }});
  if (!src.ok()) return Fail(src.status());
  const VolumeInfo& i = (*src)->info();
  std::printf("grid     %lld x %lld x %lld\n", static_cast<long long>(i.nx), static_cast<long long>(i.ny),
              static_cast<long long>(i.nz));
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
  auto stats = ScanValues(**src, input, OpenOptions{.dicom_series = series});
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
      v = DicomSliceWriter::kNoInstanceNumber;
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
    const std::string& input, const VolumeInfo& info, const DicomWriteOptions& stack_opts,
    const std::function<absl::Status(const std::string&, const DicomSliceWriter&, int64_t,
                                     const std::vector<uint8_t>&)>& put) {
  auto src = OpenVolume(input);
  if (!src.ok()) return src.status();
  const int64_t nx = info.nx, ny = info.ny, nz = info.nz;
  const float none = -std::numeric_limits<float>::infinity();
  std::vector<float> front(static_cast<size_t>(nx * nz), none),
      side(static_cast<size_t>(ny * nz), none);
  std::vector<uint8_t> b;
  std::vector<float> v(static_cast<size_t>(nx * ny));
  for (int64_t z = 0; z < nz; ++z) {
    if (absl::Status st = (*src)->ReadSlice(&b); !st.ok()) return st;
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
  DicomWriteOptions o = stack_opts;
  o.series_description = "Scout";
  o.image_type = "ORIGINAL\\PRIMARY\\LOCALIZER";
  o.series_uid = "1.2.826.0.1.3680043.2.1125.7.1";
  for (int image = 0; image < 2; ++image) {
    const VolumeInfo si = LocalizerGrid(info, image);
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
      }
    }
    auto w = DicomSliceWriter::Create(si, o);
    if (!w.ok()) return w.status();
    if (absl::Status st = put(absl::StrCat("1.2.826.0.1.3680043.2.1125.7.", image + 1, ".dcm"), *w,
                              image + 1, bytes);
        !st.ok()) {
      return st;
    }
  }
  return absl::OkStatus();
}

int Simulate(int argc, char** argv) {
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
  flags.AddString("done-file", &done_file, "NAME", "create DIR/NAME (an empty file) after the last slice");
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
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--as '", as, "': expected dicom, tiff or zarr")));
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
  auto src = OpenVolume(input);
  if (!src.ok()) return Fail(src.status());
  const VolumeInfo info = (*src)->info();
  auto numbers = InstanceNumbers(numbering, info.nz, burst, static_cast<uint32_t>(seed) + 1);
  if (!numbers.ok()) return Usage(numbers.status());
  std::error_code ec;
  if (std::filesystem::exists(out, ec)) {
    return Fail(absl::AlreadyExistsError(absl::StrCat(out, ": already exists (the simulator "
                                                      "writes a fresh acquisition)")));
  }
  // Slices are read as they are written (one burst in memory for DICOM).
  DicomWriteOptions dopt;
  std::unique_ptr<ZarrAppender> zarr;
  std::optional<DicomSliceWriter> dicom;
  if (as == "dicom") {
    if (info.dtype == DType::kFloat32) {  // the quantization needs the range: one pass first
      auto scan = OpenVolume(input);
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
    auto w = DicomSliceWriter::Create(info, dopt);
    if (!w.ok()) return Fail(w.status());
    dicom.emplace(*std::move(w));
  } else if (as == "zarr") {
    ZarrWriteOptions zo;
    zo.chunks = {4, 256, 256};
    auto w = ZarrAppender::Create(out, info, zo);
    if (!w.ok()) return Fail(w.status());
    zarr = *std::move(w);
  }
  if (as != "zarr") std::filesystem::create_directories(out, ec);
  if (ec) return Fail(absl::InternalError(absl::StrCat(out, ": ", ec.message())));
  // A DICOM file goes in under its name, or through a temporary one (--temp-names).
  auto put = [&](const std::string& name, const DicomSliceWriter& writer, int64_t z,
                 const std::vector<uint8_t>& bytes, int64_t instance) -> absl::Status {
    const std::filesystem::path dir(out), path = dir / name;
    if (temp_names == "none") return writer.Write(path.string(), z, bytes, instance);
    const std::filesystem::path temp =
        dir / (temp_names == "suffix" ? name + ".part" : "." + name + ".tmp");
    if (absl::Status st = writer.Write(temp.string(), z, bytes, instance); !st.ok()) return st;
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
        [&](const std::string& name, const DicomSliceWriter& w, int64_t instance,
            const std::vector<uint8_t>& bytes) { return put(name, w, 0, bytes, instance); });
    if (!st.ok()) return Fail(st);
  }

  const auto start = std::chrono::steady_clock::now();
  auto pace = [&](int64_t written) {  // slice `written` may not go before written / rate s
    if (rate <= 0) return;
    std::this_thread::sleep_until(start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
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
      st = WriteTiffSlice((std::filesystem::path(out) / name).string(), info, z, bytes);
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
          const std::string name = absl::StrCat("1.2.826.0.1.3680043.2.1125.",
                                                (slice * 2654435761u) % 1000003u, ".dcm");
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

}  // namespace
constexpr char kViewUsage[] =
    R"(usage: tandem view MESH | DIR [flags]
Shows a finished result in a browser: serves the viewer page (the one tandem-client
stream/watch --view shows live) on HOST:PORT (default 127.0.0.1:8080; port 0 = any free
one) and prints its address. MESH is a .ply, .obj, .stl, .glb or .drc file; DIR a folder of
sealed chunks (chunk_000000.drc, ... as tandem-client --chunks saves them), drawn chunk by
chunk. Runs until Ctrl-C, or for --linger S seconds.)";

std::atomic<bool> g_view_quit{false};

int View(int argc, char** argv) {
  std::string listen = "127.0.0.1:8080", token;
  double linger_s = -1;
  cli::FlagSet flags(kViewUsage);
  flags.AddString("view", &listen, "HOST:PORT", "where the page is served (port 0 = any free one)");
  flags.AddSecret("view-token", &token, "TOKEN", "TANDEM_VIEW_TOKEN",
                  "the page and its data need ?token=TOKEN (for an address other than "
                  "loopback, which has no other protection)");
  flags.AddDouble("linger", &linger_s, "serve for this many seconds, then exit (< 0 = until Ctrl-C)",
                  false, "S");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (flags.positional().size() != 1) {
    return Usage(absl::InvalidArgumentError("expected one mesh file or folder of chunks to show"));
  }
  const std::string path = flags.positional()[0];
  std::vector<std::string> chunks;
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    for (const auto& e : std::filesystem::directory_iterator(path, ec)) {
      const std::string name = e.path().filename().string();
      if (absl::StartsWith(name, "chunk_") && absl::EndsWith(name, ".drc")) {
        chunks.push_back(e.path().string());
      }
    }
    std::sort(chunks.begin(), chunks.end());
    if (chunks.empty()) {
      return Fail(absl::NotFoundError(absl::StrCat(path, ": no chunk_*.drc files in this folder")));
    }
  } else {
    const std::string ext = absl::AsciiStrToLower(std::filesystem::path(path).extension().string());
    if (ext != ".ply" && ext != ".obj" && ext != ".stl" && ext != ".glb" && ext != ".drc") {
      return Usage(absl::InvalidArgumentError(
          absl::StrCat(path, ": expected a .ply, .obj, .stl, .glb or .drc file, or a folder of chunks")));
    }
  }
  auto read = [](const std::string& file) -> absl::StatusOr<std::string> {
    std::ifstream in(file, std::ios::binary);
    if (!in) return absl::NotFoundError(absl::StrCat(file, ": cannot open"));
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  viewer::ViewOptions options;
  options.listen = listen;
  options.token = token;
  auto server = viewer::ViewServer::Start(options);
  if (!server.ok()) return FailWriting(server.status());
  (*server)->SetSession("", std::filesystem::path(path).filename().string(), 0);
  if (chunks.empty()) {
    auto bytes = read(path);
    if (!bytes.ok()) return Fail(bytes.status());
    (*server)->AddFile(std::filesystem::path(path).filename().string(), *std::move(bytes));
  } else {
    for (const std::string& c : chunks) {
      auto bytes = read(c);
      if (!bytes.ok()) return Fail(bytes.status());
      (*server)->AddChunk(*std::move(bytes), -1, 0);
    }
  }
  (*server)->Finish("", "");
  std::string host;
  int port = 0;
  if (viewer::ParseListen(options.listen, &host, &port).ok() && !viewer::IsLoopback(host) &&
      options.token.empty()) {
    std::fprintf(stderr, "tandem view: warning: %s has no authentication: anyone who can reach "
                         "it sees the mesh (add --view-token-file FILE or $TANDEM_VIEW_TOKEN)\n",
                 options.listen.c_str());
  }
  std::fprintf(stderr, "tandem view: %s at %s%s\n", path.c_str(), (*server)->url().c_str(),
               linger_s < 0 ? " (Ctrl-C to quit)" : "");
  std::signal(SIGINT, [](int) { g_view_quit = true; });
  std::signal(SIGTERM, [](int) { g_view_quit = true; });
  const auto until = std::chrono::steady_clock::now() +
                     std::chrono::milliseconds(static_cast<int64_t>(std::max(0.0, linger_s) * 1000));
  while (!g_view_quit && (linger_s < 0 || std::chrono::steady_clock::now() < until)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return 0;
}

}  // namespace tandem

int main(int argc, char** argv) {
  if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h" ||
      std::string(argv[1]) == "help") {
    std::fputs(tandem::kUsage, argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const std::string cmd = argv[1];
  if (cmd == "--version" || cmd == "version") {
    std::fputs(TANDEM_VERSION_LINE("tandem"), stdout);
    return 0;
  }
  try {  // no input may abort the process: report and exit 1
    if (cmd == "extract") return tandem::Extract(argc, argv);
    if (cmd == "generate") return tandem::Generate(argc, argv);
    if (cmd == "measure") return tandem::Measure(argc, argv);
    if (cmd == "info") return tandem::Info(argc, argv);
    if (cmd == "simulate") return tandem::Simulate(argc, argv);
    if (cmd == "view") return tandem::View(argc, argv);
  } catch (...) {
    const absl::Status st = tandem::StatusOfException(std::current_exception());
    std::fprintf(stderr, "tandem %s: %s\n", cmd.c_str(), std::string(st.message()).c_str());
    return 1;
  }
  std::fprintf(stderr, "tandem: unknown command '%s'\n\n%s", cmd.c_str(), tandem::kUsage);
  return 2;
}
