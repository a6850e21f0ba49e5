// Saving what stream and watch received: each surface's mesh (decoded and checked, or the
// sealed chunks welded) and its metrics.
#include "save.h"

#include <filesystem>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "command.h"
#include "tandem/common/wire.h"
#include "tandem/eval/label_metrics.h"
#include "tandem/eval/report.h"
#include "tandem/io/labels_io.h"
#include "tandem/io/mesh_io.h"
#include "tandem/status_macros.h"
#include "tandem/volume.h"

namespace tandem::client_app {
namespace {

// The final mesh of one surface, decoded and held to the counts the server announced.
absl::StatusOr<tandem::IndexedMesh> DecodeFinal(const tandem::client::SurfaceResult& s) {
  TANDEM_ASSIGN_OR_RETURN(tandem::IndexedMesh mesh, tandem::codec::DecodeDraco(s.draco));
  if (static_cast<int64_t>(mesh.num_triangles()) != s.triangles ||
      static_cast<int64_t>(mesh.num_vertices()) != s.vertices) {
    return absl::DataLossError(absl::StrCat("the final mesh decodes to ", mesh.num_triangles(),
                                            " triangles and ", mesh.num_vertices(),
                                            " vertices; the server announced ", s.triangles,
                                            " and ", s.vertices));
  }
  return mesh;
}

// Saves one surface's final mesh of a stream or a watch to `out` (.drc: Draco bytes; sealed:
// the chunks welded), prints its summary on stdout and appends its metrics JSON to *json.
// 0 or the exit status of the failure.
int SaveSurface(const tandem::client::StreamResult& result, tandem::client::SurfaceResult& s,
                const SaveOptions& o, const std::string& out, std::vector<std::string>* json) {
  const bool seal = o.seal;
  const std::string ext = Lower(std::filesystem::path(out).extension().string());
  // Decode even for .drc: it checks the bytes and the counts the server announced. Sealed:
  // the chunks, welded (their counts were checked against the metrics), encoded for .drc.
  absl::StatusOr<tandem::IndexedMesh> mesh = seal ? tandem::WeldChunks(s.sealed) : DecodeFinal(s);
  if (!mesh.ok()) return Fail(mesh.status());
  if (seal && ext == ".drc") {
    absl::StatusOr<std::string> bytes = tandem::codec::EncodeDraco(*mesh, o.draco);
    if (!bytes.ok()) return Fail(bytes.status());
    s.draco = *std::move(bytes);
  }
  tandem::io::MeshWriteOptions write;
  if (o.glb_draco) write.glb_draco = tandem::codec::GlbCompressor(o.draco);
  // The frame the session ran in, as the server echoes it: the watcher of a session learns
  // it there too. An older server sends none: the grid's own frame.
  write.space = tandem::ParseSpace(s.metrics.frame()).value_or(tandem::Space::kGrid);
  absl::Status saved =
      ext == ".drc" ? WriteFile(out, s.draco) : tandem::io::WriteMesh(out, *mesh, write);
  if (!saved.ok()) return Fail(saved);

  tandem::eval::MetricsReport report = tandem::common::ReportFromProto(s.metrics);
  report.input = o.input;
  report.frame_text = o.frame_text;
  json->push_back(tandem::eval::ReportToJson(report));
  if (o.quiet) return 0;
  if (result.num_surfaces() > 1) absl::PrintF("%s (iso %g)\n", out, s.metrics.iso());
  absl::PrintF("%s", tandem::eval::ReportSummary(report));
  absl::PrintF("  %-22s %.3f s for %d slices (%.1f slices/s), %d previews\n", o.wall_label,
               result.seconds, result.slices_sent,
               result.seconds > 0 ? result.slices_sent / result.seconds : 0.0,
               s.metrics.previews_sent());
  if (seal) {
    absl::PrintF("  %-22s %d chunks, %d bytes received in all\n", "sealed", s.sealed.size(),
                 s.metrics.bytes_sent());
  }
  return 0;
}

}  // namespace

absl::Status MakeOutputDir(const char* flag, const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::UnavailableError(absl::StrCat(flag, " ", dir, ": ", ec.message()));
  return absl::OkStatus();
}

std::function<void(const tandem::v1::SealedChunk&)> ChunkSaver(tandem::client::ChunkStore* store,
                                                               const std::string& session,
                                                               const bool& verbose,
                                                               absl::Status* error) {
  return [store, session, &verbose, error](const tandem::v1::SealedChunk& c) {
    if (verbose) {
      absl::FPrintF(stderr, "chunk index=%d slices=%d..%d triangles=%d vertices=%d bytes=%d\n",
                    c.index(), c.first_slice(), c.last_slice(), c.triangles(), c.vertices(),
                    c.draco().size());
    }
    if (store != nullptr && error->ok()) *error = store->Save(session, c);
  };
}

int SaveResult(tandem::client::StreamResult& result, const SaveOptions& o) {
  const size_t n = result.num_surfaces();
  const std::string& metrics_path = o.metrics_path;
  std::vector<std::string> json;
  for (size_t i = 0; i < n; ++i) {
    tandem::client::SurfaceResult& s = result.surface(i);
    const tandem::cli::IsoValue iso =
        i < o.isos.size() ? o.isos[i]
                          : tandem::cli::IsoValue{s.metrics.iso(), absl::StrCat(s.metrics.iso())};
    absl::StatusOr<std::string> out = tandem::cli::NameForIso("out", o.out_pattern, iso, n);
    if (!out.ok()) return Fail(out.status());
    if (int rc = SaveSurface(result, s, o, *out, &json); rc != 0) {
      return rc;
    }
    if (!metrics_path.empty() && metrics_path.find("{iso}") != std::string::npos) {
      absl::StatusOr<std::string> name = tandem::cli::NameForIso("metrics", metrics_path, iso, n);
      if (!name.ok()) return Fail(name.status());
      if (absl::Status st = WriteFile(*name, json.back()); !st.ok()) return Fail(st);
    }
  }
  if (!metrics_path.empty() && metrics_path.find("{iso}") == std::string::npos) {
    const std::string text =
        n == 1 ? json[0] : absl::StrCat("[\n", absl::StrJoin(json, ",\n"), "]\n");
    if (absl::Status st = WriteFile(metrics_path, text); !st.ok()) return Fail(st);
  }
  return 0;
}

int SaveLabels(tandem::client::StreamResult& result, const SaveOptions& o) {
  std::vector<std::pair<tandem::LabelId, tandem::IndexedMesh>> surfaces;
  std::vector<tandem::eval::LabelMetrics> measured;
  for (size_t i = 0; i < result.num_labels(); ++i) {
    const tandem::client::SurfaceResult& s = result.surface(i);
    // Sealed: the label's chunks, welded by id (their counts were checked against its metrics).
    absl::StatusOr<tandem::IndexedMesh> mesh =
        o.seal ? tandem::WeldChunks(s.sealed) : DecodeFinal(s);
    if (!mesh.ok()) {
      return Fail(absl::Status(mesh.status().code(), absl::StrCat("label ", s.metrics.label(), ": ",
                                                                  mesh.status().message())));
    }
    tandem::eval::LabelMetrics m = tandem::common::LabelMetricsFromProto(s.metrics);
    if (o.label_names != nullptr) {
      if (auto it = o.label_names->find(m.label); it != o.label_names->end()) {
        m.name = it->second.name;
      }
    }
    measured.push_back(std::move(m));
    surfaces.emplace_back(s.metrics.label(), *std::move(mesh));
  }
  tandem::io::MeshWriteOptions write;
  if (o.glb_draco) write.glb_draco = tandem::codec::GlbCompressor(o.draco);
  write.space = tandem::ParseSpace(result.session_metrics.frame()).value_or(tandem::Space::kGrid);
  if (!o.label_extension.empty()) {
    absl::StatusOr<std::vector<tandem::io::LabelFile>> files = tandem::io::WriteLabelMeshes(
        o.out_pattern, o.label_extension, surfaces, o.label_names, write);
    if (!files.ok()) return Fail(files.status());
  } else if (absl::Status st =
                 tandem::io::WriteLabelsGlb(o.out_pattern, surfaces, o.label_names, write.space);
             !st.ok()) {
    return Fail(st);
  }
  tandem::eval::MetricsReport report = tandem::common::ReportFromProto(result.session_metrics);
  report.input = o.input;
  report.frame_text = o.frame_text;
  if (!o.metrics_path.empty()) {
    if (absl::Status st =
            WriteFile(o.metrics_path, tandem::eval::ReportWithLabelsToJson(report, measured));
        !st.ok()) {
      return Fail(st);
    }
  } else if (!o.quiet) {
    absl::PrintF("%s -> %s (%d labels)\n%s  labels:\n%s", o.input, o.out_pattern, measured.size(),
                 tandem::eval::ReportSummary(report), tandem::eval::LabelMetricsSummary(measured));
    absl::PrintF("  %-22s %.3f s for %d slices (%.1f slices/s), %d previews\n", o.wall_label,
                 result.seconds, result.slices_sent,
                 result.seconds > 0 ? result.slices_sent / result.seconds : 0.0,
                 result.session_metrics.previews_sent());
  }
  if (measured.empty() && !o.quiet) {
    absl::FPrintF(stderr, "tandem-client: warning: %s holds no label but the background\n",
                  o.input);
  }
  return 0;
}

}  // namespace tandem::client_app
