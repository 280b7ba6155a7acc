// Binding of mesh vertices to lattice nodes: every vertex is a fixed linear combination of nodes.
//   trilinear: the 8 corners of the vertex's cell (fast; C0 across cells), used while dragging;
//   bspline:   the 27 nodes around the nearest node, uniform quadratic B-spline (C1), final quality.
// Both weight sets sum to one and reproduce affine maps exactly.
#pragma once
#include <larap/lattice.h>

#include <string>

namespace larap {

enum class WeightKind { Trilinear, BSpline };

WeightKind parse_weight_kind(const std::string& name);  // "trilinear" | "bspline"
const char* weight_kind_name(WeightKind kind);

struct Binding {
  WeightKind kind = WeightKind::Trilinear;
  // Per vertex: trilinear -> the id of its cell copy; bspline -> its row of node27: the id of its
  // nearest node (a corner of its cell copy), or, near a junction, a row read from its own part's
  // side (junction_stencils.h), appended after the per-node rows.
  std::vector<int32_t> base;
  // Per vertex (#V by 3, row-major): trilinear -> position in the cell in [0,1]^3;
  // bspline -> offset from the nearest node in [-1/2,1/2]^3 (in cells).
  std::vector<float> frac;
  // bspline only: rows of 27 ids of the node of the same piece at (x+dx, y+dy, z+dz), d in
  // {-1,0,1}, dx fastest: a real node or a stencil-shell node. One row per real node
  // (Lattice::stencil27), then the junction rows.
  std::vector<int32_t> node27;

  int stencil_size() const { return kind == WeightKind::Trilinear ? 8 : 27; }
  int64_t num_vertices() const { return static_cast<int64_t>(base.size()); }
  // Node ids and weights of vertex v: writes stencil_size() entries into ids and w.
  void weights_of(const Lattice& lattice, int64_t v, int32_t* ids, double* w) const;
};

// Binds `vertices` (#V by 3, the mesh the lattice was built for) with the given weights; each
// vertex binds to the cell copy of its own piece (Lattice::vertex_cell).
Binding bind_vertices(const Lattice& lattice, const RowMatrixX3d& vertices, WeightKind kind);
// Binds points given the cell copy of each (#P by 3 positions, #P cell ids).
Binding bind_points(const Lattice& lattice, const RowMatrixX3d& points, const std::vector<int32_t>& cells,
                    WeightKind kind);

// out = vertices + W * displacement, where displacement is #N by 3 (deformed - rest lattice).
// out is #V by 3 row-major; parallel over vertices, deterministic.
void transfer(const Lattice& lattice, const Binding& binding, const RowMatrixX3d& vertices,
              const RowMatrixX3d& displacement, double* out);
void transfer(const Lattice& lattice, const Binding& binding, const RowMatrixX3d& vertices,
              const RowMatrixX3d& displacement, float* out);

}  // namespace larap
