// The lattice system on the device: raw device pointers and sizes, passed by value to every
// kernel (flip_flop.h, solvers.h). Internal to native/cuda; no public header includes CUDA.
// Filled by the backend (cuda_backend.cpp) from its DeviceBuffers.
//
// Frame: every position on the device is relative to `origin` (the lattice centre), so that the
// float arithmetic of A x and the right-hand side does not lose digits to a large offset.
// Vectors of 3 columns (x, y, z) are float4 (w unused) so that one node is one 16-byte load.
#pragma once
#include <cuda_runtime.h>

#include <cstdint>

namespace larap {
namespace cuda {

struct System {
  int n = 0;                     // lattice nodes
  const float4* rest = nullptr;  // n, rest positions (centred)
  const int* adj_off = nullptr;  // n+1, lattice edge neighbourhood (CSR)
  const int* adj = nullptr;
  // Fixed-width lattice neighbours: nbr[d * n + i], d = -x,+x,-y,+y,-z,+z; a missing neighbour
  // is i itself (contributes 0 to edge sums, and a_nb = 0 there).
  const int* nbr = nullptr;
  // A split for unrolled products: diagonal, the 6 lattice-neighbour entries (slot-major, like
  // nbr), and the remaining entries (handle couplings between non-neighbours) as a short CSR.
  const float* a_diag = nullptr;
  const float* a_nb = nullptr;
  const int* rem_off = nullptr;
  const int* rem_col = nullptr;
  const float* rem_val = nullptr;
  // A = 2 g L + B^T B + a I_anchored, CSR, float; Jacobi preconditioner.
  const int* a_off = nullptr;
  const int* a_col = nullptr;
  const float* a_val = nullptr;
  const float* minv = nullptr;  // 1 / diag(A)
  // B^T as CSR over nodes: entries (handle, weight).
  const int* bt_off = nullptr;
  const int* bt_handle = nullptr;
  const float* bt_w = nullptr;
  // B by handle: m * stencil ids and weights.
  int m = 0;
  int stencil = 8;
  const int* b_ids = nullptr;
  const float* b_w = nullptr;
  const uint8_t* anchored = nullptr;  // n
  float g = 0.f;                      // gamma_eff
  float a = 0.f;                      // anchor weight
  // State.
  float4* x = nullptr;                // pose (centred)
  float4* p = nullptr;                // CG direction
  float4* r[2] = {nullptr, nullptr};  // ping-pong: residual
  float4* w[2] = {nullptr, nullptr};  // A u
  float4* s[2] = {nullptr, nullptr};  // A p
  float4* x_tmp = nullptr;            // Chebyshev / Jacobi: ping-pong partner of x
  float* rot = nullptr;               // 9 * n, SoA: rot[k * n + i]
  const float4* targets = nullptr;    // m (centred)
  // Scalars.
  double* dots = nullptr;        // (inner + 1) * 6
  float* coef = nullptr;         // (inner + 2) * 8
  unsigned* counters = nullptr;  // inner + 1
  int* iter = nullptr;           // flip-flop counter of the running solve
  double* energy = nullptr;      // per flip-flop (unscaled)
  int inner = 8;                 // inner solver iterations per flip-flop
  // Two-level preconditioner (solver "mg"): aggregates of fine nodes (coord >> shift), dense
  // inverse of the Galerkin coarse operator P^T A P, damped Jacobi smoothing (weight omega).
  int nc = 0;                          // coarse nodes
  const int* agg = nullptr;            // n, coarse id of each fine node
  const float* ainv = nullptr;         // nc * nc, row-major
  float4* rc = nullptr;                // inner * nc: restricted residual per iteration
  float4* zc = nullptr;                // nc
  float4* z = nullptr;                 // n, preconditioned residual
  float4* q = nullptr;                 // n, A p
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
};

}  // namespace cuda
}  // namespace larap
