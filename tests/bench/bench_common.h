// Small helpers shared by the benchmark's peer programs (tests/bench): flags, a wall clock,
// a binary PLY writer (the same layout tandem writes: float32 x y z, uchar/int faces) and
// the one-line JSON result every peer prints. Header-only; no dependency on core.
#ifndef TANDEM_BENCH_COMMON_H_
#define TANDEM_BENCH_COMMON_H_

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <vector>

namespace bench {

// "--name value" pairs; a bare "--name" maps to "1".
inline std::map<std::string, std::string> ParseFlags(int argc, char** argv) {
  std::map<std::string, std::string> f;
  auto is_flag = [](const char* a) { return a[0] == '-' && a[1] == '-'; };
  for (int i = 1; i < argc; ++i) {
    if (!is_flag(argv[i])) {
      std::fprintf(stderr, "unexpected argument '%s'\n", argv[i]);
      std::exit(2);
    }
    const std::string name(argv[i] + 2);
    const bool has_value = i + 1 < argc && !is_flag(argv[i + 1]);
    f.insert_or_assign(name, std::string(has_value ? argv[++i] : "1"));
  }
  return f;
}

inline std::string Require(const std::map<std::string, std::string>& f, const std::string& k) {
  auto it = f.find(k);
  if (it == f.end()) {
    std::fprintf(stderr, "--%s is required\n", k.c_str());
    std::exit(2);
  }
  return it->second;
}

[[noreturn]] inline void Die(const std::string& msg) {
  std::fprintf(stderr, "%s\n", msg.c_str());
  std::exit(1);
}

class Clock {
 public:
  Clock() : t_(std::chrono::steady_clock::now()) {}
  // Seconds since the last Lap (or construction).
  double Lap() {
    const auto now = std::chrono::steady_clock::now();
    const double s = std::chrono::duration<double>(now - t_).count();
    t_ = now;
    return s;
  }

 private:
  std::chrono::steady_clock::time_point t_;
};

// Binary little-endian PLY: float32 positions (3 per vertex), triangles as uchar 3 + int32.
inline void WritePly(const std::string& path, const float* xyz, size_t num_vertices,
                     const uint32_t* indices, size_t num_indices) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) Die(path + ": cannot open for writing");
  std::fprintf(f,
               "ply\nformat binary_little_endian 1.0\nelement vertex %zu\n"
               "property float x\nproperty float y\nproperty float z\nelement face %zu\n"
               "property list uchar int vertex_indices\nend_header\n",
               num_vertices, num_indices / 3);
  std::fwrite(xyz, sizeof(float), 3 * num_vertices, f);
  std::vector<unsigned char> buf;
  buf.reserve(13 * 4096);
  for (size_t t = 0; t < num_indices / 3; ++t) {
    buf.push_back(3);
    const unsigned char* p = reinterpret_cast<const unsigned char*>(indices + 3 * t);
    buf.insert(buf.end(), p, p + 12);
    if (buf.size() >= 13 * 4096) {
      std::fwrite(buf.data(), 1, buf.size(), f);
      buf.clear();
    }
  }
  std::fwrite(buf.data(), 1, buf.size(), f);
  if (std::fclose(f) != 0) Die(path + ": write error");
}

// Removes unreferenced vertices (after a simplifier shrank the index buffer) in place.
inline size_t CompactVertices(std::vector<float>* xyz, std::vector<uint32_t>* indices) {
  const size_t n = xyz->size() / 3;
  std::vector<uint32_t> remap(n, UINT32_MAX);
  uint32_t next = 0;
  for (uint32_t& i : *indices) {
    if (remap[i] == UINT32_MAX) {
      remap[i] = next;
      for (int c = 0; c < 3; ++c) (*xyz)[3 * size_t(next) + c] = (*xyz)[3 * size_t(i) + c];
      ++next;
    }
    i = remap[i];
  }
  xyz->resize(3 * size_t(next));
  return next;
}

// The result line every peer prints on stdout (and bench.py parses).
struct Result {
  std::string pipeline;
  int64_t triangles_extracted = 0, triangles_final = 0, vertices_final = 0;
  double read_s = 0, extract_s = 0, simplify_s = 0, write_s = 0;
  std::string note;
};

inline void PrintResult(const Result& r) {
  std::printf(
      "{\"pipeline\": \"%s\", \"triangles_extracted\": %lld, \"triangles_final\": %lld, "
      "\"vertices_final\": %lld, \"time_s\": {\"read\": %.6f, \"extract\": %.6f, "
      "\"simplify\": %.6f, \"write\": %.6f}, \"note\": \"%s\"}\n",
      r.pipeline.c_str(), static_cast<long long>(r.triangles_extracted),
      static_cast<long long>(r.triangles_final), static_cast<long long>(r.vertices_final),
      r.read_s, r.extract_s, r.simplify_s, r.write_s, r.note.c_str());
  std::fflush(stdout);
}

}  // namespace bench

#endif  // TANDEM_BENCH_COMMON_H_
