// The per-pose handle work on the device (kernels: handles.cu), so that a pose costs O(groups)
// on the host and in uploads whatever the number of handle vertices (handle_system.h has the
// maths, native/src/warm_start.h the warm start that uses the moments and motions):
//   * H of a pose given by one affine map per group, from the per-node group entries
//     (q_g[i], P_g[i]) uploaded once per handle set;
//   * the moments of the handle rows per lattice component, for the pose and the rest lattice
//     in one launch: one block per chunk of the handle nodes (chunks never straddle
//     components) and pose, then the chunks of each component summed in a fixed order
//     (deterministic);
//   * one rigid motion per lattice component applied to the pose or the rest lattice.
// Internal to native/cuda.
#pragma once
#include <cuda_runtime.h>

#include "system.h"

namespace larap {
namespace cuda {

// Per-node group entries of handle_system.h (CSR by node).
struct GroupEntries {
  const int* node_off = nullptr;  // n + 1
  const int* group = nullptr;     // group of each entry
  const double* q = nullptr;      // q_g[i]
  const double* P = nullptr;      // 3 per entry: P_g[i]
};

// s.h and s.hd (written through the non-const pointers h, hd) for the group maps
// maps[12 g .. 12 g + 12) = A_g (row-major 3x3), b~_g = A_g origin + b_g - origin.
void launch_group_rhs(const System& s, const GroupEntries& e, const double* maps, float4* h, double* hd,
                      cudaStream_t st);

// Values per component of the moments (warm_start.h's ComponentMoments without tt), in order:
// w, p (3), t (3), pt (9, row-major), pp (9, row-major).
constexpr int kMomentValues = 25;

// Nodes per chunk of the moments: one block (kBlock of device_vec.cuh).
constexpr int kMomentBlock = 256;

// The handle nodes (q_i > 0) ordered by component and cut into chunks of at most kMomentBlock.
struct MomentChunks {
  int chunks = 0;
  const int* chunk_off = nullptr;  // chunks + 1, into `nodes`
  const int* nodes = nullptr;
  int components = 0;
  const int* comp_chunk_off = nullptr;  // components + 1, into the chunks
  // M = B^T diag(alpha) B alone, CSR in double: s.m_* when there are no ties, else without the
  // glue and braces that s.m_* also holds (handle_system.h).
  const int* m_off = nullptr;
  const int* m_col = nullptr;
  const double* m_val = nullptr;
};

// out[kMomentValues c + k] for every component c, of the pose s.x against the current H (s.hd)
// with M (mc.m_*), and out[kMomentValues (components + c) + k] of the rest lattice s.rest, from
// one launch of each of the two kernels; partial: 2 kMomentValues chunks scratch.
void launch_moments(const System& s, const MomentChunks& mc, double* partial, double* out, cudaStream_t st);

// Per component c: motions[16 c .. 16 c + 16) = R (row-major 3x3), t (3), active (1 or 0), 3
// unused. x_i = R p_i + t for every node that is not anchored and whose component's motion is
// active, p = rest (from_rest) or the pose.
void launch_component_rigid(const System& s, const int* component, const float* motions, bool from_rest,
                            cudaStream_t st);

}  // namespace cuda
}  // namespace larap
