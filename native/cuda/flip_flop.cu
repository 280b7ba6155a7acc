// Kernels of the flip-flop's rotation and right-hand-side stages, and the small per-node
// kernels (see flip_flop.h; the maths in flip_flop.cuh and cell_terms.h).
#include "flip_flop.cuh"
#include "flip_flop.h"

namespace larap {
namespace cuda {
namespace {

__global__ void __launch_bounds__(kBlock) rotations_kernel(System s, bool write_rot, int slot) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;  // < ncell + n, or a spare thread
  int e_slot = slot;
  if (slot == -1) e_slot = *s.iter - 1;  // < 0 on the first flip-flop of a solve: no energy
  double v[2] = {0.0, 0.0};
  rotation_item(s, k, write_rot, e_slot >= 0, v);
  if (e_slot >= 0) block_add<2>(v, s.energy + 2 * e_slot);
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
    for (int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; k < tot;
         k += int64_t(gridDim.x) * blockDim.x)
      s.rc[k] = f4(0, 0, 0);
    const int64_t tot2 = int64_t(s.inner) * s.nc2;
    for (int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; k < tot2;
         k += int64_t(gridDim.x) * blockDim.x)
      s.rc2[k] = f4(0, 0, 0);
  }
  if (i >= s.n) return;
  s.r[0][i] = residual ? residual_at(s, i) : rhs_at(s, i);
}

// ---------------------------------------------------------------- small helpers
__global__ void displacement_kernel(System s, float4* disp) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i < s.n_all) disp[i] = s.x[i] - s.rest[i];
}

// Shell node n + k = sum_e w_e x_{ids_e} over real nodes (Lattice::fill_shell); the weights sum
// to one, so the centred frame changes nothing.
__global__ void fill_shell_kernel(System s, const int* __restrict__ off, const int* __restrict__ ids,
                                  const float* __restrict__ w) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= s.n_all - s.n) return;
  float4 acc = f4(0, 0, 0);
  for (int e = __ldg(off + k); e < __ldg(off + k + 1); ++e) acc = acc + __ldg(w + e) * s.x[__ldg(ids + e)];
  s.x[s.n + k] = acc;
}

__global__ void probe_kernel() {}

}  // namespace

void launch_rotations(const System& s, bool write_rot, int slot, cudaStream_t st) {
  const int items = s.ncell + s.n;  // rotation_items with the energy (known on the device only)
  if (items == 0) return;
  rotations_kernel<<<blocks_for(items), kBlock, 0, st>>>(s, write_rot, slot);
}

void launch_rhs(const System& s, bool residual, cudaStream_t st) {
  rhs_kernel<<<blocks_for(s.n > 0 ? s.n : 1), kBlock, 0, st>>>(s, residual);
}

void launch_displacement(const System& s, float4* disp, cudaStream_t st) {
  if (s.n_all) displacement_kernel<<<blocks_for(s.n_all), kBlock, 0, st>>>(s, disp);
}

void launch_fill_shell(const System& s, const int* off, const int* ids, const float* w, cudaStream_t st) {
  if (s.n_all > s.n) fill_shell_kernel<<<blocks_for(s.n_all - s.n), kBlock, 0, st>>>(s, off, ids, w);
}

cudaError_t probe_kernels() {
  cudaFuncAttributes attr;
  return cudaFuncGetAttributes(&attr, probe_kernel);
}

}  // namespace cuda
}  // namespace larap
