// Kernels of the two/three-level preconditioned CG (see solvers.h and docs/cuda.md).
#include <cooperative_groups.h>

#include "flip_flop.cuh"
#include "solvers.h"

namespace cg = cooperative_groups;

namespace larap {
namespace cuda {
namespace {

// ---------------------------------------------------------------- two-level PCG
// Per-column CG scalars from the dots of iteration k: dots[6k + c] = (r, z), [6k + 3 + c] = (p, Ap).
__device__ __forceinline__ float4 mg_alpha(const System& s, int k) {
  float a[3];
#pragma unroll
  for (int c = 0; c < 3; ++c) {
    const double rz = s.dots[6 * k + c], pq = s.dots[6 * k + 3 + c], rz0 = s.dots[c];
    double al = 0.0;
    if (pq > 0.0 && rz > 0.0 && rz > 1e-13 * rz0) al = rz / pq;
    if (!isfinite(al)) al = 0.0;
    a[c] = float(al);
  }
  return f4(a[0], a[1], a[2]);
}
__device__ __forceinline__ float4 mg_beta(const System& s, int k) {
  float b[3];
#pragma unroll
  for (int c = 0; c < 3; ++c) {
    const double rz = s.dots[6 * k + c], rzp = s.dots[6 * (k - 1) + c];
    double be = rzp > 0.0 ? rz / rzp : 0.0;
    if (!isfinite(be)) be = 0.0;
    b[c] = float(be);
  }
  return f4(b[0], b[1], b[2]);
}

// A_k: x += alpha_{k-1} p_{k-1}, r_k = r_{k-1} - alpha_{k-1} q (k > 0; k = 0: the previous
// flip-flop's pending final update, if any); then the pre-smoothed residual
// r1 = r_k - sm, sm = A (omega D^-1 r_k), restricted into rc[k] (atomics), sm kept for C.
// final: update only.
__device__ __forceinline__ void mg_a_node(const System& s, int i, int k, bool final, float4 al,
                                          const Pending& pd = {}) {
  const float4* rin = s.r[(k + 1) & 1];  // r_{k-1} (k > 0)
  float4 rn;
  if (k == 0 && pd.p) s.x[i] = pd.at(s.x, i);
  if (k > 0) {
    rn = rin[i] - cmul(al, s.aq[i]);
    s.x[i] = s.x[i] + cmul(al, s.pb[(k - 1) & 1][i]);
    if (final) return;
    s.r[k & 1][i] = rn;
  } else {
    rn = s.r[0][i];
  }
  const float4* rk = k > 0 ? rin : s.r[0];
  const float4* qv = s.aq;
  const float* minv = s.minv;
  const float4 ar = k > 0 ? spmv_row(s, i, [&](int j) { return __ldg(minv + j) * (rk[j] - cmul(al, qv[j])); })
                          : spmv_row(s, i, [&](int j) { return __ldg(minv + j) * rk[j]; });
  const float4 sm = s.omega * ar;
  s.sm[i] = sm;
  const float4 r1 = rn - sm;
  float4* dst = s.rc + int64_t(k) * s.nc + s.agg[i];
  atomic_add(dst, r1);
}

__global__ void __launch_bounds__(kBlock) mg_a_kernel(System s, int k, bool final) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= s.n) return;
  mg_a_node(s, i, k, final, k > 0 ? mg_alpha(s, k - 1) : f4(0, 0, 0));
}

// Dense coarsest level: rows of it (nc, or nc2 with a third level).
__device__ __forceinline__ int dense_rows(const System& s) { return s.nc2 > 0 ? s.nc2 : s.nc; }

// Coarse row `row` of zc = Ac^-1 rc[k] (two levels) or zc2 = Ac2^-1 rc2[k] (three), by one warp
// (all 32 lanes call it).
__device__ __forceinline__ void coarse_row(const System& s, int row, int lane, int k) {
  const int nd = dense_rows(s);
  const float* a = s.ainv + int64_t(row) * nd;
  const float4* rc = s.nc2 > 0 ? s.rc2 + int64_t(k) * nd : s.rc + int64_t(k) * nd;
  float ax = 0.f, ay = 0.f, az = 0.f;
  for (int j = lane; j < nd; j += 32) {
    const float w = a[j];
    const float4 v = rc[j];
    ax += w * v.x;
    ay += w * v.y;
    az += w * v.z;
  }
  for (int o = 16; o > 0; o >>= 1) {
    ax += __shfl_down_sync(kFull, ax, o);
    ay += __shfl_down_sync(kFull, ay, o);
    az += __shfl_down_sync(kFull, az, o);
  }
  if (lane == 0) (s.nc2 > 0 ? s.zc2 : s.zc)[row] = f4(ax, ay, az);
}

// B_k: dense coarsest product (one warp per row).
__global__ void __launch_bounds__(kBlock) mg_coarse_kernel(System s, int k) {
  const int row = (blockIdx.x * blockDim.x + threadIdx.x) >> 5, lane = threadIdx.x & 31;
  if (row >= dense_rows(s)) return;
  coarse_row(s, row, lane, k);
}

// (Ac1 v)_c with v_j = get(j), CSR.
template <class F>
__device__ __forceinline__ float4 coarse_spmv(const System& s, int c, F get) {
  float4 acc = f4(0, 0, 0);
  const int q0 = __ldg(s.c_off + c), q1 = __ldg(s.c_off + c + 1);
  for (int q = q0; q < q1; ++q) acc = acc + __ldg(s.c_val + q) * get(__ldg(s.c_col + q));
  return acc;
}

// Third level, A1_k: coarse pre-smoothing y = omega1 Dc^-1 rc[k] and its residual rc - Ac1 y
// restricted into rc2[k] (atomics); neighbours' y recomputed.
__device__ __forceinline__ void mg_a1_node(const System& s, int c, int k) {
  const float4* rc = s.rc + int64_t(k) * s.nc;
  const float* mi = s.c_minv;
  const float om = s.omega1;
  const float4 ay = coarse_spmv(s, c, [&](int j) { return (om * __ldg(mi + j)) * rc[j]; });
  const float4 r1 = rc[c] - ay;
  float4* dst = s.rc2 + int64_t(k) * s.nc2 + s.agg2[c];
  atomic_add(dst, r1);
}

// Third level, B1_k: z2 = y + P2 zc2; zc = z2 + omega1 Dc^-1 (rc - Ac1 z2) (neighbours' z2
// recomputed from rc and zc2).
__device__ __forceinline__ void mg_b1_node(const System& s, int c, int k) {
  const float4* rc = s.rc + int64_t(k) * s.nc;
  const float* mi = s.c_minv;
  const float om = s.omega1;
  const int* a2 = s.agg2;
  const float4* zc2 = s.zc2;
  const float4 az =
      coarse_spmv(s, c, [&](int j) { return (om * __ldg(mi + j)) * rc[j] + zc2[__ldg(a2 + j)]; });
  const float4 rcc = rc[c];
  const float omc = om * mi[c];
  const float4 z2 = omc * rcc + zc2[a2[c]];
  s.zc[c] = z2 + omc * (rcc - az);
}

__global__ void __launch_bounds__(kBlock) mg_a1_kernel(System s, int k) {
  const int c = blockIdx.x * blockDim.x + threadIdx.x;
  if (c < s.nc) mg_a1_node(s, c, k);
}
__global__ void __launch_bounds__(kBlock) mg_b1_kernel(System s, int k) {
  const int c = blockIdx.x * blockDim.x + threadIdx.x;
  if (c < s.nc) mg_b1_node(s, c, k);
}

// C_k: z2 = omega D^-1 r + P zc; z = z2 + omega D^-1 (r - A z2); adds (r, z) into v. A z2 is
// sm + (A P) zc: sm = A omega D^-1 r is the A phase's pre-smoothing product, so the only gather
// left is the coarse vector's through the rows of A P (two loads deep; at most 4 entries on a
// node away from handles and split cells, where A's row has 7).
__device__ __forceinline__ void mg_c_node(const System& s, int i, int k, double (&v)[3]) {
  const float4 ri = s.r[k & 1][i];
  const float4* zc = s.zc;
  const float4 az = s.sm[i] + prolonged_row(s, i, [&](int a) { return zc[a]; });
  const float om = s.omega * s.minv[i];
  const float4 z2i = om * ri + zc[s.agg[i]];
  const float4 zi = z2i + om * (ri - az);
  s.z[i] = zi;
  v[0] += ri.x * zi.x;
  v[1] += ri.y * zi.y;
  v[2] += ri.z * zi.z;
}

__global__ void __launch_bounds__(kBlock) mg_c_kernel(System s, int k) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  double v[3] = {0, 0, 0};
  if (i < s.n) mg_c_node(s, i, k, v);
  block_add<3>(v, s.dots + 6 * k);
}

// D_k: p_k = z + beta p_{k-1}; q = A p_k; adds (p, q) into v.
__device__ __forceinline__ void mg_d_node(const System& s, int i, int k, float4 be, double (&v)[3]) {
  const float4* pold = s.pb[(k + 1) & 1];
  const float4 pi = k > 0 ? s.z[i] + cmul(be, pold[i]) : s.z[i];
  const float4* z = s.z;
  const float4 aq = k > 0 ? spmv_row(s, i, [&](int j) { return z[j] + cmul(be, pold[j]); })
                          : spmv_row(s, i, [&](int j) { return z[j]; });
  s.pb[k & 1][i] = pi;
  s.aq[i] = aq;
  v[0] += pi.x * aq.x;
  v[1] += pi.y * aq.y;
  v[2] += pi.z * aq.z;
}

__global__ void __launch_bounds__(kBlock) mg_d_kernel(System s, int k) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  double v[3] = {0, 0, 0};
  if (i < s.n) mg_d_node(s, i, k, k > 0 ? mg_beta(s, k) : f4(0, 0, 0), v);
  block_add<3>(v, s.dots + 6 * k + 3);
}

// ---------------------------------------------------------------- fused two-level flip-flops
// A phase's items [0, count) for this thread: [begin, end) in steps of step.
struct Share {
  int begin, end, step;
};
// The grid-stride loop.
__device__ __forceinline__ Share stride_share(int count) {
  return {int(blockIdx.x * blockDim.x + threadIdx.x), count, int(gridDim.x * blockDim.x)};
}
// The nodes' and the rotation phase's loops: when the grid has a thread for every item, each block
// takes an even contiguous share (about count / blocks), so that a small lattice keeps every SM
// busy rather than filling a few blocks and leaving the rest idle (9.9k nodes on 132 SMs: 75 a
// block, not 256 on 39 blocks); otherwise the grid-stride loop, whose interleaving also balances
// the rotation phase's two kinds of items. (The third level's coarse nodes keep the grid-stride
// loop: spread over every block, their restriction's atomics were slower; results-gpu.md,
// session 24.)
__device__ __forceinline__ Share share(int count) {
  if (count > int(gridDim.x * blockDim.x)) return stride_share(count);
  const int per = (count + gridDim.x - 1) / gridDim.x;
  const int b0 = blockIdx.x * per;
  return {b0 + int(threadIdx.x), min(count, b0 + per), int(blockDim.x)};
}

// With s.stamps set, thread 0 of block 0 (one SM for the whole launch) writes clock64() at the
// start and after each phase's barrier: stamps[1 + it * fused_phases(s) + phase].
__device__ __forceinline__ void stamp(const System& s, int& k) {
  if (s.stamps && blockIdx.x == 0 && threadIdx.x == 0) s.stamps[k] = clock64();
  ++k;
}

// One cooperative launch runs `iterations` whole flip-flops (rotations + energy, rhs, `inner`
// two-level PCG iterations, final update): the phases of the separate kernels above, each a loop
// over its share of the items, separated by grid-wide barriers instead of kernel boundaries; then
// the energy of its last flip-flop (energy slot iterations - 1).
__global__ void __launch_bounds__(kBlock, 1) mg_fused_kernel(System s, int iterations) {
  cg::grid_group grid = cg::this_grid();
  const int tid = blockIdx.x * blockDim.x + threadIdx.x;
  const int stride = gridDim.x * blockDim.x;
  int st = 0;
  stamp(s, st);
  Pending pd;  // the previous flip-flop's final update, not yet applied (none on the first)
  for (int it = 0; it < iterations; ++it) {
    {  // rotations + energy of the previous flip-flop (ARAP and anchors, handle term)
      const bool want_e = it > 0;
      double v[2] = {0.0, 0.0};
      const Share sh = share(rotation_items(s, want_e));
      for (int k = sh.begin; k < sh.end; k += sh.step) rotation_item(s, k, true, want_e, v, pd);
      if (want_e) block_add<2>(v, s.energy + 2 * (it - 1));
    }
    grid.sync();
    stamp(s, st);
    // rhs, r0 = b - A x; fresh scalars and restriction slots
    if (blockIdx.x == 0) {
      for (int k = threadIdx.x; k < (s.inner + 1) * 6; k += blockDim.x) s.dots[k] = 0.0;
      if (threadIdx.x == 0) *s.iter += 1;
    }
    for (int64_t k = tid; k < int64_t(s.inner) * s.nc; k += stride) s.rc[k] = f4(0, 0, 0);
    for (int64_t k = tid; k < int64_t(s.inner) * s.nc2; k += stride) s.rc2[k] = f4(0, 0, 0);
    {
      const Share sh = share(s.n);
      for (int i = sh.begin; i < sh.end; i += sh.step) s.r[0][i] = residual_at(s, i, pd);
    }
    grid.sync();
    stamp(s, st);
    for (int k = 0; k < s.inner; ++k) {
      {
        const float4 al = k > 0 ? mg_alpha(s, k - 1) : f4(0, 0, 0);
        const Share sh = share(s.n);
        for (int i = sh.begin; i < sh.end; i += sh.step)
          mg_a_node(s, i, k, false, al, k == 0 ? pd : Pending{});
      }
      grid.sync();
      stamp(s, st);
      if (s.nc2 > 0) {  // third level: coarse pre-smoothing, restriction to level 2
        const Share sh = stride_share(s.nc);
        for (int c = sh.begin; c < sh.end; c += sh.step) mg_a1_node(s, c, k);
        grid.sync();
        stamp(s, st);
      }
      {
        const int lane = threadIdx.x & 31;
        const int nd = dense_rows(s);
        for (int row = tid >> 5; row < nd; row += stride >> 5) coarse_row(s, row, lane, k);
      }
      grid.sync();
      stamp(s, st);
      if (s.nc2 > 0) {  // third level: prolongation + coarse post-smoothing into zc
        const Share sh = stride_share(s.nc);
        for (int c = sh.begin; c < sh.end; c += sh.step) mg_b1_node(s, c, k);
        grid.sync();
        stamp(s, st);
      }
      {
        double v[3] = {0, 0, 0};
        const Share sh = share(s.n);
        for (int i = sh.begin; i < sh.end; i += sh.step) mg_c_node(s, i, k, v);
        block_add<3>(v, s.dots + 6 * k);
      }
      grid.sync();
      stamp(s, st);
      {
        double v[3] = {0, 0, 0};
        const float4 be = k > 0 ? mg_beta(s, k) : f4(0, 0, 0);
        const Share sh = share(s.n);
        for (int i = sh.begin; i < sh.end; i += sh.step) mg_d_node(s, i, k, be, v);
        block_add<3>(v, s.dots + 6 * k + 3);
      }
      grid.sync();
      stamp(s, st);
    }
    const float4 al = mg_alpha(s, s.inner - 1);
    if (it + 1 < iterations && s.exact_residual) {
      // The final update x += al p is left to the next flip-flop (Pending): its rotation and
      // rhs phases read x through it and its first CG phase applies it, so no barrier here. al is
      // read now, before the next rhs phase clears the scalars; p (pb[(inner - 1) & 1]) is written
      // again only by a direction phase, and the first of those follows the first CG phase.
      pd = Pending{s.pb[(s.inner - 1) & 1], al};
      stamp(s, st);  // an empty phase, so that the stamps keep their places
    } else {
      pd = Pending{};
      const Share sh = share(s.n);
      for (int i = sh.begin; i < sh.end; i += sh.step) mg_a_node(s, i, s.inner, true, al);
      grid.sync();
      stamp(s, st);
    }
  }
  {  // the energy of the launch's last pose with its rotations: no kernel after the loop for it,
     // and no barrier after it (the launch ends; the next launch's first flip-flop adds none)
    double v[2] = {0.0, 0.0};
    const Share sh = share(rotation_items(s, true));
    for (int k = sh.begin; k < sh.end; k += sh.step) rotation_item(s, k, false, true, v);
    block_add<2>(v, s.energy + 2 * (iterations - 1));
  }
}

}  // namespace

void launch_mg_iteration(const System& s, int k, cudaStream_t st) {
  mg_a_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, k, false);
  if (s.nc2 > 0) mg_a1_kernel<<<blocks_for(s.nc), kBlock, 0, st>>>(s, k);
  mg_coarse_kernel<<<blocks_for(int64_t(s.nc2 > 0 ? s.nc2 : s.nc) * 32), kBlock, 0, st>>>(s, k);
  if (s.nc2 > 0) mg_b1_kernel<<<blocks_for(s.nc), kBlock, 0, st>>>(s, k);
  mg_c_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, k);
  mg_d_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, k);
}

int mg_fused_max_blocks() {
  int dev = 0, coop = 0, sms = 0, per_sm = 0;
  if (cudaGetDevice(&dev) != cudaSuccess) return 0;
  if (cudaDeviceGetAttribute(&coop, cudaDevAttrCooperativeLaunch, dev) != cudaSuccess || !coop) return 0;
  if (cudaDeviceGetAttribute(&sms, cudaDevAttrMultiProcessorCount, dev) != cudaSuccess) return 0;
  if (cudaOccupancyMaxActiveBlocksPerMultiprocessor(&per_sm, mg_fused_kernel, kBlock, 0) != cudaSuccess)
    return 0;
  return sms * per_sm;
}

cudaError_t launch_mg_fused(const System& s, int iterations, int blocks, cudaStream_t st) {
  System sc = s;
  void* args[] = {&sc, &iterations};
  return cudaLaunchCooperativeKernel(reinterpret_cast<void*>(mg_fused_kernel), dim3(blocks), dim3(kBlock),
                                     args, 0, st);
}

void launch_mg_final(const System& s, cudaStream_t st) {
  mg_a_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, s.inner, true);
}

}  // namespace cuda
}  // namespace larap
