#include "warm_start.h"

#include <larap/solve_stats.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "backend.h"
#include "rigid_fit.h"

namespace larap {

double fit_rigid(const ComponentMoments& m, ComponentMotion& motion, double& before) {
  motion = ComponentMotion{};
  before = std::max(0.0, m.pp.trace() - 2.0 * m.pt.trace() + m.tt);
  if (!(m.w > 0.0)) return before;
  const Eigen::Vector3d pc = m.p / m.w, tc = m.t / m.w;
  const Eigen::Matrix3d cov_pp = m.pp - m.w * pc * pc.transpose();  // spread of the handles
  const Eigen::Matrix3d cross = m.pt.transpose() - m.w * tc * pc.transpose();  // sum (t - tc)(p - pc)^T
  const double spread_t = m.tt - m.w * tc.squaredNorm();
  Eigen::JacobiSVD<Eigen::Matrix3d> spread(cov_pp, Eigen::ComputeFullU);
  const Eigen::Vector3d s = spread.singularValues();
  // Spreads are differences of large sums: below these they are rounding noise, and a rotation
  // fitted to noise would turn a part held by one point (or aimed at one point) at random,
  // for free, so that no iteration turns it back.
  const double noise_p = 1e-12 * m.pp.trace(), noise_t = 1e-12 * m.tt;
  const bool spread_p = s[0] > noise_p, spread_to = spread_t > noise_t;
  if (spread_p && spread_to && s[1] > 1e-10 * s[0]) {
    motion.R = best_rotation(cross);
  } else if (spread_p && spread_to) {
    // Collinear handles: the spin about their line is not determined; turn the line onto the
    // targets' by the least rotation (no spin). (A point cloud's components often hold two
    // points: translated only, each took many iterations to turn.)
    const Eigen::Vector3d dp = spread.matrixU().col(0);
    const Eigen::Vector3d dt = cross * dp;  // sum (t - tc) ((p - pc) . dp): the targets' line, scaled
    if (dt.squaredNorm() > 1e-12 * s[0] * spread_t) {
      const Eigen::Vector3d u = dt.normalized();
      Eigen::Vector3d axis = dp.cross(u);
      axis -= axis.dot(dp) * dp;  // (rounding leaves a little of dp in it, which / sin magnifies)
      const double sin = axis.norm(), cos = dp.dot(u);
      // Antiparallel lines: half a turn about any normal of the line. (Eigen's
      // Quaterniond::FromTwoVectors trips GCC 13's -Wmaybe-uninitialized in its own branch.)
      motion.R = Eigen::AngleAxisd(std::atan2(sin, cos), sin > 1e-12 ? Eigen::Vector3d(axis / sin) : dp.unitOrthogonal())
                     .toRotationMatrix();
    }
  }  // a single point, or targets at one point: translate only
  motion.t = tc - motion.R * pc;
  motion.active = true;
  // sum |R (p - pc) - (t - tc)|^2 = spread_p + spread_t - 2 tr(R^T cross)
  return std::max(0.0, cov_pp.trace() + spread_t - 2.0 * (motion.R.transpose() * cross).trace());
}

std::vector<uint8_t> held_components(const std::vector<std::array<int32_t, 2>>& pairs,
                                     const std::vector<uint8_t>& held_groups, int32_t num_components) {
  std::vector<uint8_t> out(size_t(std::max(num_components, 0)), 0);
  if (held_groups.empty()) return out;
  for (const auto& [g, c] : pairs)
    if (held_groups[size_t(g)]) out[size_t(c)] = 1;
  return out;
}

void warm_start(Backend& backend, double still, SolveStats& stats, const std::vector<uint8_t>& held) {
  std::vector<ComponentMoments> now, rest;
  backend.moments(now, rest);
  const size_t nc = now.size();
  std::vector<ComponentMotion> carry(nc), from_rest(nc);
  bool any_carry = false, any_rest = false;
  for (size_t c = 0; c < nc; ++c) {
    if (!(now[c].w > 0.0)) continue;
    double before = 0.0, unused = 0.0;
    const double carried = fit_rigid(now[c], carry[c], before);
    if (before <= now[c].w * still * still) {  // its handles did not move: leave it exactly where it is
      carry[c].active = false;
      continue;
    }
    // A held group (warm_start.h): a rigid start only when it is exact, the targets a rigid motion
    // of the handles (the held rows then lie on its axis and stay where they are).
    const bool held_here = c < held.size() && held[c];
    const double exact = now[c].w * still * still;
    carry[c].active = held_here ? carried <= exact : carried < 0.5 * before;
    any_carry |= carry[c].active;
    const double rested = fit_rigid(rest[c], from_rest[c], unused);
    from_rest[c].active = rested < std::min(before, carried) && (!held_here || rested <= exact);
    any_rest |= from_rest[c].active;
  }
  if (any_carry) {
    backend.apply_rigid(carry, /*from_rest=*/false);
    stats.rigid_carry = true;
  }
  if (any_rest) {
    const double e_prev = backend.energy();
    RowMatrixX3d prev;
    backend.get_pose(prev);
    backend.apply_rigid(from_rest, /*from_rest=*/true);
    if (!(backend.energy() < e_prev)) backend.set_pose(prev);
  }
}

}  // namespace larap
