// Kernels of the per-pose handle work (see handles.h).
#include "device_vec.cuh"
#include "handles.h"

namespace larap {
namespace cuda {
namespace {

static_assert(kMomentBlock == kBlock, "one chunk of the moments is one block");

__global__ void __launch_bounds__(kBlock)
    group_rhs_kernel(System s, GroupEntries e, const double* __restrict__ maps, float4* h, double* hd) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= s.n) return;
  double acc[3] = {0.0, 0.0, 0.0};
  const int k0 = __ldg(e.node_off + i), k1 = __ldg(e.node_off + i + 1);
  for (int k = k0; k < k1; ++k) {
    const double* m = maps + 12 * int64_t(__ldg(e.group + k));
    const double P0 = __ldg(e.P + 3 * int64_t(k)), P1 = __ldg(e.P + 3 * int64_t(k) + 1),
                 P2 = __ldg(e.P + 3 * int64_t(k) + 2), q = __ldg(e.q + k);
#pragma unroll
    for (int a = 0; a < 3; ++a) acc[a] += m[3 * a] * P0 + m[3 * a + 1] * P1 + m[3 * a + 2] * P2 + q * m[9 + a];
  }
  hd[3 * int64_t(i)] = acc[0];
  hd[3 * int64_t(i) + 1] = acc[1];
  hd[3 * int64_t(i) + 2] = acc[2];
  h[i] = f4(float(acc[0]), float(acc[1]), float(acc[2]));
}

// One block per chunk (at most kBlock nodes of one component) and pose (blockIdx.y: 0 the pose
// s.x, 1 the rest lattice): the chunk's sums into partial[kMomentValues * (chunks * pose + chunk) ..].
__global__ void __launch_bounds__(kBlock) moments_chunk_kernel(System s, MomentChunks mc, double* partial) {
  constexpr int K = kMomentValues;
  const int chunk = blockIdx.x;
  const float4* __restrict__ pos = blockIdx.y ? s.rest : s.x;
  partial += int64_t(K) * mc.chunks * blockIdx.y;
  const int idx = __ldg(mc.chunk_off + chunk) + threadIdx.x;
  double v[K];
#pragma unroll
  for (int k = 0; k < K; ++k) v[k] = 0.0;
  if (idx < __ldg(mc.chunk_off + chunk + 1)) {
    const int i = __ldg(mc.nodes + idx);
    const float4 ci = pos[i];
    const double c[3] = {ci.x, ci.y, ci.z};
    double mc3[3] = {0.0, 0.0, 0.0};  // (M c)_i
    for (int q = __ldg(mc.m_off + i); q < __ldg(mc.m_off + i + 1); ++q) {
      const double w = __ldg(mc.m_val + q);
      const float4 cj = pos[__ldg(mc.m_col + q)];
      mc3[0] += w * double(cj.x);
      mc3[1] += w * double(cj.y);
      mc3[2] += w * double(cj.z);
    }
    const double qi = __ldg(s.q + i);
    const double h[3] = {__ldg(s.hd + 3 * int64_t(i)), __ldg(s.hd + 3 * int64_t(i) + 1),
                         __ldg(s.hd + 3 * int64_t(i) + 2)};
    v[0] = qi;
#pragma unroll
    for (int a = 0; a < 3; ++a) {
      v[1 + a] = qi * c[a];
      v[4 + a] = h[a];
#pragma unroll
      for (int b = 0; b < 3; ++b) {
        v[7 + 3 * a + b] = c[a] * h[b];
        v[16 + 3 * a + b] = c[a] * mc3[b];
      }
    }
  }
  __shared__ double sh[K][kBlock / 32];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
#pragma unroll
  for (int k = 0; k < K; ++k) {
    double t = v[k];
    for (int o = 16; o > 0; o >>= 1) t += __shfl_down_sync(kFull, t, o);
    if (lane == 0) sh[k][warp] = t;
  }
  __syncthreads();
  if (threadIdx.x < K) {
    double t = 0.0;
#pragma unroll
    for (int w = 0; w < kBlock / 32; ++w) t += sh[threadIdx.x][w];
    partial[int64_t(K) * chunk + threadIdx.x] = t;
  }
}

// One thread per (pose, component, value): the component's chunks summed in order.
__global__ void moments_sum_kernel(MomentChunks mc, const double* __restrict__ partial, double* out) {
  constexpr int K = kMomentValues;
  const int t = blockIdx.x * blockDim.x + threadIdx.x;
  if (t >= 2 * mc.components * K) return;
  const int pose = t / (mc.components * K), c = t / K % mc.components, k = t % K;
  partial += int64_t(K) * mc.chunks * pose;
  double sum = 0.0;
  for (int ch = mc.comp_chunk_off[c]; ch < mc.comp_chunk_off[c + 1]; ++ch) sum += partial[int64_t(K) * ch + k];
  out[t] = sum;
}

__global__ void __launch_bounds__(kBlock)
    component_rigid_kernel(System s, const int* __restrict__ component, const float* __restrict__ motions,
                           bool from_rest) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= s.n || s.anchored[i]) return;
  const float* m = motions + 16 * int64_t(__ldg(component + i));
  if (m[12] == 0.f) return;
  const float4 p = from_rest ? s.rest[i] : s.x[i];
  s.x[i] = f4(m[0] * p.x + m[1] * p.y + m[2] * p.z + m[9], m[3] * p.x + m[4] * p.y + m[5] * p.z + m[10],
              m[6] * p.x + m[7] * p.y + m[8] * p.z + m[11]);
}

}  // namespace

void launch_group_rhs(const System& s, const GroupEntries& e, const double* maps, float4* h, double* hd,
                      cudaStream_t st) {
  if (s.n) group_rhs_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, e, maps, h, hd);
}

void launch_moments(const System& s, const MomentChunks& mc, double* partial, double* out, cudaStream_t st) {
  if (mc.chunks > 0) moments_chunk_kernel<<<dim3(mc.chunks, 2), kBlock, 0, st>>>(s, mc, partial);
  const int64_t sums = int64_t(2) * mc.components * kMomentValues;  // (pose, component, value)
  if (sums > 0) moments_sum_kernel<<<blocks_for(sums), kBlock, 0, st>>>(mc, partial, out);
}

void launch_component_rigid(const System& s, const int* component, const float* motions, bool from_rest,
                            cudaStream_t st) {
  if (s.n) component_rigid_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, component, motions, from_rest);
}

}  // namespace cuda
}  // namespace larap
