#include "tandem/eval/report.h"

#include <sys/resource.h>

#include <cstdio>
#include <tuple>
#include <type_traits>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/eval/metrics.h"
#include "tandem/status_macros.h"

namespace tandem::eval {
MetricsReport MakeReport(const TandemSession& session, const IndexedMesh& mesh) {
  ShapeSums shape;
  shape.Add(mesh);
  return MakeReport(session, static_cast<int64_t>(mesh.num_triangles()),
                    static_cast<int64_t>(mesh.num_vertices()), shape);
}

MetricsReport MakeReport(const TandemSession& session, int64_t triangles, int64_t vertices,
                         const ShapeSums& shape) {
  MetricsReport r;
  r.options = session.options();
  r.stats = session.stats();
  r.frame = std::string(SpaceName(session.grid().space));
  r.frame_text = session.grid().frame;
  r.nx = session.grid().nx;
  r.ny = session.grid().ny;
  r.nz = r.stats.slices;
  r.triangles_final = triangles;
  r.vertices_final = vertices;
  r.error_max = session.MaxShapeError();
  r.anisotropy = shape.anisotropy();
  r.directional_bias = shape.directional_bias();
  return r;
}

namespace {
nlohmann::json DistanceJson(const Distances& d) {
  nlohmann::json dist;
  for (auto [name, f, b, m] : {std::tuple{"L1", d.forward.l1, d.backward.l1, d.l1_max},
                               std::tuple{"L2", d.forward.l2, d.backward.l2, d.l2_max},
                               std::tuple{"Linf", d.forward.linf, d.backward.linf, d.linf_max}}) {
    dist[name] = {{"forward", f}, {"backward", b}, {"max", m}};
  }
  return dist;
}
}  // namespace

std::string DistancesToJson(const Distances& d) {
  nlohmann::json j;
  j["distance"] = DistanceJson(d);
  return j.dump(1) + "\n";
}

namespace {
using Json = nlohmann::json;

void PutJson(Json& j, const Json::json_pointer& key, const std::optional<Distances>& d) {
  if (d) j[key] = DistanceJson(*d);
}
void PutJson(Json& j, const Json::json_pointer& key, Schedule s) {
  j[key] = std::string(ScheduleName(s));
}
template <class T>
void PutJson(Json& j, const Json::json_pointer& key, const T& v) {
  j[key] = v;
}

absl::Status GetJson(const Json& v, std::optional<Distances>* out) {
  Distances d;
  d.forward = {v["L1"]["forward"], v["L2"]["forward"], v["Linf"]["forward"]};
  d.backward = {v["L1"]["backward"], v["L2"]["backward"], v["Linf"]["backward"]};
  d.l1_max = v["L1"]["max"];
  d.l2_max = v["L2"]["max"];
  d.linf_max = v["Linf"]["max"];
  *out = d;
  return absl::OkStatus();
}
absl::Status GetJson(const Json& v, Schedule* out) {
  TANDEM_ASSIGN_OR_RETURN(Schedule s, ParseSchedule(v.get<std::string>()));
  *out = s;
  return absl::OkStatus();
}
template <class T>
absl::Status GetJson(const Json& v, T* out) {
  v.get_to(*out);
  return absl::OkStatus();
}
}  // namespace

std::string ReportToJson(const MetricsReport& r) {
  Json j;
  VisitReportFields(r, [&](const char* key, const char* /*wire*/, const auto& v, Written when) {
    if constexpr (std::is_arithmetic_v<std::remove_cvref_t<decltype(v)>>) {
      if (when == Written::kIfNonZero && v == 0) return;
    }
    if (when == Written::kIfService && !HasServiceBytes(r)) return;
    PutJson(j, Json::json_pointer(key), v);  // kIfPresent: PutJson of an optional
  });
  return j.dump(1) + "\n";
}

absl::StatusOr<MetricsReport> ReportFromJson(const std::string& json) {
  Json j = Json::parse(json, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) {
    return absl::InvalidArgumentError("metrics: not a JSON object");
  }
  MetricsReport r;
  absl::Status status;
  try {
    // A field the JSON does not hold keeps its default.
    VisitReportFields(r, [&](const char* key, const char* /*wire*/, auto& v, Written) {
      const Json::json_pointer at(key);
      if (status.ok() && j.contains(at)) status = GetJson(j.at(at), &v);
    });
  } catch (const Json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("metrics: ", e.what()));
  }
  if (!status.ok()) return absl::InvalidArgumentError(absl::StrCat("metrics: ", status.message()));
  return r;
}

std::string ReportSummary(const MetricsReport& r) {
  std::string s;
  auto line = [&s](const std::string& k, const std::string& v) {
    absl::StrAppend(&s, absl::StrFormat("  %-22s %s\n", k, v));
  };
  line("schedule", std::string(ScheduleName(r.options.schedule)));
  line("grid", absl::StrCat(r.nx, " x ", r.ny, " x ", r.nz));
  line("triangles extracted", absl::StrCat(r.stats.triangles_extracted));
  line("triangles final", absl::StrCat(r.triangles_final, " (", r.vertices_final, " vertices)"));
  const int64_t target = r.options.target_triangles;
  if (target > 0 && r.options.schedule != Schedule::kNone) {
    // Contractions never remove a component or a handle: a surface made of many small pieces
    // keeps some triangles each, at any E0.
    // Below it: the first E0 (at most 1/1000 of the smallest spacing, or --error when smaller)
    // already simplified further (docs/decisions.md 23).
    line("target", r.triangles_final > target
                       ? absl::StrCat(target, " NOT reached: no contraction the checks allow is "
                                              "left (components and handles stay)")
                   : r.triangles_final < target * 99 / 100
                       ? absl::StrCat(target, " NOT reached: the first E0 kept fewer; a smaller "
                                              "E0 (--error) starts lower")
                       : absl::StrCat(target, " reached"));
  }
  line("peak triangles held", absl::StrCat(r.stats.peak_triangles));
  if (r.options.schedule != Schedule::kNone) {
    if (r.options.target_triangles > 0) {  // E0 rose from a small start toward the count
      line("Error(K)", absl::StrFormat("%.6g (E0 reached %.6g for the target)", r.error_max,
                                       r.stats.error_reached));
    } else {
      line("Error(K)", absl::StrFormat("%.6g (E0 = %.6g)", r.error_max, r.options.error));
    }
  }
  line("anisotropy", absl::StrFormat("%.4f", r.anisotropy));
  line("directional bias", absl::StrFormat("%.5f", r.directional_bias));
  // The phases' figures add up the time of every thread that ran them (CPU seconds); the
  // total is wall-clock time in the session, which the threads overlap.
  const PhaseTimes& t = r.stats.time;
  line("wall time in session", absl::StrFormat("%.3f s", t.total_s));
  line("CPU extract/simplify",
       absl::StrFormat("%.3f s / %.3f s (all threads)", t.extract_s, t.simplify_s));
  if (r.peak_session_bytes) {
    // Through a server: the session's own peak, and the process's, which all sessions share.
    line("peak session memory", absl::StrFormat("%.1f MiB", r.peak_session_bytes / 1048576.0));
    if (r.peak_rss_bytes) {
      line("server peak RSS", absl::StrFormat("%.1f MiB (the whole process, all sessions)",
                                              r.peak_rss_bytes / 1048576.0));
    }
  } else if (r.peak_rss_bytes) {
    line("peak RSS", absl::StrFormat("%.1f MiB", r.peak_rss_bytes / 1048576.0));
  }
  const RefusalCounts& no = r.stats.refusals;
  line("contractions", absl::StrCat(r.stats.contractions, " (refused: link ", no.link, ", flip ",
                                    no.flip, ", degenerate ", no.degenerate, ", box ", no.box,
                                    ", error ", no.error, ", distance ", no.distance, ")"));
  if (r.options.sag_correction > 0) {
    line("sag correction",
         absl::StrFormat("%g: %d vertices moved", r.options.sag_correction, r.stats.sag_corrected));
  }
  if (r.distance) {
    const Distances& d = *r.distance;
    line("distance L1/L2/Linf", absl::StrFormat("%.4g / %.4g / %.4g", d.l1_max, d.l2_max, d.linf_max));
  }
  if (HasServiceBytes(r)) {
    line("bytes received/sent", absl::StrCat(r.bytes_received, " / ", r.bytes_sent));
  }
  return s;
}

int64_t PeakRssBytes() {
  struct rusage ru;
  if (getrusage(RUSAGE_SELF, &ru) != 0) return 0;
  return static_cast<int64_t>(ru.ru_maxrss) * 1024;  // Linux reports KiB
}

}  // namespace tandem::eval
