// Per-node device functions of one flip-flop (rotations with the energy, handle energy, the
// right-hand side), shared by the separate kernels (flip_flop.cu) and the fused cooperative
// kernel (solvers.cu). The arithmetic is node_terms.h's, the same as the CPU backend's; here
// only the access to the device layout: the fixed 6-slot neighbour table (a missing neighbour is
// the node itself) plus the short list of extra neighbours of split cells (system.h), and
// rotations as SoA (rot[k * n + i]). Every per-node sum is linear in the edges, so the extra
// edges are a second pass with their own accessor, taken only by nodes that have them.
#pragma once
#include "device_vec.cuh"
#include "node_terms.h"
#include "rotation.cuh"

namespace larap {
namespace cuda {

// Node i's 6 lattice slots, as node_terms.h's Edges accessor.
struct SlotEdges {
  const System& s;
  float4 pi, ci;
  int js[6];
  int i_;
  __device__ __forceinline__ SlotEdges(const System& sys, int i)
      : s(sys), pi(sys.x[i]), ci(sys.rest[i]), i_(i) {
#pragma unroll
    for (int d = 0; d < 6; ++d) js[d] = __ldg(s.nbr + d * s.n + i);
  }
  __device__ __forceinline__ int size() const { return 6; }
  __device__ __forceinline__ float weight(int k) const {
    return s.nbw ? __ldg(s.nbw + k * s.n + i_) : 1.f;
  }
  __device__ __forceinline__ void edge(int k, float (&dp)[3], float (&dc)[3]) const {
    const int j = js[k];
    const float4 p = pi - s.x[j], c = ci - s.rest[j];
    dp[0] = p.x, dp[1] = p.y, dp[2] = p.z;
    dc[0] = c.x, dc[1] = c.y, dc[2] = c.z;
  }
  __device__ __forceinline__ void rest_edge(int k, float (&dc)[3], float (&Rj)[9]) const {
    const int j = js[k];
    const float4 c = ci - s.rest[j];
    dc[0] = c.x, dc[1] = c.y, dc[2] = c.z;
#pragma unroll
    for (int q = 0; q < 9; ++q) Rj[q] = s.rot[q * s.n + j];
  }
};

// Node i's extra neighbours (split cells: more than one neighbour in a direction), the same
// accessor over nbx[nbx_off[i] .. nbx_off[i + 1]).
struct ExtraEdges {
  const System& s;
  float4 pi, ci;
  int k0, k1;
  __device__ __forceinline__ ExtraEdges(const System& sys, int i, float4 p, float4 c)
      : s(sys), pi(p), ci(c), k0(__ldg(sys.nbx_off + i)), k1(__ldg(sys.nbx_off + i + 1)) {}
  __device__ __forceinline__ int size() const { return k1 - k0; }
  __device__ __forceinline__ float weight(int k) const { return s.nbxw ? __ldg(s.nbxw + k0 + k) : 1.f; }
  __device__ __forceinline__ void edge(int k, float (&dp)[3], float (&dc)[3]) const {
    const int j = __ldg(s.nbx + k0 + k);
    const float4 p = pi - s.x[j], c = ci - s.rest[j];
    dp[0] = p.x, dp[1] = p.y, dp[2] = p.z;
    dc[0] = c.x, dc[1] = c.y, dc[2] = c.z;
  }
  __device__ __forceinline__ void rest_edge(int k, float (&dc)[3], float (&Rj)[9]) const {
    const int j = __ldg(s.nbx + k0 + k);
    const float4 c = ci - s.rest[j];
    dc[0] = c.x, dc[1] = c.y, dc[2] = c.z;
    for (int q = 0; q < 9; ++q) Rj[q] = s.rot[q * s.n + j];
  }
};

// Node i: new rotation (write_rot) and, when want_e, its energy term with the old rotations.
__device__ __forceinline__ double rot_node(const System& s, int i, bool write_rot, bool want_e) {
  const SlotEdges edges(s, i);
  float Ro[9];
  if (want_e)
#pragma unroll
    for (int k = 0; k < 9; ++k) Ro[k] = s.rot[k * s.n + i];
  float S[9];
  float arap = node_covariance(edges, want_e, Ro, S);
  const ExtraEdges extra(s, i, edges.pi, edges.ci);
  if (extra.size() > 0) {
    float S2[9];
    arap += node_covariance(extra, want_e, Ro, S2);
#pragma unroll
    for (int k = 0; k < 9; ++k) S[k] += S2[k];
  }
  double e = 0.0;
  if (want_e) {
    const float4 d = edges.pi - edges.ci;
    e = node_energy<double>(s.g, arap, s.anchored[i] != 0, s.a, dot3(d, d));
  }
  if (write_rot) {
    float R[9];
    cuda_math::best_rotation_f(S, R);
#pragma unroll
    for (int k = 0; k < 9; ++k) s.rot[k * s.n + i] = R[k];
  }
  return e;
}

// Node i's share of the handle term without K: c_i . ((M c)_i - 2 H_i), in double (system.h).
// 0 for a node no handle reads (an empty row of M).
__device__ __forceinline__ double handle_energy(const System& s, int i) {
  const int q0 = __ldg(s.m_off + i), q1 = __ldg(s.m_off + i + 1);
  if (q0 == q1) return 0.0;
  double mx = 0.0, my = 0.0, mz = 0.0;
  for (int q = q0; q < q1; ++q) {
    const double v = __ldg(s.m_val + q);
    const float4 xj = s.x[__ldg(s.m_col + q)];
    mx += v * double(xj.x);
    my += v * double(xj.y);
    mz += v * double(xj.z);
  }
  const float4 xi = s.x[i];
  const double* h = s.hd + 3 * int64_t(i);
  return double(xi.x) * (mx - 2.0 * h[0]) + double(xi.y) * (my - 2.0 * h[1]) + double(xi.z) * (mz - 2.0 * h[2]);
}

// The ARAP part of row i of the right-hand side, g sum_j w_ij (R_i + R_j)(c_i - c_j), over the slots
// and the extra neighbours.
__device__ __forceinline__ float4 arap_rhs_at(const System& s, const SlotEdges& edges, int i) {
  float Ri[9];
#pragma unroll
  for (int k = 0; k < 9; ++k) Ri[k] = s.rot[k * s.n + i];
  float arap[3];
  node_rhs(edges, s.g, Ri, arap);
  float4 b = f4(arap[0], arap[1], arap[2]);
  const ExtraEdges extra(s, i, edges.pi, edges.ci);
  if (extra.size() > 0) {
    node_rhs(extra, s.g, Ri, arap);
    b = b + f4(arap[0], arap[1], arap[2]);
  }
  return b;
}

// Row i of the right-hand side: g sum_j w_ij (R_i + R_j)(c_i - c_j) + H_i + a c_i [anchored]
// (H = B^T alpha t, centred: handle_system.h). For the experiments' solvers, which need b itself.
__device__ __forceinline__ float4 rhs_at(const System& s, int i) {
  const SlotEdges edges(s, i);
  float4 b = arap_rhs_at(s, edges, i) + s.h[i];
  if (s.anchored[i]) b = b + s.a * edges.ci;
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
//   r_i = g sum_j w_ij [(R_i + R_j)(c_i - c_j) - 2 (x_i - x_j)] + a (c_i - x_i) [anchored]
//       + (H_i - (M x)_i)  (in double: the handle term; system.h)
// The float terms are edge differences (their rounding scales with the cell size, not with the
// distance from the frame's origin); the handle part is exact up to the rounding of x itself.
__device__ __forceinline__ float4 residual_at(const System& s, int i) {
  if (!s.exact_residual) return float_residual_at(s, i);
  const SlotEdges edges(s, i);
  float4 r = arap_rhs_at(s, edges, i);
  float4 lap = f4(0, 0, 0);  // sum_j w_ij (x_i - x_j)
#pragma unroll
  for (int d = 0; d < 6; ++d) lap = lap + edges.weight(d) * (edges.pi - s.x[edges.js[d]]);
  {
    const ExtraEdges extra(s, i, edges.pi, edges.ci);
    for (int k = 0; k < extra.size(); ++k)
      lap = lap + extra.weight(k) * (edges.pi - s.x[__ldg(s.nbx + extra.k0 + k)]);
  }
  r = r - (2.f * s.g) * lap;
  if (s.anchored[i]) r = r + s.a * (edges.ci - edges.pi);
  const int q0 = __ldg(s.m_off + i), q1 = __ldg(s.m_off + i + 1);
  if (q0 < q1) {
    const double* h = s.hd + 3 * int64_t(i);
    double hx = h[0], hy = h[1], hz = h[2];
    for (int q = q0; q < q1; ++q) {
      const double v = __ldg(s.m_val + q);
      const float4 xj = s.x[__ldg(s.m_col + q)];
      hx -= v * double(xj.x);
      hy -= v * double(xj.y);
      hz -= v * double(xj.z);
    }
    r = r + f4(float(hx), float(hy), float(hz));
  }
  return r;
}

}  // namespace cuda
}  // namespace larap
