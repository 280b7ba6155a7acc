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

// ------------------------------------------------------------------ loose edges

namespace {

// A helix of `n` edges, each about `edge` long: a wire mesh (faces of two vertices).
PolygonMesh wire(int n, double edge) {
  PolygonMesh m;
  m.vertices.resize(n + 1, 3);
  for (int i = 0; i <= n; ++i) {
    const double t = 0.7 * i;
    m.vertices.row(i) << std::cos(t), std::sin(t), 0.1 * i;
  }
  const double len = (m.vertices.row(1) - m.vertices.row(0)).norm();
  m.vertices *= edge / len;
  for (int i = 0; i < n; ++i) {
    m.face_indices.push_back(i);
    m.face_indices.push_back(i + 1);
    m.face_offsets.push_back(int64_t(m.face_indices.size()));
  }
  return m;
}

}  // namespace

TEST(Lattice, SegmentsAreFacesOfTwoDistinctVertices) {
  PolygonMesh m;
  m.vertices = RowMatrixX3d::Zero(5, 3);
  m.face_indices = {0, 1, /*edge*/ 2, 1, 2, /*edge, repeated*/ 0, 1, 2, /*triangle*/ 3, /*point*/ 4, 4 /*point*/};
  m.face_offsets = {0, 2, 5, 8, 9, 11};
  const std::vector<Eigen::Vector2i> s = segments(m);
  ASSERT_EQ(s.size(), 2u);
  EXPECT_EQ(s[0], Eigen::Vector2i(0, 1));
  EXPECT_EQ(s[1], Eigen::Vector2i(1, 2));
  EXPECT_EQ(triangulate(m).size(), 1u);
}

// A wire whose edges are 3-4 cells long keeps the cells between its vertices: one lattice
// component, and every kept cell a loose edge passes through (without them every vertex was a
// component of its own, held at rest or carried alone: the wire tore apart).
TEST(Lattice, LooseEdgesKeepTheCellsTheyPassThrough) {
  const PolygonMesh m = wire(40, 0.35);
  LatticeOptions opt;
  opt.cell_size = 0.1;
  const Lattice lat = Lattice::build(m, opt);
  EXPECT_EQ(lat.num_components, 1);
  // Points along every edge lie in kept cells, and (away from the cells' faces) in no others:
  // the chain is the exact test's, not a thickened one.
  for (int i = 0; i < 40; ++i)
    for (int k = 0; k <= 20; ++k) {
      const Eigen::Vector3d p = m.vertices.row(i) + (k / 20.0) * (m.vertices.row(i + 1) - m.vertices.row(i));
      const Eigen::Vector3i c = ((p - lat.origin) / lat.h).array().floor().cast<int>();
      EXPECT_GE(lat.cell_at(c.x(), c.y(), c.z()), 0) << "edge " << i << " at " << k / 20.0;
    }
  // Each kept cell is within reach of some edge (the exact test, with its 1e-9 margin).
  for (int64_t c = 0; c < lat.num_cells(); ++c) {
    const Eigen::Vector3d centre = lat.origin + lat.h * (lat.cell_coords[c].cast<double>() + Eigen::Vector3d::Constant(0.5));
    double best = 1e300;
    for (int i = 0; i < 40; ++i) {
      const Eigen::Vector3d a = m.vertices.row(i), b = m.vertices.row(i + 1);
      auto dist = [&](double t) { return (a + t * (b - a) - centre).cwiseAbs().maxCoeff(); };
      double lo = 0.0, hi = 1.0;  // the max-norm distance is convex along the edge
      for (int it = 0; it < 100; ++it) {
        const double u = lo + (hi - lo) / 3, w = hi - (hi - lo) / 3;
        (dist(u) < dist(w) ? hi : lo) = dist(u) < dist(w) ? w : u;
      }
      best = std::min(best, dist(0.5 * (lo + hi)));
    }
    EXPECT_LE(best, 0.5 * lat.h * (1 + 1e-6)) << "cell " << c;
  }
  // The same vertices without their edges: each vertex's cell alone.
  PolygonMesh points = m;
  points.face_indices.clear();
  points.face_offsets = {0};
  EXPECT_EQ(Lattice::build(points, opt).num_components, 41);
}

// A long diagonal edge, walked slab by slab along its longest axis: one face-connected chain (no
// cell skipped where it crosses two slab boundaries at once), about 3 cells per cell of length.
TEST(Lattice, LongDiagonalEdgeIsOneChain) {
  PolygonMesh m;
  m.vertices.resize(2, 3);
  m.vertices << 0, 0, 0, 10, 10.03, 9.97;
  m.face_indices = {0, 1};
  m.face_offsets = {0, 2};
  LatticeOptions opt;
  opt.cell_size = 0.1;
  opt.split_cells = false;
  const Lattice lat = Lattice::build(m, opt);
  EXPECT_EQ(lat.num_components, 1);
  EXPECT_GT(lat.num_cells(), 3 * 100 - 10);
  EXPECT_LE(lat.num_cells(), 3 * 100 + 10);
  // Face-connected: a flood over shared faces reaches every cell.
  std::vector<uint8_t> seen(size_t(lat.num_cells()), 0);
  std::vector<int32_t> stack{0};
  seen[0] = 1;
  int64_t reached = 1;
  while (!stack.empty()) {
    const Eigen::Vector3i c = lat.cell_coords[size_t(stack.back())];
    stack.pop_back();
    for (int f = 0; f < 6; ++f) {
      Eigen::Vector3i y = c;
      y[f / 2] += f % 2 ? 1 : -1;
      const int32_t n = lat.cell_at(y.x(), y.y(), y.z());
      if (n >= 0 && !seen[size_t(n)]) {
        seen[size_t(n)] = 1;
        ++reached;
        stack.push_back(n);
      }
    }
  }
  EXPECT_EQ(reached, lat.num_cells());
}
