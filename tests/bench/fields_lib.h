// The reduction sweep's fields not made with the paper's formulas (field_volume.cc,
// fields_lib_test.cc): the shapes of `tandem generate` as a user's pipeline hands them over.
// Every field is float32 on an N³ grid, unit spacing, voxel (i, j, k) at (i, j, k); the
// shape's binary mask is the set of voxel centres where its `tandem generate` field is >= 0.
//   sdf    the Euclidean signed distance map of the mask (Felzenszwalb & Huttenlocher's exact
//          transform, in voxels), negative inside, each side moved by half a voxel so that 0
//          lies between the last voxel in and the first out (as a signed Maurer map); iso 0.
//   mask   the mask (1 in, 0 out) blurred by a Gaussian of sigma voxels (default 1); iso 0.5.
//   ct     CT-like intensities: -1000 HU outside, 400 inside, the mask blurred by sigma
//          (default 1.2: a scanner's point spread), plus white Gaussian noise of `noise` HU
//          (default 40) drawn from a hash of the seed and the voxel's index; iso -300.
//   field  roundcube only: F = (|x|^8 + |y|^8 + |z|^8)^(1/8) - R, R = 0.4 (N - 1), about the
//          grid's centre, in voxels, negative inside; iso 0 (a distance-like field whose
//          gradient has magnitude about 1 everywhere). Its mask (sdf, mask, ct) is F <= 0.
// Deterministic: the same arguments give the same bytes (no threads, no clock, no global
// random state).
#ifndef TANDEM_BENCH_FIELDS_LIB_H_
#define TANDEM_BENCH_FIELDS_LIB_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "tandem/eval/synthetic.h"
#include "tandem/io/volume_writers.h"
#include "tandem/volume.h"

namespace fields {

constexpr int kMinSize = 8;
constexpr int kMaxSize = 512;  // four float grids of this size: 2 GiB

struct Grid {
  int n;
  size_t At(int x, int y, int z) const { return (size_t(z) * n + y) * n + x; }
  size_t Size() const { return size_t(n) * n * n; }
};

struct FieldSpec {
  std::string shape;  // sphere, pillowbox, link, roundcube
  std::string kind;   // sdf, mask, ct, field
  int size = 64;
  double sigma = 0;  // 0: the kind's default
  double noise = 40;
  uint64_t seed = 1;
};

struct Field {
  std::vector<float> values;
  double iso = 0;
  double sigma = 0;  // the blur used (0 for sdf and field)
};

inline double RoundCube(int n, int x, int y, int z) {
  const double c = 0.5 * (n - 1), r = 0.4 * (n - 1);
  const double a = std::abs(x - c), b = std::abs(y - c), d = std::abs(z - c);
  return std::pow(std::pow(a, 8) + std::pow(b, 8) + std::pow(d, 8), 1.0 / 8) - r;
}

// The shape's binary mask (1 inside), or an error naming the shape.
inline absl::StatusOr<std::vector<uint8_t>> ShapeMask(const std::string& shape, const Grid& g) {
  std::vector<uint8_t> inside(g.Size());
  if (shape == "roundcube") {
    for (int z = 0; z < g.n; ++z)
      for (int y = 0; y < g.n; ++y)
        for (int x = 0; x < g.n; ++x) inside[g.At(x, y, z)] = RoundCube(g.n, x, y, z) <= 0;
    return inside;
  }
  auto parsed = tandem::eval::ParseShape(shape);
  if (!parsed.ok() || *parsed == tandem::eval::Shape::kGyroid) {
    return absl::InvalidArgumentError(
        absl::StrCat("unknown shape '", shape, "': expected sphere, pillowbox, link or roundcube"));
  }
  tandem::VolumeInfo box;
  box.nx = box.ny = box.nz = g.n;
  for (int z = 0; z < g.n; ++z)
    for (int y = 0; y < g.n; ++y)
      for (int x = 0; x < g.n; ++x)
        inside[g.At(x, y, z)] = tandem::eval::SyntheticValue(*parsed, box, x, y, z) >= 0;
  return inside;
}

// 1-D squared distance transform (Felzenszwalb & Huttenlocher 2012) of a strided line, in
// place: the lower envelope of the parabolas rooted at its finite entries.
inline void Edt1d(float* f, size_t stride, int n, std::vector<double>& d, std::vector<int>& v,
                  std::vector<double>& z) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  auto at = [&](int q) { return double(f[size_t(q) * stride]); };
  int k = -1;
  for (int q = 0; q < n; ++q) {
    if (std::isinf(at(q))) continue;
    double s = 0;
    while (k >= 0) {
      const int p = v[k];
      s = ((at(q) + double(q) * q) - (at(p) + double(p) * p)) / (2.0 * (q - p));
      if (s > z[k]) break;
      --k;
    }
    ++k;
    v[k] = q;
    z[k] = k == 0 ? -kInf : s;
    z[k + 1] = kInf;
  }
  if (k < 0) return;  // no feature on this line: it stays infinite
  k = 0;
  for (int q = 0; q < n; ++q) {
    while (z[k + 1] < q) ++k;
    d[q] = double(q - v[k]) * (q - v[k]) + at(v[k]);
  }
  for (int q = 0; q < n; ++q) f[size_t(q) * stride] = float(d[q]);
}

// Squared Euclidean distance from every voxel centre to the nearest one flagged in feature
// (exact: separable along x, y, z; integer-valued, so float holds it exactly up to 2^24).
inline std::vector<float> SquaredDistance(const Grid& g, const std::vector<uint8_t>& feature) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  std::vector<float> f(g.Size());
  for (size_t i = 0; i < f.size(); ++i) f[i] = feature[i] ? 0.0f : kInf;
  std::vector<double> d(g.n), z(g.n + 1);
  std::vector<int> v(g.n);
  const size_t line = g.n, plane = size_t(g.n) * g.n;
  for (int c = 0; c < g.n; ++c)
    for (int b = 0; b < g.n; ++b) Edt1d(&f[g.At(0, b, c)], 1, g.n, d, v, z);
  for (int c = 0; c < g.n; ++c)
    for (int a = 0; a < g.n; ++a) Edt1d(&f[g.At(a, 0, c)], line, g.n, d, v, z);
  for (int b = 0; b < g.n; ++b)
    for (int a = 0; a < g.n; ++a) Edt1d(&f[g.At(a, b, 0)], plane, g.n, d, v, z);
  return f;
}

// Signed distance in voxels, negative inside; every voxel is +-(distance to the nearest
// voxel centre of the other side - 1/2). A grid with one side only gets +-infinity.
inline std::vector<float> SignedDistance(const Grid& g, const std::vector<uint8_t>& inside) {
  std::vector<uint8_t> outside(inside.size());
  for (size_t i = 0; i < inside.size(); ++i) outside[i] = !inside[i];
  const std::vector<float> to_out = SquaredDistance(g, outside);
  std::vector<float> v = SquaredDistance(g, inside);  // to the nearest inside voxel
  for (size_t i = 0; i < v.size(); ++i) {
    v[i] = inside[i] ? 0.5f - std::sqrt(to_out[i]) : std::sqrt(v[i]) - 0.5f;
  }
  return v;
}

// Separable Gaussian blur (radius ceil(3 sigma)), the border voxel repeated. Each output
// sums the mirrored pairs first, so a field symmetric under a reflection stays exactly so.
inline std::vector<float> Blur(const Grid& g, std::vector<float> a, double sigma) {
  const int r = std::max(1, int(std::ceil(3 * sigma)));
  std::vector<double> w(r + 1);
  double sum = 0;
  for (int i = 0; i <= r; ++i) {
    w[i] = std::exp(-0.5 * i * i / (sigma * sigma));
    sum += i == 0 ? w[i] : 2 * w[i];
  }
  for (double& x : w) x /= sum;
  std::vector<float> in(g.n);
  const size_t strides[3] = {1, size_t(g.n), size_t(g.n) * g.n};
  for (size_t stride : strides) {
    for (size_t base = 0; base < g.Size(); ++base) {
      if ((base / stride) % g.n != 0) continue;  // a line starts at coordinate 0 on this axis
      for (int q = 0; q < g.n; ++q) in[q] = a[base + q * stride];
      for (int q = 0; q < g.n; ++q) {
        double s = w[0] * in[q];
        for (int i = 1; i <= r; ++i) {
          s += w[i] * (double(in[std::max(q - i, 0)]) + double(in[std::min(q + i, g.n - 1)]));
        }
        a[base + q * stride] = float(s);
      }
    }
  }
  return a;
}

inline uint64_t SplitMix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

// A standard normal deviate from (seed, i) alone (Box-Muller on two hashed uniforms): the
// same voxel gets the same noise whatever the order of computation.
inline double Gaussian(uint64_t seed, size_t i) {
  const uint64_t base = SplitMix(seed) ^ (uint64_t(i) * 2);
  const double u1 = (double(SplitMix(base) >> 11) + 0.5) / 9007199254740992.0;
  const double u2 = double(SplitMix(base + 1) >> 11) / 9007199254740992.0;
  return std::sqrt(-2 * std::log(u1)) * std::cos(2 * std::numbers::pi * u2);
}

inline absl::StatusOr<Field> MakeField(const FieldSpec& spec) {
  if (spec.size < kMinSize || spec.size > kMaxSize) {
    return absl::InvalidArgumentError(
        absl::StrCat("size ", spec.size, " is outside [", kMinSize, ", ", kMaxSize, "]"));
  }
  if (!(spec.sigma >= 0) || !(spec.noise >= 0) || spec.sigma > spec.size) {
    return absl::InvalidArgumentError("sigma must lie in [0, size] and noise must not be negative");
  }
  const Grid g{spec.size};
  Field out;
  if (spec.kind == "field") {
    if (spec.shape != "roundcube") {
      return absl::InvalidArgumentError(
          absl::StrCat("kind 'field' is the rounded cube's formula only ('", spec.shape,
                       "': tandem generate writes it)"));
    }
    out.values.resize(g.Size());
    for (int z = 0; z < g.n; ++z)
      for (int y = 0; y < g.n; ++y)
        for (int x = 0; x < g.n; ++x) out.values[g.At(x, y, z)] = float(RoundCube(g.n, x, y, z));
    return out;
  }
  if (spec.kind != "sdf" && spec.kind != "mask" && spec.kind != "ct") {
    return absl::InvalidArgumentError(
        absl::StrCat("unknown kind '", spec.kind, "': expected sdf, mask, ct or field"));
  }
  auto inside = ShapeMask(spec.shape, g);
  if (!inside.ok()) return inside.status();
  if (spec.kind == "sdf") {
    out.values = SignedDistance(g, *inside);
    if (std::isinf(out.values[0])) {
      return absl::InvalidArgumentError(
          absl::StrCat(spec.shape, " at size ", spec.size, ": no voxel is inside"));
    }
    return out;
  }
  out.sigma = spec.sigma > 0 ? spec.sigma : spec.kind == "ct" ? 1.2 : 1.0;
  std::vector<float> m(g.Size());
  for (size_t i = 0; i < m.size(); ++i) m[i] = (*inside)[i] ? 1.0f : 0.0f;
  out.values = Blur(g, std::move(m), out.sigma);
  if (spec.kind == "mask") {
    out.iso = 0.5;
    return out;
  }
  for (size_t i = 0; i < out.values.size(); ++i) {
    out.values[i] = float(-1000.0 + 1400.0 * out.values[i] + spec.noise * Gaussian(spec.seed, i));
  }
  out.iso = -300;
  return out;
}

// Writes the field as float32 in the format of path's extension (tandem's volume writers:
// .json = raw + sidecar, .nrrd, ...), with the iso-value as the suggested one.
inline absl::Status WriteField(const std::string& path, const FieldSpec& spec, const Field& f) {
  tandem::VolumeInfo info;
  info.nx = info.ny = info.nz = spec.size;
  info.dtype = tandem::DType::kFloat32;
  info.suggested_isovalues = {f.iso};
  info.description =
      absl::StrCat("tests/bench/field_volume ", spec.shape, " ", spec.kind, " --size ", spec.size);
  if (f.sigma > 0) absl::StrAppend(&info.description, " --sigma ", f.sigma);
  if (spec.kind == "ct") {
    absl::StrAppend(&info.description, " --noise ", spec.noise, " --seed ", spec.seed);
  }
  tandem::io::VolumeWriteOptions opts;
  opts.source = "tests/bench/field_volume";
  const size_t slice = size_t(spec.size) * spec.size;
  return tandem::io::WriteVolume(
      path, info,
      [&](int64_t z, std::vector<uint8_t>* bytes) {
        bytes->resize(slice * sizeof(float));
        std::memcpy(bytes->data(), f.values.data() + size_t(z) * slice, bytes->size());
        return absl::OkStatus();
      },
      opts);
}

}  // namespace fields

#endif  // TANDEM_BENCH_FIELDS_LIB_H_
