// Kernels of the rejected variants (see experiments.h). Built only with LARAP_CUDA_EXPERIMENTS.
#include "device_memory.h"
#include "experiments.h"
#include "transfer.cuh"
#include "transfer.h"

namespace larap {
namespace cuda {
namespace {

// ---------------------------------------------------------------- PCG (Chronopoulos-Gear)
// Kernel k (k = 0 is the set-up pass) applies iteration k-1 with coef[k] = (alpha, beta, first),
// then computes u = M r and w = A u for the new residual (neighbours' new values are recomputed
// from their old buffers, hence the ping-pong), and the dots gamma = (r, u), delta = (w, u). The
// last block to finish turns the dots into coef[k+1].
__global__ void __launch_bounds__(kBlock) cg_kernel(System s, int k) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  const int in = k & 1, out = in ^ 1;
  const bool pre = k == 0;
  float4 al = f4(0, 0, 0), be = f4(0, 0, 0);
  bool first = false;
  if (!pre) {
    const float* c = s.coef + 8 * k;
    al = f4(c[0], c[1], c[2]);
    be = f4(c[3], c[4], c[5]);
    first = c[6] != 0.f;
  }
  double v[6] = {0, 0, 0, 0, 0, 0};
  if (i < s.n) {
    const float4* rin = s.r[in];
    const float4* win = s.w[in];
    const float4* sin = s.s[in];
    float4 rn, sn;
    if (pre) {
      rn = rin[i];
      sn = f4(0, 0, 0);
    } else {
      const float mi = s.minv[i];
      const float4 u = mi * rin[i];
      const float4 wi = win[i];
      sn = first ? wi : wi + cmul(be, sin[i]);
      const float4 pn = first ? u : u + cmul(be, s.p[i]);
      s.p[i] = pn;
      s.x[i] = s.x[i] + cmul(al, pn);
      rn = rin[i] - cmul(al, sn);
    }
    const float4 un = s.minv[i] * rn;
    float4 wn = f4(0, 0, 0);
    for (int q = s.a_off[i]; q < s.a_off[i + 1]; ++q) {
      const int j = s.a_col[q];
      float4 rj = rin[j];
      if (!pre) {
        const float4 sj = first ? win[j] : win[j] + cmul(be, sin[j]);
        rj = rj - cmul(al, sj);
      }
      wn = wn + (s.a_val[q] * s.minv[j]) * rj;
    }
    s.r[out][i] = rn;
    s.s[out][i] = sn;
    s.w[out][i] = wn;
    v[0] = rn.x * un.x;
    v[1] = rn.y * un.y;
    v[2] = rn.z * un.z;
    v[3] = wn.x * un.x;
    v[4] = wn.y * un.y;
    v[5] = wn.z * un.z;
  }
  block_add<6>(v, s.dots + 6 * k);
  // Last block: coefficients for the next kernel.
  __shared__ bool last;
  __threadfence();
  __syncthreads();
  if (threadIdx.x == 0) last = atomicAdd(s.counters + k, 1u) == gridDim.x - 1;
  __syncthreads();
  if (!last || threadIdx.x != 0) return;
  __threadfence();
  volatile double* d = s.dots;
  float* cn = s.coef + 8 * (k + 1);
  for (int c = 0; c < 3; ++c) {
    const double gam = d[6 * k + c], del = d[6 * k + 3 + c];
    double alpha = 0.0, beta = 0.0;
    if (k == 0) {
      if (gam > 0.0 && del > 0.0) alpha = gam / del;
    } else {
      const double gprev = d[6 * (k - 1) + c];
      const double aprev = s.coef[8 * k + c];
      const double g0 = d[c];
      // Stop (alpha = 0 from here on) once converged as far as float allows, or on breakdown.
      if (aprev != 0.0 && gprev > 0.0 && gam > 1e-12 * g0 && gam > 0.0) {
        beta = gam / gprev;
        const double den = del - beta * gam / aprev;
        if (den > 0.0 && isfinite(den))
          alpha = gam / den;
        else
          beta = 0.0;
      }
    }
    if (!(alpha > 0.0) || !isfinite(alpha)) alpha = beta = 0.0;
    cn[c] = float(alpha);
    cn[3 + c] = float(beta);
  }
  cn[6] = k == 0 ? 1.f : 0.f;
  s.counters[k] = 0u;
}

// ---------------------------------------------------------------- Chebyshev / Jacobi
__global__ void __launch_bounds__(kBlock) cheby_kernel(System s, int k, float c1, float c2) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= s.n) return;
  const float4* xin = (k & 1) ? s.x_tmp : s.x;
  float4* xout = (k & 1) ? s.x : s.x_tmp;
  float4 ax = f4(0, 0, 0);
  for (int q = s.a_off[i]; q < s.a_off[i + 1]; ++q) ax = ax + s.a_val[q] * xin[s.a_col[q]];
  const float4 res = s.r[0][i] - ax;
  const float4 d = (k == 0 ? f4(0, 0, 0) : c1 * s.p[i]) + (c2 * s.minv[i]) * res;
  s.p[i] = d;
  xout[i] = xin[i] + d;
}

// ---------------------------------------------------------------- staged transfer
// One block = kBlock consecutive vertices. V is read and out written through shared memory with
// 16-byte accesses (3 kBlock values of T per block, contiguous); a partial or unaligned block
// falls back to scalar accesses. Each thread computes sum_k w_k disp[id_k] for its vertex.
template <typename T>
__device__ __forceinline__ bool aligned16(const T* p) {
  return (reinterpret_cast<uintptr_t>(p) & 15) == 0;
}

template <typename T>
__device__ __forceinline__ void stage_in(T* sh, const T* __restrict__ src, int cnt, bool vec) {
  if (vec) {
    constexpr int n4 = int(3 * kBlock * sizeof(T) / 16);
    const float4* s4 = reinterpret_cast<const float4*>(src);
    float4* d4 = reinterpret_cast<float4*>(sh);
    for (int q = threadIdx.x; q < n4; q += kBlock) d4[q] = __ldg(s4 + q);
  } else {
    for (int q = threadIdx.x; q < 3 * cnt; q += kBlock) sh[q] = src[q];
  }
}
template <typename T>
__device__ __forceinline__ void stage_out(const T* sh, T* __restrict__ dst, int cnt, bool vec) {
  if (vec) {
    constexpr int n4 = int(3 * kBlock * sizeof(T) / 16);
    const float4* s4 = reinterpret_cast<const float4*>(sh);
    float4* d4 = reinterpret_cast<float4*>(dst);
    for (int q = threadIdx.x; q < n4; q += kBlock) d4[q] = s4[q];
  } else {
    for (int q = threadIdx.x; q < 3 * cnt; q += kBlock) dst[q] = sh[q];
  }
}

template <typename T, bool Trilinear>
__global__ void __launch_bounds__(kBlock)
    staged_kernel(int64_t v0, int64_t v1, const float4* __restrict__ packed, const int* __restrict__ table,
                  const float4* __restrict__ disp, const T* __restrict__ V, T* __restrict__ out) {
  __shared__ __align__(16) T sh[3 * kBlock];
  const int64_t b0 = v0 + int64_t(blockIdx.x) * kBlock;
  const int cnt = int(v1 - b0 < kBlock ? v1 - b0 : kBlock);
  const bool vec = cnt == kBlock && aligned16(V + 3 * b0) && aligned16(out + 3 * b0);
  stage_in(sh, V + 3 * b0, cnt, vec);
  const int t = threadIdx.x;
  float4 d = f4(0.f, 0.f, 0.f);
  if (t < cnt) {
    const float4 pk = __ldg(packed + b0 + t);
    d = Trilinear ? trilinear_displacement(pk, reinterpret_cast<const int4*>(table), disp)
                  : bspline_displacement(pk, table, disp);
  }
  __syncthreads();
  if (t < cnt) {
    sh[3 * t] += T(d.x);
    sh[3 * t + 1] += T(d.y);
    sh[3 * t + 2] += T(d.z);
  }
  __syncthreads();
  stage_out(sh, out + 3 * b0, cnt, vec);
}

// ---------------------------------------------------------------- ILP transfer
// Several vertices per thread (VPT, vertices b0 + k kBlock + threadIdx.x: each k coalesced), the
// loads of all of them issued phase by phase so that VPT independent chains packed -> corners ->
// displacements are in flight at once. Stream: packed and V (read once) with __ldcs, out with
// __stcs (evict-first), so that the gathered tables (cell corners, displacements) keep L2.
template <bool Stream, typename T>
__device__ __forceinline__ T ld_once(const T* p) {
  if constexpr (Stream)
    return __ldcs(p);
  else
    return __ldg(p);
}
template <bool Stream, typename T>
__device__ __forceinline__ void st_once(T* p, T v) {
  if constexpr (Stream)
    __stcs(p, v);
  else
    *p = v;
}

template <typename T, int VPT, bool Stream>
__global__ void __launch_bounds__(kBlock)
    trilinear_ilp_kernel(int64_t v0, int64_t v1, const float4* __restrict__ packed,
                         const int4* __restrict__ cell_nodes, const float4* __restrict__ disp,
                         const T* __restrict__ V, T* __restrict__ out) {
  const int64_t b0 = v0 + int64_t(blockIdx.x) * (kBlock * VPT) + threadIdx.x;
  float4 pk[VPT];
  T vv[VPT][3];
#pragma unroll
  for (int k = 0; k < VPT; ++k) {
    const int64_t v = b0 + int64_t(k) * kBlock;
    if (v < v1) {
      pk[k] = ld_once<Stream>(packed + v);
#pragma unroll
      for (int c = 0; c < 3; ++c) vv[k][c] = ld_once<Stream>(V + 3 * v + c);
    } else {
      pk[k] = make_float4(0.f, 0.f, 0.f, 0.f);  // cell 0 (int bits of 0.f): a valid, unused gather
#pragma unroll
      for (int c = 0; c < 3; ++c) vv[k][c] = T(0);
    }
  }
  int ids[VPT][8];
#pragma unroll
  for (int k = 0; k < VPT; ++k) {
    const int c = __float_as_int(pk[k].x);
    const int4 n0 = __ldg(cell_nodes + 2 * c), n1 = __ldg(cell_nodes + 2 * c + 1);
    ids[k][0] = n0.x;
    ids[k][1] = n0.y;
    ids[k][2] = n0.z;
    ids[k][3] = n0.w;
    ids[k][4] = n1.x;
    ids[k][5] = n1.y;
    ids[k][6] = n1.z;
    ids[k][7] = n1.w;
  }
  float4 d[VPT][8];
#pragma unroll
  for (int k = 0; k < VPT; ++k)
#pragma unroll
    for (int j = 0; j < 8; ++j) d[k][j] = __ldg(disp + ids[k][j]);
#pragma unroll
  for (int k = 0; k < VPT; ++k) {
    float w[8];
    trilinear_weights(pk[k].y, pk[k].z, pk[k].w, w);
    float ax = 0.f, ay = 0.f, az = 0.f;
#pragma unroll
    for (int j = 0; j < 8; ++j) {
      ax += w[j] * d[k][j].x;
      ay += w[j] * d[k][j].y;
      az += w[j] * d[k][j].z;
    }
    const int64_t v = b0 + int64_t(k) * kBlock;
    if (v < v1) {
      st_once<Stream>(out + 3 * v, vv[k][0] + T(ax));
      st_once<Stream>(out + 3 * v + 1, vv[k][1] + T(ay));
      st_once<Stream>(out + 3 * v + 2, vv[k][2] + T(az));
    }
  }
}

}  // namespace

void launch_experimental_solver(const System& s, Solver solver, int inner, double lam_min, double lam_max,
                                cudaStream_t st) {
  const int blocks = blocks_for(s.n);
  if (solver == Solver::Pcg) {
    for (int k = 0; k <= inner; ++k) {
      cg_kernel<<<blocks, kBlock, 0, st>>>(s, k);
      LARAP_CUDA_CHECK(cudaGetLastError());
    }
    return;
  }
  // Chebyshev semi-iteration on D^-1 A with eigenvalues in [lo, hi]; Jacobi: fixed weight.
  const double lo = lam_min, hi = lam_max;
  const double theta = 0.5 * (hi + lo), delta = 0.5 * (hi - lo);
  const double sigma = theta / delta;
  double rho = 1.0 / sigma;
  for (int k = 0; k < inner; ++k) {
    float c1 = 0.f, c2 = float(1.0 / theta);
    if (solver == Solver::Chebyshev && k > 0) {
      const double rn = 1.0 / (2.0 * sigma - rho);
      c1 = float(rn * rho);
      c2 = float(2.0 * rn / delta);
      rho = rn;
    }
    cheby_kernel<<<blocks, kBlock, 0, st>>>(s, k, c1, c2);
    LARAP_CUDA_CHECK(cudaGetLastError());
  }
  if (inner & 1)
    LARAP_CUDA_CHECK(cudaMemcpyAsync(s.x, s.x_tmp, sizeof(float4) * s.n, cudaMemcpyDeviceToDevice, st));
}

namespace {

template <typename T>
void experimental_transfer(const TransferKernel& kernel, bool trilinear, int64_t v0, int64_t v1,
                           const float4* packed, const int* table, const float4* disp, const T* V, T* out,
                           cudaStream_t st) {
  if (v1 <= v0) return;
  if (kernel.mode == TransferKernel::Ilp && trilinear) {
    const int4* cn = reinterpret_cast<const int4*>(table);
    const int vpt = kernel.vertices_per_thread >= 4 ? 4 : kernel.vertices_per_thread >= 2 ? 2 : 1;
    const int blocks = int((v1 - v0 + int64_t(kBlock) * vpt - 1) / (int64_t(kBlock) * vpt));
    auto k = kernel.streaming ? (vpt == 4   ? trilinear_ilp_kernel<T, 4, true>
                                 : vpt == 2 ? trilinear_ilp_kernel<T, 2, true>
                                            : trilinear_ilp_kernel<T, 1, true>)
                              : (vpt == 4   ? trilinear_ilp_kernel<T, 4, false>
                                 : vpt == 2 ? trilinear_ilp_kernel<T, 2, false>
                                            : trilinear_ilp_kernel<T, 1, false>);
    k<<<blocks, kBlock, 0, st>>>(v0, v1, packed, cn, disp, V, out);
  } else if (kernel.mode == TransferKernel::Staged) {
    (trilinear ? staged_kernel<T, true> : staged_kernel<T, false>)<<<blocks_for(v1 - v0), kBlock, 0, st>>>(
        v0, v1, packed, table, disp, V, out);
  } else if (trilinear) {
    launch_transfer_trilinear(v0, v1, packed, table, disp, V, out, st);
  } else {  // ilp with B-spline weights: the scalar kernel
    launch_transfer_bspline(v0, v1, packed, table, disp, V, out, st);
  }
  LARAP_CUDA_CHECK(cudaGetLastError());
}

}  // namespace

void launch_experimental_transfer(const TransferKernel& kernel, bool trilinear, int64_t v0, int64_t v1,
                                  const float4* packed, const int* table, const float4* disp, const float* V,
                                  float* out, cudaStream_t st) {
  experimental_transfer(kernel, trilinear, v0, v1, packed, table, disp, V, out, st);
}
void launch_experimental_transfer(const TransferKernel& kernel, bool trilinear, int64_t v0, int64_t v1,
                                  const float4* packed, const int* table, const float4* disp, const double* V,
                                  double* out, cudaStream_t st) {
  experimental_transfer(kernel, trilinear, v0, v1, packed, table, disp, V, out, st);
}

}  // namespace cuda
}  // namespace larap
