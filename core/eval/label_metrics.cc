// Per-label figures of a label session's surfaces (tandem/eval/label_metrics.h).
#include "tandem/eval/label_metrics.h"

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "nlohmann/json.hpp"
#include "tandem/eval/metrics.h"
#include "tandem/eval/topology.h"

namespace tandem::eval {

LabelMetrics MeasureLabel(LabelId label, const IndexedMesh& mesh) {
  LabelMetrics m;
  m.label = label;
  const TopologyReport topo = AnalyzeTopology(mesh);
  m.triangles = static_cast<int64_t>(mesh.num_triangles());
  m.vertices = static_cast<int64_t>(topo.vertices);
  m.area = SurfaceArea(mesh);
  m.euler = topo.euler;
  m.components = static_cast<int64_t>(topo.components);
  m.manifold = topo.IsManifold();
  m.closed = topo.IsClosedManifold() && mesh.num_triangles() > 0;
  if (m.closed) {
    // Σ a · (b × c) / 6 over counter-clockwise triangles, relative to the first vertex so
    // that far-off coordinates do not cancel digits.
    const Vec3 o = mesh.positions[mesh.indices[0]];
    double six = 0;
    for (size_t t = 0; t < mesh.num_triangles(); ++t) {
      const uint32_t* tri = &mesh.indices[3 * t];
      six += Dot(mesh.positions[tri[0]] - o,
                 Cross(mesh.positions[tri[1]] - o, mesh.positions[tri[2]] - o));
    }
    m.volume = six / 6.0;
  }
  return m;
}

namespace {

nlohmann::ordered_json LabelJson(const LabelMetrics& m) {
  constexpr LabelId kExactInJs = LabelId{1} << 53;
  nlohmann::ordered_json j;
  if (m.label < kExactInJs) {
    j["label"] = m.label;
  } else {
    j["label"] = absl::StrCat(m.label);
  }
  j["name"] = m.name;
  j["triangles"] = m.triangles;
  j["vertices"] = m.vertices;
  j["area"] = m.area;
  j["volume"] = m.closed ? nlohmann::ordered_json(m.volume) : nlohmann::ordered_json(nullptr);
  j["euler"] = m.euler;
  j["components"] = m.components;
  j["manifold"] = m.manifold;
  j["closed"] = m.closed;
  return j;
}

nlohmann::ordered_json LabelsJson(const std::vector<LabelMetrics>& labels) {
  nlohmann::ordered_json a = nlohmann::ordered_json::array();
  for (const LabelMetrics& m : labels) a.push_back(LabelJson(m));
  return a;
}

}  // namespace

std::string LabelMetricsToJson(const std::vector<LabelMetrics>& labels) {
  return LabelsJson(labels).dump(1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

std::string ReportWithLabelsToJson(const MetricsReport& report,
                                   const std::vector<LabelMetrics>& labels) {
  using Json = nlohmann::ordered_json;
  Json j = Json::parse(ReportToJson(report));
  j["labels"] = Json::array();
  std::string s = j.dump(1, ' ', false, Json::error_handler_t::replace);
  if (labels.empty()) return s + "\n";
  // The labels one at a time, indented as inside the whole tree: as one tree, a million
  // labels' figures held gigabytes.
  s.resize(s.size() - 3);  // "]\n}" off: the text ends in "labels": [
  for (size_t i = 0; i < labels.size(); ++i) {
    const std::string item =
        LabelJson(labels[i]).dump(1, ' ', false, Json::error_handler_t::replace);
    absl::StrAppend(&s, i == 0 ? "\n  " : ",\n  ", absl::StrReplaceAll(item, {{"\n", "\n  "}}));
  }
  return s + "\n ]\n}\n";
}

std::string LabelMetricsSummary(const std::vector<LabelMetrics>& labels) {
  std::string s = absl::StrFormat("  %-20s %10s %12s %12s %6s %5s  %s\n", "label", "triangles",
                                  "area", "volume", "euler", "comp", "surface");
  for (const LabelMetrics& m : labels) {
    std::string label = m.name.empty() ? absl::StrCat(m.label) : absl::StrCat(m.label, " ", m.name);
    if (label.size() > 20) label = label.substr(0, 19) + "~";
    s += absl::StrFormat("  %-20s %10d %12.6g %12s %6d %5d  %s\n", label, m.triangles, m.area,
                         m.closed ? absl::StrFormat("%.6g", m.volume) : std::string("-"), m.euler,
                         m.components,
                         m.closed     ? "closed"
                         : m.manifold ? "open (at the volume's border)"
                                      : "NOT a manifold");
  }
  return s;
}

}  // namespace tandem::eval
