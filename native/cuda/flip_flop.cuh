// Per-node device functions of one flip-flop (rotations with the energy, handle energy, the
// right-hand side), shared by the separate kernels (flip_flop.cu) and the fused cooperative
// kernel (solvers.cu). The arithmetic is node_terms.h's, the same as the CPU backend's; here
// only the access to the device layout: the fixed 6-slot neighbour table (a missing neighbour is
// the node itself) and rotations as SoA (rot[k * n + i]).
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
  __device__ __forceinline__ SlotEdges(const System& sys, int i) : s(sys), pi(sys.x[i]), ci(sys.rest[i]) {
#pragma unroll
    for (int d = 0; d < 6; ++d) js[d] = __ldg(s.nbr + d * s.n + i);
  }
  __device__ __forceinline__ int size() const { return 6; }
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

// Node i: new rotation (write_rot) and, when want_e, its energy term with the old rotations.
__device__ __forceinline__ double rot_node(const System& s, int i, bool write_rot, bool want_e) {
  const SlotEdges edges(s, i);
  float Ro[9];
  if (want_e)
#pragma unroll
    for (int k = 0; k < 9; ++k) Ro[k] = s.rot[k * s.n + i];
  float S[9];
  const float arap = node_covariance(edges, want_e, Ro, S);
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

// Row i of the right-hand side: g sum_j (R_i + R_j)(c_i - c_j) + H_i + a c_i [anchored]
// (H = B^T alpha t, centred: handle_system.h).
__device__ __forceinline__ float4 rhs_at(const System& s, int i) {
  const SlotEdges edges(s, i);
  float Ri[9];
#pragma unroll
  for (int k = 0; k < 9; ++k) Ri[k] = s.rot[k * s.n + i];
  float arap[3];
  node_rhs(edges, s.g, Ri, arap);
  float4 b = f4(arap[0], arap[1], arap[2]);
  b = b + s.h[i];
  if (s.anchored[i]) b = b + s.a * edges.ci;
  return b;
}

}  // namespace cuda
}  // namespace larap
