// GLB (binary glTF 2.0) mesh files, written for viewers: positions, normals and indices in
// one buffer, or one Draco buffer (KHR_draco_mesh_compression; tandem/mesh_io.h).
#include <algorithm>
#include <array>

#include "mesh_io_internal.h"
#include "nlohmann/json.hpp"

namespace tandem::io::internal::meshio {

void AppendGlbHeader(BufferedWriter& out, size_t json_bytes, size_t bin_bytes) {
  out.AppendLe32(0x46546C67u);  // "glTF"
  out.AppendLe32(2);
  out.AppendLe32(static_cast<uint32_t>(12 + 8 + json_bytes + (bin_bytes > 0 ? 8 + bin_bytes : 0)));
  out.AppendLe32(static_cast<uint32_t>(json_bytes));
  out.AppendLe32(0x4E4F534Au);  // "JSON"
}

void AppendGlbBinHeader(BufferedWriter& out, size_t bin_bytes) {
  if (bin_bytes == 0) return;
  out.AppendLe32(static_cast<uint32_t>(bin_bytes));
  out.AppendLe32(0x004E4942u);  // "BIN\0"
}

void AppendGlbContainer(BufferedWriter& out, std::string json, size_t bin_bytes) {
  json.append((4 - json.size() % 4) % 4, ' ');
  AppendGlbHeader(out, json.size(), bin_bytes);
  out.Append(json);
  AppendGlbBinHeader(out, bin_bytes);
}

// GLB (binary glTF 2.0): one mesh, one triangle primitive with POSITION, NORMAL (unit
// length, as glTF requires: a vertex whose triangles have no area gets +z) and 32-bit
// indices, in one buffer. glTF's unit is the metre; positions keep the mesh's units.
// With `draco`, the primitive is that Draco buffer (KHR_draco_mesh_compression): the
// accessors say what it decodes to and have no buffer view of their own.
void WriteGlb(const IndexedMesh& mesh, const std::vector<Vec3>& normals,
              const GlbDracoPrimitive* draco, Space space, BufferedWriter& out) {
  const size_t nv = draco ? draco->vertices : mesh.num_vertices();
  const size_t ni = draco ? draco->indices : mesh.indices.size();
  std::array<double, 3> lo{0, 0, 0}, hi{0, 0, 0};
  for (size_t v = 0; v < nv; ++v) {
    for (int k = 0; k < 3; ++k) {
      const double x = static_cast<float>(mesh.positions[v][k]);  // the stored value
      lo[k] = v == 0 ? x : std::min(lo[k], x);
      hi[k] = v == 0 ? x : std::max(hi[k], x);
    }
  }
  const size_t pos_bytes = 12 * nv, nrm_bytes = 12 * nv, idx_bytes = 4 * ni;
  const size_t bin_bytes = pos_bytes + nrm_bytes + idx_bytes;  // multiples of 4 already
  nlohmann::json j;
  // glTF's own frame (metres, +y up) is not the volume's: positions stay in the volume's
  // frame and units, named here for programs that care.
  j["asset"] = {{"version", "2.0"},
                {"generator", "tandem"},
                {"extras", {{"frame", std::string(SpaceName(space))}}}};
  j["scene"] = 0;
  j["scenes"] = nlohmann::json::array({{{"nodes", {0}}}});
  j["nodes"] = nlohmann::json::array({{{"mesh", 0}}});
  nlohmann::json primitive = {{"attributes", {{"POSITION", 0}, {"NORMAL", 1}}}, {"mode", 4}};
  if (ni > 0) primitive["indices"] = 2;
  j["meshes"] = nlohmann::json::array({{{"primitives", {primitive}}}});
  j["buffers"] = nlohmann::json::array({{{"byteLength", bin_bytes}}});
  j["bufferViews"] = nlohmann::json::array(
      {{{"buffer", 0}, {"byteOffset", 0}, {"byteLength", pos_bytes}, {"target", 34962}},
       {{"buffer", 0}, {"byteOffset", pos_bytes}, {"byteLength", nrm_bytes}, {"target", 34962}},
       {{"buffer", 0},
        {"byteOffset", pos_bytes + nrm_bytes},
        {"byteLength", idx_bytes},
        {"target", 34963}}});
  nlohmann::json accessors = nlohmann::json::array(
      {{{"bufferView", 0}, {"componentType", 5126}, {"count", nv}, {"type", "VEC3"},
        {"min", lo}, {"max", hi}},
       {{"bufferView", 1}, {"componentType", 5126}, {"count", nv}, {"type", "VEC3"}}});
  if (ni > 0) {
    accessors.push_back({{"bufferView", 2}, {"componentType", 5125}, {"count", ni},
                         {"type", "SCALAR"}});
  }
  j["accessors"] = accessors;
  size_t draco_bytes = 0;
  if (draco != nullptr && nv > 0) {
    draco_bytes = draco->bytes.size();
    const size_t padded = (draco_bytes + 3) / 4 * 4;
    j["extensionsUsed"] = {"KHR_draco_mesh_compression"};
    j["extensionsRequired"] = {"KHR_draco_mesh_compression"};
    j["buffers"] = nlohmann::json::array({{{"byteLength", padded}}});
    j["bufferViews"] =
        nlohmann::json::array({{{"buffer", 0}, {"byteOffset", 0}, {"byteLength", draco_bytes}}});
    for (auto& a : j["accessors"]) a.erase("bufferView");
    j["accessors"][0]["min"] = draco->lo;
    j["accessors"][0]["max"] = draco->hi;
    j["meshes"][0]["primitives"][0]["extensions"] = {
        {"KHR_draco_mesh_compression",
         {{"bufferView", 0},
          {"attributes", {{"POSITION", draco->position_id}, {"NORMAL", draco->normal_id}}}}}};
  }
  if (nv == 0) {  // glTF forbids empty buffers and accessors: an empty scene instead
    j.erase("meshes");
    j.erase("buffers");
    j.erase("bufferViews");
    j.erase("accessors");
    j["nodes"] = nlohmann::json::array({nlohmann::json::object()});
  }
  const size_t bin_payload = draco_bytes > 0 ? (draco_bytes + 3) / 4 * 4 : bin_bytes;
  AppendGlbContainer(out, j.dump(), nv == 0 ? 0 : bin_payload);
  if (nv == 0) return;
  if (draco_bytes > 0) {
    out.Append(draco->bytes);
    out.Append(std::string(bin_payload - draco_bytes, '\0'));
    return;
  }
  for (const Vec3& p : mesh.positions) AppendVec3(out, p);
  for (const Vec3& n : normals) AppendVec3(out, Dot(n, n) > 0 ? n : Vec3{0, 0, 1});
  for (uint32_t i : mesh.indices) out.AppendLe32(i);
}

}  // namespace tandem::io::internal::meshio
