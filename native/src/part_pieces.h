// The pieces of one analysed cell whose triangles belong to several parts (mesh_parts.h), for
// cell splitting (cell_pieces.h, step 4). Internal to the lattice builder.
//
// On the cell's k^3 voxels (0 enclosed, 1 surface, 2 air, as cell_pieces.cpp finds them):
// - which parts hit each surface voxel, the voxel's box grown by kContact of a voxel to every side,
//   so that a crack under a quarter voxel between two parts never falls between two voxels;
// - two touching surface voxels join only when one part hits both; enclosed voxels join whatever
//   they touch (a part inside another's solid moves with it, and so does a pocket of space the air
//   flood did not reach: telling it from the inside of a thin part would need the triangles'
//   orientation, which soups and flipped meshes do not give).
#pragma once
#include <larap/mesh.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "geometry.h"
#include "voxel_hits.h"

namespace larap {

constexpr double kContact = 0.125;  // growth of a voxel's box for the parts' hits, in voxels

// Whether two ascending lists share an entry.
inline bool sorted_sets_meet(const int32_t* a, const int32_t* a_end, const int32_t* b, const int32_t* b_end) {
  while (a < a_end && b < b_end) {
    if (*a == *b) return true;
    *a < *b ? ++a : ++b;
  }
  return false;
}

// The parts hitting each surface voxel of a cell (CSR over its k^3 voxels, each list ascending).
struct PartSets {
  std::vector<int32_t> offsets;  // k^3 + 1
  std::vector<int32_t> parts;
  const int32_t* begin(int64_t vi) const { return parts.data() + offsets[vi]; }
  const int32_t* end(int64_t vi) const { return parts.data() + offsets[vi + 1]; }
  bool meet(int64_t a, int64_t b) const { return sorted_sets_meet(begin(a), end(a), begin(b), end(b)); }
};

// The parts hitting the surface voxels (v == 1) of the cell at `corner`, from its triangles
// tris[ids[q]], q in [q0, q1).
PartSets part_sets(const uint8_t* v, int k, const Eigen::Vector3d& corner, double hv, const RowMatrixX3d& V,
                   const std::vector<Eigen::Vector3i>& tris, const int32_t* ids, int32_t q0, int32_t q1,
                   const std::vector<int32_t>& vertex_part);

// The cell's pieces under the rules above: writes the piece labels (>= 3, in the order of each
// piece's first voxel, as the flood fill of a one-part cell) into v and the voxels per piece into
// size (at most 253 pieces: the rest merge into the last); returns the number of pieces found.
int32_t pieces_by_part(uint8_t* v, int k, const PartSets& sets, std::vector<int32_t>& size);

}  // namespace larap
