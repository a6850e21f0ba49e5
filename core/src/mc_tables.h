// Marching-cubes case tables, generated once from face rules instead of typed by hand.
//
// Cube corners: c = x | y<<1 | z<<2 (z = 0 on the lower slice). Edges, in this order:
//   x-edges 0:(0,1) 1:(2,3) 2:(4,5) 3:(6,7), y-edges 4:(0,2) 5:(1,3) 6:(4,6) 7:(5,7),
//   z-edges 8:(0,4) 9:(1,5) 10:(2,6) 11:(3,7).
// A corner is "in" when F >= C0 (values equal to the iso-value count as above it).
//
// How a case is built: on every face, walking its corners counter-clockwise as seen from
// outside the cube, each out->in crossing starts a segment that ends at an in->out crossing:
// the next one forward (in-corners separated) or backward (in-corners connected). Only faces
// whose corners alternate in/out have a choice; the caller decides it per face with the
// asymptotic decider, which depends on the face's four values only, so the two cubes sharing
// a face make the same choice and their patches meet without cracks or overlaps. Segments
// chain into closed loops; each loop is oriented counter-clockwise seen from the "out" side
// (where F < C0), which is the outward normal of the iso-surface of a solid.
// A loop triangulates as a fan from its first vertex, except when it runs through both
// segments of one ambiguous face: a fan diagonal between two points of that face could be
// made by the neighbouring cube as well (an edge in four triangles), so such a loop is fanned
// around an extra vertex at its centroid instead (`center` bit).
#ifndef TANDEM_MC_TABLES_H_
#define TANDEM_MC_TABLES_H_

#include <cstdint>

namespace tandem::mc {

inline constexpr int kEdgeCorners[12][2] = {{0, 1}, {2, 3}, {4, 5}, {6, 7}, {0, 2}, {1, 3},
                                            {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};

struct CubeCase {
  uint8_t num_loops = 0;
  uint8_t loop_len[4] = {0, 0, 0, 0};
  uint8_t edges[12] = {};  // loops back to back, each in counter-clockwise order
  uint8_t center_mask = 0; // bit l: loop l is fanned around an extra centroid vertex
};

// Corners of face f (0:x=0 1:x=1 2:y=0 3:y=1 4:z=0 5:z=1) counter-clockwise from outside.
const uint8_t (&FaceCorners(int f))[4];
// Faces whose corners alternate in/out for this corner configuration (bit f).
uint8_t AmbiguousFaces(uint8_t config);
// The case for a corner configuration (bit c = corner c is in) and, for each ambiguous face
// f, bit f of `connected` = its two in-corners are joined across the face. Bits of
// non-ambiguous faces are ignored.
const CubeCase& Lookup(uint8_t config, uint8_t connected);

// Face decision from the face's four values relative to C0 in cyclic order (ambiguous face:
// v0, v2 one diagonal, v1, v3 the other). In-corners are connected iff the bilinear
// interpolant's saddle is in, i.e. prod(in pair) >= prod(out pair). Products are formed
// per diagonal, so any cyclic start or direction gives the same answer.
inline bool InCornersConnected(double v0, double v1, double v2, double v3) {
  const double d02 = v0 * v2, d13 = v1 * v3;
  return v0 >= 0 ? d02 >= d13 : d13 >= d02;
}

}  // namespace tandem::mc

#endif  // TANDEM_MC_TABLES_H_
