// The rotation fits: the host's double fits (native/src/rigid_fit.h) and the device's float fit
// (native/cuda/rotation.cuh, Horn's quaternion method, compiled here for the host).
// Run: ctest --test-dir build -R RotationFit   (or build/larap_tests --gtest_filter='RotationFit*')
#include <gtest/gtest.h>
#include <larap/mesh.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <random>
#include <vector>

#include "rigid_fit.h"
#include "rotation.cuh"
#include "warm_start.h"

namespace {

using Mat3 = Eigen::Matrix3d;

Mat3 random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Quaterniond q(n(rng), n(rng), n(rng), n(rng));
  q.normalize();
  return q.toRotationMatrix();
}

// The float fit through its row-major interface.
Mat3 horn(const Mat3& S) {
  float s[9], r[9];
  for (int k = 0; k < 9; ++k) s[k] = float(S(k / 3, k % 3));
  larap::cuda_math::best_rotation_f(s, r);
  Mat3 R;
  for (int k = 0; k < 9; ++k) R(k / 3, k % 3) = r[k];
  return R;
}

// max tr(R^T S) over proper rotations: sum of singular values with the smallest one's sign
// flipped when det S < 0.
double best_objective(const Mat3& S) {
  Eigen::JacobiSVD<Mat3> svd(S);
  Eigen::Vector3d s = svd.singularValues();
  if (S.determinant() < 0) s[2] = -s[2];
  return s.sum();
}

void expect_proper_rotation(const Mat3& R, double tol) {
  EXPECT_LT((R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff(), tol) << R;
  EXPECT_NEAR(R.determinant(), 1.0, tol) << R;
}

// S = sum q p^T for q = M p over random points p.
Mat3 covariance_of(const Mat3& M, std::mt19937& rng, int points = 12) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Mat3 S = Mat3::Zero();
  for (int k = 0; k < points; ++k) {
    const Eigen::Vector3d p(u(rng), u(rng), u(rng));
    S += (M * p) * p.transpose();
  }
  return S;
}

TEST(RotationFit, RecoversARandomRotation) {
  std::mt19937 rng(1);
  for (int trial = 0; trial < 500; ++trial) {
    const Mat3 R = random_rotation(rng);
    const Mat3 S = covariance_of(R, rng);
    EXPECT_LT((larap::best_rotation(S) - R).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((larap::best_rotation_fast(S) - R).cwiseAbs().maxCoeff(), 1e-12);
    const Mat3 Rf = horn(S);
    EXPECT_LT((Rf - R).cwiseAbs().maxCoeff(), 2e-5) << "trial " << trial;
    expect_proper_rotation(Rf, 2e-6);
  }
}

TEST(RotationFit, RecoversTheRotationOfAStretchedCovariance) {
  // q = R A p with A symmetric positive definite: the polar factor R is the answer.
  std::mt19937 rng(2);
  for (int trial = 0; trial < 200; ++trial) {
    const Mat3 R = random_rotation(rng), Q = random_rotation(rng);
    const Mat3 A = Q * Eigen::Vector3d(0.5, 1.0, 3.0).asDiagonal() * Q.transpose();
    const Mat3 S = covariance_of(R * A, rng);
    const Mat3 want = larap::best_rotation(S);
    EXPECT_LT((larap::best_rotation_fast(S) - want).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_LT((horn(S) - want).cwiseAbs().maxCoeff(), 1e-4);
  }
}

TEST(RotationFit, AReflectionGivesTheNearestProperRotation) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < 200; ++trial) {
    const Mat3 R = random_rotation(rng);
    const Mat3 M = R * Eigen::Vector3d(1.0, 1.0, -0.3).asDiagonal();  // det < 0
    const Mat3 S = covariance_of(M, rng);
    ASSERT_LT(S.determinant(), 0.0);
    const double best = best_objective(S);
    for (const Mat3& Rf : {larap::best_rotation(S), larap::best_rotation_fast(S), horn(S)}) {
      expect_proper_rotation(Rf, 2e-6);
      EXPECT_NEAR((Rf.transpose() * S).trace(), best, 1e-5 * S.norm());
    }
  }
}

TEST(RotationFit, DegenerateCovariances) {
  // S = 0: the identity.
  expect_proper_rotation(horn(Mat3::Zero()), 1e-7);
  EXPECT_LT((horn(Mat3::Zero()) - Mat3::Identity()).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_LT((larap::best_rotation_fast(Mat3::Zero()) - Mat3::Identity()).cwiseAbs().maxCoeff(), 1e-12);
  // Rank 1 (collinear edges) and rank 2 (coplanar edges): a proper rotation that reaches the
  // optimum (the maximiser is not unique).
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    const Mat3 R = random_rotation(rng);
    const Eigen::Vector3d a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng));
    const Mat3 rank1 = (R * a) * a.transpose();
    const Mat3 rank2 = rank1 + (R * b) * b.transpose();
    for (const Mat3& S : {rank1, rank2}) {
      const double best = best_objective(S);
      for (const Mat3& Rf : {larap::best_rotation(S), larap::best_rotation_fast(S), horn(S)}) {
        expect_proper_rotation(Rf, 2e-6);
        EXPECT_NEAR((Rf.transpose() * S).trace(), best, 1e-5 * S.norm());
      }
    }
  }
}

TEST(RotationFit, ScaleInvariantAndFinite) {
  // The float fit normalises S by its largest entry: tiny and huge covariances give the same R.
  std::mt19937 rng(5);
  const Mat3 R = random_rotation(rng);
  const Mat3 S = covariance_of(R, rng);
  for (double scale : {1e-30, 1e-12, 1.0, 1e12, 1e30}) {
    const Mat3 Rf = horn(scale * S);
    ASSERT_TRUE(Rf.allFinite()) << scale;
    EXPECT_LT((Rf - R).cwiseAbs().maxCoeff(), 2e-5) << scale;
  }
}

// The warm start's rigid fit works on weighted moments of the handle rows (warm_start.h): built
// from points, it recovers a rigid motion exactly, and collinear points give a translation only.
larap::ComponentMoments moments_of(const larap::RowMatrixX3d& p, const larap::RowMatrixX3d& t,
                                   const std::vector<double>& w) {
  larap::ComponentMoments m;
  for (int j = 0; j < p.rows(); ++j) {
    const Eigen::Vector3d pj = p.row(j).transpose(), tj = t.row(j).transpose();
    m.w += w[j];
    m.p += w[j] * pj;
    m.t += w[j] * tj;
    m.pt += w[j] * pj * tj.transpose();
    m.pp += w[j] * pj * pj.transpose();
    m.tt += w[j] * tj.squaredNorm();
  }
  return m;
}

TEST(RotationFit, RigidFitFromMomentsRecoversAMotion) {
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(-1.0, 1.0), pos(0.1, 2.0);
  larap::RowMatrixX3d from(20, 3);
  std::vector<double> w(20);
  for (int i = 0; i < 20; ++i) {
    from.row(i) << u(rng), u(rng), u(rng);
    w[i] = pos(rng);
  }
  const Mat3 R = random_rotation(rng);
  const Eigen::Vector3d t(0.3, -2.0, 5.0);
  const larap::RowMatrixX3d to = (from * R.transpose()).rowwise() + t.transpose();
  larap::ComponentMotion motion;
  double before = 0.0;
  const double after = larap::fit_rigid(moments_of(from, to, w), motion, before);
  EXPECT_TRUE(motion.active);
  EXPECT_GT(before, 1.0);
  EXPECT_LT(after, 1e-12 * before);
  EXPECT_LT((motion.R - R).cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_LT((motion.t - t).cwiseAbs().maxCoeff(), 1e-10);
}

TEST(RotationFit, RigidFitFromMomentsOfCollinearPointsTurnsTheLineWithoutSpin) {
  // A line of points onto a turned line: the spin about the line is not determined; the fit
  // takes the least rotation (about the axis normal to both lines), which lands every point.
  larap::RowMatrixX3d from(5, 3), to(5, 3);
  for (int i = 0; i < 5; ++i) {
    from.row(i) << i, 0, 0;
    to.row(i) << 1, i, 2;
  }
  larap::ComponentMotion motion;
  double before = 0.0;
  const double after = larap::fit_rigid(moments_of(from, to, std::vector<double>(5, 1.0)), motion, before);
  EXPECT_GT(before, 1.0);
  EXPECT_LT(after, 1e-20 * before);
  EXPECT_LT((motion.R * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ()).norm(), 1e-12);  // no spin
  EXPECT_LT(std::abs(motion.R.determinant() - 1.0), 1e-12);
  for (int i = 0; i < 5; ++i)
    EXPECT_LT((motion.R * from.row(i).transpose() + motion.t - to.row(i).transpose()).norm(), 1e-12);
  for (int i = 0; i < 5; ++i) to.row(i) << -i, 1, 0;  // the line reversed: half a turn
  larap::fit_rigid(moments_of(from, to, std::vector<double>(5, 1.0)), motion, before);
  EXPECT_LT(std::abs(motion.R.determinant() - 1.0), 1e-12);
  for (int i = 0; i < 5; ++i)
    EXPECT_LT((motion.R * from.row(i).transpose() + motion.t - to.row(i).transpose()).norm(), 1e-12);
}

TEST(RotationFit, RigidFitOfOnePointIgnoresTheRoundingOfItsMoments) {
  // One point with an inexact weight and coordinates: its spread, a difference of large sums, is
  // rounding noise, and a rotation fitted to it turned a part held by one vertex at random.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int trial = 0; trial < 200; ++trial) {
    larap::RowMatrixX3d from(1, 3), to(1, 3);
    from.row(0) << u(rng), u(rng), u(rng);
    to.row(0) = from.row(0) + Eigen::RowVector3d(u(rng), u(rng), u(rng)) * 0.1;
    larap::ComponentMotion motion;
    double before = 0.0;
    larap::fit_rigid(moments_of(from, to, std::vector<double>(1, 0.3 + 0.01 * trial)), motion, before);
    EXPECT_TRUE(motion.R.isIdentity(0.0)) << "trial " << trial;
    // and a line of points aimed at one target point: no turn either
    larap::RowMatrixX3d line(3, 3), spot(3, 3);
    for (int i = 0; i < 3; ++i) {
      line.row(i) = from.row(0) + Eigen::RowVector3d(i * 0.7, 0, 0);
      spot.row(i) = to.row(0);
    }
    larap::fit_rigid(moments_of(line, spot, std::vector<double>(3, 0.3 + 0.01 * trial)), motion, before);
    EXPECT_TRUE(motion.R.isIdentity(0.0)) << "trial " << trial;
  }
}

TEST(RotationFit, RigidFitFromMomentsOfOnePointTranslatesOnly) {
  larap::RowMatrixX3d from(1, 3), to(1, 3);
  from.row(0) << 1, 2, 3;
  to.row(0) << -1, 0, 4;
  larap::ComponentMotion motion;
  double before = 0.0;
  larap::fit_rigid(moments_of(from, to, std::vector<double>(1, 2.0)), motion, before);
  EXPECT_TRUE(motion.R.isIdentity(0.0));
  EXPECT_LT((motion.t - Eigen::Vector3d(-2, -2, 1)).cwiseAbs().maxCoeff(), 1e-12);
}

}  // namespace
