// libFuzzer target: whole TandemSessions with arbitrary geometry and options, extreme
// doubles included (the readers' and the server's targets only reach the values their
// formats let through). The input picks, byte by byte:
//   dims (nx, ny in 2..33, nz in 2..12), schedule, pipelining, parts, a target count,
//   spacing x3, origin x3, E0, alpha, distance guard, sag correction (each either one of
//   the extreme values in kSpecial or the next 8 raw bytes as a double), a shape, and then
//   voxel edits (index, raw float) applied to the shape's slices.
// Checked (a violation aborts, so libFuzzer records it):
//   * Create fails only with INVALID_ARGUMENT or RESOURCE_EXHAUSTED, and with a message;
//   * AddSlice / Finish fail only with INVALID_ARGUMENT (a non-finite voxel) or
//     RESOURCE_EXHAUSTED, and after a RESOURCE_EXHAUSTED every later call fails the same;
//   * a finished session's mesh has finite positions inside the grid's box (grown by its
//     extent and by 10 times the larger of E0 and Error(K)), valid indices, and
//     Error(K) <= E0 unless a target count took it past E0.
// Nothing may throw out of the session, abort, hang or touch memory it does not own.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "tandem/eval/synthetic.h"
#include "tandem/tandem.h"
#include "tandem/volume.h"

namespace {

[[noreturn]] void Violation(const std::string& what) {
  std::fprintf(stderr, "fuzz_session: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kSpecial[] = {0.0,   -0.0,   1.0,    0.5,     3.2,      0.2,     1e-300,
                               1e-12, 1e-9,   1e-6,   1e6,     1e9,      1e12,    1e30,
                               1e160, 1e308,  -1.0,   -1e30,   kInf,     -kInf,
                               std::numeric_limits<double>::quiet_NaN(),
                               std::numeric_limits<double>::denorm_min(),
                               std::numeric_limits<double>::max(), 0x1p-40, 0x1p40, 2.0};
constexpr size_t kNumSpecial = sizeof(kSpecial) / sizeof(kSpecial[0]);

class Input {
 public:
  Input(const uint8_t* data, size_t size) : p_(data), end_(data + size) {}
  uint8_t Byte() { return p_ < end_ ? *p_++ : 0; }
  double Double() {
    const uint8_t sel = Byte();
    if (sel < 2 * kNumSpecial) return kSpecial[sel % kNumSpecial];
    double v = 0;
    if (end_ - p_ >= 8) {
      std::memcpy(&v, p_, 8);
      p_ += 8;
    }
    return v;
  }
  float Float() {
    float v = 0;
    if (end_ - p_ >= 4) {
      std::memcpy(&v, p_, 4);
      p_ += 4;
    }
    return v;
  }
  bool empty() const { return p_ >= end_; }

 private:
  const uint8_t* p_;
  const uint8_t* end_;
};

bool Allowed(const absl::Status& st) {
  return st.code() == absl::StatusCode::kInvalidArgument ||
         st.code() == absl::StatusCode::kResourceExhausted;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace tandem;
  Input in(data, size);
  VolumeInfo g;
  g.nx = 2 + in.Byte() % 32;
  g.ny = 2 + in.Byte() % 32;
  g.nz = 2 + in.Byte() % 11;
  g.dtype = DType::kFloat32;
  SessionOptions o;
  const uint8_t flags = in.Byte();
  constexpr Schedule kSchedules[] = {Schedule::kTandemLag, Schedule::kTandem,
                                     Schedule::kClassical, Schedule::kNone};
  o.schedule = kSchedules[flags & 3];
  o.pipeline = (flags & 4) != 0;
  o.parts = (flags >> 3) & 7;  // 0 = automatic
  o.target_triangles = (flags & 0x40) ? in.Byte() : 0;
  if (flags & 0x80) o.lockstep_error = 1;  // the finishing pass off (its own range: options_test)
  for (double& s : g.spacing) s = in.Double();
  for (double& x : g.origin) x = in.Double();
  o.error = in.Double();
  o.alpha = in.Double();
  o.distance_guard = in.Double();
  o.sag_correction = in.Double();
  o.iso = 0;
  const eval::Shape shape = static_cast<eval::Shape>(in.Byte() % 4);

  auto session = TandemSession::Create(g, o);
  if (!session.ok()) {
    if (!Allowed(session.status()) || session.status().message().empty()) {
      Violation("Create: " + session.status().ToString());
    }
    return 0;
  }
  // The shape's values at unit spacing (the field does not care about the grid's units),
  // then the input's edits.
  auto src = eval::MakeSyntheticSource(shape, g.nx, g.ny, g.nz);
  std::vector<std::vector<float>> slices;
  std::vector<uint8_t> bytes;
  while (src->ReadSlice(&bytes).ok()) {
    slices.emplace_back(static_cast<size_t>(g.nx * g.ny));
    ConvertToFloat(src->info().dtype, bytes.data(), slices.back().size(), slices.back().data());
  }
  const size_t per_slice = static_cast<size_t>(g.nx * g.ny);
  while (!in.empty()) {
    const size_t at = (size_t{in.Byte()} << 8 | in.Byte()) % (per_slice * slices.size());
    slices[at / per_slice][at % per_slice] = in.Float();
  }
  absl::Status failure;
  for (const auto& s : slices) {
    absl::Status st = (*session)->AddSlice(s.data());
    if (!st.ok() && !Allowed(st)) Violation("AddSlice: " + st.ToString());
    if (!failure.ok() && failure.code() == absl::StatusCode::kResourceExhausted && st != failure) {
      Violation("AddSlice after " + failure.ToString() + ": " + st.ToString());
    }
    if (!st.ok()) failure = st;
    if (!st.ok() && st.code() == absl::StatusCode::kInvalidArgument) return 0;  // a bad voxel
  }
  absl::Status st = (*session)->Finish();
  if (!failure.ok()) {
    if (st != failure) Violation("Finish after " + failure.ToString() + ": " + st.ToString());
    return 0;
  }
  if (!st.ok()) {
    if (!Allowed(st)) Violation("Finish: " + st.ToString());
    return 0;
  }
  const IndexedMesh mesh = (*session)->Snapshot();
  // Inside the grid's box grown by its own size and by 10 E0 (or Error(K)): a vertex put in the wrong frame
  // (origin or unit missed) lands orders of magnitude away. Not by its size alone: Error(K)
  // bounds a vertex's area-weighted RMS distance to the planes it stands for, not where along
  // them it lies, so where E0 is larger than the grid (spacing 1e-12, E0 1e-9: 67 times the
  // grid's extent in y) the surface collapses to a few vertices, and one stood 2.5 extents
  // past the grid's box (0.04 E0; tests/fuzz/crashes/fuzz_session/crash-aabb765d...).
  const int64_t dims[3] = {g.nx, g.ny, g.nz};
  // E0 is not checked without simplification: any value, -1e30 included, is let through. A
  // target count takes the error past E0: then it is the error reached (a 42-triangle target
  // on a sphere, spacing (1e-12, 1e-12, 1e-9): a vertex 44 E0 past the box; crash-8755bdcb...).
  const double e0 = o.schedule == Schedule::kNone
                        ? 0.0
                        : std::max({0.0, o.error, (*session)->MaxShapeError()});
  for (const Vec3& p : mesh.positions) {
    const double c[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) {
      if (!std::isfinite(c[a])) Violation("non-finite vertex position");
      const double extent = g.spacing[a] * static_cast<double>(dims[a] - 1);
      const double margin = extent + 10 * e0;
      if (c[a] < g.origin[a] - margin || c[a] > g.origin[a] + extent + margin) {
        char what[200];
        std::snprintf(what, sizeof what,
                      "vertex outside the grid's box on axis %d: %.6g (origin %.6g, extent %.6g, "
                      "E0 %.6g, Error(K) %.6g)",
                      a, c[a], g.origin[a], extent, o.error, (*session)->MaxShapeError());
        Violation(what);
      }
    }
  }
  for (uint32_t i : mesh.indices) {
    if (i >= mesh.positions.size()) Violation("index out of range");
  }
  if (o.schedule != Schedule::kNone && o.target_triangles == 0 &&
      !((*session)->MaxShapeError() <= o.error * (1 + 1e-9))) {
    Violation("Error(K) " + std::to_string((*session)->MaxShapeError()) + " > E0 " +
              std::to_string(o.error));
  }
  return 0;
}
