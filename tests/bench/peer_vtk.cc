// VTK peers: vtkFlyingEdges3D (VTK 9) on the volume, then one of
//   --simplify none      the full-resolution FlyingEdges3D surface
//   --simplify vtkqd     vtkCleanPolyData (exact point merge, drops degenerate cells) +
//                        vtkQuadricDecimation with TargetReduction = 1 - N / extracted
//   --simplify meshopt   meshopt_simplify to N triangles (only when built with meshoptimizer;
//                        this is "the fastest existing pipeline")
//   peer_vtk --input V.json --iso C0 --simplify MODE [--target-triangles N] --out M.ply
//   peer_vtk --modes     prints the modes this build supports
//   peer_vtk --meshopt-version   prints MESHOPTIMIZER_VERSION of the build (1020 = 1.2), or 0
// tests/bench/CMakeLists.txt compiles this file twice: peer_vtk against Debian's
// meshoptimizer, peer_vtk_meshopt_upstream against the upstream source (same settings).
// The volume is read from the same raw + JSON sidecar files as tandem reads, whole, into a
// vtkImageData of the file's own voxel type (FlyingEdges3D needs the whole volume).
// FlyingEdges3D runs with VTK's default SMP backend (TBB on Debian, all cores).
#include <vtkCellArray.h>
#include <vtkCleanPolyData.h>
#include <vtkFlyingEdges3D.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkQuadricDecimation.h>
#include <vtkSmartPointer.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "bench_common.h"
#ifdef BENCH_HAVE_MESHOPT
#include <meshoptimizer.h>
#endif

namespace {

vtkSmartPointer<vtkImageData> ReadVolume(const std::string& json_path) {
  std::ifstream in(json_path);
  if (!in) bench::Die(json_path + ": cannot open");
  const nlohmann::json j = nlohmann::json::parse(in);
  const auto dims = j.at("dims").get<std::vector<int>>();
  const auto spacing = j.value("spacing", std::vector<double>{1, 1, 1});
  const auto origin = j.value("origin", std::vector<double>{0, 0, 0});
  const std::string dtype = j.at("dtype").get<std::string>();
  std::filesystem::path raw = j.value("raw_file", std::string());
  if (raw.empty()) raw = std::filesystem::path(json_path).replace_extension(".raw").filename();
  raw = std::filesystem::path(json_path).parent_path() / raw;

  int vtk_type = 0;
  size_t size = 0;
  if (dtype == "uint8") { vtk_type = VTK_UNSIGNED_CHAR; size = 1; }
  else if (dtype == "uint16") { vtk_type = VTK_UNSIGNED_SHORT; size = 2; }
  else if (dtype == "int16") { vtk_type = VTK_SHORT; size = 2; }
  else if (dtype == "float32") { vtk_type = VTK_FLOAT; size = 4; }
  else bench::Die(json_path + ": unsupported dtype " + dtype);

  auto image = vtkSmartPointer<vtkImageData>::New();
  image->SetDimensions(dims[0], dims[1], dims[2]);
  image->SetSpacing(spacing[0], spacing[1], spacing[2]);
  image->SetOrigin(origin[0], origin[1], origin[2]);
  image->AllocateScalars(vtk_type, 1);
  const size_t bytes = size * size_t(dims[0]) * size_t(dims[1]) * size_t(dims[2]);
  FILE* f = std::fopen(raw.c_str(), "rb");
  if (f == nullptr) bench::Die(raw.string() + ": cannot open");
  const size_t got = std::fread(image->GetScalarPointer(), 1, bytes, f);
  std::fclose(f);
  if (got != bytes) bench::Die(raw.string() + ": truncated");  // little-endian host assumed
  return image;
}

// Float positions and a 32-bit index buffer of a triangle-only vtkPolyData.
void ToArrays(vtkPolyData* pd, std::vector<float>* xyz, std::vector<uint32_t>* indices) {
  const vtkIdType np = pd->GetNumberOfPoints();
  xyz->resize(3 * size_t(np));
  for (vtkIdType i = 0; i < np; ++i) {
    double p[3];
    pd->GetPoint(i, p);
    for (int c = 0; c < 3; ++c) (*xyz)[3 * size_t(i) + c] = static_cast<float>(p[c]);
  }
  vtkCellArray* polys = pd->GetPolys();
  indices->clear();
  indices->reserve(3 * size_t(polys->GetNumberOfCells()));
  vtkIdType n = 0;
  const vtkIdType* pts = nullptr;
  for (polys->InitTraversal(); polys->GetNextCell(n, pts);) {
    if (n != 3) bench::Die("non-triangle cell in VTK output");
    for (int c = 0; c < 3; ++c) indices->push_back(static_cast<uint32_t>(pts[c]));
  }
}

}  // namespace

int main(int argc, char** argv) {
  auto flags = bench::ParseFlags(argc, argv);
  if (flags.count("modes")) {
#ifdef BENCH_HAVE_MESHOPT
    std::puts("none vtkqd meshopt");
#else
    std::puts("none vtkqd");
#endif
    return 0;
  }
  if (flags.count("meshopt-version")) {
#ifdef BENCH_HAVE_MESHOPT
    std::printf("%d\n", MESHOPTIMIZER_VERSION);
#else
    std::puts("0");
#endif
    return 0;
  }
  const std::string input = bench::Require(flags, "input");
  const double iso = std::stod(bench::Require(flags, "iso"));
  const std::string mode = bench::Require(flags, "simplify");
  const std::string out = bench::Require(flags, "out");
  long long target = 0;
  if (mode != "none") target = std::stoll(bench::Require(flags, "target-triangles"));
#ifndef BENCH_HAVE_MESHOPT
  if (mode == "meshopt") bench::Die("peer_vtk was built without meshoptimizer");
#endif
  if (mode != "none" && mode != "vtkqd" && mode != "meshopt") bench::Die("unknown --simplify " + mode);

  bench::Result r;
  r.pipeline = mode == "none" ? "fe3d" : "fe3d+" + mode;
  bench::Clock clock;
  vtkSmartPointer<vtkImageData> image = ReadVolume(input);
  r.read_s = clock.Lap();

  vtkNew<vtkFlyingEdges3D> fe;
  fe->SetInputData(image);
  fe->SetValue(0, iso);
  fe->ComputeNormalsOff();
  fe->ComputeGradientsOff();
  fe->ComputeScalarsOff();
  fe->InterpolateAttributesOff();
  fe->Update();
  vtkSmartPointer<vtkPolyData> surface = fe->GetOutput();
  image = nullptr;  // the pipeline still references it; freed with `fe` below
  r.extract_s = clock.Lap();
  r.triangles_extracted = surface->GetNumberOfPolys();

  std::vector<float> xyz;
  std::vector<uint32_t> indices;
  if (mode == "vtkqd") {
    vtkNew<vtkCleanPolyData> clean;  // VTK's decimation stalls on unmerged/degenerate input
    clean->SetInputData(surface);
    clean->PointMergingOn();
    clean->SetTolerance(0.0);
    clean->ConvertLinesToPointsOff();
    clean->ConvertPolysToLinesOff();
    clean->ConvertStripsToPolysOff();
    vtkNew<vtkQuadricDecimation> qd;
    qd->SetInputConnection(clean->GetOutputPort());
    const double ratio = 1.0 - double(target) / double(std::max<int64_t>(1, r.triangles_extracted));
    qd->SetTargetReduction(std::max(0.0, ratio));
    qd->VolumePreservationOff();
    qd->AttributeErrorMetricOff();
    qd->Update();
    ToArrays(qd->GetOutput(), &xyz, &indices);
    r.simplify_s = clock.Lap();
  } else {
    ToArrays(surface, &xyz, &indices);
    surface = nullptr;
    fe->GetOutput()->Initialize();
#ifdef BENCH_HAVE_MESHOPT
    if (mode == "meshopt") {
      std::vector<uint32_t> simplified(indices.size());
      float result_error = 0;
      const size_t n = meshopt_simplify(simplified.data(), indices.data(), indices.size(),
                                        xyz.data(), xyz.size() / 3, 3 * sizeof(float),
                                        3 * size_t(target), 1.0f, 0, &result_error);
      simplified.resize(n);
      indices.swap(simplified);
      bench::CompactVertices(&xyz, &indices);
      r.simplify_s = clock.Lap();
    }
#endif
  }
  r.triangles_final = static_cast<int64_t>(indices.size() / 3);
  r.vertices_final = static_cast<int64_t>(xyz.size() / 3);
  bench::WritePly(out, xyz.data(), xyz.size() / 3, indices.data(), indices.size());
  r.write_s = clock.Lap();
  bench::PrintResult(r);
  return 0;
}
