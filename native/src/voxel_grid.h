// The uniform grid a lattice is cut from: every cell of the mesh's padded bounding box marked
// surface (an exact triangle/box test), vertex, inside (enclosed, or 4 of 6 ray-parity votes) or
// dilation (the 3x3x3 block around a vertex cell, the B-spline's reach). Lattice::build
// (lattice.cpp) voxelises, then assembles the kept cells into a lattice. Internal.
#pragma once
#include <larap/lattice.h>
#include <larap/mesh.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "cell_pieces.h"
#include "geometry.h"

namespace larap {

constexpr uint8_t kKept = kReal;  // dilation cells only count towards the target (no cells)
constexpr int kPad = 2;  // empty border cells around the bounding box (dilation + flood fill)

// The machine's physical memory in bytes (the default limit is half of it).
int64_t physical_memory_bytes();

struct Grid {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  double h = 0.0;
  Eigen::Vector3i dims = Eigen::Vector3i::Zero();
  std::vector<uint8_t> marks;
  std::vector<int64_t> vertex_cells;  // grid index of each vertex's cell
  int64_t index(int x, int y, int z) const {
    return x + int64_t(dims.x()) * (y + int64_t(dims.y()) * z);
  }
  int64_t size() const { return int64_t(dims.x()) * dims.y() * dims.z(); }
  // The cell of point p, clamped to the grid: clamped in double, then floored (the same as the
  // floor clamped, for integer bounds), so floor_int never sees a value beyond int's range.
  Eigen::Vector3i cell_of(const Eigen::Vector3d& p) const {
    Eigen::Vector3i c;
    for (int a = 0; a < 3; ++a)
      c[a] = geometry::floor_int(std::clamp((p[a] - origin[a]) / h, 0.0, double(dims[a] - 1)));
    return c;
  }
};

// Cells per axis of a grid of cell size h over `extent` (padded by kPad on each side).
Eigen::Vector3i grid_dims(const Eigen::Vector3d& extent, double h);
// Throws OutOfMemory (naming the MiB) when such a grid would not fit in max_bytes.
void check_memory(const Eigen::Vector3i& dims, double h, int64_t max_bytes);
// The marked grid of `mesh` (triangles `tris`, loose edges `segs`) over the box lo..hi at cell
// size h. A cell a loose edge passes through is marked kVertex, as if it held a vertex.
Grid voxelize(const PolygonMesh& mesh, const std::vector<Eigen::Vector3i>& tris,
              const std::vector<Eigen::Vector2i>& segs, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double h, int64_t max_bytes);
// Cells that count towards the `cells` target (see voxel_grid.cpp).
int64_t count_kept(const Grid& g);

}  // namespace larap
