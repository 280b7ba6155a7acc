// The surface cells of the lattice grid and the patches of the surface inside each: which
// triangles overlap which surface cell, which neighbouring surface cells share a triangle, and
// which cells hold more than one patch (the triangles overlapping the cell form several connected
// components where they meet inside the cell: at a shared vertex in the cell's closed box or along
// a shared edge that overlaps it; a fork's two tines joined far away are two, and so are a coarse
// mesh's two sheets whose triangles share only a vertex beyond the cell). Any two neighbouring
// cells one triangle overlaps share it, however many cells it spans. For a joined, conforming
// mesh the patches are a property of the surface in the cell, not of how it is cut into
// triangles (overlapping or duplicate triangles and T-junctions can only add patches). Internal
// to the lattice builder: cell_pieces.cpp picks its candidate cells from it.
//
// A fine mesh has hundreds of triangles per surface cell, so this is the costly part of cell
// splitting; it avoids per-cell triangle lists:
// - Per vertex, once: the cell it lies inside, farther than 1e-7 h from the cell's faces. A
//   triangle's cell range is the min/max of its vertices' (the floor is monotone, so it commutes
//   with min and max), so a triangle whose three vertices lie inside one cell overlaps that cell
//   alone (no overlap test, as before). The others ("crossing", about 10% of a fine mesh's) are
//   found once per cell they overlap; a cell holding one of their vertices needs no overlap test.
// - Patches: the vertices of the triangles inside one cell are joined globally (a concurrent
//   union-find whose classes each stay in one cell); a cell's own analysis then walks only its
//   crossing triangles: each joins the classes of its vertices inside the cell, its other
//   vertices that lie in the cell's box, and the crossing triangles across its edges that
//   overlap the box.
// The result is the same as testing every triangle against every cell of its range and joining
// each cell's triangles where they meet in the cell; tests/cpp/test_cell_pieces.cpp checks that.
#pragma once
#include <larap/mesh.h>

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace larap {

// Grid indices of a dims-sized grid (x fastest).
struct GridIndex {
  Eigen::Vector3i d;
  int64_t index(int x, int y, int z) const { return x + int64_t(d.x()) * (y + int64_t(d.y()) * z); }
  int64_t index(const Eigen::Vector3i& c) const { return index(c.x(), c.y(), c.z()); }
  Eigen::Vector3i coords(int64_t id) const {
    return Eigen::Vector3i(int(id % d.x()), int((id / d.x()) % d.y()), int(id / (int64_t(d.x()) * d.y())));
  }
  bool contains(const Eigen::Vector3i& c) const {
    return (c.array() >= 0).all() && (c.array() < d.array()).all();
  }
};

// Bit of the neighbour at offset o in {-1,0,1}^3 (o != 0) in a 27-bit mask.
inline int offset_bit(const Eigen::Vector3i& o) { return (o.x() + 1) + 3 * (o.y() + 1) + 9 * (o.z() + 1); }

struct SurfacePatches {
  GridIndex grid;
  std::vector<int32_t> surf_of;    // per grid cell: its index among the surface cells, or -1
  std::vector<int64_t> cells;      // #S grid index of each surface cell, ascending
  std::vector<uint32_t> shares;    // #S 27-bit masks: shares a triangle with the neighbour at o
  std::vector<uint8_t> several;    // #S its triangles form more than one patch
  // The triangles of each surface cell that are not inside it alone (CSR, ascending per cell).
  std::vector<int32_t> crossing_offsets, crossing;   // #S + 1 offsets; triangle ids
  // Per vertex: the surface cell it lies inside, farther than 1e-7 h from the cell's faces, or
  // kNoCell. A triangle whose three vertices have the same one lies inside that cell alone.
  std::vector<uint32_t> vertex_cell;
  static constexpr uint32_t kNoCell = 0xFFFFFFFFu;
};

// Grid: cells of size h from `origin`, `dims` per axis, kSurface marks as the voxeliser set them
// (cell_pieces.h).
SurfacePatches find_surface_patches(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                                    const std::vector<uint8_t>& marks, const RowMatrixX3d& V,
                                    const std::vector<Eigen::Vector3i>& tris);

// The triangles overlapping each surface cell of `which` (surface indices), ascending, as CSR:
// offsets has which.size() + 1 entries.
void triangles_of(const SurfacePatches& sp, const std::vector<Eigen::Vector3i>& tris,
                  const std::vector<int32_t>& which, std::vector<int32_t>& offsets,
                  std::vector<int32_t>& ids);

}  // namespace larap
