// Kernels of the CUDA backend (see kernels.h and docs/cuda.md).
#include <cooperative_groups.h>

#include "kernels.h"
#include "rotation.cuh"

namespace cg = cooperative_groups;

namespace larap {
namespace cuda {
namespace {

constexpr int kBlock = 256;
constexpr unsigned kFull = 0xffffffffu;

__device__ __forceinline__ float4 f4(float x, float y, float z) { return make_float4(x, y, z, 0.f); }
__device__ __forceinline__ float4 operator+(float4 a, float4 b) { return f4(a.x + b.x, a.y + b.y, a.z + b.z); }
__device__ __forceinline__ float4 operator-(float4 a, float4 b) { return f4(a.x - b.x, a.y - b.y, a.z - b.z); }
__device__ __forceinline__ float4 operator*(float s, float4 a) { return f4(s * a.x, s * a.y, s * a.z); }
// Per-column products (3 independent systems).
__device__ __forceinline__ float4 cmul(float4 a, float4 b) { return f4(a.x * b.x, a.y * b.y, a.z * b.z); }
__device__ __forceinline__ float dot3(float4 a, float4 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

int blocks_for(int64_t n) { return int((n + kBlock - 1) / kBlock); }

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

// (A v)_i with v_j = get(j): diagonal + 6 unrolled lattice slots (all loads in flight at once)
// + the short remainder list.
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
  for (int q = q0; q < q1; ++q) acc = acc + __ldg(s.rem_val + q) * get(__ldg(s.rem_col + q));
  return acc;
}

// ---------------------------------------------------------------- rotations (+ energy)
// Node i: new rotation (write_rot) and, when want_e, its energy term with the old rotations.
__device__ __forceinline__ double rot_node(const System& s, int i, bool write_rot, bool want_e) {
  double e = 0.0;
  const float4 pi = s.x[i], ci = s.rest[i];
  float S[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
  float Ro[9];
  if (want_e)
#pragma unroll
    for (int k = 0; k < 9; ++k) Ro[k] = s.rot[k * s.n + i];
  float ei = 0.f;
  int js[6];
#pragma unroll
  for (int d = 0; d < 6; ++d) js[d] = __ldg(s.nbr + d * s.n + i);
#pragma unroll
  for (int d = 0; d < 6; ++d) {
    const int j = js[d];  // missing neighbour: i itself, dp = dc = 0
    const float4 dp = pi - s.x[j], dc = ci - s.rest[j];
    S[0] += dp.x * dc.x; S[1] += dp.x * dc.y; S[2] += dp.x * dc.z;
    S[3] += dp.y * dc.x; S[4] += dp.y * dc.y; S[5] += dp.y * dc.z;
    S[6] += dp.z * dc.x; S[7] += dp.z * dc.y; S[8] += dp.z * dc.z;
    if (want_e) {
      const float rx = dp.x - (Ro[0] * dc.x + Ro[1] * dc.y + Ro[2] * dc.z);
      const float ry = dp.y - (Ro[3] * dc.x + Ro[4] * dc.y + Ro[5] * dc.z);
      const float rz = dp.z - (Ro[6] * dc.x + Ro[7] * dc.y + Ro[8] * dc.z);
      ei += rx * rx + ry * ry + rz * rz;
    }
  }
  if (want_e) {
    e = double(s.g) * double(ei);
    if (s.anchored[i]) {
      const float4 d = pi - ci;
      e += double(s.a) * double(dot3(d, d));
    }
  }
  if (write_rot) {
    float R[9];
    cuda_math::best_rotation_f(S, R);
#pragma unroll
    for (int k = 0; k < 9; ++k) s.rot[k * s.n + i] = R[k];
  }
  return e;
}

// Handle t's term |B_t x - t_t|^2.
__device__ __forceinline__ double handle_energy(const System& s, int t) {
  float4 acc = f4(0, 0, 0);
  for (int k = 0; k < s.stencil; ++k) {
    const int id = s.b_ids[t * s.stencil + k];
    acc = acc + s.b_w[t * s.stencil + k] * s.x[id];
  }
  const float4 d = acc - s.targets[t];
  return double(dot3(d, d));
}

__global__ void __launch_bounds__(kBlock) rotations_kernel(System s, bool write_rot, int slot) {
  const int t = blockIdx.x * blockDim.x + threadIdx.x;
  int e_slot = slot;
  if (slot == -1) e_slot = *s.iter - 1;  // < 0 on the first flip-flop of a solve: no energy
  double e = 0.0;
  if (t < s.n) e += rot_node(s, t, write_rot, e_slot >= 0);
  if (e_slot >= 0 && t < s.m) e += handle_energy(s, t);
  if (e_slot >= 0) {
    double v[1] = {e};
    block_add<1>(v, s.energy + e_slot);
  }
}

// ---------------------------------------------------------------- right-hand side
__device__ __forceinline__ float4 rhs_at(const System& s, int i) {
  const float4 ci = s.rest[i];
  float Ri[9];
#pragma unroll
  for (int k = 0; k < 9; ++k) Ri[k] = s.rot[k * s.n + i];
  float bx = 0.f, by = 0.f, bz = 0.f;
  int js[6];
#pragma unroll
  for (int d = 0; d < 6; ++d) js[d] = __ldg(s.nbr + d * s.n + i);
#pragma unroll
  for (int d = 0; d < 6; ++d) {
    const int j = js[d];  // missing neighbour: i itself, dc = 0
    const float4 dc = ci - s.rest[j];
    float M[9];
#pragma unroll
    for (int q = 0; q < 9; ++q) M[q] = Ri[q] + s.rot[q * s.n + j];
    bx += M[0] * dc.x + M[1] * dc.y + M[2] * dc.z;
    by += M[3] * dc.x + M[4] * dc.y + M[5] * dc.z;
    bz += M[6] * dc.x + M[7] * dc.y + M[8] * dc.z;
  }
  float4 b = f4(s.g * bx, s.g * by, s.g * bz);
  for (int k = s.bt_off[i]; k < s.bt_off[i + 1]; ++k) b = b + s.bt_w[k] * s.targets[s.bt_handle[k]];
  if (s.anchored[i]) b = b + s.a * ci;
  return b;
}

__global__ void __launch_bounds__(kBlock) rhs_kernel(System s, bool residual) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (blockIdx.x == 0) {  // fresh solver scalars for this flip-flop
    for (int k = threadIdx.x; k < (s.inner + 1) * 6; k += blockDim.x) s.dots[k] = 0.0;
    for (int k = threadIdx.x; k < s.inner + 1; k += blockDim.x) s.counters[k] = 0u;
    if (threadIdx.x == 0) *s.iter += 1;
  }
  if (s.nc > 0) {  // two-level CG: zero the restriction slots of this flip-flop
    const int64_t tot = int64_t(s.inner) * s.nc;
    for (int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; k < tot; k += int64_t(gridDim.x) * blockDim.x)
      s.rc[k] = f4(0, 0, 0);
    const int64_t tot2 = int64_t(s.inner) * s.nc2;
    for (int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; k < tot2; k += int64_t(gridDim.x) * blockDim.x)
      s.rc2[k] = f4(0, 0, 0);
  }
  if (i >= s.n) return;
  float4 b = rhs_at(s, i);
  if (residual) {
    const float4* x = s.x;
    b = b - spmv_row(s, i, [&](int j) { return x[j]; });
  }
  s.r[0][i] = b;
}

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
    v[0] = rn.x * un.x; v[1] = rn.y * un.y; v[2] = rn.z * un.z;
    v[3] = wn.x * un.x; v[4] = wn.y * un.y; v[5] = wn.z * un.z;
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
        if (den > 0.0 && isfinite(den)) alpha = gam / den;
        else beta = 0.0;
      }
    }
    if (!(alpha > 0.0) || !isfinite(alpha)) alpha = beta = 0.0;
    cn[c] = float(alpha);
    cn[3 + c] = float(beta);
  }
  cn[6] = k == 0 ? 1.f : 0.f;
  s.counters[k] = 0u;
}


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

// A_k: x += alpha_{k-1} p_{k-1}, r_k = r_{k-1} - alpha_{k-1} q (k > 0); then the pre-smoothed
// residual r1 = r_k - A (omega D^-1 r_k) restricted into rc[k] (atomics). final: update only.
__device__ __forceinline__ void mg_a_node(const System& s, int i, int k, bool final, float4 al) {
  const float4* rin = s.r[(k + 1) & 1];  // r_{k-1} (k > 0)
  float4 rn;
  if (k > 0) {
    rn = rin[i] - cmul(al, s.q[i]);
    s.x[i] = s.x[i] + cmul(al, s.pb[(k - 1) & 1][i]);
    if (final) return;
    s.r[k & 1][i] = rn;
  } else {
    rn = s.r[0][i];
  }
  const float4* rk = k > 0 ? rin : s.r[0];
  const float4* qv = s.q;
  const float* minv = s.minv;
  const float4 ar = k > 0 ? spmv_row(s, i, [&](int j) { return __ldg(minv + j) * (rk[j] - cmul(al, qv[j])); })
                          : spmv_row(s, i, [&](int j) { return __ldg(minv + j) * rk[j]; });
  const float4 r1 = rn - s.omega * ar;
  float4* dst = s.rc + int64_t(k) * s.nc + s.agg[i];
  atomicAdd(&dst->x, r1.x);
  atomicAdd(&dst->y, r1.y);
  atomicAdd(&dst->z, r1.z);
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
    ax += w * v.x; ay += w * v.y; az += w * v.z;
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
  atomicAdd(&dst->x, r1.x);
  atomicAdd(&dst->y, r1.y);
  atomicAdd(&dst->z, r1.z);
}

// Third level, B1_k: z2 = y + P2 zc2; zc = z2 + omega1 Dc^-1 (rc - Ac1 z2) (neighbours' z2
// recomputed from rc and zc2).
__device__ __forceinline__ void mg_b1_node(const System& s, int c, int k) {
  const float4* rc = s.rc + int64_t(k) * s.nc;
  const float* mi = s.c_minv;
  const float om = s.omega1;
  const int* a2 = s.agg2;
  const float4* zc2 = s.zc2;
  const float4 az = coarse_spmv(s, c, [&](int j) { return (om * __ldg(mi + j)) * rc[j] + zc2[__ldg(a2 + j)]; });
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

// C_k: z2 = omega D^-1 r + P zc; z = z2 + omega D^-1 (r - A z2); adds (r, z) into v.
__device__ __forceinline__ void mg_c_node(const System& s, int i, int k, double (&v)[3]) {
  const float4* r = s.r[k & 1];
  const float4 ri = r[i];
  const float om = s.omega;
  const float* minv = s.minv;
  const int* agg = s.agg;
  const float4* zc = s.zc;
  const float4 az = spmv_row(s, i, [&](int j) { return (om * __ldg(minv + j)) * r[j] + zc[__ldg(agg + j)]; });
  const float4 z2i = (s.omega * s.minv[i]) * ri + s.zc[s.agg[i]];
  const float4 zi = z2i + (s.omega * s.minv[i]) * (ri - az);
  s.z[i] = zi;
  v[0] += ri.x * zi.x; v[1] += ri.y * zi.y; v[2] += ri.z * zi.z;
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
  s.q[i] = aq;
  v[0] += pi.x * aq.x; v[1] += pi.y * aq.y; v[2] += pi.z * aq.z;
}

__global__ void __launch_bounds__(kBlock) mg_d_kernel(System s, int k) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  double v[3] = {0, 0, 0};
  if (i < s.n) mg_d_node(s, i, k, k > 0 ? mg_beta(s, k) : f4(0, 0, 0), v);
  block_add<3>(v, s.dots + 6 * k + 3);
}

// ---------------------------------------------------------------- fused two-level flip-flops
// One cooperative launch runs `iterations` whole flip-flops (rotations + energy, rhs, `inner`
// two-level PCG iterations, final update): the phases of the separate kernels above, each a
// grid-stride loop, separated by grid-wide barriers instead of kernel boundaries.
__global__ void __launch_bounds__(kBlock, 1) mg_fused_kernel(System s, int iterations) {
  cg::grid_group grid = cg::this_grid();
  const int tid = blockIdx.x * blockDim.x + threadIdx.x;
  const int stride = gridDim.x * blockDim.x;
  const int nrot = s.n > s.m ? s.n : s.m;
  for (int it = 0; it < iterations; ++it) {
    {  // rotations + energy of the previous flip-flop
      const bool want_e = it > 0;
      double e = 0.0;
      for (int t = tid; t < nrot; t += stride) {
        if (t < s.n) e += rot_node(s, t, true, want_e);
        if (want_e && t < s.m) e += handle_energy(s, t);
      }
      if (want_e) {
        double v[1] = {e};
        block_add<1>(v, s.energy + it - 1);
      }
    }
    grid.sync();
    // rhs, r0 = b - A x; fresh scalars and restriction slots
    if (blockIdx.x == 0) {
      for (int k = threadIdx.x; k < (s.inner + 1) * 6; k += blockDim.x) s.dots[k] = 0.0;
      if (threadIdx.x == 0) *s.iter += 1;
    }
    for (int64_t k = tid; k < int64_t(s.inner) * s.nc; k += stride) s.rc[k] = f4(0, 0, 0);
    for (int64_t k = tid; k < int64_t(s.inner) * s.nc2; k += stride) s.rc2[k] = f4(0, 0, 0);
    for (int i = tid; i < s.n; i += stride) {
      const float4* x = s.x;
      s.r[0][i] = rhs_at(s, i) - spmv_row(s, i, [&](int j) { return x[j]; });
    }
    grid.sync();
    for (int k = 0; k < s.inner; ++k) {
      {
        const float4 al = k > 0 ? mg_alpha(s, k - 1) : f4(0, 0, 0);
        for (int i = tid; i < s.n; i += stride) mg_a_node(s, i, k, false, al);
      }
      grid.sync();
      if (s.nc2 > 0) {  // third level: coarse pre-smoothing, restriction to level 2
        for (int c = tid; c < s.nc; c += stride) mg_a1_node(s, c, k);
        grid.sync();
      }
      {
        const int lane = threadIdx.x & 31;
        const int nd = dense_rows(s);
        for (int row = tid >> 5; row < nd; row += stride >> 5) coarse_row(s, row, lane, k);
      }
      grid.sync();
      if (s.nc2 > 0) {  // third level: prolongation + coarse post-smoothing into zc
        for (int c = tid; c < s.nc; c += stride) mg_b1_node(s, c, k);
        grid.sync();
      }
      {
        double v[3] = {0, 0, 0};
        for (int i = tid; i < s.n; i += stride) mg_c_node(s, i, k, v);
        block_add<3>(v, s.dots + 6 * k);
      }
      grid.sync();
      {
        double v[3] = {0, 0, 0};
        const float4 be = k > 0 ? mg_beta(s, k) : f4(0, 0, 0);
        for (int i = tid; i < s.n; i += stride) mg_d_node(s, i, k, be, v);
        block_add<3>(v, s.dots + 6 * k + 3);
      }
      grid.sync();
    }
    {
      const float4 al = mg_alpha(s, s.inner - 1);
      for (int i = tid; i < s.n; i += stride) mg_a_node(s, i, s.inner, true, al);
    }
    grid.sync();
  }
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

// ---------------------------------------------------------------- small helpers
struct Mat3f {
  float m[9];
};

__global__ void rigid_kernel(System s, Mat3f R, float4 t) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= s.n || s.anchored[i]) return;
  const float4 p = s.x[i];
  s.x[i] = f4(R.m[0] * p.x + R.m[1] * p.y + R.m[2] * p.z + t.x,
              R.m[3] * p.x + R.m[4] * p.y + R.m[5] * p.z + t.y,
              R.m[6] * p.x + R.m[7] * p.y + R.m[8] * p.z + t.z);
}

__global__ void handle_positions_kernel(System s, float4* out) {
  const int j = blockIdx.x * blockDim.x + threadIdx.x;
  if (j >= s.m) return;
  float4 acc = f4(0, 0, 0);
  for (int k = 0; k < s.stencil; ++k) acc = acc + s.b_w[j * s.stencil + k] * s.x[s.b_ids[j * s.stencil + k]];
  out[j] = acc;
}

__global__ void displacement_kernel(System s, float4* disp) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i < s.n) disp[i] = s.x[i] - s.rest[i];
}

// ---------------------------------------------------------------- transfer
// One block = kBlock consecutive vertices. V is read and out written through shared memory with
// 16-byte accesses (3 kBlock values of T per block, contiguous); a partial or unaligned block
// falls back to scalar accesses. Each thread computes sum_k w_k disp[id_k] for its vertex.
template <typename T>
__device__ __forceinline__ bool aligned16(const T* p) { return (reinterpret_cast<uintptr_t>(p) & 15) == 0; }

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

template <typename T, bool Staged>
__global__ void __launch_bounds__(kBlock) trilinear_kernel(int64_t v0, int64_t v1, const float4* __restrict__ packed,
                                                           const int4* __restrict__ cell_nodes,
                                                           const float4* __restrict__ disp,
                                                           const T* __restrict__ V, T* __restrict__ out) {
  __shared__ __align__(16) T sh[Staged ? 3 * kBlock : 1];
  const int64_t b0 = v0 + int64_t(blockIdx.x) * kBlock;
  const int cnt = int(v1 - b0 < kBlock ? v1 - b0 : kBlock);
  const bool vec = cnt == kBlock && aligned16(V + 3 * b0) && aligned16(out + 3 * b0);
  if (Staged) stage_in(sh, V + 3 * b0, cnt, vec);
  const int t = threadIdx.x;
  float ax = 0.f, ay = 0.f, az = 0.f;
  if (t < cnt) {
    const float4 pk = __ldg(packed + b0 + t);
    const int c = __float_as_int(pk.x);
    const float fx = pk.y, fy = pk.z, fz = pk.w;
    const int4 n0 = __ldg(cell_nodes + 2 * c), n1 = __ldg(cell_nodes + 2 * c + 1);
    const int ids[8] = {n0.x, n0.y, n0.z, n0.w, n1.x, n1.y, n1.z, n1.w};
    const float wx[2] = {1.f - fx, fx}, wy[2] = {1.f - fy, fy}, wz[2] = {1.f - fz, fz};
#pragma unroll
    for (int k = 0; k < 8; ++k) {
      const float w = wx[k & 1] * wy[(k >> 1) & 1] * wz[k >> 2];
      const float4 d = __ldg(disp + ids[k]);
      ax += w * d.x;
      ay += w * d.y;
      az += w * d.z;
    }
  }
  if (!Staged) {  // 3 scalar loads and stores per vertex
    if (t < cnt) {
      const int64_t v = b0 + t;
      out[3 * v] = V[3 * v] + T(ax);
      out[3 * v + 1] = V[3 * v + 1] + T(ay);
      out[3 * v + 2] = V[3 * v + 2] + T(az);
    }
    return;
  }
  __syncthreads();
  if (t < cnt) {
    sh[3 * t] += T(ax);
    sh[3 * t + 1] += T(ay);
    sh[3 * t + 2] += T(az);
  }
  __syncthreads();
  stage_out(sh, out + 3 * b0, cnt, vec);
}

template <typename T, bool Staged>
__global__ void __launch_bounds__(kBlock) bspline_kernel(int64_t v0, int64_t v1, const float4* __restrict__ packed,
                                                         const int* __restrict__ node27,
                                                         const float4* __restrict__ disp,
                                                         const T* __restrict__ V, T* __restrict__ out) {
  __shared__ __align__(16) T sh[Staged ? 3 * kBlock : 1];
  const int64_t b0 = v0 + int64_t(blockIdx.x) * kBlock;
  const int cnt = int(v1 - b0 < kBlock ? v1 - b0 : kBlock);
  const bool vec = cnt == kBlock && aligned16(V + 3 * b0) && aligned16(out + 3 * b0);
  if (Staged) stage_in(sh, V + 3 * b0, cnt, vec);
  const int t = threadIdx.x;
  float ax = 0.f, ay = 0.f, az = 0.f;
  if (t < cnt) {
    const float4 pk = __ldg(packed + b0 + t);
    const int64_t b = __float_as_int(pk.x);
    const float fr[3] = {pk.y, pk.z, pk.w};
    float w[3][3];
#pragma unroll
    for (int a = 0; a < 3; ++a) {
      const float u = fr[a];
      w[a][0] = 0.5f * (0.5f - u) * (0.5f - u);
      w[a][1] = 0.75f - u * u;
      w[a][2] = 0.5f * (0.5f + u) * (0.5f + u);
    }
    const int* ids = node27 + 27 * b;
#pragma unroll
    for (int z = 0; z < 3; ++z)
#pragma unroll
      for (int y = 0; y < 3; ++y) {
        const float wyz = w[1][y] * w[2][z];
#pragma unroll
        for (int x = 0; x < 3; ++x) {
          const float ww = w[0][x] * wyz;
          const float4 d = __ldg(disp + __ldg(ids + 9 * z + 3 * y + x));
          ax += ww * d.x;
          ay += ww * d.y;
          az += ww * d.z;
        }
      }
  }
  if (!Staged) {  // 3 scalar loads and stores per vertex
    if (t < cnt) {
      const int64_t v = b0 + t;
      out[3 * v] = V[3 * v] + T(ax);
      out[3 * v + 1] = V[3 * v + 1] + T(ay);
      out[3 * v + 2] = V[3 * v + 2] + T(az);
    }
    return;
  }
  __syncthreads();
  if (t < cnt) {
    sh[3 * t] += T(ax);
    sh[3 * t + 1] += T(ay);
    sh[3 * t + 2] += T(az);
  }
  __syncthreads();
  stage_out(sh, out + 3 * b0, cnt, vec);
}

// Several vertices per thread (VPT, vertices b0 + k kBlock + threadIdx.x: each k coalesced), the
// loads of all of them issued phase by phase so that VPT independent chains packed -> corners ->
// displacements are in flight at once. Stream: packed and V (read once) with __ldcs, out with
// __stcs (evict-first), so that the gathered tables (cell corners, displacements) keep L2.
template <bool Stream, typename T>
__device__ __forceinline__ T ld_once(const T* p) {
  if constexpr (Stream) return __ldcs(p);
  else return __ldg(p);
}
template <bool Stream, typename T>
__device__ __forceinline__ void st_once(T* p, T v) {
  if constexpr (Stream) __stcs(p, v);
  else *p = v;
}

template <typename T, int VPT, bool Stream>
__global__ void __launch_bounds__(kBlock) trilinear_ilp_kernel(int64_t v0, int64_t v1,
                                                               const float4* __restrict__ packed,
                                                               const int4* __restrict__ cell_nodes,
                                                               const float4* __restrict__ disp,
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
    ids[k][0] = n0.x; ids[k][1] = n0.y; ids[k][2] = n0.z; ids[k][3] = n0.w;
    ids[k][4] = n1.x; ids[k][5] = n1.y; ids[k][6] = n1.z; ids[k][7] = n1.w;
  }
  float4 d[VPT][8];
#pragma unroll
  for (int k = 0; k < VPT; ++k)
#pragma unroll
    for (int j = 0; j < 8; ++j) d[k][j] = __ldg(disp + ids[k][j]);
#pragma unroll
  for (int k = 0; k < VPT; ++k) {
    const float fx = pk[k].y, fy = pk[k].z, fz = pk[k].w;
    const float wx[2] = {1.f - fx, fx}, wy[2] = {1.f - fy, fy}, wz[2] = {1.f - fz, fz};
    float ax = 0.f, ay = 0.f, az = 0.f;
#pragma unroll
    for (int j = 0; j < 8; ++j) {
      const float w = wx[j & 1] * wy[(j >> 1) & 1] * wz[j >> 2];
      ax += w * d[k][j].x;
      ay += w * d[k][j].y;
      az += w * d[k][j].z;
    }
    const int64_t v = b0 + int64_t(k) * kBlock;
    if (v < v1) {
      st_once<Stream>(out + 3 * v, vv[k][0] + T(ax));
      st_once<Stream>(out + 3 * v + 1, vv[k][1] + T(ay));
      st_once<Stream>(out + 3 * v + 2, vv[k][2] + T(az));
    }
  }
}

__global__ void probe_kernel() {}

}  // namespace

void launch_rotations(const System& s, bool write_rot, int slot, cudaStream_t st) {
  const int64_t n = s.n > s.m ? s.n : s.m;
  if (n == 0) return;
  rotations_kernel<<<blocks_for(n), kBlock, 0, st>>>(s, write_rot, slot);
}

void launch_rhs(const System& s, bool residual, cudaStream_t st) {
  rhs_kernel<<<blocks_for(s.n > 0 ? s.n : 1), kBlock, 0, st>>>(s, residual);
}

void launch_cg(const System& s, int k, cudaStream_t st) {
  cg_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, k);
}

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
  if (cudaOccupancyMaxActiveBlocksPerMultiprocessor(&per_sm, mg_fused_kernel, kBlock, 0) != cudaSuccess) return 0;
  return sms * per_sm;
}

cudaError_t launch_mg_fused(const System& s, int iterations, int blocks, cudaStream_t st) {
  System sc = s;
  void* args[] = {&sc, &iterations};
  return cudaLaunchCooperativeKernel(reinterpret_cast<void*>(mg_fused_kernel), dim3(blocks), dim3(kBlock), args,
                                     0, st);
}

void launch_mg_final(const System& s, cudaStream_t st) {
  mg_a_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, s.inner, true);
}

void launch_cheby(const System& s, int k, float c1, float c2, cudaStream_t st) {
  cheby_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, k, c1, c2);
}

void launch_rigid(const System& s, const float* R9, float tx, float ty, float tz, cudaStream_t st) {
  Mat3f R;
  for (int k = 0; k < 9; ++k) R.m[k] = R9[k];
  if (s.n) rigid_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, R, make_float4(tx, ty, tz, 0.f));
}

void launch_handle_positions(const System& s, float4* out, cudaStream_t st) {
  if (s.m) handle_positions_kernel<<<blocks_for(s.m), kBlock, 0, st>>>(s, out);
}

void launch_displacement(const System& s, float4* disp, cudaStream_t st) {
  if (s.n) displacement_kernel<<<blocks_for(s.n), kBlock, 0, st>>>(s, disp);
}

template <typename T>
void transfer_trilinear(int64_t v0, int64_t v1, const float4* packed, const int* cell_nodes,
                        const float4* disp, const T* V, T* out, const TransferVariant& tv, cudaStream_t st) {
  if (v1 <= v0) return;
  const int4* cn = reinterpret_cast<const int4*>(cell_nodes);
  if (tv.mode == kTransferIlp) {
    const int vpt = tv.vpt >= 4 ? 4 : tv.vpt >= 2 ? 2 : 1;
    const int blocks = int((v1 - v0 + int64_t(kBlock) * vpt - 1) / (int64_t(kBlock) * vpt));
    auto k = tv.stream ? (vpt == 4 ? trilinear_ilp_kernel<T, 4, true> : vpt == 2 ? trilinear_ilp_kernel<T, 2, true>
                                                                                : trilinear_ilp_kernel<T, 1, true>)
                       : (vpt == 4 ? trilinear_ilp_kernel<T, 4, false> : vpt == 2 ? trilinear_ilp_kernel<T, 2, false>
                                                                                 : trilinear_ilp_kernel<T, 1, false>);
    k<<<blocks, kBlock, 0, st>>>(v0, v1, packed, cn, disp, V, out);
    return;
  }
  (tv.mode == kTransferStaged ? trilinear_kernel<T, true> : trilinear_kernel<T, false>)<<<blocks_for(v1 - v0), kBlock, 0, st>>>(
      v0, v1, packed, cn, disp, V, out);
}

void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed,
                               const int* cell_nodes, const float4* disp, const float* V,
                               float* out, const TransferVariant& tv, cudaStream_t st) {
  transfer_trilinear(v0, v1, packed, cell_nodes, disp, V, out, tv, st);
}
void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed,
                               const int* cell_nodes, const float4* disp, const double* V,
                               double* out, const TransferVariant& tv, cudaStream_t st) {
  transfer_trilinear(v0, v1, packed, cell_nodes, disp, V, out, tv, st);
}
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed,
                             const int* node27, const float4* disp, const float* V, float* out,
                             const TransferVariant& tv, cudaStream_t st) {
  const bool staged = tv.mode == kTransferStaged;
  if (v1 > v0)
    (staged ? bspline_kernel<float, true> : bspline_kernel<float, false>)<<<blocks_for(v1 - v0), kBlock, 0, st>>>(v0, v1, packed, node27, disp, V, out);
}
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed,
                             const int* node27, const float4* disp, const double* V, double* out,
                             const TransferVariant& tv, cudaStream_t st) {
  const bool staged = tv.mode == kTransferStaged;
  if (v1 > v0)
    (staged ? bspline_kernel<double, true> : bspline_kernel<double, false>)<<<blocks_for(v1 - v0), kBlock, 0, st>>>(v0, v1, packed, node27, disp, V, out);
}

cudaError_t probe_kernels() {
  cudaFuncAttributes attr;
  return cudaFuncGetAttributes(&attr, probe_kernel);
}

}  // namespace cuda
}  // namespace larap
