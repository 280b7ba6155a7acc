// The inner linear solver of each flip-flop on the device: CG preconditioned by a two- or
// three-level aggregation cycle ("mg", docs/cuda.md), as separate kernels (4 per inner
// iteration; 6 with three levels) or fused with the whole flip-flop into one cooperative
// kernel. Kernels: solvers.cu; host set-up: multigrid.h. Internal to native/cuda.
#pragma once
#include <cuda_runtime.h>

#include "system.h"

namespace larap {
namespace cuda {

// Two-level-preconditioned CG: inner iteration k = 0..inner-1 (after launch_rhs with
// residual = true), then the final update.
void launch_mg_iteration(const System& s, int k, cudaStream_t st);
void launch_mg_final(const System& s, cudaStream_t st);

// The same, fused: `iterations` whole flip-flops (rotations with the energy of the previous
// flip-flop into energy[it - 1], rhs, the preconditioned CG) in one cooperative launch of
// `blocks` blocks (grid-stride loops, grid-wide barriers between the phases).
cudaError_t launch_mg_fused(const System& s, int iterations, int blocks, cudaStream_t st);
// The most blocks of the fused kernel that can be co-resident (0: no cooperative launch on this
// device).
int mg_fused_max_blocks();

}  // namespace cuda
}  // namespace larap
