// MetricsReport: the figures of one run, as `tandem extract --metrics` and
// `tandem-client --metrics` write them (one JSON schema for both).
#ifndef TANDEM_REPORT_H_
#define TANDEM_REPORT_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "tandem/eval/distance.h"
#include "tandem/eval/metrics.h"
#include "tandem/options.h"
#include "tandem/stats.h"
#include "tandem/tandem.h"

namespace tandem::eval {

struct MetricsReport {
  std::string input;  // file name or description
  // The frame of the vertices: SpaceName(VolumeInfo::space) ("LPS", "RAS", "voxel", "grid"),
  // and VolumeInfo::frame, for people.
  std::string frame, frame_text;
  // The session's options and statistics, copied whole by MakeReport. The JSON and the wire
  // carry the members VisitReportFields lists, not all of them (not pipeline, parts or
  // seal, nor the front reaches and the sealed counts).
  SessionOptions options;
  SessionStats stats;
  int64_t nx = 0, ny = 0, nz = 0;  // nz: the slices the session received
  int64_t triangles_final = 0, vertices_final = 0;
  double error_max = 0;        // Error(K), physical units
  double anisotropy = 0, directional_bias = 0;
  int64_t peak_rss_bytes = 0;
  std::optional<Distances> distance;  // with --reference: to the unsimplified surface
  // Service only (0 for local runs).
  int64_t bytes_received = 0, bytes_sent = 0;
  // The most memory this one session held at once (mesh, queues, buffers, and the encoding
  // or distance measure it was about to run), as the server's per-session budget counts it;
  // peak_rss_bytes is then the whole server process's, shared by every session it served.
  int64_t peak_session_bytes = 0;
};

// When ReportToJson writes a field.
enum class Written {
  kAlways,
  kIfNonZero,   // peak_session_bytes: local runs have none
  kIfService,   // bytes_received, bytes_sent: both, when either is non-zero (HasServiceBytes)
  kIfPresent,   // distance: with --reference / compute_distances only
};
inline bool HasServiceBytes(const MetricsReport& r) { return r.bytes_received || r.bytes_sent; }

// MetricsReport's one field table: f(key, wire, member, when) for every field. `key` is where
// the JSON holds it (a JSON pointer: "/time_s/extract" is {"time_s": {"extract": ...}}); `wire`
// names its field in the proto message tandem.v1.FinalMetrics (proto/tandem/v1/tandem.proto;
// "refusals.link" is the field link of the sub-message refusals), nullptr when the wire does not
// carry it (the client knows its input itself). ReportToJson and ReportFromJson iterate it, and
// so do ReportToProto and ReportFromProto (common/wire.cc, by protobuf reflection);
// WireReport.TableNamesFinalMetricsFields (tests/service/request_validation_test.cc) fails when
// a wire name is not a FinalMetrics field of the member's type. Reporting a new SessionStats or
// SessionOptions member of a type the table already has takes two places: a line here and its
// field in tandem.proto; MakeReport copies both structs whole. A figure the session does not
// know also needs a MetricsReport member, set by whoever computes it; a member of a new type
// (another enum or struct) also needs its conversions in report.cc and wire.cc.
template <class R, class F>  // R: MetricsReport or const MetricsReport
void VisitReportFields(R& r, F&& f) {
  using W = Written;
  auto& o = r.options;
  auto& s = r.stats;
  f("/input", nullptr, r.input, W::kAlways);
  f("/frame", "frame", r.frame, W::kAlways);
  f("/frame_text", nullptr, r.frame_text, W::kAlways);
  f("/schedule", "schedule", o.schedule, W::kAlways);  // by name: "none", "classical", ...
  f("/iso", "iso", o.iso, W::kAlways);
  f("/error_threshold", "error_threshold", o.error, W::kAlways);
  f("/error_reached", "error_reached", s.error_reached, W::kAlways);
  f("/alpha", "alpha", o.alpha, W::kAlways);
  f("/distance_guard", "distance_guard", o.distance_guard, W::kAlways);
  f("/sag_correction", "sag_correction", o.sag_correction, W::kAlways);
  f("/sag_corrected", "sag_corrected", s.sag_corrected, W::kAlways);
  f("/lockstep_error", "lockstep_error", o.lockstep_error, W::kAlways);
  f("/target_triangles", "target_triangles", o.target_triangles, W::kAlways);
  f("/grid/0", "nx", r.nx, W::kAlways);
  f("/grid/1", "ny", r.ny, W::kAlways);
  f("/grid/2", "nz", r.nz, W::kAlways);
  f("/slices", "slices", s.slices, W::kAlways);
  f("/crossed_cubes", "crossed_cubes", s.crossed_cubes, W::kAlways);
  f("/triangles_extracted", "triangles_extracted", s.triangles_extracted, W::kAlways);
  f("/triangles_final", "triangles_final", r.triangles_final, W::kAlways);
  f("/vertices_final", "vertices_final", r.vertices_final, W::kAlways);
  f("/peak_triangles", "peak_triangles", s.peak_triangles, W::kAlways);
  f("/error_max", "error_max", r.error_max, W::kAlways);
  f("/anisotropy", "anisotropy", r.anisotropy, W::kAlways);
  f("/directional_bias", "directional_bias", r.directional_bias, W::kAlways);
  f("/time_s/extract", "time_extract_s", s.time.extract_s, W::kAlways);
  f("/time_s/simplify", "time_simplify_s", s.time.simplify_s, W::kAlways);
  f("/time_s/total", "time_total_s", s.time.total_s, W::kAlways);
  f("/peak_rss_bytes", "peak_rss_bytes", r.peak_rss_bytes, W::kAlways);
  f("/trace", "trace", s.trace, W::kAlways);
  f("/contractions", "contractions", s.contractions, W::kAlways);
  f("/evaluations", "evaluations", s.evaluations, W::kAlways);
  f("/q_pushes", "q_pushes", s.q_pushes, W::kAlways);
  f("/w_pushes", "w_pushes", s.w_pushes, W::kAlways);
  f("/refusals/link", "refusals.link", s.refusals.link, W::kAlways);
  f("/refusals/flip", "refusals.flip", s.refusals.flip, W::kAlways);
  f("/refusals/degenerate", "refusals.degenerate", s.refusals.degenerate, W::kAlways);
  f("/refusals/box", "refusals.box", s.refusals.box, W::kAlways);
  f("/refusals/error", "refusals.error", s.refusals.error, W::kAlways);
  f("/refusals/distance", "refusals.distance", s.refusals.distance, W::kAlways);
  f("/distance", "distance", r.distance, W::kIfPresent);
  f("/bytes_received", "bytes_received", r.bytes_received, W::kIfService);
  f("/bytes_sent", "bytes_sent", r.bytes_sent, W::kIfService);
  f("/peak_session_bytes", "peak_session_bytes", r.peak_session_bytes, W::kIfNonZero);
}

// Fills every field a finished session knows (mesh measures are computed on `mesh`).
MetricsReport MakeReport(const TandemSession& session, const IndexedMesh& mesh);
// The same for a mesh that left the session in sealed chunks: its counts and shape sums.
MetricsReport MakeReport(const TandemSession& session, int64_t triangles, int64_t vertices,
                         const ShapeSums& shape);

// JSON text: the fields of VisitReportFields (docs/guide.md lists them).
std::string ReportToJson(const MetricsReport& r);
// {"distance": {"L1": {"forward", "backward", "max"}, "L2": ..., "Linf": ...}}: the block
// ReportToJson writes, alone (tandem measure --json).
std::string DistancesToJson(const Distances& d);
// A key the JSON lacks keeps MetricsReport's default (SessionOptions' for the options).
absl::StatusOr<MetricsReport> ReportFromJson(const std::string& json);
// A short human-readable summary, one figure per line.
std::string ReportSummary(const MetricsReport& r);

// Peak resident set size of this process in bytes (getrusage), 0 if unknown.
int64_t PeakRssBytes();

}  // namespace tandem::eval

#endif  // TANDEM_REPORT_H_
