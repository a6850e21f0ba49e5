// MetricsReport: the figures of one run, as `tandem extract --metrics` and
// `tandem-client --metrics` write them (one JSON schema for both).
#ifndef TANDEM_REPORT_H_
#define TANDEM_REPORT_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "tandem/distance.h"
#include "tandem/metrics.h"
#include "tandem/stats.h"
#include "tandem/tandem.h"

namespace tandem {

struct MetricsReport {
  std::string input;     // file name or description
  std::string frame;     // the world frame of the vertices (VolumeInfo::frame)
  std::string schedule;  // "none", "classical", "tandem", "tandem-lag"
  double iso = 0, error_threshold = 0, alpha = 0;
  double distance_guard = 0;  // K of SessionOptions::distance_guard (0 = off)
  double sag_correction = 0;  // F of SessionOptions::sag_correction (0 = off)
  int64_t sag_corrected = 0;  // vertices it moved
  int64_t target_triangles = 0;
  int64_t nx = 0, ny = 0, nz = 0;
  int64_t slices = 0, crossed_cubes = 0;
  int64_t triangles_extracted = 0, triangles_final = 0, vertices_final = 0;
  int64_t peak_triangles = 0;
  double error_max = 0;        // Error(K), physical units
  double anisotropy = 0, directional_bias = 0;
  double time_extract_s = 0, time_simplify_s = 0, time_total_s = 0;
  int64_t peak_rss_bytes = 0;
  std::vector<int64_t> trace;  // triangles after every EXTRACT and every SIMPLIFY
  RefusalCounts refusals;
  int64_t contractions = 0;
  std::optional<Distances> distance;  // with --reference: to the unsimplified surface
  // Service only (0 for local runs).
  int64_t bytes_received = 0, bytes_sent = 0;
  // The most memory this one session held at once (mesh, queues, buffers, and the encoding
  // or distance measure it was about to run), as the server's per-session budget counts it;
  // peak_rss_bytes is then the whole server process's, shared by every session it served.
  int64_t peak_session_bytes = 0;
};

// Fills every field a finished session knows (mesh measures are computed on `mesh`).
MetricsReport MakeReport(const TandemSession& session, const IndexedMesh& mesh);
// The same for a mesh that left the session in sealed chunks: its counts and shape sums.
MetricsReport MakeReport(const TandemSession& session, int64_t triangles, int64_t vertices,
                         const ShapeSums& shape);

// JSON text (keys: see tests/core/cli_test.cc and README.md).
std::string ReportToJson(const MetricsReport& r);
// {"distance": {"L1": {"forward", "backward", "max"}, "L2": ..., "Linf": ...}}: the block
// ReportToJson writes, alone (tandem measure --json).
std::string DistancesToJson(const Distances& d);
absl::StatusOr<MetricsReport> ReportFromJson(const std::string& json);
// A short human-readable summary, one figure per line.
std::string ReportSummary(const MetricsReport& r);

// Peak resident set size of this process in bytes (getrusage), 0 if unknown.
int64_t PeakRssBytes();

}  // namespace tandem

#endif  // TANDEM_REPORT_H_
