// Device side of the CUDA backend: raw device pointers and the kernel launchers. Internal (only
// native/src/cuda_backend.cpp and native/cuda/*.cu include it); no public header includes CUDA.
//
// Frame: every position on the device is relative to `origin` (the lattice centre), so that the
// float arithmetic of A x and the right-hand side does not lose digits to a large offset.
// Vectors of 3 columns (x, y, z) are float4 (w unused) so that one node is one 16-byte load.
#pragma once
#include <cuda_runtime.h>

#include <cstdint>
#include <string>

namespace larap {
namespace cuda {

struct System {
  int n = 0;                      // lattice nodes
  const float4* rest = nullptr;   // n, rest positions (centred)
  const int* adj_off = nullptr;   // n+1, lattice edge neighbourhood (CSR)
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
  const float* minv = nullptr;    // 1 / diag(A)
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
  float g = 0.f;                  // gamma_eff
  float a = 0.f;                  // anchor weight
  // State.
  float4* x = nullptr;            // pose (centred)
  float4* p = nullptr;            // CG direction
  float4* r[2] = {nullptr, nullptr};  // ping-pong: residual
  float4* w[2] = {nullptr, nullptr};  // A u
  float4* s[2] = {nullptr, nullptr};  // A p
  float4* x_tmp = nullptr;        // Chebyshev / Jacobi: ping-pong partner of x
  float* rot = nullptr;           // 9 * n, SoA: rot[k * n + i]
  const float4* targets = nullptr;  // m (centred)
  // Scalars.
  double* dots = nullptr;         // (inner + 1) * 6
  float* coef = nullptr;          // (inner + 2) * 8
  unsigned* counters = nullptr;   // inner + 1
  int* iter = nullptr;            // flip-flop counter of the running solve
  double* energy = nullptr;       // per flip-flop (unscaled)
  int inner = 8;                  // inner solver iterations per flip-flop
  // Two-level preconditioner (solver "mg"): aggregates of fine nodes (coord >> shift), dense
  // inverse of the Galerkin coarse operator P^T A P, damped Jacobi smoothing (weight omega).
  int nc = 0;                     // coarse nodes
  const int* agg = nullptr;       // n, coarse id of each fine node
  const float* ainv = nullptr;    // nc * nc, row-major
  float4* rc = nullptr;           // inner * nc: restricted residual per iteration
  float4* zc = nullptr;           // nc
  float4* z = nullptr;            // n, preconditioned residual
  float4* q = nullptr;            // n, A p
  float4* pb[2] = {nullptr, nullptr};  // ping-pong: direction
  float omega = 0.6f;
  // Third level (nc2 > 0): the coarse system above is then not inverted but preconditioned by
  // one symmetric two-level cycle of its own (damped Jacobi pre/post-smoothing with omega1 on
  // the sparse Galerkin operator Ac1 = P^T A P, CSR with its diagonal, and a dense inverse of
  // Ac2 = P2^T Ac1 P2 in `ainv`, nc2 x nc2; agg2: level-2 id of each coarse node).
  int nc2 = 0;
  const int* agg2 = nullptr;      // nc
  const int* c_off = nullptr;     // nc + 1, Ac1 (CSR, diagonal included)
  const int* c_col = nullptr;
  const float* c_val = nullptr;
  const float* c_minv = nullptr;  // nc, 1 / diag(Ac1)
  float omega1 = 0.6f;
  float4* rc2 = nullptr;          // inner * nc2
  float4* zc2 = nullptr;          // nc2
};

// Flip-flop stages. `slot`: -1 = add the energy of the current pose with the current rotations
// into energy[*iter - 1] when *iter > 0 (fused into the rotation step of the next flip-flop);
// -2 = no energy; >= 0 = into energy[slot]. write_rot = false: energy only.
void launch_rotations(const System& s, bool write_rot, int slot, cudaStream_t st);
// b into r[0] (residual = false) or r0 = b - A x (residual = true); zeroes the solver scalars;
// (*iter)++.
void launch_rhs(const System& s, bool residual, cudaStream_t st);
// Preconditioned CG, Chronopoulos-Gear form, one fused kernel per iteration (k = 0..inner).
void launch_cg(const System& s, int k, cudaStream_t st);
// Chebyshev-accelerated (or weighted) Jacobi step k with b in r[0]: reads x from buffer k & 1
// (x, x_tmp), writes the other; d (in p) = c1 d + c2 D^-1 (b - A x); x += d.
// Two-level-preconditioned CG (4 kernels per iteration k = 0..inner-1, then a final update).
void launch_mg_iteration(const System& s, int k, cudaStream_t st);
void launch_mg_final(const System& s, cudaStream_t st);
// The same, fused: `iterations` whole flip-flops (rotations with the energy of the previous
// flip-flop into energy[it - 1], rhs, the two-level PCG) in one cooperative launch of `blocks`
// blocks (grid-stride loops, grid-wide barriers between the phases). mg_fused_max_blocks(): the
// most blocks that can be co-resident (0: no cooperative launch on this device).
int mg_fused_max_blocks();
cudaError_t launch_mg_fused(const System& s, int iterations, int blocks, cudaStream_t st);
void launch_cheby(const System& s, int k, float c1, float c2, cudaStream_t st);

void launch_rigid(const System& s, const float* R9, float tx, float ty, float tz, cudaStream_t st);
void launch_handle_positions(const System& s, float4* out, cudaStream_t st);
void launch_displacement(const System& s, float4* disp, cudaStream_t st);

// Transfer: out[3 v + c] = V[3 v + c] + sum_k w_k disp[id_k], v in [v0, v1). packed[v] =
// (base cell / node id as int bits, 3 fractions): one 16-byte load per vertex. Variants
// (LARAP_CUDA_TRANSFER): mode kTransferScalar: one vertex per thread, 3 scalar loads/stores;
// kTransferStaged: V and out through shared memory with 16-byte accesses; kTransferIlp: vpt
// vertices per thread (trilinear only; B-spline uses the scalar kernel), all their loads issued
// before the first use (packed + V, then the cell corners, then the 8 displacements), and with
// stream = true read-once data (packed, V) read and out written with streaming cache hints.
enum TransferMode { kTransferScalar = 0, kTransferStaged = 1, kTransferIlp = 2 };
struct TransferVariant {
  int mode = kTransferIlp;
  int vpt = 2;
  bool stream = false;
};
void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed,
                               const int* cell_nodes, const float4* disp, const float* V,
                               float* out, const TransferVariant& tv, cudaStream_t st);
void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed,
                               const int* cell_nodes, const float4* disp, const double* V,
                               double* out, const TransferVariant& tv, cudaStream_t st);
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed,
                             const int* node27, const float4* disp, const float* V, float* out,
                             const TransferVariant& tv, cudaStream_t st);
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed,
                             const int* node27, const float4* disp, const double* V, double* out,
                             const TransferVariant& tv, cudaStream_t st);

// Can this build's kernels run on the current device? (no image for its architecture, ...)
cudaError_t probe_kernels();

}  // namespace cuda
}  // namespace larap
