// The interface every solver backend (CPU, CUDA) implements. Internal: public headers never
// include this file, and the CUDA backend hides every CUDA type behind it.
//
// The problem (see docs/method.md and handle_system.h): lattice nodes c' (#N by 3), handle rows
// j = 1..m with weights B (m by #N, 8 or 27 entries a row), row weights alpha and targets t.
//   E(c', R) = gamma_eff * sum_c w_c sum_{edges (a,b) of c} |(c'_a - c'_b) - R_c (c_a - c_b)|^2
//            + sum_j alpha_j |B_j c' - t_j|^2 + a * sum_{i anchored} |c'_i - c_i|^2
//            + mu * sum_{(i, k) glued} |c'_i - c'_k|^2 + beta * sum_{(a, b, c) braced} |c'_a - 2 c'_b + c'_c|^2
// over the cell copies c (cell_terms.h), minimised by flip-flop: R_c the rotation fit of
// S_c = sum_{edges of c} (c'_a - c'_b)(c_a - c_b)^T, then
//   (2 gamma_eff L + M + T + a I_anchored) c' = gamma_eff b + B^T alpha t + a c_anchored,
//   b_i = sum_{copies c with corner i} w_c R_c s_ci (node_cells.h),   M = B^T diag(alpha) B,
// L the graph Laplacian of the lattice edges with the weights w_ij = half their copies' w_c sum,
// T = mu G^T G + beta S^T S the ties (tie_matrix). A lattice component that holds no handle is
// carried by a handled one it lies along, glued to it (G, carried_parts.h), or else anchored: held
// at rest. The braces (S, junction_braces.h) hold straight the columns where the solid branches. A pose's targets reach the backend as H~ = B^T alpha t~
// and K~ (handle_system.h), so nothing per pose costs in proportion to the handle rows.
#pragma once
#include <larap/binding.h>
#include <larap/solve_stats.h>

#include <Eigen/Core>
#include <memory>
#include <string>

#include "handle_system.h"
#include "warm_start.h"

namespace larap {

class Backend {
 public:
  virtual ~Backend() = default;
  virtual std::string name() const = 0;  // "cpu" or "cuda"

  // A new handle set (or new weights): prepare the linear solve. Keeps the current pose.
  virtual void set_handles(const HandleSystem& handles) = 0;
  // A pose's targets (rows or group maps): H~ and K~ for the iterations and the energy.
  virtual void set_targets(const HandleTargets& targets) = 0;
  // The current lattice pose (#N by 3).
  virtual void set_pose(const RowMatrixX3d& nodes) = 0;
  virtual void get_pose(RowMatrixX3d& nodes) const = 0;
  // Per lattice component, the moments of the handle rows against the targets (warm_start.h),
  // for the current pose and for the rest lattice: both in one call, so that a device backend
  // computes and copies them back with one synchronisation a pose. `now` and `rest` are two
  // different vectors.
  virtual void moments(std::vector<ComponentMoments>& now, std::vector<ComponentMoments>& rest) = 0;
  // Per lattice component: x -> R x + t on its nodes (from_rest: on its rest positions) where
  // the motion is active; other components keep their pose.
  virtual void apply_rigid(const std::vector<ComponentMotion>& motions, bool from_rest) = 0;
  // `iterations` flip-flop steps towards the targets; appends the energy after each step to
  // stats.energy and adds stage times to stats.
  virtual void iterate(int iterations, SolveStats& stats) = 0;
  // Energy (scaled) of the current pose with its best rotations, without changing the pose.
  virtual double energy() = 0;
  // out (#V by 3, row-major) = rest vertices + W (pose - rest lattice); W from `binding`.
  virtual void transfer(const Binding& binding, double* out, SolveStats& stats) = 0;
  virtual void transfer(const Binding& binding, float* out, SolveStats& stats) = 0;
  // The same transfer into a #V by 3 float32 row-major buffer that stays on the device, owned by
  // the backend and valid until its next transfer or destruction. nullptr: no device (the CPU).
  virtual const float* transfer_on_device(const Binding& /*binding*/, SolveStats& /*stats*/) {
    return nullptr;
  }
};

std::unique_ptr<Backend> make_cpu_backend(const Lattice& lattice, const RowMatrixX3d& vertices);

// Defined in the CUDA part when built with it; otherwise throws DeviceError.
std::unique_ptr<Backend> make_cuda_backend(const Lattice& lattice, const RowMatrixX3d& vertices);
// Is a usable CUDA device present? When not, *why says why.
bool cuda_available(std::string* why);

}  // namespace larap
