// The vertex transfer on the device: out[3 v + c] = V[3 v + c] + sum_k w_k disp[id_k] for
// v in [v0, v1), with the weights of stencil.h (the host's, compiled for the device). packed[v] =
// (base cell / node id as int bits, 3 fractions): one 16-byte load per vertex. One vertex per
// thread, 3 scalar loads and stores (the staged and ILP variants measured no faster:
// docs/results-gpu.md; they are experiments, native/cuda/experiments/). Kernels: transfer.cu.
#pragma once
#include <cuda_runtime.h>

#include <cstdint>

namespace larap {
namespace cuda {

// Trilinear: the cell's 8 corner ids as cell_nodes[8 c .. 8 c + 8).
void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed, const int* cell_nodes,
                               const float4* disp, const float* V, float* out, cudaStream_t st);
void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed, const int* cell_nodes,
                               const float4* disp, const double* V, double* out, cudaStream_t st);
// B-spline: the 27 node ids around node b as node27[27 b .. 27 b + 27).
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed, const int* node27,
                             const float4* disp, const float* V, float* out, cudaStream_t st);
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed, const int* node27,
                             const float4* disp, const double* V, double* out, cudaStream_t st);

}  // namespace cuda
}  // namespace larap
