// Where a solve starts: per lattice component, the previous pose carried by the best rigid
// motion of that component's handles when it explains most of their move, and the rigidly moved
// rest pose when the targets are close to a rigid motion of the handles' rest positions and it
// lowers the energy. A component whose handles did not move is left exactly where it was; parts
// never jump because handles elsewhere moved. A component that holds a handle group the user kept
// where it was since the last solve (held_groups) gets a rigid start only when it is exact (the
// targets a rigid motion of the handles, the held rows on its axis): otherwise it would carry the
// held group, and every part of the component that no handle holds, away for the iterations to
// pull back; on thin joints they never did (docs/method.md, *Warm start*).
//
// Everything is computed from per-component moments of the handle rows (Backend::moments), so
// the cost is O(lattice nodes + components), whatever the number of handle vertices.
#pragma once
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

namespace larap {

class Backend;
struct SolveStats;

// Weighted sums over the handle rows j of one lattice component, for a lattice pose c', with
// p_j = B_j c' - origin and t_j = target_j - origin:
struct ComponentMoments {
  double w = 0;                                  // sum alpha_j
  Eigen::Vector3d p = Eigen::Vector3d::Zero();   // sum alpha_j p_j
  Eigen::Vector3d t = Eigen::Vector3d::Zero();   // sum alpha_j t_j
  Eigen::Matrix3d pt = Eigen::Matrix3d::Zero();  // sum alpha_j p_j t_j^T
  Eigen::Matrix3d pp = Eigen::Matrix3d::Zero();  // sum alpha_j p_j p_j^T
  double tt = 0;                                 // sum alpha_j |t_j|^2
};

// x -> R x + t on one component's nodes (active), or nothing.
struct ComponentMotion {
  bool active = false;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
};

// Best rigid motion taking the handles' current positions (moments m) to their targets; returns
// the weighted residual after the motion, and in `before` the residual without it.
double fit_rigid(const ComponentMoments& m, ComponentMotion& motion, double& before);

// Per lattice component, 1 when it holds a group of `held_groups` (1 = kept where it was):
// `pairs` lists each (group, component) a group's handle rows read (HandleSystem::moments).
// Empty held_groups: none held.
std::vector<uint8_t> held_components(const std::vector<std::array<int32_t, 2>>& pairs,
                                     const std::vector<uint8_t>& held_groups, int32_t num_components);

// Chooses the start of `backend`'s next iterations for the targets it holds (set_targets).
// A component whose handles miss their targets by less than `still` (root mean square, a
// length) counts as not moved. `held` (per component, or empty): no rigid start there. Sets
// stats.rigid_carry when some component was carried.
void warm_start(Backend& backend, double still, SolveStats& stats, const std::vector<uint8_t>& held = {});

}  // namespace larap
