// tandem extract: a volume, read slice by slice, to simplified iso-surface meshes and
// their metrics.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <future>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "apps/common/cli_util.h"
#include "apps/common/extract_flags.h"
#include "apps/common/flags.h"
#include "command.h"
#ifdef TANDEM_HAVE_DRACO
#include "neuroglancer_export.h"
#include "tandem/codec/draco_codec.h"
#endif
#include "tandem/eval/distance.h"
#include "tandem/io/follow.h"
#include "tandem/io/mesh_io.h"
#include "tandem/eval/metrics.h"
#include "tandem/eval/report.h"
#include "tandem/io/open_volume.h"
#include "tandem/io/run_session.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace tandem::app {

int ExtractCommand(int argc, char** argv) {
  cli::ExtractFlags f;
  int64_t samples = 0;
  std::string neuroglancer;
  int64_t neuroglancer_lods = 3;
  double neuroglancer_nm = 0;
  int64_t neuroglancer_chunk = 32;
  double neuroglancer_skirt = -1;
  cli::FlagSet flags(
      "usage: tandem extract --input FILE --out MESH [flags]\n"
      "Reads the volume one slice at a time, extracts the iso-surface F = C0 layer by layer\n"
      "(marching cubes) and simplifies it in tandem by quadric-error edge contraction.");
  f.Add(&flags,
        "output mesh: binary PLY (.ply) or OBJ (.obj), both with vertex normals, "
        "binary STL (.stl), or glTF binary (.glb)");
  flags.AddInt("samples", &samples,
               "surface samples per direction for --reference (0 = automatic)");
  flags.AddString("neuroglancer", &neuroglancer, "DIR",
                  "also write the surfaces as a Neuroglancer precomputed segmentation in DIR "
                  "(multi-resolution Draco meshes, sharded; segment id 1, or 1..N for N "
                  "--iso values): open it as precomputed://URL-of-DIR");
  flags.AddInt("neuroglancer-lods", &neuroglancer_lods,
               "--neuroglancer: levels of detail, from sweeps at E0, 2 E0, 4 E0, ... (1..8)");
  flags.AddDouble("neuroglancer-nm", &neuroglancer_nm,
                  "--neuroglancer: nanometres per unit of the volume's spacing", false, "N");
  flags.SetDefaultText("neuroglancer-nm", "1e6 for DICOM/NIfTI (mm), else 1");
  flags.AddInt("neuroglancer-chunk", &neuroglancer_chunk,
               "--neuroglancer: the finest octree node's edge in voxels; level k's nodes are "
               "2^k times larger (1..4096)");
  flags.AddDouble("neuroglancer-skirt", &neuroglancer_skirt,
                  "--neuroglancer: least depth in voxels of the strips that close the cuts "
                  "where two levels meet, up to 4 times deeper where the levels' cuts lie "
                  "further apart (0: none)",
                  false, "N");
  flags.SetDefaultText("neuroglancer-skirt", "1");
  flags.SetEpilog(
      "Progress (slices done / total) is shown on stderr when it is a terminal. Exit status: 0\n"
      "done, 1 a failure while running (the input, a file, the session), 2 a mistake in the\n"
      "command line, 3 with --strict: the iso-value is outside the data (a warning on stderr\n"
      "otherwise).\n");
  if (int rc = ParseOrExit(flags, argc, argv); rc >= 0) return rc;
  if (!flags.positional().empty()) {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("unexpected argument '", flags.positional()[0], "'")));
  }
  if (absl::Status st = f.Check(flags); !st.ok()) return Usage(st);
  const std::string& out = f.out;
  if (!f.labels && !io::IsMeshOutputPath(out)) {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--out ", out, ": the extension must be ", io::kMeshExtensions)));
  }
  if (neuroglancer.empty() && (flags.IsSet("neuroglancer-lods") || flags.IsSet("neuroglancer-nm") ||
                                flags.IsSet("neuroglancer-chunk") ||
                                flags.IsSet("neuroglancer-skirt"))) {
    return Usage(absl::InvalidArgumentError(
        "--neuroglancer-lods, -nm, -chunk and -skirt go with --neuroglancer DIR"));
  }
  if (neuroglancer_chunk < 1 || neuroglancer_chunk > 4096) {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--neuroglancer-chunk must be in [1, 4096], got ", neuroglancer_chunk)));
  }
  if (flags.IsSet("neuroglancer-skirt") && !(neuroglancer_skirt >= 0 && neuroglancer_skirt < 1e6)) {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--neuroglancer-skirt must be 0 or more, got ", neuroglancer_skirt)));
  }
  if (neuroglancer_lods < 1 || neuroglancer_lods > 8) {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--neuroglancer-lods must be in [1, 8], got ", neuroglancer_lods)));
  }
  if (flags.IsSet("neuroglancer-nm") && !(neuroglancer_nm > 0 && neuroglancer_nm < 1e15)) {
    return Usage(absl::InvalidArgumentError(
        absl::StrCat("--neuroglancer-nm must be positive, got ", neuroglancer_nm)));
  }
#ifndef TANDEM_HAVE_DRACO
  if (!neuroglancer.empty()) {
    return Usage(absl::InvalidArgumentError(
        "--neuroglancer: this tandem was built without Draco (-DTANDEM_BUILD_SERVICE=OFF)"));
  }
#endif
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
    io::FollowOptions fo = f.Follow(note);
    fo.progress = [&](int64_t s, int64_t r) {
      seen = s;
      read = r;
    };
    source = io::FollowVolume(input_path, fo);
  } else {
    source = io::OpenVolume(input_path, f.Open(note));
  }
  if (!source.ok()) return Fail(source.status());
  if (absl::StatusOr<std::string> warn = f.ApplyGeometry(&*source); !warn.ok()) {
    return Usage(warn.status());
  } else if (!warn->empty()) {
    std::fprintf(stderr, "tandem extract: warning: %s\n", warn->c_str());
  }
  const VolumeInfo info = (*source)->info();

  io::MeshWriteOptions write;
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
  if (f.labels) {
    const NeuroglancerRequest ng{neuroglancer, static_cast<int>(neuroglancer_lods),
                                 flags.IsSet("neuroglancer-nm") ? neuroglancer_nm : 0.0,
                                 static_cast<int>(neuroglancer_chunk),
                                 flags.IsSet("neuroglancer-skirt") ? neuroglancer_skirt : -1.0};
    return ExtractLabels(f, flags, **source, write, ng);
  }
  auto parsed_opt = f.Options(flags, info);
  if (!parsed_opt.ok()) return Usage(parsed_opt.status());
  SessionOptions opt = *parsed_opt;
  if (const std::string w = cli::OptionsWarning(opt, info); !w.empty()) {
    std::fprintf(stderr, "tandem extract: warning: %s\n", w.c_str());
  }
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
    std::unique_ptr<io::ChunkedMeshWriter> writer;
    eval::ShapeSums shape;
    IndexedMesh mesh;
    eval::MetricsReport report;
  };
  std::vector<Surface> surfaces(isos.size());
  std::vector<SessionOptions> options;
  for (size_t i = 0; i < isos.size(); ++i) {
    Surface& s = surfaces[i];
    s.opt = opt;
    s.opt.iso = isos[i].value;
    s.out = outs[i];
    options.push_back(s.opt);
    if (opt.seal && io::ChunkedMeshWriter::Supports(s.out) && !reference && neuroglancer.empty()) {
      auto w = io::ChunkedMeshWriter::Open(s.out, write);
      if (!w.ok()) return Fail(w.status());
      s.writer = *std::move(w);
    }
  }
  // --neuroglancer: the coarser levels, surface i's level k (1..) at E0 * 2^k, read in the
  // same pass; session surfaces.size() + i * (lods - 1) + k - 1.
  const size_t coarser = neuroglancer.empty() ? 0 : static_cast<size_t>(neuroglancer_lods - 1);
  for (size_t i = 0; i < surfaces.size(); ++i) {
    for (size_t k = 1; k <= coarser; ++k) {
      SessionOptions o = surfaces[i].opt;
      o.error = std::ldexp(o.error, static_cast<int>(k));
      // Triangles go about as 1 / E0: each level asks for half the count of the one before.
      if (o.target_triangles > 0) o.target_triangles = std::max<int64_t>(4, o.target_triangles >> k);
      options.push_back(o);
    }
  }
  std::vector<std::vector<SealedChunk>> level_chunks(options.size() - surfaces.size());
  auto on_chunk = [&](size_t i, SealedChunk c) -> absl::Status {
    if (i >= surfaces.size()) {
      level_chunks[i - surfaces.size()].push_back(std::move(c));
      return absl::OkStatus();
    }
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
  auto sessions = io::RunSessions(
      range, options,
      [&](int64_t d, int64_t t) {
        if (follow) {
          status_line(d);
        } else {
          if (!quiet) progress.Update(d, t);
        }
      },
      on_chunk, nullptr,
      [&](const std::vector<TandemSession::Finishing>& f) {
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
  if (!sessions.ok())
    return Fail(
        absl::Status(sessions.status().code(),
                     absl::StrCat(input_path, ": ", std::string(sessions.status().message()))));
  for (size_t i = 0; i < surfaces.size(); ++i) {
    Surface& s = surfaces[i];
    const TandemSession& session = *(*sessions)[i];
    if (s.writer) {
      if (absl::Status st = s.writer->Finish(); !st.ok()) return Fail(st);
      s.report = eval::MakeReport(session, s.writer->triangles(), s.writer->vertices(), s.shape);
    } else {
      s.mesh = s.opt.seal ? WeldChunks(s.chunks) : session.Snapshot();
      s.chunks = {};
      // The report's measures (Error(K), anisotropy, bias) only read the mesh and the
      // finished session: work them out on another core while the mesh is written.
      // (async | deferred: runs here, later, when no thread can be had.)
      std::future<eval::MetricsReport> measured =
          std::async(std::launch::async | std::launch::deferred,
                     [&] { return eval::MakeReport(session, s.mesh); });
      if (absl::Status st = io::WriteMesh(s.out, s.mesh, write); !st.ok()) return Fail(st);
      s.report = measured.get();
    }
    s.report.input = input_path;
  }
#ifdef TANDEM_HAVE_DRACO
  if (!neuroglancer.empty()) {
    std::vector<std::pair<LabelId, std::vector<IndexedMesh>>> segments;
    for (size_t i = 0; i < surfaces.size(); ++i) {
      std::vector<IndexedMesh> lods{surfaces[i].mesh};
      for (size_t k = 1; k <= coarser; ++k) {
        const size_t at = surfaces.size() + i * coarser + k - 1;
        std::vector<SealedChunk>& chunks = level_chunks[at - surfaces.size()];
        lods.push_back(options[at].seal ? WeldChunks(chunks) : (*sessions)[at]->Snapshot());
        chunks = {};
      }
      segments.emplace_back(static_cast<LabelId>(i + 1), std::move(lods));
    }
    const double nm = flags.IsSet("neuroglancer-nm") ? neuroglancer_nm : DefaultNmPerUnit(info);
    const NeuroglancerOctree octree{static_cast<int>(neuroglancer_chunk),
                                    flags.IsSet("neuroglancer-skirt") ? neuroglancer_skirt : -1.0};
    if (absl::Status st = WriteNeuroglancerExport(neuroglancer, info, std::move(segments), nm,
                                                  static_cast<int>(f.compression_level), octree);
        !st.ok()) {
      return Fail(st);
    }
  }
#endif
  if (reference) {
    auto ref_source = io::OpenVolume(input_path, f.Open(nullptr));
    if (!ref_source.ok()) return Fail(ref_source.status());
    if (absl::Status st = f.ApplyGeometry(&*ref_source).status(); !st.ok()) return Usage(st);
    std::vector<SessionOptions> ref_options(options.begin(), options.begin() + surfaces.size());
    for (SessionOptions& o : ref_options) {
      o.schedule = Schedule::kNone;
      o.seal = false;
    }
    cli::Progress ref_progress("reference slices");
    auto refs = io::RunSessions(**ref_source, ref_options, [&](int64_t d, int64_t t) {
      if (!quiet) ref_progress.Update(d, t);
    });
    ref_progress.Done();
    if (!refs.ok()) return Fail(refs.status());
    eval::DistanceOptions dopt;
    dopt.samples = static_cast<size_t>(samples);
    for (size_t i = 0; i < surfaces.size(); ++i) {
      surfaces[i].report.distance =
          eval::MeasureDistances((*refs)[i]->Snapshot(), surfaces[i].mesh, dopt);
    }
  }
  bool outside = false;
  std::vector<std::string> json;
  for (size_t i = 0; i < surfaces.size(); ++i) {
    Surface& s = surfaces[i];
    s.report.peak_rss_bytes = eval::PeakRssBytes();  // the process's, as /usr/bin/time reports it
    if (!metrics.empty()) {
      if (metrics.find("{iso}") != std::string::npos) {
        auto name = cli::NameForIso("metrics", metrics, isos[i], isos.size());
        if (!name.ok()) return Usage(name.status());
        if (absl::Status st = WriteText(*name, eval::ReportToJson(s.report)); !st.ok())
          return Fail(st);
      } else {
        json.push_back(eval::ReportToJson(s.report));
      }
    } else if (!quiet) {
      const std::string which = isos.size() > 1 ? absl::StrCat(" (iso ", isos[i].text, ")") : "";
      std::fprintf(stderr, "%s -> %s%s\n%s", input_path.c_str(), s.out.c_str(), which.c_str(),
                   eval::ReportSummary(s.report).c_str());
    }
    // An iso-value the data never crosses gives an empty mesh: say so, never silently.
    if (range.Outside(s.opt.iso)) {
      outside = true;
      std::fprintf(
          stderr, "tandem extract: warning: %s\n",
          range.lo() > range.hi()
              ? absl::StrCat("the volume holds no finite value: no surface at iso ", s.opt.iso)
                    .c_str()
              : absl::StrCat("iso ", s.opt.iso, " is outside the data's value range [", range.lo(),
                             ", ", range.hi(), "]: the surface is empty (see tandem info)")
                    .c_str());
    }
  }
  if (!json.empty()) {
    // One surface: its report; several into one file: a JSON array of them, in --iso order.
    std::string text =
        json.size() == 1 ? json[0] : absl::StrCat("[\n", absl::StrJoin(json, ",\n"), "]\n");
    if (absl::Status st = WriteText(metrics, text); !st.ok()) return Fail(st);
  }
  if (outside && f.strict) return 3;
  return 0;
}

}  // namespace tandem::app
