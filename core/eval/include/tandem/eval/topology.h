// Combinatorial checks of a triangle mesh: manifoldness, orientation, Euler characteristic,
// components and boundary loops. Pure functions of an IndexedMesh; O(T log T).
#ifndef TANDEM_TOPOLOGY_H_
#define TANDEM_TOPOLOGY_H_

#include <cstdint>
#include <vector>

#include "tandem/mesh.h"

namespace tandem::eval {

struct TopologyReport {
  size_t vertices = 0;   // vertices used by at least one triangle
  size_t edges = 0;
  size_t triangles = 0;
  int64_t euler = 0;     // V - E + F
  size_t boundary_edges = 0;        // in exactly one triangle
  size_t nonmanifold_edges = 0;     // in three or more triangles
  size_t misoriented_edges = 0;     // two triangles traverse it in the same direction
  size_t repeated_index_triangles = 0;  // a vertex index repeated (not geometry.h's zero area)
  size_t nonmanifold_vertices = 0;  // triangles around it form more than one fan
  size_t components = 0;            // connected through shared vertices
  size_t boundary_loops = 0;
  std::vector<int64_t> component_euler;  // per component, ordered by smallest triangle id

  // An orientable 2-manifold, possibly with boundary.
  bool IsManifold() const {
    return nonmanifold_edges == 0 && misoriented_edges == 0 && repeated_index_triangles == 0 &&
           nonmanifold_vertices == 0;
  }
  bool IsClosedManifold() const { return IsManifold() && boundary_edges == 0; }
};

TopologyReport AnalyzeTopology(const IndexedMesh& mesh);

// Number of vertices whose positions coincide exactly with another vertex's.
size_t CountDuplicatePositions(const IndexedMesh& mesh);
// The mesh as a reader that merges vertices by position sees it (STL readers, slicers): the
// vertices at one exact position become one (the first of them, in id order), the
// triangles kept as they are.
IndexedMesh WeldByPosition(const IndexedMesh& mesh);

}  // namespace tandem::eval

#endif  // TANDEM_TOPOLOGY_H_
