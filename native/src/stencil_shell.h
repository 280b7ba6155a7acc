// The stencil shell: nodes that complete the quadratic B-spline stencils without adding stiffness,
// coupling or volume loss (docs/method.md).
//
// Every real node n gets a B-spline stencil: for each offset d in {-1,0,1}^3 the node of n's piece
// at grid point p = n + d. That is
//   - a real node m at p that shares a cell copy with n (when exactly one does), or
//   - a shell node, shared by the stencils of neighbouring real nodes of the same piece: items
//     (n, d) and (n', d') of a lattice edge n-n' that name the same point are one node (unless
//     that would join two different real nodes, or n's point is ambiguous: then it stays private).
// A shell node sits at the mean of its items' extrapolations
//   ext(n, d) = x_n + sum_a |d_a| * (mean over n's edge neighbours m one step towards sign(d_a)
//               along a of x_m - x_n; or, with none that way, of x_n - x_m one step back),
// a fixed linear combination of real nodes with weights summing to one: affine maps (rigid
// motions included) are reproduced exactly, and the shell never feeds back into the real nodes.
//
// What a solver backend must do: solve only for the real nodes [0, real_nodes) (shell nodes have
// no edges and no handle rows), and set the shell rows with Lattice::fill_shell after every
// change of the real rows (global step, set_pose, rigid carry) -- or at least before a B-spline
// transfer.
#pragma once
#include <larap/lattice.h>

namespace larap {

// Appends the shell nodes to `lat` (real nodes only so far) and fills stencil27 and shell_*.
void build_stencil_shell(Lattice& lat);

// What the cell copies say of each stencil item: for real node n (of the first `nodes`) and offset
// index k = (dx+1) + 3 (dy+1) + 9 (dz+1), cover[27 n + k] is the one real node at n + d that
// shares a cell copy with n, kStencilNone when no copy reaches there, kStencilAmbiguous when
// copies of several pieces do (n is a node where pieces meet: junction_stencils.h).
constexpr int32_t kStencilNone = -1, kStencilAmbiguous = -2;
std::vector<int32_t> stencil_cover(const Lattice& lat, int64_t nodes);
inline int stencil_offset_index(int dx, int dy, int dz) { return (dx + 1) + 3 * (dy + 1) + 9 * (dz + 1); }

}  // namespace larap
