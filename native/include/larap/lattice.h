// The volumetric lattice: a sparse set of cubic cells of a uniform grid around a mesh.
//
// Kept cells are (1) every cell a triangle of the mesh overlaps (exact separating-axis
// triangle/box test, so large triangles and thin parts are never missed), (2) every cell that
// contains a vertex (loose vertices and point clouds bind too), (3) every cell inside the solid,
// and (4) the 3x3x3 block of cells around each vertex's cell, so that every quadratic B-spline
// stencil is complete. Cells entirely outside are deleted.
//
// "Inside" is the union of two tests that fail in different ways, so that real meshes (open,
// soups, inconsistently oriented, non-manifold) work:
//   - enclosed: not reachable from the grid border through cells the surface does not touch
//     (orientation-free; closes gaps smaller than a cell);
//   - ray parity vote: rays through the cell centre along +-x, +-y, +-z; a ray that crosses the
//     surface an odd number of times votes "inside"; 4 of 6 votes make the cell inside (survives
//     holes that only a few directions see).
// Neither fills a genus-1 hole wider than a cell, nor the space between separate parts.
//
// Cells are addressed by integer grid coordinates relative to `origin`; the grid's cell size is
// `h`. A coarser level of a hierarchy groups 2x2x2 cells: coarse cell (i>>1, j>>1, k>>1).
// Nodes are the corners of kept cells. The ARAP neighbourhood of a node is its lattice edges (the
// axis-aligned edges of kept cells): see docs/method.md.
#pragma once
#include <larap/mesh.h>

#include <array>
#include <cstdint>
#include <vector>

namespace larap {

struct LatticeOptions {
  double cell_size = 0.0;  // > 0: use this edge length
  int64_t cells = 0;       // > 0: aim for about this many kept cells (used when cell_size == 0)
  // Refuse (OutOfMemory) a grid whose estimated memory exceeds this many bytes; 0 = derived from
  // the machine's physical memory (half of it).
  int64_t max_bytes = 0;
};

// Default target cell count when neither cells nor cell_size is given.
constexpr int64_t kDefaultCells = 6000;

class Lattice {
 public:
  // Builds the lattice of `mesh` (already validated). Throws InvalidInput for bad options and
  // OutOfMemory when the grid would not fit.
  static Lattice build(const PolygonMesh& mesh, const LatticeOptions& options);

  // ------------------------------------------------------------------ grid
  Eigen::Vector3d origin;  // position of grid corner (0,0,0)
  double h = 0.0;          // cell edge length
  Eigen::Vector3i dims;    // number of grid cells per axis (nodes: dims + 1)

  // ------------------------------------------------------------------ cells
  std::vector<Eigen::Vector3i> cell_coords;   // #C integer coordinates of kept cells
  std::vector<std::array<int32_t, 8>> cell_nodes;  // #C corner node ids, corner c = (c&1, c>>1&1, c>>2)
  std::vector<uint8_t> cell_kind;             // #C bit 1 surface, 2 inside, 4 vertex, 8 dilation

  // ------------------------------------------------------------------ nodes
  std::vector<Eigen::Vector3i> node_coords;   // #N integer coordinates
  RowMatrixX3d rest;                          // #N by 3 rest positions (origin + h * coords)
  std::vector<int32_t> adj_offsets;           // #N+1 CSR offsets of the edge neighbourhood
  std::vector<int32_t> adj;                   // neighbour node ids, sorted per node
  std::vector<std::array<int32_t, 2>> edges;  // #E undirected edges (i < j)
  std::vector<int32_t> component;             // #N connected component id of each node
  int32_t num_components = 0;

  int64_t num_cells() const { return static_cast<int64_t>(cell_coords.size()); }
  int64_t num_nodes() const { return static_cast<int64_t>(node_coords.size()); }

  // Node id at integer grid coordinates, or -1 if no kept cell has that corner.
  int32_t node_at(int x, int y, int z) const;
  // Kept cell id at integer grid coordinates, or -1.
  int32_t cell_at(int x, int y, int z) const;

  // The next coarser level: cells are 2x2x2 blocks of this lattice's cells (same origin, twice
  // the cell size); a block is kept when any of its cells is.
  Lattice coarsened() const;

  // Bytes a grid of these dimensions needs while building (dense index grids + marks).
  static int64_t estimate_bytes(const Eigen::Vector3i& dims);

 private:
  static Lattice from_marks(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                            const std::vector<uint8_t>& marks);
  std::vector<int32_t> node_grid_;  // (dims+1)^3 dense map to node ids
  std::vector<int32_t> cell_grid_;  // dims^3 dense map to cell ids
};

}  // namespace larap
