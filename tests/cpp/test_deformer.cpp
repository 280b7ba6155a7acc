// Run: cmake --build build && ctest --test-dir build -R Deformer
#include <gtest/gtest.h>
#include <larap/deformer.h>
#include <larap/errors.h>

#include <Eigen/Geometry>
#include <limits>
#include <random>

#include "parallel.h"
#include "test_meshes.h"

using namespace larap;

namespace {

PolygonMesh ball() { return gen::sphere({0.2, -0.1, 0.3}, 1.0, 12, 24); }

std::vector<int64_t> spread(int64_t n, int k) {
  std::vector<int64_t> idx;
  for (int i = 0; i < k; ++i) idx.push_back((i * 7919) % n);
  std::sort(idx.begin(), idx.end());
  idx.erase(std::unique(idx.begin(), idx.end()), idx.end());
  return idx;
}

RowMatrixX3d gather(const RowMatrixX3d& V, const std::vector<int64_t>& idx) {
  RowMatrixX3d T(idx.size(), 3);
  for (size_t j = 0; j < idx.size(); ++j) T.row(j) = V.row(idx[j]);
  return T;
}

double diag(const RowMatrixX3d& V) { return (V.colwise().maxCoeff() - V.colwise().minCoeff()).norm(); }

}  // namespace

class DeformerWeights : public ::testing::TestWithParam<WeightKind> {};

TEST_P(DeformerWeights, RestAndRigid) {
  const PolygonMesh m = ball();
  DeformerOptions opt;
  opt.lattice.cells = 1500;
  opt.weights = GetParam();
  Deformer d(m, opt);
  const auto idx = spread(m.num_vertices(), 30);
  d.set_handles(idx);
  RowMatrixX3d X(m.num_vertices(), 3);
  RowMatrixX3d T = gather(m.vertices, idx);
  d.solve(T.data(), 5, X.data());
  EXPECT_LE((X - m.vertices).cwiseAbs().maxCoeff(), 1e-6 * diag(m.vertices));

  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI / 3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(1.0, -2.0, 0.5);
  RowMatrixX3d moved = (m.vertices * R.transpose()).rowwise() + t;
  T = gather(moved, idx);
  d.solve(T.data(), 60, X.data());
  EXPECT_LE((X - moved).cwiseAbs().maxCoeff(), 1e-3 * diag(m.vertices));
}

TEST_P(DeformerWeights, EnergyNeverIncreases) {
  const PolygonMesh m = ball();
  DeformerOptions opt;
  opt.lattice.cells = 1500;
  opt.weights = GetParam();
  Deformer d(m, opt);
  std::vector<int64_t> idx;
  for (int64_t i = 0; i < m.num_vertices(); ++i)
    if (std::abs(m.vertices(i, 2) - 0.3) > 0.8) idx.push_back(i);
  d.set_handles(idx);
  RowMatrixX3d T = gather(m.vertices, idx);
  for (int64_t j = 0; j < T.rows(); ++j)
    if (T(j, 2) > 0.3) T(j, 0) += 0.6;  // shear the top against the bottom
  RowMatrixX3d X(m.num_vertices(), 3);
  d.solve(T.data(), 20, X.data());
  const auto& e = d.stats().energy;
  ASSERT_EQ(e.size(), 20u);
  for (size_t k = 1; k < e.size(); ++k) EXPECT_LE(e[k], e[k - 1] * (1 + 1e-9)) << k;
  EXPECT_LT(e.back(), e.front());
}

INSTANTIATE_TEST_SUITE_P(Weights, DeformerWeights, ::testing::Values(WeightKind::Trilinear, WeightKind::BSpline));

TEST(Deformer, DeterministicAcrossThreadCounts) {
  const PolygonMesh m = ball();
  DeformerOptions opt;
  opt.lattice.cells = 1500;
  const auto idx = spread(m.num_vertices(), 20);
  RowMatrixX3d T = gather(m.vertices, idx);
  T.col(1).array() += 0.3;
  RowMatrixX3d X[2];
  const int threads[2] = {1, 2};
  for (int k = 0; k < 2; ++k) {
    set_num_threads(threads[k]);
    Deformer d(m, opt);
    d.set_handles(idx);
    X[k].resize(m.num_vertices(), 3);
    d.solve(T.data(), 8, X[k].data());
  }
  set_num_threads(0);
  // Every stage is a per-node or per-vertex gather, and the simplicial factor calls no BLAS:
  // bit-identical at any thread count.
  EXPECT_EQ((X[0] - X[1]).cwiseAbs().maxCoeff(), 0.0);
}

TEST(Deformer, Errors) {
  const PolygonMesh m = ball();
  DeformerOptions opt;
  opt.lattice.cells = 500;
  Deformer d(m, opt);
  RowMatrixX3d X(m.num_vertices(), 3);
  const double t[3] = {0, 0, 0};
  EXPECT_THROW(d.solve(t, 5, X.data()), StateError);
  EXPECT_THROW(d.set_handles({0, m.num_vertices()}), InvalidInput);
  EXPECT_THROW(d.set_handles({-1}), InvalidInput);
  EXPECT_THROW(d.set_handles({3, 3}), InvalidInput);
  d.set_handles({0});
  const double bad[3] = {0, std::nan(""), 0};
  EXPECT_THROW(d.solve(bad, 5, X.data()), InvalidInput);
  EXPECT_THROW(d.solve(t, -1, X.data()), InvalidInput);
  d.solve(t, 2, X.data());  // still usable
  EXPECT_TRUE(X.allFinite());
  opt.gamma = -1;
  EXPECT_THROW(Deformer(m, opt), InvalidInput);
  opt.gamma = 0.1;
  opt.device = "tpu";
  EXPECT_THROW(Deformer(m, opt), InvalidInput);
  PolygonMesh empty;
  opt.device = "cpu";
  EXPECT_THROW(Deformer(empty, opt), InvalidInput);
}

TEST(Deformer, NoHandlesGiveRest) {
  const PolygonMesh m = ball();
  DeformerOptions opt;
  opt.lattice.cells = 500;
  Deformer d(m, opt);
  d.set_handles({});
  RowMatrixX3d X(m.num_vertices(), 3);
  d.solve(nullptr, 5, X.data());
  EXPECT_EQ((X - m.vertices).cwiseAbs().maxCoeff(), 0.0);
}

TEST(Deformer, HierarchyRestAndRigid) {
  const PolygonMesh m = ball();
  DeformerOptions opt;
  opt.lattice.cells = 1500;
  opt.levels = 3;
  Deformer d(m, opt);
  EXPECT_EQ(d.levels(), 3);
  const auto idx = spread(m.num_vertices(), 30);
  d.set_handles(idx);
  RowMatrixX3d X(m.num_vertices(), 3);
  RowMatrixX3d T = gather(m.vertices, idx);
  d.solve(T.data(), 5, X.data());
  EXPECT_LE((X - m.vertices).cwiseAbs().maxCoeff(), 1e-6 * diag(m.vertices));
  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI / 3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const RowMatrixX3d moved = (m.vertices * R.transpose()).rowwise() + Eigen::RowVector3d(1.0, -2.0, 0.5);
  T = gather(moved, idx);
  d.solve(T.data(), 30, X.data());
  EXPECT_LE((X - moved).cwiseAbs().maxCoeff(), 1e-3 * diag(m.vertices));
  opt.levels = 0;
  EXPECT_THROW(Deformer(m, opt), InvalidInput);
}

// A cancelled drag puts the lattice state back: the next solve continues exactly as if the drag
// had not happened, on every level of a hierarchy; a state of another shape changes nothing.
class LatticeStateLevels : public ::testing::TestWithParam<int> {};

TEST_P(LatticeStateLevels, PuttingTheStateBackUndoesTheSolvesSince) {
  const PolygonMesh m = ball();
  DeformerOptions opt;
  opt.lattice.cells = 1500;
  opt.levels = GetParam();
  const auto idx = spread(m.num_vertices(), 30);
  RowMatrixX3d A = gather(m.vertices, idx), B = A, A2 = A;
  A.col(1).array() += 0.3;
  B.col(0).array() -= 0.5;
  A2.col(1).array() += 0.35;
  RowMatrixX3d X(m.num_vertices(), 3), Y(m.num_vertices(), 3);

  Deformer d(m, opt);
  d.set_handles(idx);
  d.solve(A.data(), 10, X.data());
  const std::vector<RowMatrixX3d> state = d.lattice_state();
  ASSERT_EQ(int(state.size()), d.levels());
  d.solve(B.data(), 10, X.data());  // the drag
  d.set_lattice_state(state);       // cancelled
  EXPECT_EQ((d.lattice_state()[0] - state[0]).cwiseAbs().maxCoeff(), 0.0);
  d.solve(A2.data(), 5, X.data());

  Deformer e(m, opt);  // no drag at all
  e.set_handles(idx);
  e.solve(A.data(), 10, Y.data());
  e.solve(A2.data(), 5, Y.data());
  EXPECT_EQ((X - Y).cwiseAbs().maxCoeff(), 0.0);

  // Wrong level count, wrong node count, a NaN: InvalidInput, and the state is kept (every bad
  // state starts with a valid but different fine level, which a partial update would keep).
  const std::vector<RowMatrixX3d> before = d.lattice_state();
  std::vector<RowMatrixX3d> moved = before;
  moved[0].array() += 0.25;
  std::vector<RowMatrixX3d> bad = moved;
  bad.push_back(before[0]);
  EXPECT_THROW(d.set_lattice_state(bad), InvalidInput);
  bad = moved;
  bad.back().conservativeResize(bad.back().rows() - 1, 3);
  EXPECT_THROW(d.set_lattice_state(bad), InvalidInput);
  bad = moved;
  bad.back()(3, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(d.set_lattice_state(bad), InvalidInput);
  const std::vector<RowMatrixX3d> after = d.lattice_state();
  for (size_t l = 0; l < before.size(); ++l) EXPECT_EQ((after[l] - before[l]).cwiseAbs().maxCoeff(), 0.0);
}

INSTANTIATE_TEST_SUITE_P(Levels, LatticeStateLevels, ::testing::Values(1, 3));
