// Zero-area triangles left in a simplified mesh (they break normals, STL slicers and
// some viewers). Marching cubes on integer scans puts the surface point of every crossed edge
// at a grid point whose value equals the iso-value, and simplification removes almost all of
// what that makes; what stays is what the link condition or the checks must keep: a triangle
// with its three corners on one line, or with corners at one point where two sheets touch.
// TidyDegenerate, run on the final mesh (Simplifier::TidyDegenerate) or on the triangles a
// sealer is about to seal (TidyDegenerateAmong), mends both without changing the topology:
//   - collinear corners (a, b and m between them): the edge ab is flipped to m c, c the far
//     corner of the triangle across ab; the two new triangles tile that one exactly, so the
//     surface does not move;
//   - a closed component of four triangles at one point, off the grid's box (a lone voxel
//     exactly at the iso-value: the most the link condition lets contractions make of it)
//     becomes a regular tetrahedron of circumradius `size` around the point, facing out;
//   - a triangle alone in its component, flat on the grid's box at a point or along a line
//     (a voxel at the iso-value on the box): it parts by `size`, facing into the box, within
//     its face, or on an edge of the box within one of its two faces, the moved corners
//     stepping off the other straight into the box;
//   - other corners at one point, or on one line where no flip can mend it (the line along
//     the grid's box): each corner at another's point, else the middle one, moves toward
//     the centroid of its own neighbours elsewhere by kApart of the way (along its box faces
//     if it is on the box), which parts the sheets; a corner on an edge of the box, where
//     every such step stays on the edge's line, may step off one of its two faces instead.
// A corner that steps off a face of the box loses that face's flag.
// A move is taken only where no triangle turns over or collapses, the mended ones come out
// facing as their neighbours across their edges do, and `may_move` agrees (the simplifier's
// error bound). On the shared scans at the benchmark's reductions (TARGET.md's 12 points)
// none is left, sealed or not (the sealer mends the triangles around a corner before it
// hands the corner out: once out, it may not move).
#ifndef TANDEM_DEGENERATE_H_
#define TANDEM_DEGENERATE_H_

#include <cstdint>
#include <functional>
#include <span>

#include "mesh_store.h"
#include "tandem/types.h"

namespace tandem {

struct DegenerateCounts {
  int64_t flipped = 0;  // edges flipped
  int64_t moved = 0;    // vertices moved apart
  int64_t left = 0;     // zero-area triangles neither could mend
};

// Fraction of the way to its neighbours' centroid a corner moves apart.
inline constexpr double kApart = 0.05;

// Mends the zero-area triangles (IsDegenerateTriangle) of the store. `may_move(v, p)`: whether
// vertex v may move to p. Moved vertices are passed to `moved(v)`.
DegenerateCounts TidyDegenerate(MeshStore* store, double size,
                                const std::function<bool(VertexId, Vec3)>& may_move,
                                const std::function<void(VertexId)>& moved);
// The same for the zero-area triangles among `tris` only (live ones; a sealed chunk's, before
// it is sealed). Without `flips`, only corners move (may_move deciding): the topology stays
// as it is, for triangles the simplifier still works on.
DegenerateCounts TidyDegenerateAmong(MeshStore* store, std::span<const TriId> tris, double size,
                                     const std::function<bool(VertexId, Vec3)>& may_move,
                                     const std::function<void(VertexId)>& moved,
                                     bool flips = true);

// Whether moving v to q keeps its triangles facing as they do, none collapsing (the test a
// corner's move above must pass), e.g. for the second copy of a seam vertex (slabs.h). A
// degenerate triangle must come out facing as its neighbours across its edges do, else as
// VertexFacing(v), else (no triangle near v has an area) as `otherwise`: the second copy of a
// seam vertex whose slab holds only a sliver there faces as the first copy's slab.
bool MoveKeepsFacing(const MeshStore& store, VertexId v, Vec3 q, Vec3 otherwise = {0, 0, 0});
// The way v's triangles face: the sum of their twice-area vectors, the degenerate ones left
// out; where all are degenerate, the nearest triangles' with an area, a few rings out across
// edges; zero if there are none.
Vec3 VertexFacing(const MeshStore& store, VertexId v);

}  // namespace tandem

#endif  // TANDEM_DEGENERATE_H_
