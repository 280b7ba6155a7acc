#include "rigid_fit.h"

#include <Eigen/LU>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

namespace larap {

Eigen::Matrix3d best_rotation(const Eigen::Matrix3d& S) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(S, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d U = svd.matrixU();
  const Eigen::Matrix3d V = svd.matrixV();
  if ((U * V.transpose()).determinant() < 0.0) U.col(2) = -U.col(2);
  return U * V.transpose();
}

Eigen::Matrix3d best_rotation_fast(const Eigen::Matrix3d& S) {
  // Polar decomposition S = R P with P = (S^T S)^(1/2): R = S V diag(1/sigma) V^T from the
  // closed-form eigen decomposition of S^T S, then one Newton step R <- (R + R^-T) / 2 to make it
  // orthonormal to rounding. Valid when S is well conditioned and det S > 0 (no reflection);
  // otherwise the SVD path decides.
  const double det = S.determinant();
  if (det > 0.0) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
    eig.computeDirect(S.transpose() * S);
    const Eigen::Vector3d lambda = eig.eigenvalues();  // ascending
    if (lambda[0] > 1e-10 * lambda[2]) {
      const Eigen::Matrix3d& V = eig.eigenvectors();
      const Eigen::Vector3d inv_sigma = lambda.cwiseSqrt().cwiseInverse();
      Eigen::Matrix3d R = S * V * inv_sigma.asDiagonal() * V.transpose();
      R = 0.5 * (R + R.inverse().transpose());
      if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-9) return R;
    }
  }
  return best_rotation(S);
}

}  // namespace larap
