// Device helpers shared by the kernels of native/cuda (*.cu only): float4 arithmetic on the
// (x, y, z) columns, block sums into double atomics, and the product of one row of A.
#pragma once
#include <cuda_runtime.h>

#include <cstdint>

#include "system.h"

namespace larap {
namespace cuda {

constexpr int kBlock = 256;
constexpr unsigned kFull = 0xffffffffu;

__device__ __forceinline__ float4 f4(float x, float y, float z) { return make_float4(x, y, z, 0.f); }
__device__ __forceinline__ float4 operator+(float4 a, float4 b) {
  return f4(a.x + b.x, a.y + b.y, a.z + b.z);
}
// *dst += v (x, y, z; w is 0 in both): one vector atomic on compute capability 9.x, three before.
__device__ __forceinline__ void atomic_add(float4* dst, float4 v) {
#if __CUDA_ARCH__ >= 900 && CUDART_VERSION >= 12010  // float4 atomicAdd: CUDA 12.1, 9.x
  atomicAdd(dst, v);
#else
  atomicAdd(&dst->x, v.x);
  atomicAdd(&dst->y, v.y);
  atomicAdd(&dst->z, v.z);
#endif
}
__device__ __forceinline__ float4 operator-(float4 a, float4 b) {
  return f4(a.x - b.x, a.y - b.y, a.z - b.z);
}
__device__ __forceinline__ float4 operator*(float s, float4 a) { return f4(s * a.x, s * a.y, s * a.z); }
// Per-column products (3 independent systems).
__device__ __forceinline__ float4 cmul(float4 a, float4 b) { return f4(a.x * b.x, a.y * b.y, a.z * b.z); }
__device__ __forceinline__ float dot3(float4 a, float4 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

inline int blocks_for(int64_t n) { return int((n + kBlock - 1) / kBlock); }

// Sums NV doubles over the block and adds them to dst[0..NV) (one atomic per value and block).
template <int NV>
__device__ void block_add(double (&v)[NV], double* dst) {
  __shared__ double sh[NV][kBlock / 32];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
#pragma unroll
  for (int k = 0; k < NV; ++k)
    for (int o = 16; o > 0; o >>= 1) v[k] += __shfl_down_sync(kFull, v[k], o);
  if (lane == 0)
#pragma unroll
    for (int k = 0; k < NV; ++k) sh[k][warp] = v[k];
  __syncthreads();
  if (warp == 0) {
#pragma unroll
    for (int k = 0; k < NV; ++k) {
      double t = lane < kBlock / 32 ? sh[k][lane] : 0.0;
      for (int o = 16; o > 0; o >>= 1) t += __shfl_down_sync(kFull, t, o);
      if (lane == 0 && t != 0.0) atomicAdd(dst + k, t);
    }
  }
}

// body(val[q], col[q]) for q in [q0, q1), in order, kRowBatch entries at a time: a batch's
// column and value loads are all issued before the first of its gathers, so that a long row (a
// handle node's: about 20 remainder entries of A, 27 of M) costs a few load latencies, not two
// per entry. A batch is padded with (zero, pad): a zero term on an entry the caller reads
// anyway, so the sums are the loop's (bit for bit, but for the sign of an exact zero, and a
// non-finite value at the padding entry would make its zero term NaN; docs/results-gpu.md,
// session 24).
constexpr int kRowBatch = 8;
template <class V, class F>
__device__ __forceinline__ void for_row(int q0, int q1, int pad, const int* __restrict__ col,
                                        const V* __restrict__ val, F body) {
  for (int q = q0; q < q1; q += kRowBatch) {
    int js[kRowBatch];
    V vs[kRowBatch];
#pragma unroll
    for (int u = 0; u < kRowBatch; ++u) {
      const bool in = q + u < q1;  // a padded entry loads nothing (the loads are under `in`)
      js[u] = in ? __ldg(col + q + u) : pad;
      vs[u] = in ? __ldg(val + q + u) : V{};
    }
#pragma unroll
    for (int u = 0; u < kRowBatch; ++u) body(vs[u], js[u]);
  }
}

// (A v)_i with v_j = get(j): diagonal + 6 unrolled lattice slots (all loads in flight at once)
// + the short remainder list, in batches (for_row).
template <class F>
__device__ __forceinline__ float4 spmv_row(const System& s, int i, F get) {
  int js[6];
  float as[6];
#pragma unroll
  for (int d = 0; d < 6; ++d) {
    js[d] = __ldg(s.nbr + d * s.n + i);
    as[d] = __ldg(s.a_nb + d * s.n + i);
  }
  float4 acc = __ldg(s.a_diag + i) * get(i);
#pragma unroll
  for (int d = 0; d < 6; ++d) acc = acc + as[d] * get(js[d]);
  const int q0 = __ldg(s.rem_off + i), q1 = __ldg(s.rem_off + i + 1);
  for_row(q0, q1, i, s.rem_col, s.rem_val, [&](float v, int j) { acc = acc + v * get(j); });
  return acc;
}

// ((A P) v)_i with v_a = get(a) for a coarse vector v: kApSlots slots (all loads in flight at
// once, so the gather is two loads deep) + the remainder (handle nodes, split cells), in batches.
template <class F>
__device__ __forceinline__ float4 prolonged_row(const System& s, int i, F get) {
  int as[kApSlots];
  float vs[kApSlots];
#pragma unroll
  for (int d = 0; d < kApSlots; ++d) {
    as[d] = __ldg(s.ap_col + d * s.n + i);
    vs[d] = __ldg(s.ap_val + d * s.n + i);
  }
  const int q0 = __ldg(s.ap_off + i), q1 = __ldg(s.ap_off + i + 1);
  float4 acc = vs[0] * get(as[0]);
#pragma unroll
  for (int d = 1; d < kApSlots; ++d) acc = acc + vs[d] * get(as[d]);
  for_row(q0, q1, as[0], s.ap_rcol, s.ap_rval, [&](float v, int a) { acc = acc + v * get(a); });
  return acc;
}

}  // namespace cuda
}  // namespace larap
