#include "tandem/report.h"

#include <sys/resource.h>

#include <cstdio>
#include <tuple>

#include <nlohmann/json.hpp>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "tandem/metrics.h"

namespace tandem {
MetricsReport MakeReport(const TandemSession& session, const IndexedMesh& mesh) {
  ShapeSums shape;
  shape.Add(mesh);
  return MakeReport(session, static_cast<int64_t>(mesh.num_triangles()),
                    static_cast<int64_t>(mesh.num_vertices()), shape);
}

MetricsReport MakeReport(const TandemSession& session, int64_t triangles, int64_t vertices,
                         const ShapeSums& shape) {
  MetricsReport r;
  const SessionStats& st = session.stats();
  const SessionOptions& o = session.options();
  r.schedule = std::string(ScheduleName(o.schedule));
  r.iso = o.iso;
  r.error_threshold = o.error;
  r.alpha = o.alpha;
  r.distance_guard = o.distance_guard;
  r.sag_correction = o.sag_correction;
  r.sag_corrected = st.sag_corrected;
  r.target_triangles = o.target_triangles;
  r.nx = session.grid().nx;
  r.ny = session.grid().ny;
  r.nz = st.slices;
  r.slices = st.slices;
  r.crossed_cubes = st.crossed_cubes;
  r.triangles_extracted = st.triangles_extracted;
  r.triangles_final = triangles;
  r.vertices_final = vertices;
  r.peak_triangles = st.peak_triangles;
  r.error_max = session.MaxShapeError();
  r.anisotropy = shape.anisotropy();
  r.directional_bias = shape.directional_bias();
  r.time_extract_s = st.time.extract_s;
  r.time_simplify_s = st.time.simplify_s;
  r.time_total_s = st.time.total_s;
  r.trace = st.trace;
  r.refusals = st.refusals;
  r.contractions = st.contractions;
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

std::string ReportToJson(const MetricsReport& r) {
  nlohmann::json j;
  j["input"] = r.input;
  j["frame"] = r.frame;
  j["schedule"] = r.schedule;
  j["iso"] = r.iso;
  j["error_threshold"] = r.error_threshold;
  j["alpha"] = r.alpha;
  j["distance_guard"] = r.distance_guard;
  j["sag_correction"] = r.sag_correction;
  j["sag_corrected"] = r.sag_corrected;
  j["target_triangles"] = r.target_triangles;
  j["grid"] = {r.nx, r.ny, r.nz};
  j["slices"] = r.slices;
  j["crossed_cubes"] = r.crossed_cubes;
  j["triangles_extracted"] = r.triangles_extracted;
  j["triangles_final"] = r.triangles_final;
  j["vertices_final"] = r.vertices_final;
  j["peak_triangles"] = r.peak_triangles;
  j["error_max"] = r.error_max;
  j["anisotropy"] = r.anisotropy;
  j["directional_bias"] = r.directional_bias;
  j["time_s"] = {{"extract", r.time_extract_s}, {"simplify", r.time_simplify_s},
                 {"total", r.time_total_s}};
  j["peak_rss_bytes"] = r.peak_rss_bytes;
  j["trace"] = r.trace;
  j["contractions"] = r.contractions;
  j["refusals"] = {{"link", r.refusals.link},         {"flip", r.refusals.flip},
                   {"degenerate", r.refusals.degenerate}, {"box", r.refusals.box},
                   {"error", r.refusals.error},           {"distance", r.refusals.distance}};
  if (r.distance) j["distance"] = DistanceJson(*r.distance);
  if (r.bytes_received || r.bytes_sent) {
    j["bytes_received"] = r.bytes_received;
    j["bytes_sent"] = r.bytes_sent;
  }
  if (r.peak_session_bytes) j["peak_session_bytes"] = r.peak_session_bytes;
  return j.dump(1) + "\n";
}

absl::StatusOr<MetricsReport> ReportFromJson(const std::string& json) {
  nlohmann::json j = nlohmann::json::parse(json, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) {
    return absl::InvalidArgumentError("metrics: not a JSON object");
  }
  MetricsReport r;
  try {
    r.input = j.value("input", "");
    r.frame = j.value("frame", "");
    r.schedule = j.value("schedule", "");
    r.iso = j.value("iso", 0.0);
    r.error_threshold = j.value("error_threshold", 0.0);
    r.alpha = j.value("alpha", 0.0);
    r.distance_guard = j.value("distance_guard", 0.0);
    r.sag_correction = j.value("sag_correction", 0.0);
    r.sag_corrected = j.value("sag_corrected", int64_t{0});
    r.target_triangles = j.value("target_triangles", int64_t{0});
    if (j.contains("grid") && j["grid"].size() == 3) {
      r.nx = j["grid"][0];
      r.ny = j["grid"][1];
      r.nz = j["grid"][2];
    }
    r.slices = j.value("slices", int64_t{0});
    r.crossed_cubes = j.value("crossed_cubes", int64_t{0});
    r.triangles_extracted = j.value("triangles_extracted", int64_t{0});
    r.triangles_final = j.value("triangles_final", int64_t{0});
    r.vertices_final = j.value("vertices_final", int64_t{0});
    r.peak_triangles = j.value("peak_triangles", int64_t{0});
    r.error_max = j.value("error_max", 0.0);
    r.anisotropy = j.value("anisotropy", 0.0);
    r.directional_bias = j.value("directional_bias", 0.0);
    if (j.contains("time_s")) {
      r.time_extract_s = j["time_s"].value("extract", 0.0);
      r.time_simplify_s = j["time_s"].value("simplify", 0.0);
      r.time_total_s = j["time_s"].value("total", 0.0);
    }
    r.peak_rss_bytes = j.value("peak_rss_bytes", int64_t{0});
    r.trace = j.value("trace", std::vector<int64_t>{});
    r.contractions = j.value("contractions", int64_t{0});
    if (j.contains("refusals")) {
      const auto& f = j["refusals"];
      r.refusals.link = f.value("link", int64_t{0});
      r.refusals.flip = f.value("flip", int64_t{0});
      r.refusals.degenerate = f.value("degenerate", int64_t{0});
      r.refusals.box = f.value("box", int64_t{0});
      r.refusals.error = f.value("error", int64_t{0});
      r.refusals.distance = f.value("distance", int64_t{0});
    }
    if (j.contains("distance")) {
      const auto& d = j["distance"];
      Distances dd;
      dd.forward = {d["L1"]["forward"], d["L2"]["forward"], d["Linf"]["forward"]};
      dd.backward = {d["L1"]["backward"], d["L2"]["backward"], d["Linf"]["backward"]};
      dd.l1_max = d["L1"]["max"];
      dd.l2_max = d["L2"]["max"];
      dd.linf_max = d["Linf"]["max"];
      r.distance = dd;
    }
    r.bytes_received = j.value("bytes_received", int64_t{0});
    r.bytes_sent = j.value("bytes_sent", int64_t{0});
    r.peak_session_bytes = j.value("peak_session_bytes", int64_t{0});
  } catch (const nlohmann::json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("metrics: ", e.what()));
  }
  return r;
}

std::string ReportSummary(const MetricsReport& r) {
  std::string s;
  auto line = [&s](const std::string& k, const std::string& v) {
    absl::StrAppend(&s, absl::StrFormat("  %-22s %s\n", k, v));
  };
  line("schedule", r.schedule);
  line("grid", absl::StrCat(r.nx, " x ", r.ny, " x ", r.nz));
  line("triangles extracted", absl::StrCat(r.triangles_extracted));
  line("triangles final", absl::StrCat(r.triangles_final, " (", r.vertices_final, " vertices)"));
  line("peak triangles held", absl::StrCat(r.peak_triangles));
  if (r.schedule != "none") {
    line("Error(K)", absl::StrFormat("%.6g (E0 = %.6g)", r.error_max, r.error_threshold));
  }
  line("anisotropy", absl::StrFormat("%.4f", r.anisotropy));
  line("directional bias", absl::StrFormat("%.5f", r.directional_bias));
  // The phases' figures add up the time of every thread that ran them (CPU seconds); the
  // total is wall-clock time in the session, which the threads overlap.
  line("wall time in session", absl::StrFormat("%.3f s", r.time_total_s));
  line("CPU extract/simplify", absl::StrFormat("%.3f s / %.3f s (all threads)", r.time_extract_s,
                                               r.time_simplify_s));
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
  line("contractions", absl::StrCat(r.contractions, " (refused: link ", r.refusals.link, ", flip ",
                                    r.refusals.flip, ", degenerate ", r.refusals.degenerate,
                                    ", box ", r.refusals.box, ", error ", r.refusals.error,
                                    ", distance ", r.refusals.distance, ")"));
  if (r.sag_correction > 0) {
    line("sag correction",
         absl::StrFormat("%g: %d vertices moved", r.sag_correction, r.sag_corrected));
  }
  if (r.distance) {
    const Distances& d = *r.distance;
    line("distance L1/L2/Linf", absl::StrFormat("%.4g / %.4g / %.4g", d.l1_max, d.l2_max, d.linf_max));
  }
  if (r.bytes_received || r.bytes_sent) {
    line("bytes received/sent", absl::StrCat(r.bytes_received, " / ", r.bytes_sent));
  }
  return s;
}

int64_t PeakRssBytes() {
  struct rusage ru;
  if (getrusage(RUSAGE_SELF, &ru) != 0) return 0;
  return static_cast<int64_t>(ru.ru_maxrss) * 1024;  // Linux reports KiB
}

}  // namespace tandem
