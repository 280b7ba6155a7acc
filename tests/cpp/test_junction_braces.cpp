// Braces where the solid branches (junction_braces.h): which columns are braced, and that the
// brace is a fixed quadratic zero under every affine map, added to the system through tie_matrix.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R JunctionBraces
#include <gtest/gtest.h>
#include <larap/binding.h>
#include <larap/lattice.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <random>

#include "backend.h"
#include "handle_system.h"
#include "junction_braces.h"
#include "test_meshes.h"
#include "test_moments.h"

using namespace larap;

namespace {

// Two slabs 0.1 apart rising from a block that ends inside grid cell (1,1,2) (a loose vertex at
// the origin puts the cell faces on whole numbers): that cell holds the block's end and both
// slabs' roots, one piece; the cells above hold the slabs alone, two copies each (a palm's end
// and two fingers).
PolygonMesh two_slabs_on_a_block() {
  return gen::concat({gen::point({0, 0, 0}), gen::box({1.1, 1.1, 1.1}, {1.9, 1.9, 2.5}),
                      gen::box({1.1, 1.1, 2.3}, {1.9, 1.45, 4.9}), gen::box({1.1, 1.55, 2.3}, {1.9, 1.9, 4.9})});
}

Lattice build(const PolygonMesh& m, bool split) {
  LatticeOptions opt;
  opt.cell_size = 1.0;
  opt.split_cells = split;
  return Lattice::build(m, opt);
}

// The handle system of `lat` with every vertex of `m` in one group, braces weighing `brace`.
HandleSystem system_of(const Lattice& lat, const PolygonMesh& m, double brace) {
  const int64_t n = m.num_vertices();
  HandleSpec spec;
  spec.group_offsets = {0, n};
  spec.rest = m.vertices;
  std::vector<int32_t> cells(static_cast<size_t>(n));
  for (int64_t v = 0; v < n; ++v) {
    spec.vertices.push_back(v);
    cells[size_t(v)] = lat.vertex_cell[size_t(v)];
  }
  const Binding b = bind_points(lat, m.vertices, cells, WeightKind::Trilinear);
  std::vector<int32_t> ids(size_t(n) * 8);
  std::vector<double> w(ids.size());
  for (int64_t v = 0; v < n; ++v) b.weights_of(lat, v, &ids[size_t(v) * 8], &w[size_t(v) * 8]);
  return make_handle_system(lat, 8, ids, w, spec, 0.03, junction_braces(lat), brace, 1.0,
                            Eigen::Vector3d(0.2, -0.1, 0.3));
}

Eigen::Vector3i cell_of_point(const Lattice& lat, const Eigen::Vector3d& p) {
  return ((p - lat.origin) / lat.h).array().floor().cast<int>();
}

}  // namespace

TEST(JunctionBraces, TheBlocksEndIsBracedAlongItsFourCornerColumns) {
  const Lattice lat = build(two_slabs_on_a_block(), true);
  const Eigen::Vector3i end = cell_of_point(lat, {1.5, 1.5, 2.4}), up = cell_of_point(lat, {1.5, 1.5, 3.5});
  ASSERT_EQ(up - end, Eigen::Vector3i(0, 0, 1));
  ASSERT_EQ(lat.cell_copies(end.x(), end.y(), end.z()), 1);  // the block's end and both roots
  ASSERT_EQ(lat.cell_copies(up.x(), up.y(), up.z()), 2);     // the slabs, apart
  const auto braces = junction_braces(lat);
  ASSERT_EQ(braces.size(), 4u);
  const int32_t above = lat.cell_at(up.x(), up.y(), up.z());
  const int32_t below = lat.cell_at(end.x(), end.y(), end.z() - 1);
  ASSERT_EQ(lat.cell_copies(end.x(), end.y(), end.z() - 1), 1);
  for (auto [a, b, c] : braces) {
    ASSERT_LT(a, c);
    for (int32_t i : {a, b, c}) ASSERT_LT(i, lat.num_real_nodes());
    if (lat.node_coords[size_t(a)].z() > lat.node_coords[size_t(c)].z()) std::swap(a, c);
    // A straight column along z through the block's end: below it (a corner of the block's copy
    // below), its near and its far face.
    const auto& trunk = lat.cell_nodes[size_t(below)];
    EXPECT_NE(std::find(trunk.begin(), trunk.end(), a), trunk.end());
    const Eigen::Vector3i pa = lat.node_coords[size_t(a)], pb = lat.node_coords[size_t(b)], pc = lat.node_coords[size_t(c)];
    EXPECT_EQ(pb - pa, Eigen::Vector3i(0, 0, 1));
    EXPECT_EQ(pc - pb, Eigen::Vector3i(0, 0, 1));
    EXPECT_EQ(pb.z(), end.z());
    EXPECT_TRUE(pb.x() >= end.x() && pb.x() <= end.x() + 1 && pb.y() >= end.y() && pb.y() <= end.y() + 1);
    EXPECT_EQ(lat.component[size_t(a)], lat.component[size_t(c)]);
    // The far node is both slabs' root: a corner of each copy above.
    for (int32_t d = above; d < above + 2; ++d) {
      const auto& n = lat.cell_nodes[size_t(d)];
      EXPECT_NE(std::find(n.begin(), n.end(), c), n.end()) << "copy " << d;
    }
  }
}

TEST(JunctionBraces, SlabsHangingBelowABlockAreBracedTheOtherWayRound) {
  // The same fork upside down: the block above, the slabs leaving its end downwards (the branching
  // copy branches towards -z; its trunk is above).
  const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::box({1.1, 1.1, 2.5}, {1.9, 1.9, 3.9}),
                                     gen::box({1.1, 1.1, 0.1}, {1.9, 1.45, 2.7}), gen::box({1.1, 1.55, 0.1}, {1.9, 1.9, 2.7})});
  const Lattice lat = build(m, true);
  const Eigen::Vector3i end = cell_of_point(lat, {1.5, 1.5, 2.6});
  ASSERT_EQ(lat.cell_copies(end.x(), end.y(), end.z()), 1);
  ASSERT_EQ(lat.cell_copies(end.x(), end.y(), end.z() - 1), 2);
  const auto braces = junction_braces(lat);
  ASSERT_EQ(braces.size(), 4u);
  for (auto [a, b, c] : braces) {
    if (lat.node_coords[size_t(a)].z() < lat.node_coords[size_t(c)].z()) std::swap(a, c);
    // a on the trunk's side (above), b on the face the branching copy shares with it, c below.
    EXPECT_EQ(lat.node_coords[size_t(a)].z(), end.z() + 2);
    EXPECT_EQ(lat.node_coords[size_t(b)].z(), end.z() + 1);
    EXPECT_EQ(lat.node_coords[size_t(c)].z(), end.z());
  }
}

TEST(JunctionBraces, NothingBranchesWithoutSplitCellsOrWithOneSlab) {
  EXPECT_TRUE(junction_braces(build(two_slabs_on_a_block(), false)).empty());
  const PolygonMesh one = gen::concat({gen::point({0, 0, 0}), gen::box({1.1, 1.1, 1.1}, {1.9, 1.9, 2.5}),
                                       gen::box({1.1, 1.1, 2.3}, {1.9, 1.45, 4.9})});
  EXPECT_TRUE(junction_braces(build(one, true)).empty());
}

TEST(JunctionBraces, TheTieMatrixIsTheBracesEnergyAndVanishesUnderAffineMaps) {
  const PolygonMesh m = two_slabs_on_a_block();
  const Lattice lat = build(m, true);
  const HandleSystem hs = system_of(lat, m, 50.0);
  ASSERT_EQ(hs.braces.size(), 4u);
  EXPECT_TRUE(hs.glue.empty());  // one handled component: the braces are the only ties
  ASSERT_TRUE(hs.has_ties());
  // Per unit of gamma_eff times the mean edge weight, as the anchors.
  EXPECT_NEAR(hs.brace_weight / hs.anchor_weight, 50.0 / 2.0, 1e-12);
  const int64_t n = lat.num_real_nodes();
  const Eigen::SparseMatrix<double> T = tie_matrix(hs, n);
  // x^T T x = beta sum |x_a - 2 x_b + x_c|^2 for any x.
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::MatrixXd X(n, 3);
  for (int64_t i = 0; i < n; ++i) X.row(i) << u(rng), u(rng), u(rng);
  double want = 0.0;
  for (const auto& [a, b, c] : hs.braces) want += hs.brace_weight * (X.row(a) - 2.0 * X.row(b) + X.row(c)).squaredNorm();
  EXPECT_NEAR((X.transpose() * (T * X)).trace(), want, 1e-9 * want);
  // An affine map of the rest lattice (shear, scale, turn, shift): T x = 0 up to rounding.
  Eigen::Matrix3d A;
  A << 1.3, 0.4, -0.2, 0.1, 0.8, 0.5, -0.3, 0.2, 1.1;
  const Eigen::MatrixXd Y = (lat.rest.topRows(n) * A.transpose()).rowwise() + Eigen::RowVector3d(3.0, -2.0, 5.0);
  EXPECT_LT((T * Y).cwiseAbs().maxCoeff(), 1e-9 * hs.brace_weight * 10.0);
}

TEST(JunctionBraces, AWeightOfZeroTurnsThemOff) {
  const PolygonMesh m = two_slabs_on_a_block();
  const Lattice lat = build(m, true);
  const HandleSystem hs = system_of(lat, m, 0.0);
  EXPECT_TRUE(hs.braces.empty());
  EXPECT_FALSE(hs.has_ties());
  EXPECT_EQ(tie_matrix(hs, lat.num_real_nodes()).nonZeros(), 0);
}

// The warm start's moments are sums over the handle rows (warm_start.h): the braces, like the
// glue, must not enter them, even on a pose that bends every braced column. On the CPU backend,
// and on the CUDA backend where the tests are built with it and a device is present (it keeps a
// second copy of M without the ties for them, native/cuda/cuda_system.cpp).
void expect_moments_leave_the_braces_out(bool cuda) {
  const PolygonMesh m = two_slabs_on_a_block();
  const Lattice lat = build(m, true);
  RowMatrixX3d targets = m.vertices;
  targets.col(0).array() += 0.3;
  targets(3, 2) += 0.2;
  RowMatrixX3d pose = lat.rest;
  for (int64_t i = 0; i < pose.rows(); ++i)
    pose.row(i) += Eigen::RowVector3d(0.01 * (i % 7), -0.02 * (i % 5), 0.03 * (i % 3));
  std::vector<ComponentMoments> got[2];
  for (int k = 0; k < 2; ++k) {
    const HandleSystem hs = system_of(lat, m, k == 0 ? 0.0 : 50.0);
    ASSERT_EQ(hs.braces.size(), k == 0 ? 0u : 4u);
    if (k == 1)  // the pose bends every brace: they would pull if they entered
      for (const auto& [a, b, c] : hs.braces) ASSERT_GT((pose.row(a) - 2.0 * pose.row(b) + pose.row(c)).squaredNorm(), 1e-6);
    auto backend = cuda ? make_cuda_backend(lat, m.vertices) : make_cpu_backend(lat, m.vertices);
    backend->set_handles(hs);
    backend->set_targets(HandleTargets{targets.data(), nullptr});
    backend->set_pose(pose);
    std::vector<ComponentMoments> at_rest;
    backend->moments(got[k], at_rest);
  }
  ASSERT_EQ(got[0].size(), got[1].size());
  // The device holds the pose in float and sums in double: the same pose, so the same sums but for
  // the order (the braces' pull, were they in, is of the order of the pose's bends, 1e-2).
  for (size_t c = 0; c < got[0].size(); ++c)
    test::expect_moments_near(got[1][c], got[0][c], cuda ? 1e-9 : 1e-12);
  EXPECT_GT(got[0][0].w, 0.0);
}

TEST(JunctionBraces, TheWarmStartsMomentsLeaveThemOut) { expect_moments_leave_the_braces_out(false); }

TEST(JunctionBraces, TheWarmStartsMomentsLeaveThemOutOnTheDevice) {
  std::string why;
  if (!cuda_available(&why)) GTEST_SKIP() << "no CUDA device: " << why;
  expect_moments_leave_the_braces_out(true);
}
