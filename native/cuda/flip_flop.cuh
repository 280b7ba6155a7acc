// Device functions of one flip-flop (per cell copy: rotation with the energy; per node: anchor
// and handle energy, the right-hand side, the starting residual), shared by the separate kernels
// (flip_flop.cu) and the fused cooperative kernel (solvers.cu). The arithmetic is cell_terms.h's,
// the same as the CPU backend's; here only the access to the device layout: corners as SoA over
// the copies, rotations as three float4 rows per copy (system.h), the per-node list of copies for
// the right-hand side, and for the Laplacian the fixed 6-slot neighbour table (a missing
// neighbour is the node itself) plus the short list of extra neighbours of split cells. Rows of
// M and the copies of a node are read in batches (device_vec.cuh, for_row).
#pragma once
#include "cell_terms.h"
#include "device_vec.cuh"
#include "rotation.cuh"

namespace larap {
namespace cuda {

// The previous flip-flop's final update x += al p, which the fused kernel leaves to the next
// flip-flop's first CG phase (one grid-wide barrier fewer a flip-flop: solvers.cu): until then
// the rotation and right-hand-side phases read the pose through at(). Empty (p null): x itself,
// as for every caller outside the fused kernel.
struct Pending {
  const float4* p = nullptr;
  float4 al = {0.f, 0.f, 0.f, 0.f};
  __device__ __forceinline__ float4 at(const float4* x, int j) const {
    return p ? x[j] + cmul(al, p[j]) : x[j];
  }
};

// Node i's 6 lattice slots and weights (the Laplacian in residual_at).
struct SlotEdges {
  const System& s;
  float4 pi, ci;
  int js[6];
  int i_;
  __device__ __forceinline__ SlotEdges(const System& sys, int i, const Pending& pd)
      : s(sys), pi(pd.at(sys.x, i)), ci(sys.rest[i]), i_(i) {
#pragma unroll
    for (int d = 0; d < 6; ++d) js[d] = __ldg(s.nbr + d * s.n + i);
  }
  __device__ __forceinline__ float weight(int k) const { return s.nbw ? __ldg(s.nbw + k * s.n + i_) : 1.f; }
};

// Node i's extra neighbours (split cells: more than one neighbour in a direction) and their
// weights, over nbx[nbx_off[i] .. nbx_off[i + 1]).
struct ExtraEdges {
  const System& s;
  float4 pi, ci;
  int k0, k1;
  __device__ __forceinline__ ExtraEdges(const System& sys, int i, float4 p, float4 c)
      : s(sys), pi(p), ci(c), k0(__ldg(sys.nbx_off + i)), k1(__ldg(sys.nbx_off + i + 1)) {}
  __device__ __forceinline__ int size() const { return k1 - k0; }
  __device__ __forceinline__ float weight(int k) const { return s.nbxw ? __ldg(s.nbxw + k0 + k) : 1.f; }
};

// Cell copy c's corners, as cell_terms.h's Corners accessor.
struct CellCorners {
  const System& s;
  const Pending& pd;
  int ids[8];
  __device__ __forceinline__ CellCorners(const System& sys, int c, const Pending& pend) : s(sys), pd(pend) {
#pragma unroll
    for (int q = 0; q < 8; ++q) ids[q] = __ldg(sys.cell_nodes + q * sys.ncell + c);
  }
  __device__ __forceinline__ void pose(int q, float (&p)[3]) const {
    const float4 v = pd.at(s.x, ids[q]);
    p[0] = v.x, p[1] = v.y, p[2] = v.z;
  }
  __device__ __forceinline__ void rest(int q, float (&c)[3]) const {
    const float4 v = s.rest[ids[q]];
    c[0] = v.x, c[1] = v.y, c[2] = v.z;
  }
};

// Cell copy c's rotation (row-major), three 16-byte loads: where the right-hand side gathers a
// node's copies, 3 loads a copy instead of 9 scattered ones (results-gpu.md, session 24).
__device__ __forceinline__ void load_rotation(const System& s, int c, float (&R)[9]) {
#pragma unroll
  for (int a = 0; a < 3; ++a) {
    const float4 r = s.rot[3 * c + a];
    R[3 * a] = r.x, R[3 * a + 1] = r.y, R[3 * a + 2] = r.z;
  }
}

// Cell copy c: new rotation (write_rot) and, when want_e, its energy term g w_c e_c with the old
// rotation. A branch copy with couplings fits its rotation to w_c S_c plus each coupling's weight
// times its trunk copy's S, and its energy counts the trunk's edges under its rotation too (the
// CPU backend's rotations()).
__device__ __forceinline__ double rot_cell(const System& s, int c, bool write_rot, bool want_e,
                                           const Pending& pd = {}) {
  const CellCorners corners(s, c, pd);
  float Ro[9];
  const int q0 = s.cp_off ? __ldg(s.cp_off + c) : 0, q1 = s.cp_off ? __ldg(s.cp_off + c + 1) : 0;
  if (want_e) load_rotation(s, c, Ro);
  float S[9];
  float arap = cell_covariance(corners, want_e, Ro, S);
  if (q0 < q1) {  // coupled: weighted sums (rare, a few copies per junction)
    const float wc = s.cell_w ? __ldg(s.cell_w + c) : 1.f;
    arap *= wc;
#pragma unroll
    for (int t = 0; t < 9; ++t) S[t] *= wc;
    for (int q = q0; q < q1; ++q) {
      const CellCorners trunk(s, __ldg(s.cp_trunk + q), pd);
      const float w = __ldg(s.cp_w + q);
      float St[9];
      arap += w * cell_covariance(trunk, want_e, Ro, St);
#pragma unroll
      for (int t = 0; t < 9; ++t) S[t] += w * St[t];
    }
  }
  double e = 0.0;
  if (want_e) e = double(s.g) * (q0 < q1 ? 1.0 : double(s.cell_w ? __ldg(s.cell_w + c) : 1.f)) * double(arap);
  if (write_rot) {
    float R[9];
    cuda_math::best_rotation_f(S, R);
#pragma unroll
    for (int a = 0; a < 3; ++a) s.rot[3 * c + a] = f4(R[3 * a], R[3 * a + 1], R[3 * a + 2]);
  }
  return e;
}

// Node i's anchor term a |x_i - c_i|^2 (0 where it is not anchored).
__device__ __forceinline__ double anchor_energy(const System& s, int i, const Pending& pd = {}) {
  if (!s.anchored[i]) return 0.0;
  const float4 d = pd.at(s.x, i) - s.rest[i];
  return double(s.a) * double(dot3(d, d));
}

// Node i's share of the handle term without K: c_i . ((M c)_i - 2 H_i), in double (system.h).
// 0 for a node no handle reads (an empty row of M).
__device__ __forceinline__ double handle_energy(const System& s, int i, const Pending& pd = {}) {
  const int q0 = __ldg(s.m_off + i), q1 = __ldg(s.m_off + i + 1);
  if (q0 == q1) return 0.0;
  double mx = 0.0, my = 0.0, mz = 0.0;
  for_row(q0, q1, i, s.m_col, s.m_val, [&](double v, int j) {
    const float4 xj = pd.at(s.x, j);
    mx += v * double(xj.x);
    my += v * double(xj.y);
    mz += v * double(xj.z);
  });
  const float4 xi = pd.at(s.x, i);
  const double* h = s.hd + 3 * int64_t(i);
  return double(xi.x) * (mx - 2.0 * h[0]) + double(xi.y) * (my - 2.0 * h[1]) +
         double(xi.z) * (mz - 2.0 * h[2]);
}

// The rotation stage's work item k: cell copy k's rotation and energy (k < ncell), or node
// k - ncell's anchor and handle energy (only with want_e; nothing for k >= rotation_items); v[0]:
// ARAP and anchors, v[1]: the handle term without K. Copies and nodes are separate items, so that
// a node's row of M is not read after a copy's rotation fit by the same thread
// (docs/results-gpu.md, session 24).
__device__ __forceinline__ int rotation_items(const System& s, bool want_e) {
  return s.ncell + (want_e ? s.n : 0);
}
__device__ __forceinline__ void rotation_item(const System& s, int k, bool write_rot, bool want_e,
                                              double (&v)[2], const Pending& pd = {}) {
  if (k < s.ncell) {
    v[0] += rot_cell(s, k, write_rot, want_e, pd);
  } else if (want_e && k - s.ncell < s.n) {
    v[0] += anchor_energy(s, k - s.ncell, pd);
    v[1] += handle_energy(s, k - s.ncell, pd);
  }
}

// The ARAP part of row i of the right-hand side, g sum_(c, q) w_c R_c s_cq over the copies node i
// is a corner of (cell_terms.h, node_cells.h).
__device__ __forceinline__ float4 arap_rhs_at(const System& s, int i) {
  float acc[3] = {0.f, 0.f, 0.f};
  // Batched as a row (for_row); a padded entry is copy 0 with a zero edge sum (a node with copies
  // means ncell > 0).
  for_row(__ldg(s.nc_off + i), __ldg(s.nc_off + i + 1), 0, s.nc_cell, s.nc_s, [&](float4 sv, int c) {
    const float sk[3] = {sv.x, sv.y, sv.z};
    float R[9];
    load_rotation(s, c, R);
    cell_rhs_add(R, sk, acc);
  });
  return s.g * f4(acc[0], acc[1], acc[2]);
}

// Row i of the right-hand side: g sum_(c, q) w_c R_c s_cq + H_i + a c_i [anchored]
// (H = B^T alpha t, centred: handle_system.h). For the experiments' solvers, which need b itself.
__device__ __forceinline__ float4 rhs_at(const System& s, int i) {
  float4 b = arap_rhs_at(s, i) + s.h[i];
  if (s.anchored[i]) b = b + s.a * s.rest[i];
  return b;
}

// Row i of the global step's starting residual r = b - A x, as residual_at below but in float
// from b and A x: the rounding of A x scales with |x| (kept only to measure; system.h).
__device__ __forceinline__ float4 float_residual_at(const System& s, int i) {
  const float4* x = s.x;
  return rhs_at(s, i) - spmv_row(s, i, [&](int j) { return x[j]; });
}

// Row i of the global step's starting residual r = b - A x, A = 2 g L + M + a I_anchored, formed
// so that nothing large cancels in float:
//   r_i = g [sum_(c, q) w_c R_c s_cq - 2 sum_j w_ij (x_i - x_j)] + a (c_i - x_i) [anchored]
//       + (H_i - (M x)_i)  (in double: the handle term; system.h)
// The float terms are edge differences (their rounding scales with the cell size, not with the
// distance from the frame's origin); the handle part is exact up to the rounding of x itself.
// A pending update (pd) only with exact_residual (the fused kernel folds only then).
__device__ __forceinline__ float4 residual_at(const System& s, int i, const Pending& pd = {}) {
  if (!s.exact_residual) return float_residual_at(s, i);
  const SlotEdges edges(s, i, pd);
  float4 r = arap_rhs_at(s, i);
  float4 lap = f4(0, 0, 0);  // sum_j w_ij (x_i - x_j)
#pragma unroll
  for (int d = 0; d < 6; ++d) lap = lap + edges.weight(d) * (edges.pi - pd.at(s.x, edges.js[d]));
  {
    const ExtraEdges extra(s, i, edges.pi, edges.ci);
    for (int k = 0; k < extra.size(); ++k)
      lap = lap + extra.weight(k) * (edges.pi - pd.at(s.x, __ldg(s.nbx + extra.k0 + k)));
  }
  r = r - (2.f * s.g) * lap;
  if (s.anchored[i]) r = r + s.a * (edges.ci - edges.pi);
  const int q0 = __ldg(s.m_off + i), q1 = __ldg(s.m_off + i + 1);
  if (q0 < q1) {
    const double* h = s.hd + 3 * int64_t(i);
    double hx = h[0], hy = h[1], hz = h[2];
    for_row(q0, q1, i, s.m_col, s.m_val, [&](double v, int j) {
      const float4 xj = pd.at(s.x, j);
      hx -= v * double(xj.x);
      hy -= v * double(xj.y);
      hz -= v * double(xj.z);
    });
    r = r + f4(float(hx), float(hy), float(hz));
  }
  return r;
}

}  // namespace cuda
}  // namespace larap
