#include "codec/draco_codec.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "absl/strings/str_cat.h"
#include "draco/compression/config/compression_shared.h"
#include "draco/compression/decode.h"
#include "draco/compression/encode.h"
#include "draco/core/decoder_buffer.h"
#include "draco/core/encoder_buffer.h"
#include "draco/mesh/mesh.h"

namespace tandem::codec {
namespace {

constexpr int kSequentialLevel = 0;
// Unit normals in a GLB: 10 bits (Draco's octahedral coding), under a quarter of a degree.
constexpr int kNormalBits = 10;

// Builds a draco::Mesh with one point per vertex (identity mapping, no value
// deduplication), so point ids equal vertex ids.
absl::StatusOr<std::unique_ptr<draco::Mesh>> ToDracoMesh(const IndexedMesh& mesh,
                                                          const DracoOptions& options,
                                                          std::span<const uint32_t> ids) {
  const size_t nv = mesh.num_vertices();
  if (!ids.empty() && ids.size() != nv) {
    return absl::InvalidArgumentError(
        absl::StrCat(ids.size(), " vertex ids for ", nv, " vertices"));
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
  for (size_t i = 0; i < nv; ++i) {
    const Vec3& p = mesh.positions[i];
    const float v[3] = {static_cast<float>(p.x), static_cast<float>(p.y), static_cast<float>(p.z)};
    if (!std::isfinite(v[0]) || !std::isfinite(v[1]) || !std::isfinite(v[2])) {
      return absl::InvalidArgumentError(absl::StrCat("vertex ", i, " is not finite"));
    }
    if (options.grid_range > 0) {
      float c[3];
      for (int a = 0; a < 3; ++a) {
        c[a] = std::clamp(v[a], options.grid_origin[a], options.grid_origin[a] + options.grid_range);
      }
      att->SetAttributeValue(draco::AttributeValueIndex(static_cast<uint32_t>(i)), c);
    } else {
      att->SetAttributeValue(draco::AttributeValueIndex(static_cast<uint32_t>(i)), v);
    }
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
  if (options.quantization_bits < 1 || options.quantization_bits > 30) {
    return absl::InvalidArgumentError(absl::StrCat(
        "quantization_bits must be in [1, 30], got ", options.quantization_bits));
  }
  if (options.compression_level < 0 || options.compression_level > 10) {
    return absl::InvalidArgumentError(absl::StrCat(
        "compression_level must be in [0, 10], got ", options.compression_level));
  }
  if (!(options.grid_range >= 0) || !std::isfinite(options.grid_range) ||
      !std::isfinite(options.grid_origin[0]) || !std::isfinite(options.grid_origin[1]) ||
      !std::isfinite(options.grid_origin[2])) {
    return absl::InvalidArgumentError("the quantization grid must be finite, its range >= 0");
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> EncodeDraco(const IndexedMesh& mesh, const DracoOptions& options,
                                        std::span<const uint32_t> ids) {
  if (absl::Status st = ValidateDracoOptions(options); !st.ok()) return st;
  auto dmesh = ToDracoMesh(mesh, options, ids);
  if (!dmesh.ok()) return dmesh.status();
  if (mesh.num_triangles() == 0) {
    // Draco's mesh decoders refuse zero faces: a mesh without triangles travels as a
    // point cloud (sequential, so point order is kept).
    draco::Encoder encoder;
    // Draco's quantizer dereferences the first value: an empty cloud goes unquantized.
    if (mesh.num_vertices() > 0) SetQuantization(&encoder, options);
    encoder.SetSpeedOptions(10, 10);
    encoder.SetEncodingMethod(draco::POINT_CLOUD_SEQUENTIAL_ENCODING);
    draco::EncoderBuffer buffer;
    const draco::Status st = encoder.EncodePointCloudToBuffer(**dmesh, &buffer);
    if (!st.ok()) {
      return absl::InternalError(absl::StrCat("Draco encoding failed: ", st.error_msg_string()));
    }
    return std::string(buffer.data(), buffer.size());
  }
  if (options.compression_level == kSequentialLevel) {
    return EncodeWith(**dmesh, options, kSequentialLevel);
  }
  // Edgebreaker rebuilds connectivity from a corner table: it drops isolated vertices and
  // faces with a repeated corner, and splits non-manifold vertices. The drops are found
  // here; a split only adds vertices, so once nothing can be dropped, equal decoded counts
  // prove nothing was split either (a drop and a split could otherwise cancel out).
  if (HasUnusedVertexOrRepeatedCorner(mesh)) {
    return EncodeWith(**dmesh, options, kSequentialLevel);
  }
  auto bytes = EncodeWith(**dmesh, options, options.compression_level);
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
  return EncodeWith(**dmesh, options, kSequentialLevel);
}

absl::StatusOr<IndexedMesh> DecodeDraco(std::string_view bytes, std::vector<uint32_t>* ids) {
  auto decoded = DecodeToDraco(bytes);
  if (!decoded.ok()) return decoded.status();
  const draco::PointCloud& pc = *decoded->points;
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
  if (decoded->mesh == nullptr) return out;  // a mesh without triangles
  const draco::Mesh& dm = *decoded->mesh;
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
                                                     const DracoOptions& options) {
  if (absl::Status st = ValidateDracoOptions(options); !st.ok()) return st;
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
  auto dmesh = ToDracoMesh(mesh, options, {});
  if (!dmesh.ok()) return dmesh.status();
  draco::GeometryAttribute normal;
  normal.Init(draco::GeometryAttribute::NORMAL, nullptr, 3, draco::DT_FLOAT32, false,
              sizeof(float) * 3, 0);
  const uint32_t nv = static_cast<uint32_t>(mesh.num_vertices());
  draco::PointAttribute* na = (*dmesh)->attribute((*dmesh)->AddAttribute(normal, true, nv));
  for (uint32_t i = 0; i < nv; ++i) {
    const Vec3& n = normals[i];
    const bool unit = Dot(n, n) > 0;  // glTF wants unit normals: +z where there is none
    const float v[3] = {unit ? static_cast<float>(n.x) : 0.f, unit ? static_cast<float>(n.y) : 0.f,
                        unit ? static_cast<float>(n.z) : 1.f};
    na->SetAttributeValue(draco::AttributeValueIndex(i), v);
  }
  const int level = HasUnusedVertexOrRepeatedCorner(mesh) ? kSequentialLevel
                                                          : options.compression_level;
  auto bytes = EncodeWith(**dmesh, options, level);
  if (!bytes.ok()) return bytes.status();
  // What a glTF reader will decode: the accessors must say so exactly.
  auto decoded = DecodeToDraco(*bytes);
  if (!decoded.ok()) return decoded.status();
  if (decoded->mesh == nullptr) return absl::InternalError("Draco gave no mesh back");
  const draco::PointAttribute* pos =
      decoded->points->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  const draco::PointAttribute* nrm =
      decoded->points->GetNamedAttribute(draco::GeometryAttribute::NORMAL);
  if (pos == nullptr || nrm == nullptr) return absl::InternalError("Draco lost an attribute");
  out.vertices = decoded->points->num_points();
  out.indices = static_cast<size_t>(decoded->mesh->num_faces()) * 3;
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
  out.bytes = *std::move(bytes);
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
  // Draco quantizes float32 values and dequantizes in float32: a few roundings of the
  // largest coordinate come on top of the step.
  return step + 4 * static_cast<double>(std::numeric_limits<float>::epsilon()) * magnitude;
}

}  // namespace tandem::codec
