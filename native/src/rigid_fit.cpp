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

double rigid_fit(const RowMatrixX3d& from, const RowMatrixX3d& to, Eigen::Matrix3d& R,
                 Eigen::Vector3d& t) {
  const int64_t m = from.rows();
  R.setIdentity();
  t.setZero();
  if (m == 0) return 0.0;
  const Eigen::RowVector3d cf = from.colwise().mean(), ct = to.colwise().mean();
  const RowMatrixX3d P = from.rowwise() - cf, Q = to.rowwise() - ct;
  const Eigen::Matrix3d S = Q.transpose() * P, C = P.transpose() * P;
  Eigen::JacobiSVD<Eigen::Matrix3d> spread(C);
  const Eigen::Vector3d s = spread.singularValues();
  if (m >= 3 && s[1] > 1e-10 * s[0] && s[0] > 0.0) R = best_rotation(S);
  t = ct.transpose() - R * cf.transpose();
  // R p + t - q = R (p - cf) - (q - ct)
  return (P * R.transpose() - Q).squaredNorm();
}

}  // namespace larap
