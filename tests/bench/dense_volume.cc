// dense_volume: the generated inputs of the dense benchmark family (issue 25, tests/bench/
// dense.py): uint16 volumes at instrument slice sizes with a surface in every slice, written
// slice by slice as raw + JSON sidecar (the layout `tandem generate` and bench.py use).
//   dense_volume gyroid --period P --size N --slices Z [--open-ends] --out V.json
//   dense_volume noise  --scale L --seed S --size N --slices Z [--open-ends] --out V.json
// gyroid  sin(wx)cos(wy) + sin(wy)cos(wz) + sin(wz)cos(wx), w = 2π/P (P in voxels; the
//         formula of depth.sh), stored as (g + 1.5) * 20000.
// noise   two octaves of value noise (random lattice values every L and L/2 voxels, a hash
//         of the seed and the lattice point, quintic-smoothed trilinear interpolation),
//         (n1 + n2 / 2) / 1.5 in [0, 1], stored as n * 60000: a foam-like, irregular
//         surface about the median.
// The iso-value is 30000 for both (the sidecar suggests it). A 2-voxel frame at the x and y
// borders and the first and last slices hold 60000 (above the iso-value), so the surface is
// closed. The caps on the end slices are flat and large: at 2048²×64 they are about 8 M of
// the 48 M triangles extracted at period 64 and 8.5 M of 18.5 M at period 256. --open-ends
// leaves the end slices as the field is (the surface then has boundary loops there): the
// volumes issue 25 measured (40 M and 10 M triangles), as depth.sh generates them.
// Deterministic: the same arguments give the same volume (but for last-bit differences of
// sin and cos between C libraries).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "bench_common.h"

namespace {

constexpr double kIso = 30000;
constexpr uint16_t kOutside = 60000;
constexpr int kFrame = 2;

uint16_t Quantize(double v) {  // v in [0, 60000]
  return static_cast<uint16_t>(std::lround(std::fmin(60000.0, std::fmax(0.0, v))));
}

// One uint16 slice of the gyroid; tables of sin/cos along x and y make it a few FMAs a voxel.
class Gyroid {
 public:
  Gyroid(int n, double period) : n_(n), w_(2 * M_PI / period), sin_(n), cos_(n) {
    for (int i = 0; i < n; ++i) {
      sin_[i] = std::sin(w_ * i);
      cos_[i] = std::cos(w_ * i);
    }
  }
  void Slice(int k, uint16_t* out) const {
    const double sz = std::sin(w_ * k), cz = std::cos(w_ * k);
    for (int y = 0; y < n_; ++y) {
      for (int x = 0; x < n_; ++x) {
        const double g = sin_[x] * cos_[y] + sin_[y] * cz + sz * cos_[x];
        out[size_t(y) * n_ + x] = Quantize((g + 1.5) * 20000);
      }
    }
  }

 private:
  int n_;
  double w_;
  std::vector<double> sin_, cos_;
};

// Value noise: a lattice every `cell` voxels, the value at lattice point (i, j, l) a hash of
// (seed, octave, i, j, l) in [0, 1). A slice first interpolates the two lattice planes around
// it along z, then each row along y, then x: two loads and a lerp per voxel and octave.
class ValueNoise {
 public:
  ValueNoise(int n, int cell, uint64_t seed) : n_(n), cell_(cell), seed_(seed) {
    lattice_ = n / cell + 2;
    plane_.resize(size_t(lattice_) * lattice_);
    row_.resize(lattice_);
  }
  // Adds weight * noise to acc (one slice, n*n).
  void AddSlice(int k, double weight, double* acc) {
    const int l = k / cell_;
    const double tz = Smooth(double(k % cell_) / cell_);
    for (int j = 0; j < lattice_; ++j) {
      for (int i = 0; i < lattice_; ++i) {
        const double a = Hash(i, j, l), b = Hash(i, j, l + 1);
        plane_[size_t(j) * lattice_ + i] = a + tz * (b - a);
      }
    }
    for (int y = 0; y < n_; ++y) {
      const int j = y / cell_;
      const double ty = Smooth(double(y % cell_) / cell_);
      for (int i = 0; i < lattice_; ++i) {
        const double a = plane_[size_t(j) * lattice_ + i], b = plane_[size_t(j + 1) * lattice_ + i];
        row_[i] = a + ty * (b - a);
      }
      double* out = acc + size_t(y) * n_;
      for (int x = 0; x < n_; ++x) {
        const int i = x / cell_;
        const double tx = Smooth(double(x % cell_) / cell_);
        out[x] += weight * (row_[i] + tx * (row_[i + 1] - row_[i]));
      }
    }
  }

 private:
  static double Smooth(double t) { return t * t * t * (t * (t * 6 - 15) + 10); }
  double Hash(uint64_t i, uint64_t j, uint64_t l) const {  // splitmix64 of the point
    uint64_t h = seed_ ^ (i * 0x9E3779B97F4A7C15ull) ^ (j * 0xC2B2AE3D27D4EB4Full) ^
                 (l * 0x165667B19E3779F9ull) ^ (uint64_t(cell_) << 48);
    h += 0x9E3779B97F4A7C15ull;
    h = (h ^ (h >> 30)) * 0xBF58476D1CE4E5B9ull;
    h = (h ^ (h >> 27)) * 0x94D049BB133111EBull;
    h ^= h >> 31;
    return double(h >> 11) * 0x1.0p-53;
  }
  int n_, cell_, lattice_;
  uint64_t seed_;
  std::vector<double> plane_, row_;
};

void Frame(int n, int k, int nz, bool close_ends, uint16_t* slice) {
  const bool end = close_ends && (k == 0 || k == nz - 1);
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      if (end || x < kFrame || y < kFrame || x >= n - kFrame || y >= n - kFrame) {
        slice[size_t(y) * n + x] = kOutside;
      }
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || argv[1][0] == '-') {
    std::fprintf(stderr,
                 "usage: dense_volume gyroid --period P --size N --slices Z [--open-ends] "
                 "--out V.json\n"
                 "       dense_volume noise --scale L --seed S --size N --slices Z [--open-ends] "
                 "--out V.json\n");
    return 2;
  }
  const std::string shape = argv[1];
  auto flags = bench::ParseFlags(argc - 1, argv + 1);
  const int n = std::stoi(bench::Require(flags, "size"));
  const int nz = std::stoi(bench::Require(flags, "slices"));
  const std::string out = bench::Require(flags, "out");
  const bool close_ends = flags.count("open-ends") == 0;
  if (n < 2 * kFrame + 2 || nz < 3) bench::Die("--size must be at least 6, --slices at least 3");
  if (out.size() < 6 || out.substr(out.size() - 5) != ".json") {
    bench::Die("--out must end in .json");
  }
  const std::string raw = out.substr(0, out.size() - 5) + ".raw";
  const std::string raw_name = raw.substr(raw.find_last_of('/') + 1);

  std::string generated;  // the sidecar's record of the arguments (dense.py compares it)
  std::vector<uint16_t> slice(size_t(n) * n);
  std::vector<double> acc;
  std::unique_ptr<Gyroid> gyroid;
  std::vector<ValueNoise> octaves;
  if (shape == "gyroid") {
    const double period = std::stod(bench::Require(flags, "period"));
    if (!(period >= 2)) bench::Die("--period must be at least 2 voxels");
    gyroid = std::make_unique<Gyroid>(n, period);
    char buf[64];
    std::snprintf(buf, sizeof buf, "{\"shape\": \"gyroid\", \"period\": %g, \"closed\": %s}",
                  period, close_ends ? "true" : "false");
    generated = buf;
  } else if (shape == "noise") {
    const int scale = std::stoi(bench::Require(flags, "scale"));
    const uint64_t seed = std::stoull(bench::Require(flags, "seed"));
    if (scale < 4) bench::Die("--scale must be at least 4 voxels");
    octaves.emplace_back(n, scale, seed);
    octaves.emplace_back(n, scale / 2, seed);
    acc.resize(slice.size());
    generated = "{\"shape\": \"noise\", \"scale\": " + std::to_string(scale) +
                ", \"seed\": " + std::to_string(seed) +
                ", \"closed\": " + (close_ends ? "true" : "false") + "}";
  } else {
    bench::Die("unknown shape '" + shape + "': gyroid or noise");
  }

  FILE* f = std::fopen(raw.c_str(), "wb");
  if (f == nullptr) bench::Die(raw + ": cannot open for writing");
  for (int k = 0; k < nz; ++k) {
    if (gyroid) {
      gyroid->Slice(k, slice.data());
    } else {
      std::fill(acc.begin(), acc.end(), 0.0);
      octaves[0].AddSlice(k, 1.0 / 1.5, acc.data());
      octaves[1].AddSlice(k, 0.5 / 1.5, acc.data());
      for (size_t i = 0; i < acc.size(); ++i) slice[i] = Quantize(acc[i] * 60000);
    }
    Frame(n, k, nz, close_ends, slice.data());
    if (std::fwrite(slice.data(), sizeof(uint16_t), slice.size(), f) != slice.size()) {
      bench::Die(raw + ": write error");  // little-endian host assumed, as the readers do
    }
  }
  if (std::fclose(f) != 0) bench::Die(raw + ": write error");

  FILE* j = std::fopen(out.c_str(), "w");
  if (j == nullptr) bench::Die(out + ": cannot open for writing");
  std::fprintf(j,
               "{\"dims\": [%d, %d, %d], \"dtype\": \"uint16\", \"spacing\": [1, 1, 1], "
               "\"raw_file\": \"%s\", \"suggested_isovalues\": [%g], \"generated\": %s, "
               "\"description\": \"tests/bench/dense_volume %s\"}\n",
               n, n, nz, raw_name.c_str(), kIso, generated.c_str(), shape.c_str());
  if (std::fclose(j) != 0) bench::Die(out + ": write error");
  return 0;
}
