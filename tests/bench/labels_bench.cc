// labels_bench: the segmentation benchmark's inputs and measures (labels_lib.h says what each
// measure is; tests/bench/labels.py runs it).
//   labels_bench voronoi --out V.json [--dims 256,256,64] [--spacing 4,4,40] [--cells 400]
//                [--background 0.1] [--wobble 0.3] [--elongation 4] [--seed 1] [--dtype uint32]
//   labels_bench ct-bands --input CT.json --out V.json --thresholds 60,120,200
//                [--min-voxels 64] [--max-labels 1000] [--seed 1] [--dtype uint32]
//   labels_bench reference --input V.json --out DIR    one PLY per label, <id>.ply
//   labels_bench measure --input V.json --method NAME=DIR[,FULLDIR] [--method ...] --out M.json
//                [--gap-samples 32] [--rms-samples 20000] [--margin 2] [--margin-length X]
//                [--threads 2]
// (--margin-length: the interface samples' margin as a length, per axis, when more voxels than
// --margin; labels_lib.h MarginFor)
// measure: for each method (a folder of <id>.ply, one surface per label), per label the RMS
// and Hausdorff distances to the label's reference surface (both directions, the larger) and,
// given FULLDIR (the method's own full-resolution surfaces), the RMS distance to those too and
// whether the label's Euler characteristic or number of components changed,
// its triangles and whether it is a manifold; per touching pair the gap at the pair's
// interface samples. Prints a summary and writes everything to M.json.
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_common.h"
#include "labels_lib.h"
#include "tandem/eval/distance.h"
#include "tandem/eval/topology.h"
#include "tandem/io/mesh_io.h"

namespace {

using labels::Fail;
using labels::LabelBox;
using labels::LabelVolume;

std::vector<double> Numbers(const std::string& csv) {
  std::vector<double> out;
  std::stringstream s(csv);
  std::string item;
  while (std::getline(s, item, ',')) out.push_back(std::stod(item));
  return out;
}

std::string Get(const std::map<std::string, std::string>& f, const std::string& k,
                const std::string& fallback) {
  auto it = f.find(k);
  return it == f.end() ? fallback : it->second;
}

uint32_t MaxId(const std::string& dtype) {
  const size_t bytes = labels::DTypeBytes(dtype);
  if (bytes == 0) Fail("--dtype must be uint8, uint16 or uint32");
  return bytes == 4 ? UINT32_MAX : uint32_t((uint64_t{1} << (8 * bytes)) - 1);
}

void Summarize(const std::string& what, const LabelVolume& v) {
  const auto boxes = labels::LabelBoxes(v);
  std::printf("%s: %lldx%lldx%lld, %zu labels\n", what.c_str(), (long long)v.nx, (long long)v.ny,
              (long long)v.nz, boxes.size());
}

int Voronoi(const std::map<std::string, std::string>& f) {
  labels::VoronoiOptions o;
  const auto dims = Numbers(Get(f, "dims", "256,256,64"));
  const auto spacing = Numbers(Get(f, "spacing", "4,4,40"));
  if (dims.size() != 3 || spacing.size() != 3) Fail("--dims and --spacing take 3 numbers");
  o.nx = int64_t(dims[0]);
  o.ny = int64_t(dims[1]);
  o.nz = int64_t(dims[2]);
  o.spacing = {spacing[0], spacing[1], spacing[2]};
  o.cells = std::stoi(Get(f, "cells", "400"));
  o.background_fraction = std::stod(Get(f, "background", "0.1"));
  o.wobble = std::stod(Get(f, "wobble", "0.3"));
  o.elongation = std::stod(Get(f, "elongation", "4"));
  o.seed = std::stoull(Get(f, "seed", "1"));
  const std::string dtype = Get(f, "dtype", "uint32");
  o.max_id = MaxId(dtype);
  const LabelVolume v = labels::MakeVoronoi(o);
  nlohmann::json extra = {
      {"description", "synthetic EM-like segmentation: bent Voronoi cells, scattered ids"},
      {"generated",
       {{"kind", "voronoi"},
        {"cells", o.cells},
        {"background", o.background_fraction},
        {"wobble", o.wobble},
        {"elongation", o.elongation},
        {"seed", o.seed}}}};
  labels::WriteLabelVolume(bench::Require(f, "out"), v, dtype, extra);
  Summarize(bench::Require(f, "out"), v);
  return 0;
}

int CtBands(const std::map<std::string, std::string>& f) {
  const std::string input = bench::Require(f, "input");
  const LabelVolume ct = labels::ReadLabelVolume(input);
  const auto thresholds = Numbers(bench::Require(f, "thresholds"));
  const std::string dtype = Get(f, "dtype", "uint32");
  const LabelVolume v = labels::BandComponents(
      ct, thresholds, std::stoll(Get(f, "min-voxels", "64")),
      std::stoull(Get(f, "max-labels", "1000")), MaxId(dtype), std::stoull(Get(f, "seed", "1")));
  nlohmann::json extra = {
      {"description", "bands of " + std::filesystem::path(input).filename().string() +
                          " split into 6-connected components, scattered ids"},
      {"generated",
       {{"kind", "ct-bands"},
        {"thresholds", thresholds},
        {"min_voxels", Get(f, "min-voxels", "64")}}}};
  labels::WriteLabelVolume(bench::Require(f, "out"), v, dtype, extra);
  Summarize(bench::Require(f, "out"), v);
  return 0;
}

int Reference(const std::map<std::string, std::string>& f) {
  const LabelVolume v = labels::ReadLabelVolume(bench::Require(f, "input"));
  const std::filesystem::path dir = bench::Require(f, "out");
  std::filesystem::create_directories(dir);
  for (const LabelBox& box : labels::LabelBoxes(v)) {
    const tandem::IndexedMesh mesh = labels::ReferenceSurface(v, box);
    const auto path = dir / (std::to_string(box.id) + ".ply");
    if (auto st = tandem::io::WriteMesh(path.string(), mesh); !st.ok())
      Fail(std::string(st.message()));
  }
  return 0;
}

// Runs fn(0..n-1) on `threads` workers.
template <typename Fn>
void ParallelFor(size_t n, int threads, Fn fn) {
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t i = next++; i < n; i = next++) fn(i);
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

struct LabelResult {
  bool found = false;
  size_t triangles = 0;
  double rms = NAN, hausdorff = NAN, rms_own = NAN;
  bool manifold = true;
  bool topology_changed = false;  // Euler characteristic or components unlike its own full res.
};

struct Method {
  std::string name;
  std::filesystem::path dir, full_dir;
  std::vector<LabelResult> per_label;
};

bool LoadSurface(const std::filesystem::path& dir, uint32_t id, tandem::IndexedMesh* mesh) {
  const auto path = dir / (std::to_string(id) + ".ply");
  if (!std::filesystem::exists(path)) return false;
  auto read = tandem::io::ReadMesh(path.string());
  if (!read.ok()) Fail(std::string(read.status().message()));
  *mesh = std::move(*read);
  return mesh->num_triangles() > 0;
}

double GeoMean(const std::vector<double>& xs) {
  if (xs.empty()) return NAN;
  double s = 0;
  for (double x : xs) s += std::log(std::max(x, 1e-12));
  return std::exp(s / double(xs.size()));
}

int Measure(int argc, char** argv) {
  std::map<std::string, std::string> f;
  std::vector<Method> methods;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (a.rfind("--", 0) != 0 || i + 1 >= argc) Fail("measure: expected --flag value pairs");
    const std::string value = argv[++i];
    if (a == "--method") {
      const size_t eq = value.find('=');
      if (eq == std::string::npos) Fail("--method takes NAME=DIR");
      const size_t comma = value.find(',', eq);
      Method m;
      m.name = value.substr(0, eq);
      m.dir = value.substr(eq + 1, comma == std::string::npos ? comma : comma - eq - 1);
      if (comma != std::string::npos) m.full_dir = value.substr(comma + 1);
      methods.push_back(std::move(m));
    } else {
      f[a.substr(2)] = value;
    }
  }
  const LabelVolume v = labels::ReadLabelVolume(bench::Require(f, "input"));
  const size_t gap_samples = std::stoull(Get(f, "gap-samples", "32"));
  const size_t rms_samples = std::stoull(Get(f, "rms-samples", "20000"));
  const labels::Margin margin = labels::MarginFor(v, std::stoi(Get(f, "margin", "2")),
                                                  std::stod(Get(f, "margin-length", "0")));
  const int threads = std::max(1, std::stoi(Get(f, "threads", "2")));

  const std::vector<LabelBox> boxes = labels::LabelBoxes(v);
  std::unordered_map<uint32_t, size_t> slot;
  for (size_t s = 0; s < boxes.size(); ++s) slot[boxes[s].id] = s;
  for (Method& m : methods) m.per_label.resize(boxes.size());
  std::vector<size_t> reference_triangles(boxes.size());

  // Per label: the reference surface, then each method's surface against it.
  ParallelFor(boxes.size(), threads, [&](size_t s) {
    const tandem::IndexedMesh ref = labels::ReferenceSurface(v, boxes[s]);
    reference_triangles[s] = ref.num_triangles();
    if (ref.num_triangles() == 0) return;
    const tandem::eval::TriangleBvh ref_bvh(ref);
    for (Method& m : methods) {
      tandem::IndexedMesh mesh;
      LabelResult& r = m.per_label[s];
      if (!LoadSurface(m.dir, boxes[s].id, &mesh)) continue;
      r.found = true;
      r.triangles = mesh.num_triangles();
      const tandem::eval::TopologyReport topology = tandem::eval::AnalyzeTopology(mesh);
      r.manifold = topology.IsManifold();
      tandem::eval::DistanceOptions opt;
      opt.threads = 1;
      opt.samples = std::clamp<size_t>(2 * mesh.num_triangles(), 1000, rms_samples);
      const auto fwd = tandem::eval::MeasureDirectedDistance(mesh, ref_bvh, opt);
      opt.samples = std::clamp<size_t>(2 * ref.num_triangles(), 1000, rms_samples);
      const auto bwd =
          tandem::eval::MeasureDirectedDistance(ref, tandem::eval::TriangleBvh(mesh), opt);
      r.rms = std::max(fwd.l2, bwd.l2);
      r.hausdorff = std::max(fwd.linf, bwd.linf);
      tandem::IndexedMesh full;
      if (m.full_dir.empty() || !LoadSurface(m.full_dir, boxes[s].id, &full)) continue;
      opt.samples = std::clamp<size_t>(2 * mesh.num_triangles(), 1000, rms_samples);
      const auto own_fwd =
          tandem::eval::MeasureDirectedDistance(mesh, tandem::eval::TriangleBvh(full), opt);
      opt.samples = std::clamp<size_t>(2 * full.num_triangles(), 1000, rms_samples);
      const auto own_bwd =
          tandem::eval::MeasureDirectedDistance(full, tandem::eval::TriangleBvh(mesh), opt);
      r.rms_own = std::max(own_fwd.l2, own_bwd.l2);
      const tandem::eval::TopologyReport full_topology = tandem::eval::AnalyzeTopology(full);
      r.topology_changed =
          topology.euler != full_topology.euler || topology.components != full_topology.components;
    }
  });

  const std::vector<labels::PairSamples> pairs = labels::InterfaceSamples(v, gap_samples, margin);
  size_t samples = 0, pairs_sampled = 0;
  for (const auto& p : pairs) {
    samples += p.points.size();
    pairs_sampled += !p.points.empty();
  }
  size_t ref_total = 0;
  for (size_t t : reference_triangles) ref_total += t;
  nlohmann::json out = {{"input", bench::Require(f, "input")},
                        {"labels", boxes.size()},
                        {"reference_triangles", ref_total},
                        {"pairs", pairs.size()},
                        {"pairs_sampled", pairs_sampled},
                        {"gap_samples", samples},
                        {"margin_voxels", {margin[0], margin[1], margin[2]}},
                        {"spacing", v.spacing},
                        {"methods", nlohmann::json::object()}};
  std::printf(
      "%zu labels, %zu reference triangles, %zu touching pairs (%zu sampled, %zu samples)\n",
      boxes.size(), ref_total, pairs.size(), pairs_sampled, samples);

  const double zero = 1e-6 * std::min({v.spacing[0], v.spacing[1], v.spacing[2]});
  const double reach = 0.5 * std::min({margin[0] * v.spacing[0], margin[1] * v.spacing[1],
                                       margin[2] * v.spacing[2]});
  for (Method& m : methods) {
    // The gap needs every surface of the method at once.
    std::vector<std::unique_ptr<tandem::eval::TriangleBvh>> bvh(boxes.size());
    ParallelFor(boxes.size(), threads, [&](size_t s) {
      tandem::IndexedMesh mesh;
      if (LoadSurface(m.dir, boxes[s].id, &mesh))
        bvh[s] = std::make_unique<tandem::eval::TriangleBvh>(mesh);
    });
    std::vector<double> pair_max(pairs.size(), NAN), pair_sum(pairs.size(), 0);
    std::vector<size_t> pair_zero(pairs.size(), 0), pair_n(pairs.size(), 0),
        pair_beyond(pairs.size(), 0);
    ParallelFor(pairs.size(), threads, [&](size_t p) {
      const auto& a = bvh[slot.at(pairs[p].a)];
      const auto& b = bvh[slot.at(pairs[p].b)];
      if (!a || !b || pairs[p].points.empty()) return;
      double mx = 0;
      for (const tandem::Vec3& q : pairs[p].points) {
        const std::optional<double> within = labels::GapWithin(*a, *b, q, reach);
        if (!within) {
          ++pair_beyond[p];
          continue;
        }
        const double g = *within;
        mx = std::max(mx, g);
        pair_sum[p] += g;
        pair_zero[p] += g <= zero;
        ++pair_n[p];
      }
      pair_max[p] = mx;
    });
    double gap_max = 0, gap_sum = 0;
    size_t gap_n = 0, gap_zero = 0, gap_beyond = 0;
    for (size_t p = 0; p < pairs.size(); ++p) {
      gap_beyond += pair_beyond[p];
      if (pair_n[p] == 0) continue;
      gap_max = std::max(gap_max, pair_max[p]);
      gap_sum += pair_sum[p];
      gap_n += pair_n[p];
      gap_zero += pair_zero[p];
    }

    std::vector<double> rms, rms_own;
    double rms_own_max = 0;
    double rms_max = 0, hausdorff_max = 0;
    uint32_t worst = 0;
    size_t found = 0, triangles = 0, nonmanifold = 0, topology_changed = 0;
    nlohmann::json per_label = nlohmann::json::array();
    for (size_t s = 0; s < boxes.size(); ++s) {
      const LabelResult& r = m.per_label[s];
      if (!r.found) continue;
      ++found;
      triangles += r.triangles;
      nonmanifold += !r.manifold;
      topology_changed += r.topology_changed;
      if (!std::isnan(r.rms)) {
        rms.push_back(r.rms);
        if (r.rms > rms_max) {
          rms_max = r.rms;
          worst = boxes[s].id;
        }
        hausdorff_max = std::max(hausdorff_max, r.hausdorff);
      }
      if (!std::isnan(r.rms_own)) {
        rms_own.push_back(r.rms_own);
        rms_own_max = std::max(rms_own_max, r.rms_own);
      }
      per_label.push_back(
          {boxes[s].id, r.triangles, reference_triangles[s], r.rms, r.hausdorff, r.rms_own});
    }
    const double gap_mean = gap_n ? gap_sum / double(gap_n) : NAN;
    out["methods"][m.name] = {{"dir", m.dir.string()},
                              {"labels_found", found},
                              {"labels_missing", boxes.size() - found},
                              {"triangles", triangles},
                              {"nonmanifold_labels", nonmanifold},
                              {"rms_geomean", GeoMean(rms)},
                              {"rms_max", rms_max},
                              {"rms_max_label", worst},
                              {"hausdorff_max", hausdorff_max},
                              {"rms_own_geomean", GeoMean(rms_own)},
                              {"rms_own_max", rms_own_max},
                              {"rms_own_labels", rms_own.size()},
                              {"topology_changed_labels", topology_changed},
                              {"gap_max", gap_max},
                              {"gap_mean", gap_mean},
                              {"gap_samples", gap_n},
                              {"gap_zero_samples", gap_zero},
                              {"gap_beyond_reach", gap_beyond},
                              {"per_label", per_label}};
    std::printf(
        "%-14s labels %zu/%zu  triangles %zu  rms geomean %.4g max %.4g (own full "
        "resolution: %.4g, %.4g)  gap max %.4g mean %.4g (%zu samples, %zu zero, %zu beyond reach) "
        " "
        "non-manifold %zu, topology changed %zu\n",
        m.name.c_str(), found, boxes.size(), triangles, GeoMean(rms), rms_max, GeoMean(rms_own),
        rms_own_max, gap_max, gap_mean, gap_n, gap_zero, gap_beyond, nonmanifold, topology_changed);
  }
  std::ofstream js(bench::Require(f, "out"));
  js << out.dump(1) << "\n";
  if (!js) Fail(bench::Require(f, "out") + ": write error");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string cmd = argc > 1 ? argv[1] : "";
  if (cmd == "measure") return Measure(argc, argv);
  const auto flags = bench::ParseFlags(argc - 1, argv + 1);
  if (cmd == "voronoi") return Voronoi(flags);
  if (cmd == "ct-bands") return CtBands(flags);
  if (cmd == "reference") return Reference(flags);
  std::fprintf(stderr,
               "usage: labels_bench voronoi|ct-bands|reference|measure ... (see the source)\n");
  return 2;
}
