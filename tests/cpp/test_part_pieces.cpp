// The pieces of a cell whose triangles belong to several parts (part_pieces.h): the parts' masks
// and their bit-row pieces give the same sets and the same labels as the lists and the voxel union-
// find, and both follow the rule as a voxel-by-voxel flood reads it: two touching material voxels
// join when one is enclosed or one part hits both. Random cells of 2 to 70 parts (more than 64:
// lists), k from 1 to 64, surface voxels that no part's grown voxel reaches, pieces past the 253
// labels; the parts' sets against the exact test of every grown voxel.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R 'PartPieces\.'
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include "geometry.h"
#include "part_pieces.h"
#include "voxel_hits.h"

using namespace larap;

namespace {

struct Cell {
  int k = 0;
  double hv = 0.0;
  Eigen::Vector3d corner = Eigen::Vector3d::Zero();
  RowMatrixX3d V;
  std::vector<Eigen::Vector3i> tris;
  std::vector<int32_t> vertex_part, ids;
  std::vector<uint8_t> v;  // 0 enclosed, 1 surface, 2 air
};

// A cell of k^3 voxels with `triangles` random triangles of `parts` parts; the voxels they hit
// (plain) are surface, the others enclosed or air at random (air with probability `air`), and
// `orphans` voxels are surface although no triangle is near them.
Cell random_cell(std::mt19937& rng, int k, int parts, int triangles, double air, int orphans) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Cell c;
  c.k = k;
  c.hv = 1.0 / k;
  c.V.resize(3 * triangles, 3);
  for (int t = 0; t < triangles; ++t) {
    const Eigen::Vector3d centre(unit(rng), unit(rng), unit(rng));
    const double size = 0.05 + 0.4 * unit(rng);
    for (int i = 0; i < 3; ++i) {
      c.V.row(3 * t + i) = (centre + size * Eigen::Vector3d(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5)).transpose();
      // the first `parts` triangles one part each, so that every part is there (64 and 65 exactly)
      c.vertex_part.push_back(
          int32_t(t < parts ? t : std::uniform_int_distribution<int>(0, parts - 1)(rng)) * 3 + 7);
    }
    // a triangle's vertices are of one part
    c.vertex_part[size_t(3 * t + 1)] = c.vertex_part[size_t(3 * t + 2)] = c.vertex_part[size_t(3 * t)];
    c.tris.emplace_back(3 * t, 3 * t + 1, 3 * t + 2);
    c.ids.push_back(t);
  }
  const int64_t k3 = int64_t(k) * k * k;
  c.v.assign(size_t(k3), 0);
  for (int64_t vi = 0; vi < k3; ++vi) c.v[size_t(vi)] = unit(rng) < air ? 2 : 0;
  for (const Eigen::Vector3i& t : c.tris)
    for_each_voxel_hit(c.corner, c.hv, k, c.V.row(t[0]).transpose(), c.V.row(t[1]).transpose(),
                       c.V.row(t[2]).transpose(), 0.0, [](int64_t) { return false; },
                       [&](int64_t vi) { c.v[size_t(vi)] = 1; });
  for (int o = 0; o < orphans; ++o) c.v[size_t(std::uniform_int_distribution<int64_t>(0, k3 - 1)(rng))] = 1;
  return c;
}

PartSets sets_of(const Cell& c, int max_mask_parts) {
  return part_sets(c.v.data(), c.k, c.corner, c.hv, c.V, c.tris, c.ids.data(), 0, int32_t(c.ids.size()),
                   c.vertex_part, max_mask_parts);
}

// The rule, voxel by voxel: pieces by a stack flood, labelled in the order of their first voxel
// (all of them, no merging past 253).
std::vector<int32_t> reference_pieces(const Cell& c, const PartSets& sets) {
  const int k = c.k;
  const int64_t k3 = int64_t(k) * k * k;
  std::vector<int32_t> piece(size_t(k3), -1);
  std::vector<int32_t> sa, sb;
  int32_t np = 0;
  for (int64_t s = 0; s < k3; ++s) {
    if (c.v[size_t(s)] == 2 || piece[size_t(s)] >= 0) continue;
    std::vector<int64_t> stack{s};
    piece[size_t(s)] = np;
    while (!stack.empty()) {
      const int64_t vi = stack.back();
      stack.pop_back();
      const int64_t x[3] = {vi % k, (vi / k) % k, vi / (int64_t(k) * k)};
      const int64_t step[3] = {1, k, int64_t(k) * k};
      for (int a = 0; a < 3; ++a)
        for (int d : {-1, 1}) {
          if (x[a] + d < 0 || x[a] + d >= k) continue;
          const int64_t ni = vi + d * step[a];
          if (c.v[size_t(ni)] == 2 || piece[size_t(ni)] >= 0) continue;
          bool joined = c.v[size_t(vi)] == 0 || c.v[size_t(ni)] == 0;
          if (!joined) {
            const auto [a0, a1] = sets.of(vi, sa);
            const auto [b0, b1] = sets.of(ni, sb);
            joined = sorted_sets_meet(a0, a1, b0, b1);
          }
          if (!joined) continue;
          piece[size_t(ni)] = np;
          stack.push_back(ni);
        }
    }
    ++np;
  }
  return piece;
}

}  // namespace

TEST(PartPieces, MasksAndListsGiveTheRulesPieces) {
  std::mt19937 rng(5);
  int cells = 0, several_pieces = 0, merged = 0, cells64 = 0;
  int64_t partless = 0;  // surface voxels that no part's grown voxel reaches
  for (int k : {1, 3, 8, 17, 24, 64})
    for (int parts : {2, 3, 7, 64, 65, 70})
      for (double air : {0.2, 0.6, 0.95})
        for (int round = 0; round < 3; ++round) {
          const int orphans = round == 2 ? 1 + k : 0;
          const Cell c =
              random_cell(rng, k, parts, parts >= 64 ? parts + 70 : 2 + 3 * round + parts, air, orphans);
          const PartSets masks = sets_of(c, kMaskParts), lists = sets_of(c, 0);
          ASSERT_EQ(masks.parts, lists.parts);
          ASSERT_EQ(masks.masks.empty(), masks.parts.size() > size_t(kMaskParts));
          ASSERT_TRUE(lists.masks.empty());
          // The same sets voxel by voxel, and they are the parts whose triangles the surface
          // voxel, grown by kContact, overlaps (the exact test on every voxel).
          const int64_t k3 = int64_t(k) * k * k;
          std::vector<std::vector<int32_t>> grown(static_cast<size_t>(k3));
          if (k <= 17) {
            const Eigen::Vector3d half =
                Eigen::Vector3d::Constant(0.5 * c.hv * (1.0 + 2.0 * kContact + 1e-9));
            for (const Eigen::Vector3i& t : c.tris)
              for (int64_t vi = 0; vi < k3; ++vi) {
                const Eigen::Vector3d centre =
                    c.corner +
                    c.hv * Eigen::Vector3d(vi % k + 0.5, (vi / k) % k + 0.5, vi / (int64_t(k) * k) + 0.5);
                if (c.v[size_t(vi)] == 1 &&
                    geometry::triangle_box_overlap(centre, half, c.V.row(t[0]).transpose(),
                                                   c.V.row(t[1]).transpose(), c.V.row(t[2]).transpose()))
                  grown[size_t(vi)].push_back(c.vertex_part[size_t(t[0])]);
              }
            for (auto& g : grown) {
              std::sort(g.begin(), g.end());
              g.erase(std::unique(g.begin(), g.end()), g.end());
            }
          }
          std::vector<int32_t> s1, s2;
          for (int64_t vi = 0; vi < k3; ++vi) {
            const auto [a0, a1] = masks.of(vi, s1);
            const auto [b0, b1] = lists.of(vi, s2);
            ASSERT_TRUE(std::equal(a0, a1, b0, b1)) << "voxel " << vi;
            ASSERT_TRUE(std::is_sorted(a0, a1));
            if (k <= 17)
              ASSERT_TRUE(std::equal(a0, a1, grown[size_t(vi)].begin(), grown[size_t(vi)].end())) << vi;
            if (c.v[size_t(vi)] != 1) ASSERT_EQ(a0, a1);
            partless += c.v[size_t(vi)] == 1 && a0 == a1;
          }
          std::vector<uint8_t> va = c.v, vb = c.v;
          std::vector<int32_t> za, zb;
          const int32_t na = pieces_by_part(va.data(), k, masks, za);
          const int32_t nb = pieces_by_part(vb.data(), k, lists, zb);
          ASSERT_EQ(va, vb);
          ASSERT_EQ(za, zb);
          ASSERT_EQ(na, nb);
          // Against the rule: the same partition, labelled in order of the pieces' first voxels.
          const std::vector<int32_t> want = reference_pieces(c, lists);
          int32_t want_n = 0;
          for (int64_t vi = 0; vi < k3; ++vi) {
            if (c.v[size_t(vi)] == 2) {
              ASSERT_EQ(va[size_t(vi)], 2);
              continue;
            }
            want_n = std::max(want_n, want[size_t(vi)] + 1);
            ASSERT_EQ(va[size_t(vi)], 3 + std::min(want[size_t(vi)], 252)) << "voxel " << vi;
          }
          ASSERT_EQ(na, want_n);
          int64_t material = 0;
          for (int32_t z : za) material += z;
          ASSERT_EQ(material, int64_t(std::count_if(c.v.begin(), c.v.end(), [](uint8_t x) { return x != 2; })));
          ++cells;
          several_pieces += na > 1;
          merged += na > 253;
          cells64 += masks.parts.size() == 64 && !masks.masks.empty();
        }
  EXPECT_GT(several_pieces, cells / 3);
  EXPECT_GT(partless, 10);
  EXPECT_GT(merged, 0);
  EXPECT_GT(cells64, 10);
}
