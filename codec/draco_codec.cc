#include "tandem/codec/draco_codec.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <span>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/str_cat.h"
#include "draco_encode.h"
#include "draco/compression/config/compression_shared.h"
#include "draco/compression/decode.h"
#include "draco/compression/encode.h"
#include "draco/core/decoder_buffer.h"
#include "draco/core/encoder_buffer.h"
#include "draco/mesh/mesh.h"
#include "tandem/geometry.h"
#include "tandem/status_macros.h"

namespace tandem::codec {
namespace {

constexpr int kSequentialLevel = 0;
// Unit normals in a GLB: 10 bits (Draco's octahedral coding), under a quarter of a degree.
constexpr int kNormalBits = 10;

using Point = std::array<float, 3>;
using Lattice = std::array<int64_t, 3>;

// Draco's position grid (AttributeQuantizationTransform with its Quantizer): a coordinate v
// goes to q = floor((v - origin) * inverse_delta + 0.5) in float32 arithmetic, inverse_delta
// = max_q / range, max_q = 2^bits - 1. Reproduced here operation for operation (the build
// targets baseline x86-64: no FMA contracts the product and the sum).
struct Grid {
  std::array<float, 3> origin{};
  float inverse_delta = 1, delta = 1;
  int32_t max_q = 0;
  Grid(const std::array<float, 3>& o, float range, int bits)
      : origin(o), max_q(static_cast<int32_t>((uint32_t{1} << bits) - 1)) {
    inverse_delta = static_cast<float>(max_q) / range;
    delta = range / static_cast<float>(max_q);
  }
  int32_t Quantize(float v, int axis) const {
    float value = v - origin[axis];
    value *= inverse_delta;
    const float q = std::floor(value + 0.5f);
    // Off the int32 range (or NaN: a box too large for float32, inf * 0): what x86's
    // conversion gives in Draco, where the cast is undefined.
    if (!(q >= -2147483648.0f && q < 2147483648.0f)) return std::numeric_limits<int32_t>::min();
    return static_cast<int32_t>(q);
  }
  // A grid point as one number: its coordinates side by side where each fits in 21 bits (up
  // to 21 quantization bits), else mixed (splitmix64's finaliser), where two points share
  // one with a chance of 2^-64, which would only make a vertex step off a free point.
  static uint64_t Key(const Lattice& q) {
    constexpr int64_t kBits = 21;
    if (std::all_of(q.begin(), q.end(), [](int64_t c) { return c >= 0 && c < (1 << kBits); })) {
      return static_cast<uint64_t>(q[0]) | static_cast<uint64_t>(q[1]) << kBits |
             static_cast<uint64_t>(q[2]) << (2 * kBits);
    }
    uint64_t h = static_cast<uint64_t>(q[0]) * 0x9E3779B97F4A7C15u ^
                 static_cast<uint64_t>(q[1]) * 0xC2B2AE3D27D4EB4Fu ^
                 static_cast<uint64_t>(q[2]) * 0x165667B19E3779F9u;
    h = (h ^ (h >> 30)) * 0xBF58476D1CE4E5B9u;
    h = (h ^ (h >> 27)) * 0x94D049BB133111EBu;
    return (h ^ (h >> 31)) | uint64_t{1} << 63;  // never a packed key
  }
  // A grid whose step float32 can hold (positions spread beyond float32's range cannot).
  bool usable() const {
    return std::isfinite(inverse_delta) && inverse_delta > 0 && std::isfinite(delta) && delta > 0;
  }
};

Vec3 AsVec(const Point& p) { return Vec3{p[0], p[1], p[2]}; }
Vec3 AsVec(const Lattice& q) {
  return Vec3{static_cast<double>(q[0]), static_cast<double>(q[1]), static_cast<double>(q[2])};
}
bool HasArea(Vec3 a, Vec3 b, Vec3 c) { return !IsWrittenDegenerate(a, b, c); }
// On the grid, with the corners' lattice points: it has an area and faces as `facing` (the
// triangle's twice-area vector as written). Lattice coordinates are below 2^30: their
// differences' products and sums are exact in doubles.
bool KeepsArea(const Lattice& a, const Lattice& b, const Lattice& c, Vec3 facing) {
  const Vec3 pa = AsVec(a), pb = AsVec(b), pc = AsVec(c);
  return HasArea(pa, pb, pc) && Dot(TwiceAreaVector(pa, pb, pc), facing) > 0;
}

// Nearly every triangle: on the grid it has an area and each corner lies more than 6 grid
// steps from the line of the other two. Its corners as given lie within sqrt(3)/2 of a step
// of their grid points, or within 1.5 sqrt(3) for a corner moved (or about to be) one step,
// which changes a corner's distance to that line by at most twice that, under 6 steps: as
// given, it has an area and faces as it does on the grid, and no check is needed.
bool FarFromLosingArea(const Lattice& a, const Lattice& b, const Lattice& c) {
  const Vec3 pa = AsVec(a), pb = AsVec(b), pc = AsVec(c);
  const Vec3 n = TwiceAreaVector(pa, pb, pc);
  const double longest = std::max({Dot(pb - pa, pb - pa), Dot(pc - pb, pc - pb),
                                   Dot(pa - pc, pa - pc)});
  // The least height squared is |n|^2 over the longest edge squared (in steps squared).
  return Dot(n, n) > 36 * longest && HasArea(pa, pb, pc);
}

// Where a triangle with an area as written would have none on the grid (or turn over), one
// of its corners steps to one of its 26 neighbouring grid points (the nearest to where it was
// given first), the first where none of that corner's triangles that have an area loses it
// or turns over. Where vertices quantize to one grid point (or to one of `avoid`'s: the
// vertices another buffer on the same grid sent), all but one step off it the same way, so
// that no two share a position as decoded, which a reader welding by position would join.
// A step never lands on a grid point that another vertex holds. `fixed` corners (by vertex;
// empty: none) stay. A step moves a corner by one grid step along each axis at most, so it
// lies at most 1.5 steps from where it was given. Returns the triangles left without an area
// on the grid and the vertices left on a grid point with another.
int64_t KeepOnGrid(const IndexedMesh& mesh, const Grid& grid, std::span<const uint8_t> fixed,
                   std::span<const Vec3> avoid, std::vector<Point>* points, MovedCorners* moved) {
  const size_t nv = points->size(), nt = mesh.num_triangles();
  std::vector<Lattice> q(nv);
  for (size_t i = 0; i < nv; ++i) {
    for (int a = 0; a < 3; ++a) q[i][a] = grid.Quantize((*points)[i][a], a);
  }
  auto is_fixed = [&](uint32_t v) { return !fixed.empty() && fixed[v]; };
  // Who holds each grid point: a vertex, or kAvoided (another buffer's). A vertex that finds
  // its point held must step, unless it is fixed and the holder is not (they swap).
  constexpr uint32_t kAvoided = ~uint32_t{0};
  absl::flat_hash_map<uint64_t, uint32_t> held;  // by Key: half the bytes of a Lattice's
  held.reserve(nv + avoid.size());
  for (const Vec3& p : avoid) {
    held.emplace(grid.Key({grid.Quantize(static_cast<float>(p.x), 0),
                           grid.Quantize(static_cast<float>(p.y), 1),
                           grid.Quantize(static_cast<float>(p.z), 2)}),
                 kAvoided);
  }
  std::vector<uint32_t> crowded;
  for (uint32_t v = 0; v < nv; ++v) {
    auto [it, fresh] = held.emplace(grid.Key(q[v]), v);
    if (fresh) continue;
    if (is_fixed(v) && it->second != kAvoided && !is_fixed(it->second)) {
      crowded.push_back(it->second);
      it->second = v;
    } else {
      crowded.push_back(v);
    }
  }
  // The facing every check keeps: the positions as given. Nothing moves before the first
  // pass has found a vertex that must move; only then are they copied.
  std::span<const Point> given(*points);
  std::vector<Point> given_copy;
  auto corners = [&](size_t t) { return &mesh.indices[3 * t]; };
  auto facing = [&](size_t t, Vec3* out) {  // false: repeated corner or no area as given
    const uint32_t* v = corners(t);
    if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0]) return false;
    const Vec3 a = AsVec(given[v[0]]), b = AsVec(given[v[1]]), c = AsVec(given[v[2]]);
    if (!HasArea(a, b, c)) return false;
    *out = TwiceAreaVector(a, b, c);
    return true;
  };
  auto kept = [&](size_t t, uint32_t moved, const Lattice& at) {
    const uint32_t* v = corners(t);
    auto p = [&](int k) -> const Lattice& { return v[k] == moved ? at : q[v[k]]; };
    if (FarFromLosingArea(p(0), p(1), p(2))) return true;
    Vec3 f;
    return !facing(t, &f) || KeepsArea(p(0), p(1), p(2), f);  // nothing to keep, or kept
  };
  std::vector<uint32_t> lost;
  for (size_t t = 0; t < nt; ++t) {
    if (!kept(t, kInvalid, {})) lost.push_back(static_cast<uint32_t>(t));
  }
  if (lost.empty() && crowded.empty()) return 0;
  given_copy = *points;
  given = given_copy;
  // The triangles of each vertex (CSR), only when some vertex must move.
  std::vector<uint32_t> first(nv + 1, 0), around(3 * nt);
  for (uint32_t v : mesh.indices) ++first[v + 1];
  for (size_t i = 0; i < nv; ++i) first[i + 1] += first[i];
  {
    std::vector<uint32_t> fill(first.begin(), first.end() - 1);
    for (size_t k = 0; k < 3 * nt; ++k) around[fill[mesh.indices[k]]++] = static_cast<uint32_t>(k / 3);
  }
  std::vector<Lattice> steps;
  for (int norm = 1; norm <= 3; ++norm) {
    for (int64_t x = -1; x <= 1; ++x) {
      for (int64_t y = -1; y <= 1; ++y) {
        for (int64_t z = -1; z <= 1; ++z) {
          if (x * x + y * y + z * z == norm) steps.push_back({x, y, z});
        }
      }
    }
  }
  // Moves vertex m to the free grid point next to its own (the nearest to where it was
  // given first: a vertex that moved again stays next to its own), of those where none of
  // its triangles that keeps its area and facing loses them and `mend` (a triangle of m's,
  // or kInvalid) gets them back; false if there is none.
  const std::vector<Lattice> own = q;
  std::vector<std::pair<double, int>> order(steps.size());
  std::vector<uint8_t> stepped(nv, 0);
  auto step = [&](uint32_t m, uint32_t mend) {
    if (is_fixed(m)) return false;
    for (size_t k = 0; k < steps.size(); ++k) {
      double far = 0;
      for (int a = 0; a < 3; ++a) {
        const double off = (given[m][a] - grid.origin[a]) * grid.inverse_delta -
                           static_cast<double>(own[m][a]) - static_cast<double>(steps[k][a]);
        far += off * off;
      }
      order[k] = {far, static_cast<int>(k)};
    }
    std::sort(order.begin(), order.end());
    for (const auto& [far, k] : order) {
      const Lattice& d = steps[k];
      Lattice at{own[m][0] + d[0], own[m][1] + d[1], own[m][2] + d[2]};
      if (std::any_of(at.begin(), at.end(), [&](int64_t c) { return c < 0 || c > grid.max_q; }) ||
          at == q[m] || held.contains(grid.Key(at))) {
        continue;
      }
      bool ok = mend == kInvalid || kept(mend, m, at);
      for (uint32_t i = first[m]; i < first[m + 1] && ok; ++i) {
        ok = kept(around[i], m, at) || !kept(around[i], kInvalid, {});
      }
      if (!ok) continue;
      Point p;
      for (int a = 0; a < 3; ++a) {
        p[a] = grid.origin[a] + static_cast<float>(at[a]) * grid.delta;
        ok = ok && grid.Quantize(p[a], a) == at[a];
      }
      if (!ok) continue;
      if (auto it = held.find(grid.Key(q[m])); it != held.end() && it->second == m) held.erase(it);
      held.emplace(grid.Key(at), m);
      (*points)[m] = p;
      q[m] = at;
      stepped[m] = 1;
      return true;
    }
    return false;
  };
  // Whether vertex m has its grid point to itself, taking it if it is free, or stepping off.
  auto separate = [&](uint32_t m) {
    auto [it, fresh] = held.emplace(grid.Key(q[m]), m);
    return fresh || it->second == m || step(m, kInvalid);
  };
  // Whether triangle t keeps its area and facing, or a step of one of its corners (the one
  // across the longest edge first: it moves the farthest from that line) mends it.
  auto mend = [&](uint32_t t) {
    if (kept(t, kInvalid, {})) return true;
    const uint32_t* v = corners(t);
    std::array<int, 3> order{0, 1, 2};
    auto across = [&](int k) {
      const Vec3 d = AsVec(given[v[(k + 1) % 3]]) - AsVec(given[v[(k + 2) % 3]]);
      return Dot(d, d);
    };
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return across(a) > across(b); });
    return std::any_of(order.begin(), order.end(), [&](int k) { return step(v[k], t); });
  };
  // A step may free a grid point, or take a corner off a triangle's line, that another
  // vertex or triangle waited for: a few rounds, while they help.
  for (int round = 0; round < 4 && !(crowded.empty() && lost.empty()); ++round) {
    const size_t before = crowded.size() + lost.size();
    std::erase_if(crowded, separate);
    std::erase_if(lost, mend);
    if (crowded.size() + lost.size() == before) break;
  }
  if (moved != nullptr) {
    for (uint32_t m = 0; m < nv; ++m) {
      if (stepped[m]) moved->emplace_back(m, AsVec((*points)[m]));
    }
  }
  return static_cast<int64_t>(crowded.size() + lost.size());
}

// Builds a draco::Mesh with one point per vertex (identity mapping, no value
// deduplication), so point ids equal vertex ids. Without an explicit grid, `options` gets
// the one Draco would take (the positions' box: origin at its low corner, range its largest
// extent, 1 if none), so that the positions can be kept off degenerate places on it.
absl::StatusOr<std::unique_ptr<draco::Mesh>> ToDracoMesh(
    const IndexedMesh& mesh, DracoOptions* options, std::span<const uint32_t> ids,
    std::span<const uint8_t> fixed, MovedCorners* moved, std::span<const Vec3> avoid) {
  const size_t nv = mesh.num_vertices();
  if (!ids.empty() && ids.size() != nv) {
    return absl::InvalidArgumentError(
        absl::StrCat(ids.size(), " vertex ids for ", nv, " vertices"));
  }
  if (!fixed.empty() && fixed.size() != nv) {
    return absl::InvalidArgumentError(
        absl::StrCat(fixed.size(), " fixed-vertex flags for ", nv, " vertices"));
  }
  if (mesh.indices.size() % 3 != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("mesh has ", mesh.indices.size(), " indices, not a multiple of 3"));
  }
  if (nv > static_cast<size_t>(std::numeric_limits<int32_t>::max())) {
    return absl::InvalidArgumentError(absl::StrCat("mesh has ", nv, " vertices (limit 2^31)"));
  }
  auto out = std::make_unique<draco::Mesh>();
  out->set_num_points(static_cast<uint32_t>(nv));
  draco::GeometryAttribute pos;
  pos.Init(draco::GeometryAttribute::POSITION, nullptr, 3, draco::DT_FLOAT32, false,
           sizeof(float) * 3, 0);
  const int att_id = out->AddAttribute(pos, /*identity_mapping=*/true, static_cast<uint32_t>(nv));
  draco::PointAttribute* att = out->attribute(att_id);
  std::vector<Point> points(nv);
  for (size_t i = 0; i < nv; ++i) {
    const Vec3& p = mesh.positions[i];
    Point& v = points[i];
    v = {static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)};
    if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2])) {
      return absl::InvalidArgumentError(absl::StrCat("vertex ", i, " is not finite"));
    }
    if (options->grid_range > 0) {
      for (int a = 0; a < 3; ++a) {
        v[a] = std::clamp(v[a], options->grid_origin[a], options->grid_origin[a] + options->grid_range);
      }
    }
  }
  if (nv > 0 && options->grid_range == 0) {
    Point lo = points[0], hi = points[0];
    for (const Point& p : points) {
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], p[a]);
        hi[a] = std::max(hi[a], p[a]);
      }
    }
    float range = 0;
    for (int a = 0; a < 3; ++a) range = std::max(range, hi[a] - lo[a]);
    options->grid_origin = lo;
    options->grid_range = range > 0 ? range : 1.0f;
  }
  if (!ids.empty()) {
    draco::GeometryAttribute id;
    id.Init(draco::GeometryAttribute::GENERIC, nullptr, 1, draco::DT_UINT32, false,
            sizeof(uint32_t), 0);
    const int id_att = out->AddAttribute(id, /*identity_mapping=*/true, static_cast<uint32_t>(nv));
    draco::PointAttribute* ida = out->attribute(id_att);
    for (size_t i = 0; i < nv; ++i) {
      ida->SetAttributeValue(draco::AttributeValueIndex(static_cast<uint32_t>(i)), &ids[i]);
    }
  }
  const size_t nt = mesh.num_triangles();
  out->SetNumFaces(nt);
  for (size_t t = 0; t < nt; ++t) {
    draco::Mesh::Face face;
    for (int c = 0; c < 3; ++c) {
      const uint32_t v = mesh.indices[3 * t + c];
      if (v >= nv) {
        return absl::InvalidArgumentError(
            absl::StrCat("triangle ", t, " refers to vertex ", v, " of ", nv));
      }
      face[c] = draco::PointIndex(v);
    }
    out->SetFace(draco::FaceIndex(static_cast<uint32_t>(t)), face);
  }
  if (const Grid grid(options->grid_origin, options->grid_range, options->quantization_bits);
      nv > 0 && grid.usable()) {  // the indices are checked
    KeepOnGrid(mesh, grid, fixed, avoid, &points, moved);
  }
  for (size_t i = 0; i < nv; ++i) {
    att->SetAttributeValue(draco::AttributeValueIndex(static_cast<uint32_t>(i)), points[i].data());
  }
  return out;
}

bool HasUnusedVertexOrRepeatedCorner(const IndexedMesh& mesh) {
  std::vector<bool> used(mesh.num_vertices(), false);
  for (size_t t = 0; t < mesh.num_triangles(); ++t) {
    const uint32_t* v = &mesh.indices[3 * t];
    if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0]) return true;
    used[v[0]] = used[v[1]] = used[v[2]] = true;
  }
  return std::find(used.begin(), used.end(), false) != used.end();
}

// Position quantization: on the mesh's box, or on the explicit grid of the options.
void SetQuantization(draco::Encoder* encoder, const DracoOptions& options) {
  if (options.grid_range > 0) {
    encoder->SetAttributeExplicitQuantization(draco::GeometryAttribute::POSITION,
                                              options.quantization_bits, 3,
                                              options.grid_origin.data(), options.grid_range);
  } else {
    encoder->SetAttributeQuantization(draco::GeometryAttribute::POSITION,
                                      options.quantization_bits);
  }
}

absl::StatusOr<std::string> EncodeWith(const draco::Mesh& mesh, const DracoOptions& options,
                                       int level) {
  draco::Encoder encoder;
  SetQuantization(&encoder, options);
  if (mesh.GetNamedAttributeId(draco::GeometryAttribute::NORMAL) >= 0) {
    encoder.SetAttributeQuantization(draco::GeometryAttribute::NORMAL, kNormalBits);
  }
  return EncodeMeshAtLevel(encoder, mesh, level);
}

// Decodes into Draco's own types: a Mesh, or a PointCloud (then *faces stays null).
struct Decoded {
  std::unique_ptr<draco::PointCloud> points;
  const draco::Mesh* mesh = nullptr;  // points.get() as a Mesh, when it is one
};

absl::StatusOr<Decoded> DecodeToDraco(std::string_view bytes) {
  draco::DecoderBuffer in;
  in.Init(bytes.data(), bytes.size());
  auto type = draco::Decoder::GetEncodedGeometryType(&in);
  if (!type.ok()) {
    return absl::InvalidArgumentError(
        absl::StrCat("not a Draco buffer (", bytes.size(), " bytes): ",
                     type.status().error_msg_string()));
  }
  draco::Decoder decoder;
  Decoded out;
  draco::Status status;
  if (type.value() == draco::TRIANGULAR_MESH) {
    auto mesh = decoder.DecodeMeshFromBuffer(&in);
    status = mesh.status();
    if (mesh.ok()) {
      out.mesh = mesh.value().get();
      out.points = std::move(mesh).value();
    }
  } else {
    auto cloud = decoder.DecodePointCloudFromBuffer(&in);
    status = cloud.status();
    if (cloud.ok()) out.points = std::move(cloud).value();
  }
  if (!status.ok()) {
    return absl::DataLossError(absl::StrCat("Draco decoding failed (", bytes.size(),
                                            " bytes): ", status.error_msg_string()));
  }
  return out;
}

}  // namespace

absl::Status ValidateDracoOptions(const DracoOptions& options) {
  if (options.quantization_bits < kMinQuantizationBits ||
      options.quantization_bits > kMaxQuantizationBits) {
    return absl::InvalidArgumentError(
        absl::StrCat("quantization_bits must be in [", kMinQuantizationBits, ", ",
                     kMaxQuantizationBits, "], got ", options.quantization_bits));
  }
  if (options.compression_level < kMinCompressionLevel ||
      options.compression_level > kMaxCompressionLevel) {
    return absl::InvalidArgumentError(
        absl::StrCat("compression_level must be in [", kMinCompressionLevel, ", ",
                     kMaxCompressionLevel, "], got ", options.compression_level));
  }
  if (!(options.grid_range >= 0) || !std::isfinite(options.grid_range) ||
      !std::isfinite(options.grid_origin[0]) || !std::isfinite(options.grid_origin[1]) ||
      !std::isfinite(options.grid_origin[2])) {
    return absl::InvalidArgumentError("the quantization grid must be finite, its range >= 0");
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> EncodeDraco(const IndexedMesh& mesh, const DracoOptions& given,
                                        std::span<const uint32_t> ids,
                                        std::span<const uint8_t> fixed, MovedCorners* moved,
                                        std::span<const Vec3> avoid) {
  TANDEM_RETURN_IF_ERROR(ValidateDracoOptions(given));
  DracoOptions options = given;  // with the grid made explicit
  if (moved != nullptr) moved->clear();
  TANDEM_ASSIGN_OR_RETURN(auto dmesh, ToDracoMesh(mesh, &options, ids, fixed, moved, avoid));
  if (mesh.num_triangles() == 0) {
    // Draco's mesh decoders refuse zero faces: a mesh without triangles travels as a
    // point cloud (sequential, so point order is kept).
    draco::Encoder encoder;
    // Draco's quantizer dereferences the first value: an empty cloud goes unquantized.
    if (mesh.num_vertices() > 0) SetQuantization(&encoder, options);
    encoder.SetSpeedOptions(10, 10);
    encoder.SetEncodingMethod(draco::POINT_CLOUD_SEQUENTIAL_ENCODING);
    draco::EncoderBuffer buffer;
    const draco::Status st = encoder.EncodePointCloudToBuffer(*dmesh, &buffer);
    if (!st.ok()) {
      return absl::InternalError(absl::StrCat("Draco encoding failed: ", st.error_msg_string()));
    }
    return std::string(buffer.data(), buffer.size());
  }
  if (options.compression_level == kSequentialLevel) {
    return EncodeWith(*dmesh, options, kSequentialLevel);
  }
  // Edgebreaker rebuilds connectivity from a corner table: it drops isolated vertices and
  // faces with a repeated corner, and splits non-manifold vertices. The drops are found
  // here; a split only adds vertices, so once nothing can be dropped, equal decoded counts
  // prove nothing was split either (a drop and a split could otherwise cancel out).
  if (HasUnusedVertexOrRepeatedCorner(mesh)) {
    return EncodeWith(*dmesh, options, kSequentialLevel);
  }
  auto bytes = EncodeWith(*dmesh, options, options.compression_level);
  if (!bytes.ok()) return bytes.status();
  auto check = DecodeToDraco(*bytes);
  // With ids, a vertex Edgebreaker splits comes back as copies with one id and one position
  // (a sealed chunk is a piece of a surface: where two of its fans meet at one vertex, the
  // sequential fallback cost four times the bytes), so only the triangles must be kept.
  if (check.ok() && check->mesh != nullptr &&
      (check->mesh->num_points() == mesh.num_vertices() || !ids.empty()) &&
      check->mesh->num_faces() == mesh.num_triangles()) {
    return bytes;
  }
  return EncodeWith(*dmesh, options, kSequentialLevel);
}

absl::StatusOr<IndexedMesh> DecodeDraco(std::string_view bytes, std::vector<uint32_t>* ids) {
  TANDEM_ASSIGN_OR_RETURN(auto decoded, DecodeToDraco(bytes));
  const draco::PointCloud& pc = *decoded.points;
  IndexedMesh out;
  const uint32_t nv = pc.num_points();
  if (ids != nullptr) {
    const draco::PointAttribute* id = pc.GetNamedAttribute(draco::GeometryAttribute::GENERIC);
    if (nv > 0 && (id == nullptr || id->num_components() != 1)) {
      return absl::InvalidArgumentError("Draco geometry has no vertex id attribute");
    }
    ids->resize(nv);
    for (uint32_t i = 0; i < nv; ++i) {
      if (!id->ConvertValue<uint32_t, 1>(id->mapped_index(draco::PointIndex(i)), &(*ids)[i])) {
        return absl::InvalidArgumentError(absl::StrCat("Draco vertex id ", i, " is unreadable"));
      }
    }
  }
  if (nv > 0) {
    const draco::PointAttribute* pos = pc.GetNamedAttribute(draco::GeometryAttribute::POSITION);
    if (pos == nullptr || pos->num_components() != 3) {
      return absl::InvalidArgumentError("Draco geometry has no 3-component position attribute");
    }
    out.positions.resize(nv);
    for (uint32_t i = 0; i < nv; ++i) {
      float v[3];
      if (!pos->ConvertValue<float, 3>(pos->mapped_index(draco::PointIndex(i)), v)) {
        return absl::InvalidArgumentError(absl::StrCat("Draco position ", i, " is unreadable"));
      }
      out.positions[i] = Vec3{v[0], v[1], v[2]};
    }
  }
  if (decoded.mesh == nullptr) return out;  // a mesh without triangles
  const draco::Mesh& dm = *decoded.mesh;
  out.indices.resize(static_cast<size_t>(dm.num_faces()) * 3);
  for (uint32_t f = 0; f < dm.num_faces(); ++f) {
    const draco::Mesh::Face& face = dm.face(draco::FaceIndex(f));
    for (int c = 0; c < 3; ++c) {
      const uint32_t v = face[c].value();
      if (v >= nv) {
        return absl::InvalidArgumentError(
            absl::StrCat("Draco face ", f, " refers to point ", v, " of ", nv));
      }
      out.indices[3 * static_cast<size_t>(f) + c] = v;
    }
  }
  return out;
}

absl::StatusOr<GlbDracoPrimitive> EncodeGlbPrimitive(const IndexedMesh& mesh,
                                                     const std::vector<Vec3>& normals,
                                                     const DracoOptions& given) {
  TANDEM_RETURN_IF_ERROR(ValidateDracoOptions(given));
  DracoOptions options = given;  // with the grid made explicit
  GlbDracoPrimitive out;
  if (mesh.num_vertices() == 0) return out;  // an empty scene: nothing to compress
  if (mesh.num_triangles() == 0) {
    return absl::InvalidArgumentError(
        "a mesh without triangles cannot be a Draco-compressed glTF primitive");
  }
  if (normals.size() != mesh.num_vertices()) {
    return absl::InvalidArgumentError(
        absl::StrCat(normals.size(), " normals for ", mesh.num_vertices(), " vertices"));
  }
  TANDEM_ASSIGN_OR_RETURN(auto dmesh, ToDracoMesh(mesh, &options, {}, {}, nullptr, {}));
  draco::GeometryAttribute normal;
  normal.Init(draco::GeometryAttribute::NORMAL, nullptr, 3, draco::DT_FLOAT32, false,
              sizeof(float) * 3, 0);
  const uint32_t nv = static_cast<uint32_t>(mesh.num_vertices());
  draco::PointAttribute* na = dmesh->attribute(dmesh->AddAttribute(normal, true, nv));
  for (uint32_t i = 0; i < nv; ++i) {
    const Vec3& n = normals[i];
    const bool unit = Dot(n, n) > 0;  // glTF wants unit normals: +z where there is none
    const float v[3] = {unit ? static_cast<float>(n.x) : 0.f, unit ? static_cast<float>(n.y) : 0.f,
                        unit ? static_cast<float>(n.z) : 1.f};
    na->SetAttributeValue(draco::AttributeValueIndex(i), v);
  }
  const int level = HasUnusedVertexOrRepeatedCorner(mesh) ? kSequentialLevel
                                                          : options.compression_level;
  TANDEM_ASSIGN_OR_RETURN(auto bytes, EncodeWith(*dmesh, options, level));
  // What a glTF reader will decode: the accessors must say so exactly.
  TANDEM_ASSIGN_OR_RETURN(auto decoded, DecodeToDraco(bytes));
  if (decoded.mesh == nullptr) return absl::InternalError("Draco gave no mesh back");
  const draco::PointAttribute* pos =
      decoded.points->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  const draco::PointAttribute* nrm =
      decoded.points->GetNamedAttribute(draco::GeometryAttribute::NORMAL);
  if (pos == nullptr || nrm == nullptr) return absl::InternalError("Draco lost an attribute");
  out.vertices = decoded.points->num_points();
  out.indices = static_cast<size_t>(decoded.mesh->num_faces()) * 3;
  out.position_id = static_cast<int>(pos->unique_id());
  out.normal_id = static_cast<int>(nrm->unique_id());
  for (uint32_t i = 0; i < out.vertices; ++i) {
    float v[3];
    pos->ConvertValue<float, 3>(pos->mapped_index(draco::PointIndex(i)), v);
    for (int a = 0; a < 3; ++a) {
      out.lo[a] = i == 0 ? v[a] : std::min<double>(out.lo[a], v[a]);
      out.hi[a] = i == 0 ? v[a] : std::max<double>(out.hi[a], v[a]);
    }
  }
  out.bytes = std::move(bytes);
  return out;
}

GlbDracoCompressor GlbCompressor(const DracoOptions& options) {
  return [options](const IndexedMesh& mesh, const std::vector<Vec3>& normals) {
    return EncodeGlbPrimitive(mesh, normals, options);
  };
}

double PositionTolerance(const IndexedMesh& mesh, int bits) {
  if (mesh.positions.empty() || bits < 1 || bits > 30) return 0;
  Vec3 lo = mesh.positions[0], hi = lo;
  for (const Vec3& p : mesh.positions) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], p[a]);
      hi[a] = std::max(hi[a], p[a]);
    }
  }
  const double extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  const double magnitude = std::max({std::abs(lo.x), std::abs(lo.y), std::abs(lo.z),
                                     std::abs(hi.x), std::abs(hi.y), std::abs(hi.z)});
  const double step = extent / static_cast<double>((uint32_t{1} << bits) - 1);
  // Half a step to the nearest grid point, one more for a corner moved to keep a triangle's
  // area, rounded up to two. Draco quantizes float32 values and dequantizes in float32: a
  // few roundings of the largest coordinate come on top.
  return 2 * step + 4 * static_cast<double>(std::numeric_limits<float>::epsilon()) * magnitude;
}

absl::StatusOr<std::string> EncodeMeshAtLevel(draco::Encoder& encoder, const draco::Mesh& mesh,
                                              int level) {
  const int speed = 10 - level;
  encoder.SetSpeedOptions(speed, speed);
  encoder.SetEncodingMethod(level == kSequentialLevel ? draco::MESH_SEQUENTIAL_ENCODING
                                                      : draco::MESH_EDGEBREAKER_ENCODING);
  draco::EncoderBuffer buffer;
  const draco::Status st = encoder.EncodeMeshToBuffer(mesh, &buffer);
  if (!st.ok()) {
    return absl::InternalError(absl::StrCat("Draco encoding failed: ", st.error_msg_string()));
  }
  return std::string(buffer.data(), buffer.size());
}

}  // namespace tandem::codec
