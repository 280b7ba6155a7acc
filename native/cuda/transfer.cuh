// Per-vertex device functions of the transfer: the weighted sum of the node displacements of one
// vertex, with the weights of stencil.h. Shared by transfer.cu and the experimental kernels.
#pragma once
#include "device_vec.cuh"
#include "stencil.h"

namespace larap {
namespace cuda {

// sum_k w_k disp[corner_k] over the 8 corners of cell int_bits(pk.x) at fractions (pk.y, pk.z, pk.w).
__device__ __forceinline__ float4 trilinear_displacement(float4 pk, const int4* __restrict__ cell_nodes,
                                                         const float4* __restrict__ disp) {
  const int c = __float_as_int(pk.x);
  const int4 n0 = __ldg(cell_nodes + 2 * c), n1 = __ldg(cell_nodes + 2 * c + 1);
  const int ids[8] = {n0.x, n0.y, n0.z, n0.w, n1.x, n1.y, n1.z, n1.w};
  float w[8];
  trilinear_weights(pk.y, pk.z, pk.w, w);
  float ax = 0.f, ay = 0.f, az = 0.f;
#pragma unroll
  for (int k = 0; k < 8; ++k) {
    const float4 d = __ldg(disp + ids[k]);
    ax += w[k] * d.x;
    ay += w[k] * d.y;
    az += w[k] * d.z;
  }
  return f4(ax, ay, az);
}

// sum_k w_k disp[node_k] over the 27 nodes around node int_bits(pk.x) at offsets (pk.y, pk.z, pk.w).
__device__ __forceinline__ float4 bspline_displacement(float4 pk, const int* __restrict__ node27,
                                                       const float4* __restrict__ disp) {
  const int* ids = node27 + 27 * int64_t(__float_as_int(pk.x));
  float w[27];
  bspline_weights(pk.y, pk.z, pk.w, w);
  float ax = 0.f, ay = 0.f, az = 0.f;
#pragma unroll
  for (int k = 0; k < 27; ++k) {
    const float4 d = __ldg(disp + __ldg(ids + k));
    ax += w[k] * d.x;
    ay += w[k] * d.y;
    az += w[k] * d.z;
  }
  return f4(ax, ay, az);
}

}  // namespace cuda
}  // namespace larap
