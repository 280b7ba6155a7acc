// Run: cmake --build build && ctest --test-dir build -R Lattice
#include <gtest/gtest.h>
#include <larap/binding.h>
#include <larap/errors.h>
#include <larap/lattice.h>

#include "test_meshes.h"

using namespace larap;

TEST(Lattice, BoxIsSolidAndEnclosed) {
  const PolygonMesh m = gen::box({0, 0, 0}, {1, 1, 1});
  LatticeOptions opt;
  opt.cell_size = 0.1;
  const Lattice lat = Lattice::build(m, opt);
  // Every cell whose centre is strictly inside the box is kept and marked inside or surface.
  int inside = 0;
  for (size_t k = 0; k < lat.cell_coords.size(); ++k) {
    const Eigen::Vector3d c = lat.origin + lat.h * (lat.cell_coords[k].cast<double>() + Eigen::Vector3d::Constant(0.5));
    if ((c.array() > 0.05).all() && (c.array() < 0.95).all()) inside += (lat.cell_kind[k] & 2) ? 1 : 0;
  }
  EXPECT_GE(inside, 8 * 8 * 8);
  EXPECT_EQ(lat.num_components, 1);
  // Edges connect nodes exactly one cell apart.
  for (const auto& e : lat.edges)
    EXPECT_NEAR((lat.rest.row(e[0]) - lat.rest.row(e[1])).norm(), lat.h, 1e-12);
}

TEST(Lattice, SeparatePartsAreNotBridged) {
  PolygonMesh a = gen::sphere({0, 0, 0}, 1.0, 12, 24);
  const PolygonMesh b = gen::sphere({4, 0, 0}, 1.0, 12, 24);
  const int64_t na = a.num_vertices();
  a.vertices.conservativeResize(na + b.num_vertices(), 3);
  a.vertices.bottomRows(b.num_vertices()) = b.vertices;
  for (size_t f = 1; f < b.face_offsets.size(); ++f) {
    for (int64_t k = b.face_offsets[f - 1]; k < b.face_offsets[f]; ++k) a.face_indices.push_back(b.face_indices[k] + na);
    a.face_offsets.push_back(static_cast<int64_t>(a.face_indices.size()));
  }
  LatticeOptions opt;
  opt.cell_size = 0.2;
  const Lattice lat = Lattice::build(a, opt);
  EXPECT_EQ(lat.num_components, 2);
  // No kept cell in the gap between the spheres, away from both.
  for (const auto& c : lat.cell_coords) {
    const double x = lat.origin.x() + lat.h * (c.x() + 0.5);
    EXPECT_FALSE(x > 1.8 && x < 2.2);
  }
}

TEST(Lattice, CellsOptionIsApproximate) {
  const PolygonMesh m = gen::sphere({0, 0, 0}, 1.0, 16, 32);
  LatticeOptions opt;
  opt.cells = 3000;
  const Lattice lat = Lattice::build(m, opt);
  EXPECT_GT(lat.num_cells(), 3000 / 1.5);
  EXPECT_LT(lat.num_cells(), 3000 * 1.5);
}

TEST(Lattice, RefusesHugeGrids) {
  const PolygonMesh m = gen::box({0, 0, 0}, {1, 1, 1});
  LatticeOptions opt;
  opt.cell_size = 1e-6;
  EXPECT_THROW(Lattice::build(m, opt), OutOfMemory);
  opt.cell_size = -1;
  EXPECT_THROW(Lattice::build(m, opt), InvalidInput);
}

class BindingAffine : public ::testing::TestWithParam<WeightKind> {};

TEST_P(BindingAffine, ReproducesAffineMaps) {
  const PolygonMesh m = gen::sphere({0.3, -0.2, 0.1}, 1.0, 10, 20);
  LatticeOptions opt;
  opt.cells = 800;
  const Lattice lat = Lattice::build(m, opt);
  const Binding b = bind_vertices(lat, m.vertices, GetParam());
  Eigen::Matrix3d A;
  A << 1.2, 0.3, -0.1, 0.05, 0.8, 0.4, -0.2, 0.1, 1.1;
  const Eigen::Vector3d t(0.5, -1.0, 2.0);
  const RowMatrixX3d disp = gen::affine_displacement(lat.rest, A, t);
  std::vector<double> out(3 * m.num_vertices());
  transfer(lat, b, m.vertices, disp, out.data());
  double worst = 0;
  for (int64_t v = 0; v < m.num_vertices(); ++v) {
    const Eigen::Vector3d expect = A * m.vertices.row(v).transpose() + t;
    worst = std::max(worst, (Eigen::Vector3d(out[3 * v], out[3 * v + 1], out[3 * v + 2]) - expect).norm());
  }
  EXPECT_LT(worst, 1e-6 * 2.0);
  // Weights sum to one.
  std::vector<int32_t> ids(b.stencil_size());
  std::vector<double> w(b.stencil_size());
  for (int64_t v = 0; v < m.num_vertices(); v += 7) {
    b.weights_of(lat, v, ids.data(), w.data());
    double s = 0;
    for (double x : w) s += x;
    EXPECT_NEAR(s, 1.0, 1e-12);
  }
}

INSTANTIATE_TEST_SUITE_P(Weights, BindingAffine, ::testing::Values(WeightKind::Trilinear, WeightKind::BSpline));

TEST(Lattice, CoarsenedLevelCoversEveryCell) {
  const PolygonMesh m = gen::sphere({0, 0, 0}, 1.0, 12, 24);
  LatticeOptions opt;
  opt.cell_size = 0.1;
  const Lattice fine = Lattice::build(m, opt);
  const Lattice coarse = fine.coarsened();
  EXPECT_DOUBLE_EQ(coarse.h, 2 * fine.h);
  EXPECT_EQ(coarse.origin, fine.origin);
  EXPECT_LT(coarse.num_cells(), fine.num_cells());
  EXPECT_GE(coarse.num_cells() * 8, fine.num_cells());
  for (const auto& c : fine.cell_coords) EXPECT_GE(coarse.cell_at(c.x() / 2, c.y() / 2, c.z() / 2), 0);
  // Every coarse cell has a kept child, and coarse nodes sit at even fine coordinates.
  for (const auto& c : coarse.cell_coords) {
    bool child = false;
    for (int k = 0; k < 8 && !child; ++k)
      child = fine.cell_at(2 * c.x() + (k & 1), 2 * c.y() + ((k >> 1) & 1), 2 * c.z() + (k >> 2)) >= 0;
    EXPECT_TRUE(child);
  }
  // A coarse node at a corner of the fine grid sits exactly on that fine node.
  for (int64_t i = 0; i < coarse.num_nodes(); ++i) {
    const Eigen::Vector3i q = 2 * coarse.node_coords[i];
    const int32_t j = fine.node_at(q.x(), q.y(), q.z());
    if (j >= 0) EXPECT_NEAR((coarse.rest.row(i) - fine.rest.row(j)).norm(), 0.0, 1e-12);
  }
}
