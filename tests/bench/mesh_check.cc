// mesh_check MESH.{ply,obj}: prints one JSON line with the mesh's topology (tandem_core's
// AnalyzeTopology: manifold, Euler characteristic, boundary edges, components), shape
// measures (anisotropy, directional bias, SPEC §7) and the number of vertices sharing
// their exact position with another (unwelded output, e.g. FlyingEdges3D on integer data).
// "welded_*" repeat manifold/Euler after merging exactly coincident vertices.
// "degenerate_triangles" are triangles with a repeated vertex index; "zero_area_triangles"
// are those with three distinct corners but no area as written (issue 24, item 5: twice
// the area at most 2e-6 of the squared edges, tandem/geometry.h's kWrittenSquared).
#include <cstdio>

#include "tandem/geometry.h"
#include "tandem/io/mesh_io.h"
#include "tandem/eval/metrics.h"
#include "tandem/eval/topology.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: mesh_check MESH.{ply,obj}\n");
    return 2;
  }
  auto mesh = tandem::io::ReadMesh(argv[1]);
  if (!mesh.ok()) {
    std::fprintf(stderr, "%s\n", std::string(mesh.status().message()).c_str());
    return 1;
  }
  const tandem::eval::TopologyReport t = tandem::eval::AnalyzeTopology(*mesh);
  const size_t dups = tandem::eval::CountDuplicatePositions(*mesh);

  const tandem::eval::TopologyReport w =
      dups > 0 ? tandem::eval::AnalyzeTopology(tandem::eval::WeldByPosition(*mesh)) : t;
  size_t zero_area = 0;
  for (size_t k = 0; k + 2 < mesh->indices.size(); k += 3) {
    const uint32_t* v = &mesh->indices[k];
    if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0]) continue;
    const tandem::Vec3 a = mesh->positions[v[0]], b = mesh->positions[v[1]],
                       c = mesh->positions[v[2]];
    zero_area += tandem::IsWrittenDegenerate(a, b, c);
  }

  std::printf(
      "{\"triangles\": %zu, \"vertices\": %zu, \"manifold\": %s, \"euler\": %lld, "
      "\"boundary_edges\": %zu, \"nonmanifold_edges\": %zu, \"nonmanifold_vertices\": %zu, "
      "\"misoriented_edges\": %zu, \"degenerate_triangles\": %zu, \"components\": %zu, "
      "\"boundary_loops\": %zu, \"duplicate_positions\": %zu, \"welded_manifold\": %s, "
      "\"welded_euler\": %lld, \"welded_degenerate_triangles\": %zu, \"anisotropy\": %.6g, "
      "\"directional_bias\": %.6g, \"zero_area_triangles\": %zu}\n",
      t.triangles, mesh->num_vertices(), t.IsManifold() ? "true" : "false",
      static_cast<long long>(t.euler), t.boundary_edges, t.nonmanifold_edges,
      t.nonmanifold_vertices, t.misoriented_edges, t.repeated_index_triangles, t.components,
      t.boundary_loops, dups, w.IsManifold() ? "true" : "false", static_cast<long long>(w.euler),
      w.repeated_index_triangles, tandem::eval::Anisotropy(*mesh),
      tandem::eval::DirectionalBias(*mesh), zero_area);
  return 0;
}
