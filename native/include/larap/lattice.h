// The volumetric lattice: a sparse set of cubic cells of a uniform grid around a mesh.
//
// Kept cells are (1) every cell a triangle of the mesh overlaps (exact separating-axis
// triangle/box test, so large triangles and thin parts are never missed), (2) every cell that
// contains a vertex (loose vertices and point clouds bind too) or that a loose edge passes
// through (mesh.h's segments: a wire stays one piece), and (3) every cell inside the solid.
// Cells entirely outside are deleted.
//
// Cell splitting (virtual node algorithm, docs/method.md): a kept cell that holds more than one
// connected piece of the solid is kept once per piece (a "copy"); copies of face-adjacent cells
// share the nodes of the shared face only where their pieces connect across it (cell_pieces.h).
// So cell_coords and node_coords may repeat. Where nothing is split the lattice is the plain one.
//
// Stencil shell: the quadratic B-spline reads the 27 nodes around a vertex's nearest node. Where
// the lattice has no node of the vertex's piece there, a shell node stands in (nodes
// [num_real_nodes(), num_nodes())): it has no edges, takes no part in the energy, and its position
// is a fixed linear extrapolation of real nodes of its own piece (shell_* below), so the pose of
// the real nodes does not depend on the weight kind. See stencil_shell.h.
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
#include <functional>
#include <vector>

namespace larap {

class Lattice;

struct LatticeOptions {
  double cell_size = 0.0;  // > 0: use this edge length
  int64_t cells = 0;       // > 0: aim for about this many kept cells (used when cell_size == 0)
  // Refuse (OutOfMemory) a grid whose estimated memory exceeds this many bytes; 0 = derived from
  // the machine's physical memory (half of it).
  int64_t max_bytes = 0;
  // Cell splitting (on by default): each cell is kept once per connected piece of the solid in
  // it, decided on a split_resolution^3 voxel grid inside the cells that may hold several pieces.
  // Two surfaces of one part farther apart than 2 sqrt(3) h / split_resolution separate (along an
  // axis, beyond 2 h / split_resolution) where the air between them reaches a seed; surfaces of
  // separate parts closer (measured: beyond 1.55 sqrt(3) h / split_resolution; docs/method.md).
  bool split_cells = true;
  int split_resolution = 24;  // in [4, 64]
  // One copy per branch where separate parts meet (research stage, off by default; needs
  // split_cells):
  // docs/method.md, "One copy per branch", native/src/branch_copies.h.
  bool branch_copies = false;
  double branch_coupling = 10.0;  // a coupling's weight per unit of its trunk copy's weight
  // Research hook (scripts/experiments/branch_engine.py): applied to the fine lattice after
  // assembly and before the stencil shell. Not part of the public API.
  std::function<void(Lattice&)> edit;
};

// A branch copy's rotation also answers for the 12 edges of the copy it was split from (its
// trunk's), weighing `weight` (docs/method.md, "One copy per branch"): the energy gains
// weight * sum over the trunk copy's edges |(p_a - p_b) - R_branch (c_a - c_b)|^2.
struct Coupling {
  int32_t branch = -1, trunk = -1;
  double weight = 0.0;
};

// The arrays of a lattice's copies, from which Lattice::replace_copies rebuilds one on the same
// grid (research hook; copies in grid order, copies of a cell consecutive).
struct LatticeCopies {
  std::vector<Eigen::Vector3i> cell_coords;
  std::vector<std::array<int32_t, 8>> cell_nodes;  // any node labels: equal labels are one node
  std::vector<uint8_t> cell_kind;
  std::vector<double> cell_weight;                 // empty: all 1
  std::vector<int32_t> vertex_cell;
  std::vector<Coupling> couplings;
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
  // Copies of one grid cell are consecutive, in grid order (x fastest).
  std::vector<Eigen::Vector3i> cell_coords;   // #C integer coordinates of kept cells (may repeat)
  std::vector<std::array<int32_t, 8>> cell_nodes;  // #C corner node ids, corner c = (c&1, c>>1&1, c>>2)
  std::vector<uint8_t> cell_kind;             // #C bit 1 surface, 2 inside, 4 vertex or loose edge
  // Stiffness of each copy (empty: all 1, the plain lattice). A copy of a split cell carries its
  // piece's share of the cell's material (material voxels / split_resolution^3, at least one
  // voxel layer, 1 / split_resolution): a sliver of a finger that crosses a cell corner is as
  // stiff as the material it holds, not as a whole cell (the elasticity of Nesme et al. 2009).
  // Cells kept whole, and every cell of a coarser level, weigh 1.
  std::vector<double> cell_weight;
  // Branch couplings (fine level only; empty where nothing is split per branch). Their weights
  // count in edge_weight (the system's Laplacian) like a copy's, not in gamma's normalisation
  // (handle_system.cpp: they are not material).
  std::vector<Coupling> couplings;

  // ------------------------------------------------------------------ nodes
  // Real nodes first (corners of kept cells, in grid order, copies at one point consecutive), then
  // the shell nodes.
  std::vector<Eigen::Vector3i> node_coords;   // #N integer coordinates (may repeat)
  RowMatrixX3d rest;                          // #N by 3 rest positions (origin + h * coords)
  std::vector<int32_t> adj_offsets;           // #N+1 CSR offsets of the edge neighbourhood
  std::vector<int32_t> adj;                   // neighbour node ids, sorted per node
  std::vector<std::array<int32_t, 2>> edges;  // #E undirected edges (i < j), real nodes only
  // Edge weights: the ARAP energy is a sum over cell copies, each with one rotation, of its 12
  // edges, sum_c w_c sum_(a,b) |(p_a - p_b) - R_c (c_a - c_b)|^2 (docs/method.md, "Energy"), so
  // an edge's weight in the system is half the sum of cell_weight over the copies it is an edge
  // of (the Laplacian's entry 2 g w_ij): 2 inside a plain lattice (4 cells), 1 or 0.5 on its
  // surface; a face a whole cell shares with a nearly empty copy weighs about half as much as one
  // between two whole cells.
  std::vector<double> edge_weight;            // #E, parallel to edges
  std::vector<double> adj_weight;             // parallel to adj
  std::vector<int32_t> component;             // #N connected component id of each node
  int32_t num_components = 0;
  int32_t real_nodes = 0;                     // nodes [0, real_nodes) are real

  // ------------------------------------------------------------------ binding support
  std::vector<int32_t> vertex_cell;           // #V the cell copy holding each mesh vertex's piece
  // Stencil shell (fine level only): shell node s = real_nodes + k sits at
  //   x_s = sum_{e in [shell_offsets[k], shell_offsets[k+1])} shell_weights[e] x_{shell_ids[e]}
  // over real nodes (weights sum to one; affine maps are reproduced exactly).
  std::vector<int32_t> shell_offsets;         // #shell + 1
  std::vector<int32_t> shell_ids;
  std::vector<double> shell_weights;
  // B-spline stencils: per real node, the 27 nodes (real or shell) of its piece at
  // (x+dx, y+dy, z+dz), d in {-1,0,1}, dx fastest. Empty when the lattice has no shell.
  std::vector<int32_t> stencil27;

  int64_t num_cells() const { return static_cast<int64_t>(cell_coords.size()); }
  int64_t num_nodes() const { return static_cast<int64_t>(node_coords.size()); }
  int64_t num_real_nodes() const { return real_nodes; }
  int64_t num_shell_nodes() const { return num_nodes() - real_nodes; }

  // The lowest node id at integer grid coordinates, or -1 if no kept cell has that corner. With
  // split cells a point may hold several nodes: use cell_nodes of the right copy instead.
  int32_t node_at(int x, int y, int z) const;
  // The first copy of the kept cell at integer grid coordinates, or -1; its copies are
  // [cell_at, cell_at + cell_copies).
  int32_t cell_at(int x, int y, int z) const;
  int32_t cell_copies(int x, int y, int z) const;

  // Positions of the shell nodes from those of the real nodes (rows [real_nodes, #N) of P).
  void fill_shell(RowMatrixX3d& P) const;

  // The next coarser level: cells are 2x2x2 blocks of this lattice's cells (same origin, twice
  // the cell size). A block holds one copy per group of its fine copies connected through shared
  // nodes; two coarse copies share a corner when some of their fine copies share a node. No
  // shell. vertex_cell maps each vertex to the coarse copy of its fine copy; parent (if given)
  // receives the coarse copy of every fine cell copy.
  Lattice coarsened(std::vector<int32_t>* parent = nullptr) const;

  // Rebuilds this lattice's cells, nodes and edges from `copies` on the same grid (no shell; the
  // caller builds it). Throws InvalidInput when the arrays do not fit the grid.
  void replace_copies(const LatticeCopies& copies);

  // Bytes a grid of these dimensions needs while building (dense index grids + marks).
  static int64_t estimate_bytes(const Eigen::Vector3i& dims);

 private:
  friend class LatticeAssembly;
  std::vector<int32_t> node_grid_;  // (dims+1)^3 dense map to the lowest node id at each point
  std::vector<int32_t> cell_grid_;  // dims^3 dense map to the first copy of each cell
  std::vector<int32_t> cell_count_; // dims^3 number of copies of each cell
};

}  // namespace larap
