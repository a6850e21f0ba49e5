// The figures of a label session's surfaces, one record per label (tandem/labels.h's
// SplitByLabel output): what `tandem extract --labels` prints and writes into --metrics.
#ifndef TANDEM_EVAL_LABEL_METRICS_H_
#define TANDEM_EVAL_LABEL_METRICS_H_

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "tandem/eval/report.h"
#include "tandem/labels.h"
#include "tandem/mesh.h"

namespace tandem::eval {

struct LabelMetrics {
  LabelId label = 0;
  std::string name;  // from --label-names, else empty
  int64_t triangles = 0, vertices = 0;
  double area = 0;
  // The volume the surface encloses (the divergence theorem over its triangles), when it is
  // closed; 0 and meaningless otherwise (`closed` says which).
  double volume = 0;
  int64_t euler = 0;  // V - E + F (2 per sphere, 0 per torus)
  int64_t components = 0;
  bool manifold = false;  // an oriented 2-manifold, with boundary or not
  bool closed = false;    // manifold and without boundary
};

// One surface's figures (AnalyzeTopology, SurfaceArea and the enclosed volume).
LabelMetrics MeasureLabel(LabelId label, const IndexedMesh& mesh);

// JSON array text: one object per label, {"label": id (a string when past 2^53, where
// JavaScript's numbers end), "name", "triangles", "vertices", "area", "volume" (null
// when open), "euler", "components", "manifold", "closed"}.
std::string LabelMetricsToJson(const std::vector<LabelMetrics>& labels);
// ReportToJson(report) with the labels' array added as "labels" (the --metrics file of a
// label run).
std::string ReportWithLabelsToJson(const MetricsReport& report,
                                   const std::vector<LabelMetrics>& labels);
// A short table for people, one line per label.
std::string LabelMetricsSummary(const std::vector<LabelMetrics>& labels);

}  // namespace tandem::eval

#endif  // TANDEM_EVAL_LABEL_METRICS_H_
