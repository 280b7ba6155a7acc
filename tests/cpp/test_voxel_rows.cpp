// Bit-row floods of a cell's voxels (voxel_rows.h), which cell splitting's air, enclosed material
// and pieces are found with: the same voxels as a voxel-by-voxel flood fill, on random grids of
// every density and on mazes, at k from 1 to 64 (a row is one 64-bit word at k = 64).
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R 'VoxelRows\.'
#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

#include "voxel_rows.h"

using namespace larap;

namespace {

// Calls visit(ni) for each 6-neighbour ni of voxel vi within a k^3 grid.
template <class F>
void each_neighbour(int k, int64_t vi, F&& visit) {
  const int64_t c[3] = {vi % k, (vi / k) % k, vi / (int64_t(k) * k)};
  const int64_t step[3] = {1, k, int64_t(k) * k};
  for (int a = 0; a < 3; ++a)
    for (int s : {-1, 1})
      if (c[a] + s >= 0 && c[a] + s < k) visit(vi + s * step[a]);
}

// The reference: a stack flood over the open voxels, 6-connected, from the seed voxels.
std::vector<uint8_t> flood_voxels(int k, const std::vector<uint8_t>& open, const std::vector<uint8_t>& seed) {
  const int64_t k3 = int64_t(k) * k * k;
  std::vector<uint8_t> in(size_t(k3), 0);
  std::vector<int64_t> stack;
  for (int64_t vi = 0; vi < k3; ++vi)
    if (seed[size_t(vi)] && open[size_t(vi)]) {
      in[size_t(vi)] = 1;
      stack.push_back(vi);
    }
  while (!stack.empty()) {
    const int64_t vi = stack.back();
    stack.pop_back();
    each_neighbour(k, vi, [&](int64_t ni) {
      if (open[size_t(ni)] && !in[size_t(ni)]) {
        in[size_t(ni)] = 1;
        stack.push_back(ni);
      }
    });
  }
  return in;
}

std::vector<uint64_t> to_rows(int k, const std::vector<uint8_t>& voxels) {
  std::vector<uint64_t> rows(size_t(k) * k);
  rows_equal(voxels.data(), k, 1, rows.data());
  return rows;
}

std::vector<uint8_t> to_voxels(int k, const std::vector<uint64_t>& rows) {
  std::vector<uint8_t> v(size_t(k) * k * k, 0);
  for_each_bit(rows.data(), k, [&](int64_t vi) { v[size_t(vi)] = 1; });
  return v;
}

}  // namespace

TEST(VoxelRows, FillRowReachesTheRunsOfItsSeeds) {
  std::mt19937_64 rng(7);
  for (int t = 0; t < 20000; ++t) {
    const uint64_t open = rng() & rng() | rng() & rng(), seed = rng() & rng() & rng();
    uint64_t expect = seed & open;
    for (bool grew = true; grew;) {  // one bit at a time, both ways
      const uint64_t next = expect | (((expect << 1) | (expect >> 1)) & open);
      grew = next != expect;
      expect = next;
    }
    ASSERT_EQ(fill_row(seed, open), expect) << t;
  }
  EXPECT_EQ(fill_row(1, ~uint64_t(0)), ~uint64_t(0));
  EXPECT_EQ(fill_row(uint64_t(1) << 63, ~uint64_t(0)), ~uint64_t(0));
  EXPECT_EQ(fill_row(uint64_t(1) << 63, ~uint64_t(0) >> 1), 0u);  // a seed outside open stays out
}

TEST(VoxelRows, RowsRoundTripEveryValueAndK) {
  std::mt19937 rng(3);
  for (int k : {1, 2, 3, 5, 8, 15, 16, 17, 24, 33, 63, 64}) {
    const int64_t k3 = int64_t(k) * k * k;
    std::vector<uint8_t> v(static_cast<size_t>(k3));
    for (auto& x : v) x = uint8_t(rng() % 5 == 0 ? 255 : rng() % 4);
    for (uint8_t value : {uint8_t(0), uint8_t(1), uint8_t(2), uint8_t(255)}) {
      std::vector<uint64_t> rows(size_t(k) * k);
      rows_equal(v.data(), k, value, rows.data());
      const std::vector<uint8_t> back = to_voxels(k, rows);
      for (int64_t vi = 0; vi < k3; ++vi)
        ASSERT_EQ(back[size_t(vi)], v[size_t(vi)] == value) << k << " " << vi;
    }
    std::vector<uint64_t> rows(size_t(k) * k);
    rows_below(v.data(), k, 2, rows.data());
    const std::vector<uint8_t> back = to_voxels(k, rows);
    for (int64_t vi = 0; vi < k3; ++vi) ASSERT_EQ(back[size_t(vi)], v[size_t(vi)] < 2) << k << " " << vi;
  }
}

TEST(VoxelRows, FloodEqualsAVoxelByVoxelFlood) {
  std::mt19937 rng(11);
  for (int k : {1, 2, 4, 7, 24, 31, 64})
    for (double density : {0.2, 0.3116, 0.5, 0.7, 0.95}) {  // 0.3116: site percolation in 3D
      const int64_t k3 = int64_t(k) * k * k;
      std::vector<uint8_t> open(static_cast<size_t>(k3)), seed(static_cast<size_t>(k3), 0);
      std::bernoulli_distribution is_open(density);
      for (auto& x : open) x = is_open(rng);
      for (int s = 0; s < 3; ++s) {  // three seeds on open voxels, when there are any
        int64_t at = int64_t(rng() % k3);
        for (int64_t tries = 0; tries < k3 && !open[size_t(at)]; ++tries) at = (at + 1) % k3;
        seed[size_t(at)] = 1;
      }
      const std::vector<uint8_t> expect = flood_voxels(k, open, seed);
      std::vector<uint64_t> open_rows = to_rows(k, open), region = to_rows(k, seed);
      for (size_t r = 0; r < region.size(); ++r) region[r] &= open_rows[r];
      flood_rows(k, open_rows.data(), region.data());
      EXPECT_EQ(to_voxels(k, region), expect) << "k " << k << " density " << density;
    }
}

TEST(VoxelRows, FloodFollowsAMazeThatTurnsBackEveryRow) {
  // A serpentine corridor in every other layer: rows along x joined alternately at their two ends
  // (a row fill crosses a whole row at once), the layers joined at one corner, alternately the
  // first and the last row's: the flood needs several pairs of sweeps (2 at k = 4, 7 at 24, 17 at
  // 64). The staircase in PiecesAreLabelledAsByAVoxelByVoxelFlood needs one pair per two steps.
  for (int k : {4, 24, 64}) {
    const int64_t k3 = int64_t(k) * k * k;
    std::vector<uint8_t> open(size_t(k3), 0);
    auto at = [k](int i, int j, int l) { return size_t(i + k * (j + int64_t(k) * l)); };
    for (int l = 0; l < k; l += 2) {
      for (int j = 0; j < k; j += 2) {
        for (int i = 0; i < k; ++i) open[at(i, j, l)] = 1;
        if (j + 2 < k) open[at((j / 2) % 2 ? 0 : k - 1, j + 1, l)] = 1;
      }
      if (l + 2 < k) open[at(0, (l / 2) % 2 ? 0 : k - 2, l + 1)] = 1;
    }
    std::vector<uint8_t> seed(size_t(k3), 0);
    seed[0] = 1;
    const std::vector<uint8_t> expect = flood_voxels(k, open, seed);
    std::vector<uint64_t> open_rows = to_rows(k, open), region = to_rows(k, seed);
    flood_rows(k, open_rows.data(), region.data());
    EXPECT_EQ(to_voxels(k, region), expect) << k;
  }
}

TEST(VoxelRows, DilateReachesTheSixNeighboursWithinTheCell) {
  for (int k : {1, 3, 24, 64}) {
    const int64_t k3 = int64_t(k) * k * k;
    std::mt19937 rng(static_cast<uint32_t>(k));
    std::vector<uint8_t> v(size_t(k3), 0);
    for (int s = 0; s < 5; ++s) v[size_t(rng() % k3)] = 1;
    v[size_t(k3 - 1)] = 1;  // a corner: nothing wraps to the next row or layer
    std::vector<uint64_t> rows = to_rows(k, v), out(rows.size());
    dilate_rows(k, rows.data(), out.data());
    std::vector<uint8_t> expect(size_t(k3), 0);
    for (int64_t vi = 0; vi < k3; ++vi) {
      if (!v[size_t(vi)]) continue;
      expect[size_t(vi)] = 1;
      each_neighbour(k, vi, [&](int64_t ni) { expect[size_t(ni)] = 1; });
    }
    EXPECT_EQ(to_voxels(k, out), expect) << k;
  }
}

namespace {

// The reference labelling: a stack flood from each unlabelled material voxel in voxel order (the
// cell splitter's before bit rows).
int32_t label_voxels(std::vector<uint8_t>& v, int k, std::vector<int32_t>& size) {
  const int64_t k3 = int64_t(k) * k * k;
  int32_t np = 0;
  std::vector<int64_t> todo;
  for (int64_t start = 0; start < k3; ++start) {
    if (v[size_t(start)] >= 2) continue;
    const uint8_t label = uint8_t(3 + std::min(np, 252));
    ++np;
    if (size.size() < 253) size.push_back(0);
    v[size_t(start)] = label;
    todo.push_back(start);
    while (!todo.empty()) {
      const int64_t vi = todo.back();
      todo.pop_back();
      ++size[label - 3];
      each_neighbour(k, vi, [&](int64_t ni) {
        if (v[size_t(ni)] < 2) {
          v[size_t(ni)] = label;
          todo.push_back(ni);
        }
      });
    }
  }
  return np;
}

}  // namespace

TEST(VoxelRows, PiecesAreLabelledAsByAVoxelByVoxelFlood) {
  // Material (0 enclosed, 1 surface) among air (2) at densities from isolated voxels (hundreds of
  // pieces: the labels past 253 merge) to one piece, and a staircase that turns every row.
  std::mt19937 rng(17);
  int merged = 0;
  for (int k : {1, 4, 13, 24, 64})
    for (double density : {0.02, 0.15, 0.3116, 0.6, 1.0}) {
      const int64_t k3 = int64_t(k) * k * k;
      std::vector<uint8_t> v(static_cast<size_t>(k3));
      std::bernoulli_distribution material(density);
      for (auto& x : v) x = material(rng) ? uint8_t(rng() % 2) : uint8_t(2);
      std::vector<uint8_t> expect = v;
      std::vector<int32_t> size, expect_size;
      const int32_t np = label_pieces(v.data(), k, size), expect_np = label_voxels(expect, k, expect_size);
      EXPECT_EQ(np, expect_np) << k << " " << density;
      EXPECT_EQ(size, expect_size) << k << " " << density;
      EXPECT_EQ(v, expect) << k << " " << density;
      merged += np > 253;
    }
  EXPECT_GE(merged, 3);        // some cells had more pieces than labels
  for (int k : {8, 24, 64}) {  // a staircase: up one row (y), back one layer (z), ...
    const int64_t k3 = int64_t(k) * k * k;
    std::vector<uint8_t> v(static_cast<size_t>(k3), 2);
    int j = 0, l = k - 1;
    for (int step = 0; j < k && l >= 0; ++step) {
      v[size_t(k / 2 + k * (j + int64_t(k) * l))] = 0;
      (step % 2 ? l : j) += step % 2 ? -1 : 1;
    }
    std::vector<uint8_t> expect = v;
    std::vector<int32_t> size, expect_size;
    EXPECT_EQ(label_pieces(v.data(), k, size), label_voxels(expect, k, expect_size)) << k;
    EXPECT_EQ(size, expect_size) << k;
    EXPECT_EQ(size.size(), 1u) << k;
    EXPECT_EQ(v, expect) << k;
  }
}
