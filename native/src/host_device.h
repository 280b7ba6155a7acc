// LARAP_HD marks maths written once and compiled for both the host (plain C++) and the device
// (nvcc): the stencils (stencil.h), the per-cell flip-flop terms (cell_terms.h) and the float
// rotation fit (native/cuda/rotation.cuh). Under nvcc it is __host__ __device__ and forced
// inline; in a host compiler it is plain `inline`. LARAP_UNROLL asks nvcc to unroll the loop
// that follows, LARAP_NO_UNROLL not to (a host compiler sees neither).
#pragma once

#ifdef __CUDACC__
#define LARAP_HD __host__ __device__ __forceinline__
#define LARAP_UNROLL _Pragma("unroll")
#define LARAP_NO_UNROLL _Pragma("unroll 1")
#else
#define LARAP_HD inline
#define LARAP_UNROLL
#define LARAP_NO_UNROLL
#endif
