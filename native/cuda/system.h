// The lattice system on the device: raw device pointers and sizes, passed by value to every
// kernel (flip_flop.h, solvers.h). Internal to native/cuda; no public header includes CUDA.
// Filled by the backend (cuda_backend.cpp, cuda_system.cpp) from its DeviceBuffers.
//
// Frame: every position on the device is relative to an origin (the handle system's `origin`,
// the rest lattice's centre), so that float positions do not lose digits to a large offset, and
// the handle sums H, K and the moments need no change of frame. The global step's starting
// residual b - A x is formed from edge differences (x_i - x_j, c_i - x_i) and, for the handle
// term, in double (H - M x): its error is then float rounding of edge-sized and misfit-sized
// quantities, not of |x| (docs/cuda.md, "Precision").
// Vectors of 3 columns (x, y, z) are float4 (w unused) so that one node is one 16-byte load.
#pragma once
#include <cuda_runtime.h>

#include <cstdint>

namespace larap {
namespace cuda {

// Slots of a row of A P stored beside each other per fine node (multigrid.h, ProlongedRows): a
// node away from handles and split cells has at most 4 coarse neighbours.
constexpr int kApSlots = 4;

struct System {
  // Nodes: the real nodes [0, n) are the unknowns; the stencil shell [n, n_all) follows them
  // (Lattice::fill_shell, here launch_fill_shell) and has no edges, rows or rotations. Only x and
  // rest (and the transfer's displacement) hold all n_all nodes; every other array holds n.
  int n = 0;                     // real lattice nodes
  int n_all = 0;                 // real + shell nodes
  const float4* rest = nullptr;  // n_all, rest positions (centred)
  // Lattice neighbours: the first neighbour in each direction in a fixed-width table,
  // nbr[d * n + i], d = -x,+x,-y,+y,-z,+z (a missing neighbour is i itself: it contributes 0 to
  // edge sums, and a_nb = 0 there); with split cells (copies of a cell, lattice.h) a node may
  // have more than one neighbour in a direction: the others are in a short CSR, nbx_off/nbx
  // (empty rows where nothing is split).
  const int* nbr = nullptr;
  const int* nbx_off = nullptr;  // n + 1
  const int* nbx = nullptr;
  // Edge weights (Lattice::adj_weight) of the slots (like nbr) and of the extras (like nbx), for
  // the Laplacian in the residual (always set: half the sum of the copies' weights).
  const float* nbw = nullptr;
  const float* nbxw = nullptr;
  // A split for unrolled products: diagonal, the 6 slot entries (slot-major, like nbr), and the
  // remaining entries (extra neighbours of split cells, handle couplings between non-neighbours)
  // as a short CSR.
  const float* a_diag = nullptr;
  const float* a_nb = nullptr;
  const int* rem_off = nullptr;
  const int* rem_col = nullptr;
  const float* rem_val = nullptr;
  // A = 2 g L + M + a I_anchored, CSR, float; Jacobi preconditioner.
  const int* a_off = nullptr;
  const int* a_col = nullptr;
  const float* a_val = nullptr;
  const float* minv = nullptr;  // 1 / diag(A)
  // The handle term (handle_system.h): c^T M c - 2 c . H + K, M = B^T diag(alpha) B plus the
  // ties, the glue of carried parts and the junction braces (tie_matrix), as CSR over all n nodes
  // (rows of nodes no handle or tie reads are empty), in double: the term is a small difference of large sums near
  // convergence, which float would lose. K (per pose, per lattice component) stays on the host.
  // Nothing here runs over handle rows.
  const int* m_off = nullptr;   // n + 1
  const int* m_col = nullptr;
  const double* m_val = nullptr;
  const double* q = nullptr;    // n: B^T alpha
  const float4* h = nullptr;    // n: H of the current pose's targets (float: the experiments' rhs)
  const double* hd = nullptr;   // 3 n: the same in double, for the residual, energy and moments
  const uint8_t* anchored = nullptr;  // n
  float g = 0.f;                      // gamma_eff
  float a = 0.f;                      // anchor weight
  // State.
  float4* x = nullptr;                // pose (centred), n_all
  float4* p = nullptr;                // CG direction
  float4* r[2] = {nullptr, nullptr};  // ping-pong: residual
  float4* w[2] = {nullptr, nullptr};  // A u
  float4* s[2] = {nullptr, nullptr};  // A p
  float4* x_tmp = nullptr;            // Chebyshev / Jacobi: ping-pong partner of x
  float4* rot = nullptr;              // 3 * ncell: rows a = 0..2 of copy c's rotation at rot[3 c + a]
  // Cell copies (cell_terms.h): corners cell_nodes[q * ncell + c] (real nodes), weights cell_w
  // (null: all 1); per node the copies it is a corner of, nc_off/nc_cell (CSR over n, ascending
  // copies), with w_c times the sum of that corner's 3 rest edges, nc_s (node_cells.h).
  int ncell = 0;
  const int* cell_nodes = nullptr;
  const float* cell_w = nullptr;
  const int* nc_off = nullptr;
  const int* nc_cell = nullptr;
  const float4* nc_s = nullptr;
  // Branch couplings (Lattice::couplings; null when there are none): copy c's couplings are
  // [cp_off[c], cp_off[c + 1]), each a trunk copy cp_trunk and a weight cp_w (rot_cell).
  const int* cp_off = nullptr;
  const int* cp_trunk = nullptr;
  const float* cp_w = nullptr;
  // Scalars.
  double* dots = nullptr;        // (inner + 1) * 6
  float* coef = nullptr;         // (inner + 2) * 8
  unsigned* counters = nullptr;  // inner + 1
  int* iter = nullptr;           // flip-flop counter of the running solve
  double* energy = nullptr;      // 2 per flip-flop (unscaled): ARAP + anchors, c.(M c - 2 H)
  int inner = 8;                 // inner solver iterations per flip-flop
  bool exact_residual = true;    // residual_at (true) or b - A x in float (measurement only)
  // Two-level preconditioner (solver "mg"): aggregates of fine nodes (coord >> shift), dense
  // inverse of the Galerkin coarse operator P^T A P, damped Jacobi smoothing (weight omega).
  int nc = 0;                          // coarse nodes
  const int* agg = nullptr;            // n, coarse id of each fine node
  // A P (the coarse correction's gather): kApSlots slots per node, slot-major like nbr (padding:
  // own aggregate, value 0), and a CSR remainder.
  const int* ap_col = nullptr;
  const float* ap_val = nullptr;
  const int* ap_off = nullptr;
  const int* ap_rcol = nullptr;
  const float* ap_rval = nullptr;
  float4* sm = nullptr;                // n: omega A D^-1 r_k, the pre-smoothing's product (A phase)
  const float* ainv = nullptr;         // nc * nc, row-major
  float4* rc = nullptr;                // inner * nc: restricted residual per iteration
  float4* zc = nullptr;                // nc
  float4* z = nullptr;                 // n, preconditioned residual
  float4* aq = nullptr;                // n, A p
  float4* pb[2] = {nullptr, nullptr};  // ping-pong: direction
  float omega = 0.6f;
  // Third level (nc2 > 0): the coarse system above is then not inverted but preconditioned by
  // one symmetric two-level cycle of its own (damped Jacobi pre/post-smoothing with omega1 on
  // the sparse Galerkin operator Ac1 = P^T A P, CSR with its diagonal, and a dense inverse of
  // Ac2 = P2^T Ac1 P2 in `ainv`, nc2 x nc2; agg2: level-2 id of each coarse node).
  int nc2 = 0;
  const int* agg2 = nullptr;   // nc
  const int* c_off = nullptr;  // nc + 1, Ac1 (CSR, diagonal included)
  const int* c_col = nullptr;
  const float* c_val = nullptr;
  const float* c_minv = nullptr;  // nc, 1 / diag(Ac1)
  float omega1 = 0.6f;
  float4* rc2 = nullptr;  // inner * nc2
  float4* zc2 = nullptr;  // nc2
  // Measurement only (LARAP_CUDA_PHASES): when set, the fused kernel's first thread writes its
  // SM's clock64() at the start and after every grid-wide phase (solvers.h, fused_phases).
  long long* stamps = nullptr;
};

}  // namespace cuda
}  // namespace larap
