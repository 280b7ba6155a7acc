// Launchers of the flip-flop's stages other than the linear solve (kernels: flip_flop.cu), and
// the small per-node kernels of the backend (displacement, probe). The per-pose handle work
// (H from group maps, moments, rigid motions) is handles.h. Internal to native/cuda.
#pragma once
#include <cuda_runtime.h>

#include "system.h"

namespace larap {
namespace cuda {

// Rotations (+ energy). `slot`: -1 = add the energy of the current pose with the current
// rotations into energy slot *iter - 1 when *iter > 0 (fused into the rotation step of the next
// flip-flop); -2 = no energy; >= 0 = into slot `slot`. Slot k is energy[2k] (ARAP + anchors)
// and energy[2k + 1] (handle term without K). write_rot = false: energy only.
void launch_rotations(const System& s, bool write_rot, int slot, cudaStream_t st);
// b into r[0] (residual = false) or r0 = b - A x (residual = true: formed without cancellation,
// flip_flop.cuh's residual_at); zeroes the solver scalars; (*iter)++.
void launch_rhs(const System& s, bool residual, cudaStream_t st);

// disp[i] = x_i - rest_i over all n_all nodes (shell included).
void launch_displacement(const System& s, float4* disp, cudaStream_t st);
// The stencil shell's rows of x from the real rows (Lattice::fill_shell): CSR off (#shell + 1),
// ids (real nodes) and weights.
void launch_fill_shell(const System& s, const int* off, const int* ids, const float* w, cudaStream_t st);

// Can this build's kernels run on the current device? (no image for its architecture, ...)
cudaError_t probe_kernels();

}  // namespace cuda
}  // namespace larap
