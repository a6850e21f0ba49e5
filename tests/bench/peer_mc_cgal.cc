// Peer "mc+cgal": our marching cubes (tandem_core, no simplification) followed by CGAL 5.5's
// Surface_mesh_simplification::edge_collapse with the Garland-Heckbert plane policies
// (classic quadric error metric: cost and optimal placement), wrapped in
// Bounded_normal_change_placement (refuses collapses that flip a face), stopped at a target
// face count.
//   peer_mc_cgal --input V.json --iso C0 --target-triangles N --out M.ply
// CGAL is GPL: this program is part of the benchmark only and is never linked into core,
// server or client.
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/Bounded_normal_change_placement.h>
#include <CGAL/Surface_mesh_simplification/Policies/Edge_collapse/GarlandHeckbert_plane_policies.h>
#include <CGAL/Surface_mesh_simplification/edge_collapse.h>

#include "bench_common.h"
#include "core_extract.h"

namespace SMS = CGAL::Surface_mesh_simplification;
using Kernel = CGAL::Simple_cartesian<double>;
using Mesh = CGAL::Surface_mesh<Kernel::Point_3>;

// Stops once the mesh has at most `target` faces (Surface_mesh::number_of_faces() does not
// count faces already removed by a collapse).
struct FaceCountStop {
  const Mesh* mesh;
  size_t target;
  template <typename F, typename Profile>
  bool operator()(const F&, const Profile&, size_t, size_t) const {
    return mesh->number_of_faces() <= target;
  }
};

int main(int argc, char** argv) {
  bench::Result r;
  r.pipeline = "mc+cgal";
  bench::Clock clock;
  bench::PeerInput in = bench::ExtractPeerInput(argc, argv, &r, &clock);
  const long long target = in.target;
  const std::string& out = in.out;
  std::vector<float>& xyz = in.xyz;
  std::vector<uint32_t>& indices = in.indices;

  Mesh mesh;
  const size_t nv = xyz.size() / 3;
  mesh.reserve(nv, 3 * indices.size() / 2, indices.size() / 3);
  std::vector<Mesh::Vertex_index> vid(nv);
  for (size_t i = 0; i < nv; ++i) vid[i] = mesh.add_vertex(Kernel::Point_3(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]));
  size_t rejected = 0;
  for (size_t t = 0; t < indices.size(); t += 3) {
    if (mesh.add_face(vid[indices[t]], vid[indices[t + 1]], vid[indices[t + 2]]) == Mesh::null_face()) ++rejected;
  }
  std::vector<float>().swap(xyz);
  std::vector<uint32_t>().swap(indices);
  if (rejected > 0) r.note = std::to_string(rejected) + " faces rejected by Surface_mesh";

  using GHPolicies = SMS::GarlandHeckbert_plane_policies<Mesh, Kernel>;
  GHPolicies gh(mesh);
  SMS::Bounded_normal_change_placement<GHPolicies::Get_placement> placement(gh.get_placement());
  FaceCountStop stop{&mesh, static_cast<size_t>(target)};
  SMS::edge_collapse(mesh, stop, CGAL::parameters::get_cost(gh.get_cost()).get_placement(placement));
  mesh.collect_garbage();

  // Back to arrays (vertex indices are contiguous after collect_garbage).
  xyz.reserve(3 * mesh.number_of_vertices());
  for (Mesh::Vertex_index v : mesh.vertices()) {
    const auto& p = mesh.point(v);
    xyz.push_back(float(p.x()));
    xyz.push_back(float(p.y()));
    xyz.push_back(float(p.z()));
  }
  indices.reserve(3 * mesh.number_of_faces());
  for (Mesh::Face_index f : mesh.faces()) {
    for (Mesh::Vertex_index v : vertices_around_face(mesh.halfedge(f), mesh)) indices.push_back(uint32_t(v));
  }
  r.simplify_s = clock.Lap();  // includes building the Surface_mesh and converting back
  r.triangles_final = static_cast<int64_t>(indices.size() / 3);
  r.vertices_final = static_cast<int64_t>(xyz.size() / 3);
  bench::WritePly(out, xyz.data(), xyz.size() / 3, indices.data(), indices.size());
  r.write_s = clock.Lap();
  bench::PrintResult(r);
  return 0;
}
