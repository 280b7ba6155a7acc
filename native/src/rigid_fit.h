// Rotation fits (host, double): the CPU backend's per-cell rotation and the rotation of the
// per-component rigid fit that starts a pose (warm_start.cpp, from moments). The device's float
// rotation fit is native/cuda/rotation.cuh.
#pragma once
#include <Eigen/Core>

namespace larap {

// The rotation R maximising tr(R^T S), i.e. minimising sum |q_j - R p_j|^2 for
// S = sum q_j p_j^T. 3x3 SVD S = U diag(s) V^T, R = U V^T; a reflection is turned into the
// nearest rotation by flipping the singular vector of the smallest singular value.
Eigen::Matrix3d best_rotation(const Eigen::Matrix3d& S);

// The same rotation, faster: closed-form polar decomposition for well-conditioned S without
// reflection (the common case), the SVD above otherwise.
Eigen::Matrix3d best_rotation_fast(const Eigen::Matrix3d& S);

}  // namespace larap
