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
#include <utility>
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

// The parts hitting each surface voxel of a cell. A cell of at most kMaskParts parts (nearly
// every one) keeps a mask per voxel, bit i for parts[i]; one of more keeps a list per voxel (CSR
// over its k^3 voxels, each ascending). Either way the same sets.
constexpr int kMaskParts = 64;
struct PartSets {
  std::vector<int32_t> parts;           // the cell's parts, ascending
  std::vector<uint64_t> masks;          // k^3 masks, or empty
  std::vector<int32_t> offsets, lists;  // k^3 + 1 offsets and the lists, when masks is empty
  bool meet(int64_t a, int64_t b) const {
    if (!masks.empty()) return (masks[size_t(a)] & masks[size_t(b)]) != 0;
    return sorted_sets_meet(lists.data() + offsets[a], lists.data() + offsets[a + 1],
                            lists.data() + offsets[b], lists.data() + offsets[b + 1]);
  }
  // The parts of voxel vi, ascending: a range of lists, or of scratch, which a mask is read into
  // (valid until the next call with the same scratch).
  std::pair<const int32_t*, const int32_t*> of(int64_t vi, std::vector<int32_t>& scratch) const {
    if (masks.empty()) return {lists.data() + offsets[vi], lists.data() + offsets[vi + 1]};
    scratch.clear();
    for (uint64_t m = masks[size_t(vi)]; m; m &= m - 1) scratch.push_back(parts[size_t(__builtin_ctzll(m))]);
    return {scratch.data(), scratch.data() + scratch.size()};
  }
};

// The parts hitting the surface voxels (v == 1) of the cell at `corner`, from its triangles
// tris[ids[q]], q in [q0, q1); masks when the cell has at most max_mask_parts parts (a parameter
// for the tests, which compare the two forms).
PartSets part_sets(const uint8_t* v, int k, const Eigen::Vector3d& corner, double hv, const RowMatrixX3d& V,
                   const std::vector<Eigen::Vector3i>& tris, const int32_t* ids, int32_t q0, int32_t q1,
                   const std::vector<int32_t>& vertex_part, int max_mask_parts = kMaskParts);

// The cell's pieces under the rules above: writes the piece labels (>= 3, in the order of each
// piece's first voxel, as the flood fill of a one-part cell) into v and the voxels per piece into
// size (at most 253 pieces: the rest merge into the last); returns the number of pieces found.
int32_t pieces_by_part(uint8_t* v, int k, const PartSets& sets, std::vector<int32_t>& size);

}  // namespace larap
