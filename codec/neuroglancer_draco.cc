// Neuroglancer mesh fragments as Draco meshes with integer positions (neuroglancer_draco.h).
#include "tandem/codec/neuroglancer_draco.h"

#include <limits>
#include <memory>
#include <vector>

#include "absl/strings/str_cat.h"
#include "draco/compression/decode.h"
#include "draco/core/decoder_buffer.h"
#include "draco/mesh/mesh.h"
#include "draco_encode.h"
#include "tandem/status_macros.h"

namespace tandem::codec {
namespace {

absl::StatusOr<std::string> Encode(const draco::Mesh& mesh, int level) {
  draco::Encoder encoder;  // no quantization: Neuroglancer takes the integers as they are
  return EncodeMeshAtLevel(encoder, mesh, level);
}

absl::StatusOr<std::unique_ptr<draco::Mesh>> Decode(std::string_view bytes) {
  draco::DecoderBuffer in;
  in.Init(bytes.data(), bytes.size());
  draco::Decoder decoder;
  auto mesh = decoder.DecodeMeshFromBuffer(&in);
  if (!mesh.ok()) {
    return absl::DataLossError(absl::StrCat("Draco decoding failed (", bytes.size(),
                                            " bytes): ", mesh.status().error_msg_string()));
  }
  return std::move(mesh).value();
}

}  // namespace

absl::StatusOr<std::string> EncodeNeuroglancerFragment(
    std::span<const std::array<uint32_t, 3>> positions, std::span<const uint32_t> indices,
    int compression_level) {
  if (compression_level < 0 || compression_level > 10) {
    return absl::InvalidArgumentError(
        absl::StrCat("compression_level must be in [0, 10], got ", compression_level));
  }
  if (indices.empty() || indices.size() % 3 != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("a fragment needs whole triangles, got ", indices.size(), " indices"));
  }
  const size_t nv = positions.size();
  if (nv > static_cast<size_t>(std::numeric_limits<int32_t>::max())) {
    return absl::InvalidArgumentError(absl::StrCat(nv, " vertices (limit 2^31)"));
  }
  draco::Mesh mesh;
  mesh.set_num_points(static_cast<uint32_t>(nv));
  draco::GeometryAttribute pos;
  // int32: the type Neuroglancer's decoder reads positions of (it refuses unsigned ones).
  pos.Init(draco::GeometryAttribute::POSITION, nullptr, 3, draco::DT_INT32, false,
           sizeof(int32_t) * 3, 0);
  draco::PointAttribute* att =
      mesh.attribute(mesh.AddAttribute(pos, /*identity_mapping=*/true, static_cast<uint32_t>(nv)));
  for (size_t i = 0; i < nv; ++i) {
    int32_t v[3];
    for (int j = 0; j < 3; ++j) {
      if (positions[i][j] > static_cast<uint32_t>(std::numeric_limits<int32_t>::max())) {
        return absl::InvalidArgumentError(
            absl::StrCat("vertex ", i, ": coordinate ", positions[i][j], " is 2^31 or more"));
      }
      v[j] = static_cast<int32_t>(positions[i][j]);
    }
    att->SetAttributeValue(draco::AttributeValueIndex(static_cast<uint32_t>(i)), v);
  }
  const size_t nt = indices.size() / 3;
  mesh.SetNumFaces(nt);
  for (size_t t = 0; t < nt; ++t) {
    draco::Mesh::Face face;
    for (int c = 0; c < 3; ++c) {
      const uint32_t v = indices[3 * t + c];
      if (v >= nv) {
        return absl::InvalidArgumentError(
            absl::StrCat("triangle ", t, ": vertex ", v, " out of range (", nv, " vertices)"));
      }
      face[c] = draco::PointIndex(v);
    }
    mesh.SetFace(draco::FaceIndex(static_cast<uint32_t>(t)), face);
  }
  // Edgebreaker drops a vertex no triangle uses, and the sequential coding of a mesh with more
  // vertices than corners is refused by Draco's decoder (Neuroglancer's too).
  std::vector<bool> used(nv, false);
  for (uint32_t v : indices) used[v] = true;
  for (size_t i = 0; i < nv; ++i) {
    if (!used[i]) {
      return absl::InvalidArgumentError(absl::StrCat("vertex ", i, " is in no triangle"));
    }
  }
  absl::StatusOr<std::string> bytes = Encode(mesh, compression_level);
  if (!bytes.ok() || compression_level == 0) return bytes;
  // Edgebreaker drops degenerate triangles and splits non-manifold vertices: keep every
  // triangle by coding sequentially when the counts would change.
  absl::StatusOr<std::unique_ptr<draco::Mesh>> back = Decode(*bytes);
  if (back.ok() && (*back)->num_faces() == nt && (*back)->num_points() == nv) return bytes;
  return Encode(mesh, 0);
}

absl::StatusOr<IntegerMesh> DecodeNeuroglancerFragment(std::string_view bytes) {
  TANDEM_ASSIGN_OR_RETURN(std::unique_ptr<draco::Mesh> mesh, Decode(bytes));
  const draco::Mesh& m = *mesh;
  const draco::PointAttribute* pos = m.GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (pos == nullptr || pos->num_components() != 3 || pos->data_type() != draco::DT_INT32) {
    return absl::InvalidArgumentError("the fragment's POSITION is not 3 x int32");
  }
  IntegerMesh out;
  out.positions.resize(m.num_points());
  for (uint32_t i = 0; i < m.num_points(); ++i) {
    int32_t v[3];
    pos->GetMappedValue(draco::PointIndex(i), v);
    for (int j = 0; j < 3; ++j) out.positions[i][j] = static_cast<uint32_t>(v[j]);
  }
  out.indices.reserve(3 * m.num_faces());
  for (uint32_t f = 0; f < m.num_faces(); ++f) {
    const draco::Mesh::Face& face = m.face(draco::FaceIndex(f));
    for (int c = 0; c < 3; ++c) out.indices.push_back(face[c].value());
  }
  return out;
}

}  // namespace tandem::codec
