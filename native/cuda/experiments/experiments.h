// Variants of the CUDA backend that were measured and rejected (docs/results-gpu.md), kept for
// comparison and compiled only with the CMake option LARAP_CUDA_EXPERIMENTS=ON. Chosen through
// CudaOptions (LARAP_CUDA_SOLVER=pcg|cheby|jacobi, LARAP_CUDA_TRANSFER=staged|ilp*); the
// product's paths (solvers.h, transfer.h) never call them.
//   pcg:    Jacobi-preconditioned CG in the Chronopoulos-Gear form, one fused kernel per
//           iteration (both dots from one reduction; the last block turns them into alpha/beta)
//   cheby:  Chebyshev-accelerated Jacobi, eigenvalues of D^-1 A assumed in [lam_min, lam_max]
//   jacobi: weighted Jacobi (weight 1 / theta)
//   staged: the transfer with V and out through shared memory, 16-byte accesses
//   ilp<k>[s]: k vertices per thread (trilinear; B-spline uses the scalar kernel), the loads of a
//           phase issued together; s: streaming cache hints on read-once data
#pragma once
#ifdef LARAP_CUDA_EXPERIMENTS
#include <cuda_runtime.h>

#include <cstdint>

#include "cuda_options.h"
#include "system.h"

namespace larap {
namespace cuda {

// `inner` iterations of an experimental solver with b in r[0] (after launch_rhs with residual =
// true for pcg, false for the others); leaves the new pose in x. Checks every launch.
void launch_experimental_solver(const System& s, Solver solver, int inner, double lam_min, double lam_max,
                                cudaStream_t st);

// The transfer with an experimental kernel (see transfer.h for the arguments). Checks the launch.
void launch_experimental_transfer(const TransferKernel& kernel, bool trilinear, int64_t v0, int64_t v1,
                                  const float4* packed, const int* table, const float4* disp, const float* V,
                                  float* out, cudaStream_t st);
void launch_experimental_transfer(const TransferKernel& kernel, bool trilinear, int64_t v0, int64_t v1,
                                  const float4* packed, const int* table, const float4* disp, const double* V,
                                  double* out, cudaStream_t st);

}  // namespace cuda
}  // namespace larap
#endif  // LARAP_CUDA_EXPERIMENTS
