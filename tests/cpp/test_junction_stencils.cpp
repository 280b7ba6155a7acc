// Run: cmake --build build && ctest --test-dir build -R Junction
#include <gtest/gtest.h>
#include <larap/binding.h>
#include <larap/lattice.h>

#include "junction_stencils.h"
#include "test_meshes.h"

using namespace larap;

namespace {

// A comb of separate parts: a base block and three tines 0.4 cells thick and 0.1 apart, pushed
// into the base (so the cells where they leave it are junctions), each tine a few boxes long so
// that vertices sit near the junction.
PolygonMesh comb() {
  std::vector<PolygonMesh> parts{gen::box({-3.0, 0.0, 0.0}, {-0.1, 1.4, 0.4})};
  for (int t = 0; t < 3; ++t)
    for (int s = 0; s < 8; ++s) {
      const double y = 0.5 * t, x0 = -0.5 + 0.3 * s;
      parts.push_back(gen::box({x0, y, 0.0}, {x0 + 0.3, y + 0.4, 0.4}));
    }
  PolygonMesh m;
  for (const auto& p : parts) m = gen::concat({m, p});
  return m;
}

Lattice unit_lattice(const PolygonMesh& m) {
  LatticeOptions opt;
  opt.cell_size = 1.0;
  return Lattice::build(m, opt);
}

}  // namespace

TEST(JunctionStencils, ResolvedRowsReproduceAffineMapsAndRest) {
  const PolygonMesh m = comb();
  const Lattice lat = unit_lattice(m);
  Binding b = bind_vertices(lat, m.vertices, WeightKind::BSpline);
  const size_t before = b.node27.size();
  resolve_junction_stencils(lat, m, b);
  ASSERT_GT(b.node27.size(), before) << "the comb has junctions, some vertices read their own side";
  int moved = 0;
  for (int64_t v = 0; v < m.num_vertices(); ++v) moved += b.base[v] >= lat.num_real_nodes();
  EXPECT_GT(moved, 0);

  Eigen::Matrix3d A;
  A << 1.2, 0.3, -0.1, 0.05, 0.8, 0.4, -0.2, 0.1, 1.1;
  const Eigen::Vector3d t(0.5, -1.0, 2.0);
  for (int affine = 0; affine < 2; ++affine) {
    const RowMatrixX3d disp = affine ? gen::affine_displacement(lat.rest, A, t)
                                     : RowMatrixX3d(RowMatrixX3d::Zero(lat.num_nodes(), 3));
    std::vector<double> out(3 * m.num_vertices());
    transfer(lat, b, m.vertices, disp, out.data());
    double worst = 0;
    for (int64_t v = 0; v < m.num_vertices(); ++v) {
      const Eigen::Vector3d x = m.vertices.row(v).transpose();
      const Eigen::Vector3d expect = affine ? Eigen::Vector3d(A * x + t) : x;
      worst = std::max(worst, (Eigen::Vector3d(out[3 * v], out[3 * v + 1], out[3 * v + 2]) - expect).norm());
    }
    if (affine) EXPECT_LT(worst, 1e-8 * 6.5) << "affine map (the comb is 6.5 long)";
    else EXPECT_EQ(worst, 0.0) << "rest pose, bit for bit";
  }
  std::vector<int32_t> ids(27);
  std::vector<double> w(27);
  for (int64_t v = 0; v < m.num_vertices(); ++v) {
    b.weights_of(lat, v, ids.data(), w.data());
    double s = 0;
    for (int k = 0; k < 27; ++k) {
      s += w[k];
      ASSERT_GE(ids[k], 0);
      ASSERT_LT(ids[k], lat.num_nodes());
    }
    EXPECT_NEAR(s, 1.0, 1e-12);
  }
}

TEST(JunctionStencils, TrilinearAndSinglePartsAreLeftAlone) {
  const PolygonMesh m = comb();
  const Lattice lat = unit_lattice(m);
  Binding tri = bind_vertices(lat, m.vertices, WeightKind::Trilinear);
  const std::vector<int32_t> base = tri.base;
  resolve_junction_stencils(lat, m, tri);
  EXPECT_EQ(tri.base, base);
  const PolygonMesh s = gen::sphere({0, 0, 0}, 1.0, 8, 16);
  const Lattice ls = unit_lattice(s);
  Binding bs = bind_vertices(ls, s.vertices, WeightKind::BSpline);
  const size_t rows = bs.node27.size();
  resolve_junction_stencils(ls, s, bs);
  EXPECT_EQ(bs.node27.size(), rows);
}
