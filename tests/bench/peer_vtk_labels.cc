// The VTK peer of the segmentation benchmark: vtkDiscreteFlyingEdges3D (VTK 9) extracts each
// label's surface, then each label is simplified on its own:
//   peer_vtk_labels --input V.json --out DIR [--simplify none|qd|pro] [--keep F | --targets FILE]
//                   [--extract crop|all]
//   --simplify none   the full-resolution discrete flying-edges surfaces
//   --simplify qd     vtkQuadricDecimation per label (TargetReduction = 1 - target / extracted)
//   --simplify pro    vtkDecimatePro per label with PreserveTopology on (same target)
//   --keep F          target = F x the label's extracted triangles (default 0.1)
//   --targets FILE    lines "id triangles": per-label targets (labels not listed: --keep)
//   --extract crop    (default) one DiscreteFlyingEdges3D per label on its bounding box grown
//                     by one voxel: what a script meshing thousands of ids does, since the
//                     filter makes one pass over its whole input per contour value
//   --extract all     one DiscreteFlyingEdges3D with every label as a contour value
// Writes DIR/<id>.ply per label (binary PLY, as tandem) and prints bench_common's result line.
// Reads the raw + JSON sidecar (uint8/uint16/uint32) whole, as VTK needs.
#include <vtkCellArray.h>
#include <vtkDecimatePro.h>
#include <vtkDiscreteFlyingEdges3D.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkQuadricDecimation.h>
#include <vtkSmartPointer.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <unordered_map>

#include "bench_common.h"

namespace {

struct Volume {
  int dims[3] = {0, 0, 0};
  double spacing[3] = {1, 1, 1};
  int vtk_type = 0;
  size_t bytes = 0;
  std::vector<uint8_t> data;
  uint32_t At(size_t n) const {
    uint32_t x = 0;
    std::memcpy(&x, data.data() + n * bytes, bytes);  // little-endian host assumed
    return x;
  }
};

Volume ReadVolume(const std::string& json_path) {
  std::ifstream in(json_path);
  if (!in) bench::Die(json_path + ": cannot open");
  const nlohmann::json j = nlohmann::json::parse(in);
  Volume v;
  for (int a = 0; a < 3; ++a) {
    v.dims[a] = j.at("dims")[a];
    if (j.contains("spacing")) v.spacing[a] = j["spacing"][a];
  }
  const std::string dtype = j.at("dtype");
  if (dtype == "uint8") {
    v.vtk_type = VTK_UNSIGNED_CHAR;
    v.bytes = 1;
  } else if (dtype == "uint16") {
    v.vtk_type = VTK_UNSIGNED_SHORT;
    v.bytes = 2;
  } else if (dtype == "uint32") {
    v.vtk_type = VTK_UNSIGNED_INT;
    v.bytes = 4;
  } else
    bench::Die(json_path + ": label dtype " + dtype + " is not uint8, uint16 or uint32");
  std::filesystem::path raw = j.value("raw_file", std::string());
  if (raw.empty()) raw = std::filesystem::path(json_path).replace_extension(".raw").filename();
  raw = std::filesystem::path(json_path).parent_path() / raw;
  v.data.resize(v.bytes * size_t(v.dims[0]) * size_t(v.dims[1]) * size_t(v.dims[2]));
  FILE* f = std::fopen(raw.c_str(), "rb");
  if (f == nullptr) bench::Die(raw.string() + ": cannot open");
  const size_t got = std::fread(v.data.data(), 1, v.data.size(), f);
  std::fclose(f);
  if (got != v.data.size()) bench::Die(raw.string() + ": truncated");
  return v;
}

struct Box {
  uint32_t id = 0;
  int64_t voxels = 0;
  int lo[3] = {INT32_MAX, INT32_MAX, INT32_MAX}, hi[3] = {-1, -1, -1};
};

// Every label but 0 with its bounding box, in increasing id.
std::vector<Box> Boxes(const Volume& v) {
  std::unordered_map<uint32_t, size_t> slot;
  std::vector<Box> boxes;
  size_t n = 0;
  for (int k = 0; k < v.dims[2]; ++k) {
    for (int j = 0; j < v.dims[1]; ++j) {
      for (int i = 0; i < v.dims[0]; ++i, ++n) {
        const uint32_t id = v.At(n);
        if (id == 0) continue;
        auto [it, added] = slot.try_emplace(id, boxes.size());
        if (added) {
          boxes.emplace_back();
          boxes.back().id = id;
        }
        Box& b = boxes[it->second];
        ++b.voxels;
        const int c[3] = {i, j, k};
        for (int a = 0; a < 3; ++a) {
          b.lo[a] = std::min(b.lo[a], c[a]);
          b.hi[a] = std::max(b.hi[a], c[a]);
        }
      }
    }
  }
  std::sort(boxes.begin(), boxes.end(), [](const Box& a, const Box& b) { return a.id < b.id; });
  return boxes;
}

// The voxels of [lo, hi] (grown by one, clipped) as an image placed where they are.
vtkSmartPointer<vtkImageData> Crop(const Volume& v, const Box& b) {
  int lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::max(0, b.lo[a] - 1);
    hi[a] = std::min(v.dims[a] - 1, b.hi[a] + 1);
  }
  auto image = vtkSmartPointer<vtkImageData>::New();
  image->SetDimensions(hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1);
  image->SetSpacing(v.spacing);
  image->SetOrigin(lo[0] * v.spacing[0], lo[1] * v.spacing[1], lo[2] * v.spacing[2]);
  image->AllocateScalars(v.vtk_type, 1);
  auto* dst = static_cast<uint8_t*>(image->GetScalarPointer());
  const size_t row = size_t(hi[0] - lo[0] + 1) * v.bytes;
  for (int k = lo[2]; k <= hi[2]; ++k) {
    for (int j = lo[1]; j <= hi[1]; ++j) {
      const size_t src = ((size_t(k) * v.dims[1] + j) * v.dims[0] + lo[0]) * v.bytes;
      std::memcpy(dst, v.data.data() + src, row);
      dst += row;
    }
  }
  return image;
}

vtkSmartPointer<vtkImageData> Whole(const Volume& v) {
  auto image = vtkSmartPointer<vtkImageData>::New();
  image->SetDimensions(v.dims);
  image->SetSpacing(v.spacing);
  image->SetOrigin(0, 0, 0);
  image->AllocateScalars(v.vtk_type, 1);
  std::memcpy(image->GetScalarPointer(), v.data.data(), v.data.size());
  return image;
}

void Configure(vtkDiscreteFlyingEdges3D* fe) {
  fe->ComputeNormalsOff();
  fe->ComputeGradientsOff();
  fe->InterpolateAttributesOff();
}

// Point ids of the triangles of `pd`.
std::vector<std::array<vtkIdType, 3>> Triangles(vtkPolyData* pd) {
  std::vector<std::array<vtkIdType, 3>> tris;
  vtkCellArray* polys = pd->GetPolys();
  tris.reserve(size_t(polys->GetNumberOfCells()));
  vtkIdType n = 0;
  const vtkIdType* pts = nullptr;
  for (polys->InitTraversal(); polys->GetNextCell(n, pts);) {
    if (n != 3) bench::Die("non-triangle cell in VTK output");
    tris.push_back({pts[0], pts[1], pts[2]});
  }
  return tris;
}

// Float positions and indices of the triangles `tris` of `pd`, unreferenced points dropped.
// `remap` (one entry per point of pd, all kNone) is returned as it came.
constexpr uint32_t kNone = UINT32_MAX;
void ToArrays(vtkPolyData* pd, const std::vector<std::array<vtkIdType, 3>>& tris,
              std::vector<uint32_t>* remap, std::vector<float>* xyz,
              std::vector<uint32_t>* indices) {
  xyz->clear();
  indices->clear();
  std::vector<vtkIdType> used;
  remap->resize(size_t(pd->GetNumberOfPoints()), kNone);
  for (const auto& t : tris) {
    for (vtkIdType p : t) {
      uint32_t& to = (*remap)[size_t(p)];
      if (to == kNone) {
        to = uint32_t(xyz->size() / 3);
        used.push_back(p);
        double q[3];
        pd->GetPoint(p, q);
        for (double x : q) xyz->push_back(float(x));
      }
      indices->push_back(to);
    }
  }
  for (vtkIdType p : used) (*remap)[size_t(p)] = kNone;
}

void ToArrays(vtkPolyData* pd, std::vector<float>* xyz, std::vector<uint32_t>* indices) {
  std::vector<uint32_t> remap;
  ToArrays(pd, Triangles(pd), &remap, xyz, indices);
}

vtkSmartPointer<vtkPolyData> ToPolyData(const std::vector<float>& xyz,
                                        const std::vector<uint32_t>& indices) {
  vtkNew<vtkPoints> points;
  points->SetNumberOfPoints(vtkIdType(xyz.size() / 3));
  for (size_t i = 0; i < xyz.size() / 3; ++i)
    points->SetPoint(vtkIdType(i), xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
  vtkNew<vtkCellArray> cells;
  for (size_t t = 0; t < indices.size() / 3; ++t) {
    const vtkIdType tri[3] = {indices[3 * t], indices[3 * t + 1], indices[3 * t + 2]};
    cells->InsertNextCell(3, tri);
  }
  auto pd = vtkSmartPointer<vtkPolyData>::New();
  pd->SetPoints(points);
  pd->SetPolys(cells);
  return pd;
}

std::unordered_map<uint32_t, int64_t> ReadTargets(const std::string& path) {
  std::unordered_map<uint32_t, int64_t> t;
  std::ifstream in(path);
  if (!in) bench::Die(path + ": cannot open");
  uint64_t id = 0;
  int64_t count = 0;
  while (in >> id >> count) t[uint32_t(id)] = count;
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  auto flags = bench::ParseFlags(argc, argv);
  const std::string input = bench::Require(flags, "input");
  const std::filesystem::path out = bench::Require(flags, "out");
  const std::string mode = flags.count("simplify") ? flags["simplify"] : "none";
  const std::string extract = flags.count("extract") ? flags["extract"] : "crop";
  const double keep = flags.count("keep") ? std::stod(flags["keep"]) : 0.1;
  if (mode != "none" && mode != "qd" && mode != "pro") bench::Die("unknown --simplify " + mode);
  if (extract != "crop" && extract != "all") bench::Die("unknown --extract " + extract);
  std::unordered_map<uint32_t, int64_t> targets;
  if (flags.count("targets")) targets = ReadTargets(flags["targets"]);
  std::filesystem::create_directories(out);

  bench::Result r;
  r.pipeline = "vtk-dfe" + std::string(mode == "none" ? "" : "+" + mode) + " (" + extract + ")";
  bench::Clock clock;
  const Volume volume = ReadVolume(input);
  const std::vector<Box> boxes = Boxes(volume);
  r.read_s = clock.Lap();

  // --extract all: one filter, every label a contour value; its point scalars tell them apart.
  vtkSmartPointer<vtkPolyData> all;
  std::unordered_map<uint32_t, std::vector<std::array<vtkIdType, 3>>> tris_of;
  std::vector<uint32_t> remap;
  if (extract == "all") {
    vtkNew<vtkDiscreteFlyingEdges3D> fe;
    fe->SetInputData(Whole(volume));
    Configure(fe);
    fe->ComputeScalarsOn();
    fe->SetNumberOfContours(int(boxes.size()));
    for (size_t i = 0; i < boxes.size(); ++i) fe->SetValue(int(i), boxes[i].id);
    fe->Update();
    all = fe->GetOutput();
    vtkDataArray* label_of = all->GetPointData()->GetScalars();
    if (label_of == nullptr) bench::Die("DiscreteFlyingEdges3D gave no scalars");
    for (const auto& t : Triangles(all)) tris_of[uint32_t(label_of->GetTuple1(t[0]))].push_back(t);
    r.extract_s += clock.Lap();
  }

  std::vector<float> xyz;
  std::vector<uint32_t> indices;
  for (const Box& b : boxes) {
    if (extract == "all") {
      ToArrays(all, tris_of[b.id], &remap, &xyz, &indices);
    } else {
      vtkNew<vtkDiscreteFlyingEdges3D> fe;
      fe->SetInputData(Crop(volume, b));
      Configure(fe);
      fe->ComputeScalarsOff();
      fe->SetValue(0, b.id);
      fe->Update();
      ToArrays(fe->GetOutput(), &xyz, &indices);
    }
    const int64_t extracted = int64_t(indices.size() / 3);
    r.triangles_extracted += extracted;
    r.extract_s += clock.Lap();
    if (mode != "none" && extracted > 0) {
      auto it = targets.find(b.id);
      const double target =
          it != targets.end() ? double(it->second) : std::ceil(keep * double(extracted));
      const double reduction = std::clamp(1.0 - target / double(extracted), 0.0, 1.0);
      vtkSmartPointer<vtkPolyData> pd = ToPolyData(xyz, indices);
      vtkSmartPointer<vtkPolyData> simplified;
      if (mode == "qd") {
        vtkNew<vtkQuadricDecimation> qd;
        qd->SetInputData(pd);
        qd->SetTargetReduction(reduction);
        qd->VolumePreservationOff();
        qd->AttributeErrorMetricOff();
        qd->Update();
        simplified = qd->GetOutput();
      } else {
        vtkNew<vtkDecimatePro> pro;
        pro->SetInputData(pd);
        pro->SetTargetReduction(reduction);
        pro->PreserveTopologyOn();
        pro->SplittingOff();
        pro->BoundaryVertexDeletionOn();
        pro->Update();
        simplified = pro->GetOutput();
      }
      ToArrays(simplified, &xyz, &indices);
      r.simplify_s += clock.Lap();
    }
    r.triangles_final += int64_t(indices.size() / 3);
    r.vertices_final += int64_t(xyz.size() / 3);
    bench::WritePly((out / (std::to_string(b.id) + ".ply")).string(), xyz.data(), xyz.size() / 3,
                    indices.data(), indices.size());
    r.write_s += clock.Lap();
  }
  r.note = std::to_string(boxes.size()) + " labels";
  bench::PrintResult(r);
  return 0;
}
