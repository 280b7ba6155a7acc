// Stiff branchings (branching_copies.h, LatticeOptions::junction_stiffness): which copies branch,
// and that stiffening them changes their own weight alone and not gamma's normalisation.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R Branching
#include <gtest/gtest.h>
#include <larap/lattice.h>

#include <map>
#include <utility>

#include "branching_copies.h"
#include "test_meshes.h"

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

Lattice build(const PolygonMesh& m, bool split, double stiffness) {
  LatticeOptions opt;
  opt.cell_size = 1.0;
  opt.split_cells = split;
  opt.junction_stiffness = stiffness;
  return Lattice::build(m, opt);
}

Eigen::Vector3i cell_of_point(const Lattice& lat, const Eigen::Vector3d& p) {
  return ((p - lat.origin) / lat.h).array().floor().cast<int>();
}

}  // namespace

TEST(BranchingCopies, TheBlockUnderTwoSlabsBranchesAndTheSlabsDoNot) {
  const Lattice lat = build(two_slabs_on_a_block(), true, 300.0);
  const Eigen::Vector3i block = cell_of_point(lat, {1.5, 1.5, 2.4}), above = cell_of_point(lat, {1.5, 1.5, 3.5});
  ASSERT_EQ(lat.cell_copies(block.x(), block.y(), block.z()), 1);
  ASSERT_EQ(lat.cell_copies(above.x(), above.y(), above.z()), 2);
  const std::vector<uint8_t> b = branching_copies(lat);
  const int32_t block_copy = lat.cell_at(block.x(), block.y(), block.z());
  EXPECT_TRUE(b[size_t(block_copy)]);
  int64_t count = 0;
  for (int64_t c = 0; c < lat.num_cells(); ++c) {
    count += b[size_t(c)];
    // Nothing branches along the slabs: each copy there is joined to one copy across a face.
    if (lat.cell_coords[size_t(c)].z() >= above.z()) EXPECT_FALSE(b[size_t(c)]) << "copy " << c;
  }
  // The block's end alone: the slabs stay inside one column of cells.
  EXPECT_EQ(count, 1);
}

TEST(BranchingCopies, ThePlainLatticeHasNone) {
  const Lattice lat = build(two_slabs_on_a_block(), false, 300.0);
  for (uint8_t x : branching_copies(lat)) EXPECT_FALSE(x);
  EXPECT_TRUE(lat.cell_weight.empty());  // nothing stiffened, nothing weighed
}

TEST(BranchingCopies, StiffnessScalesTheirWeightAloneAndKeepsGammasNormalisation) {
  const Lattice soft = build(two_slabs_on_a_block(), true, 1.0), stiff = build(two_slabs_on_a_block(), true, 300.0);
  ASSERT_EQ(soft.num_cells(), stiff.num_cells());
  ASSERT_EQ(soft.edges, stiff.edges);
  const std::vector<uint8_t> b = branching_copies(stiff);
  auto weight = [](const Lattice& l, int64_t c) { return l.cell_weight.empty() ? 1.0 : l.cell_weight[size_t(c)]; };
  std::map<std::pair<int32_t, int32_t>, double> extra;  // per edge: what the branchings add
  for (int64_t c = 0; c < stiff.num_cells(); ++c) {
    const double expect = weight(soft, c) * (b[size_t(c)] ? 300.0 : 1.0);
    EXPECT_DOUBLE_EQ(weight(stiff, c), expect) << "copy " << c;
    if (!b[size_t(c)]) continue;
    const auto& n = stiff.cell_nodes[size_t(c)];
    for (int q = 0; q < 8; ++q)
      for (int a = 0; a < 3; ++a)
        if (!((q >> a) & 1)) extra[std::make_pair(n[q], n[q | (1 << a)])] += 0.5 * 299.0 * weight(soft, c);
  }
  ASSERT_FALSE(extra.empty());
  double soft_sum = 0.0;
  for (size_t e = 0; e < stiff.edges.size(); ++e) {
    const auto it = extra.find(std::make_pair(stiff.edges[e][0], stiff.edges[e][1]));
    const double add = it == extra.end() ? 0.0 : it->second;
    EXPECT_NEAR(stiff.edge_weight[e], soft.edge_weight[e] + add, 1e-9 * stiff.edge_weight[e]) << "edge " << e;
    soft_sum += soft.edge_weight[e];
  }
  EXPECT_NEAR(soft.plain_edge_weight_sum, soft_sum, 1e-9 * soft_sum);
  EXPECT_NEAR(stiff.plain_edge_weight_sum, soft_sum, 1e-9 * soft_sum);
}
