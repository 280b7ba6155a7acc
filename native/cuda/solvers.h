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
// `blocks` blocks (each phase a loop over its share of the items, grid-wide barriers between
// the phases; each flip-flop's final update but the launch's last is left to the next one), and
// after them the last pose's energy into energy[iterations - 1].
cudaError_t launch_mg_fused(const System& s, int iterations, int blocks, cudaStream_t st);
// Phases of one fused flip-flop (rotations, rhs, per inner iteration 4 or, with three levels, 6,
// the final update, which is empty where it is left to the next flip-flop): with System::stamps
// set, a launch writes 1 + iterations * fused_phases(s) clock64() values (measurement only,
// LARAP_CUDA_PHASES).
inline int fused_phases(const System& s) { return 3 + s.inner * (s.nc2 > 0 ? 6 : 4); }
// The most blocks of the fused kernel that can be co-resident (0: no cooperative launch on this
// device).
int mg_fused_max_blocks();

}  // namespace cuda
}  // namespace larap
