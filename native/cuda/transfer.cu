// Kernels of the vertex transfer (see transfer.h). The two kernels share their shape (one vertex a
// thread: rest position plus displacement) but not their maths, which is written once in
// transfer.cuh; they stay two kernels so that each gets its own register budget (the B-spline
// gathers 27 nodes, the trilinear 8: docs/results-gpu.md measured the kernels separately).
#include "transfer.cuh"
#include "transfer.h"

namespace larap {
namespace cuda {
namespace {

template <typename T>
__global__ void __launch_bounds__(kBlock)
    trilinear_kernel(int64_t v0, int64_t v1, const float4* __restrict__ packed,
                     const int4* __restrict__ cell_nodes, const float4* __restrict__ disp,
                     const T* __restrict__ V, T* __restrict__ out) {
  const int64_t v = v0 + int64_t(blockIdx.x) * kBlock + threadIdx.x;
  if (v >= v1) return;
  const float4 d = trilinear_displacement(__ldg(packed + v), cell_nodes, disp);
  out[3 * v] = V[3 * v] + T(d.x);
  out[3 * v + 1] = V[3 * v + 1] + T(d.y);
  out[3 * v + 2] = V[3 * v + 2] + T(d.z);
}

template <typename T>
__global__ void __launch_bounds__(kBlock)
    bspline_kernel(int64_t v0, int64_t v1, const float4* __restrict__ packed, const int* __restrict__ node27,
                   const float4* __restrict__ disp, const T* __restrict__ V, T* __restrict__ out) {
  const int64_t v = v0 + int64_t(blockIdx.x) * kBlock + threadIdx.x;
  if (v >= v1) return;
  const float4 d = bspline_displacement(__ldg(packed + v), node27, disp);
  out[3 * v] = V[3 * v] + T(d.x);
  out[3 * v + 1] = V[3 * v + 1] + T(d.y);
  out[3 * v + 2] = V[3 * v + 2] + T(d.z);
}

template <typename T>
void trilinear(int64_t v0, int64_t v1, const float4* packed, const int* cell_nodes, const float4* disp,
               const T* V, T* out, cudaStream_t st) {
  if (v1 > v0)
    trilinear_kernel<T><<<blocks_for(v1 - v0), kBlock, 0, st>>>(
        v0, v1, packed, reinterpret_cast<const int4*>(cell_nodes), disp, V, out);
}

template <typename T>
void bspline(int64_t v0, int64_t v1, const float4* packed, const int* node27, const float4* disp, const T* V,
             T* out, cudaStream_t st) {
  if (v1 > v0)
    bspline_kernel<T><<<blocks_for(v1 - v0), kBlock, 0, st>>>(v0, v1, packed, node27, disp, V, out);
}

}  // namespace

void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed, const int* cell_nodes,
                               const float4* disp, const float* V, float* out, cudaStream_t st) {
  trilinear(v0, v1, packed, cell_nodes, disp, V, out, st);
}
void launch_transfer_trilinear(int64_t v0, int64_t v1, const float4* packed, const int* cell_nodes,
                               const float4* disp, const double* V, double* out, cudaStream_t st) {
  trilinear(v0, v1, packed, cell_nodes, disp, V, out, st);
}
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed, const int* node27,
                             const float4* disp, const float* V, float* out, cudaStream_t st) {
  bspline(v0, v1, packed, node27, disp, V, out, st);
}
void launch_transfer_bspline(int64_t v0, int64_t v1, const float4* packed, const int* node27,
                             const float4* disp, const double* V, double* out, cudaStream_t st) {
  bspline(v0, v1, packed, node27, disp, V, out, st);
}

}  // namespace cuda
}  // namespace larap
