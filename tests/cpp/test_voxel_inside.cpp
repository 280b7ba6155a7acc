// The voxels' inside test (voxel_inside.h): six ray-parity votes per voxel, parity per part.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R VoxelInside
#include <gtest/gtest.h>
#include <larap/mesh.h>

#include <algorithm>
#include <numeric>

#include "mesh_parts.h"
#include "test_meshes.h"
#include "voxel_inside.h"

using namespace larap;

namespace {

constexpr int kRes = 12;  // voxels per cell edge

// Votes of the voxels of the unit cell at `corner`: each axis's row of cells through it, with
// every triangle offered to it (the cell is the row's cell 2, to read crossings below the row's
// origin too).
std::vector<uint8_t> votes_of(const PolygonMesh& m, const Eigen::Vector3d& corner) {
  const std::vector<Eigen::Vector3i> tris = triangulate(m);
  std::vector<int32_t> all(tris.size());
  std::iota(all.begin(), all.end(), 0);
  const std::vector<int32_t> parts = mesh_parts(m);
  std::vector<uint8_t> votes(size_t(kRes) * kRes * kRes, 0);
  for (int a = 0; a < 3; ++a) {
    Eigen::Vector3d origin = corner;
    origin[a] -= 2.0;
    RowRays rays(a, origin, 1.0 / kRes, kRes);
    rays.cross(all.data(), all.size(), m.vertices, tris, parts);
    EXPECT_LE(int64_t(rays.crossings_found()), rays.max_crossings(all.data(), all.size(), m.vertices, tris));
    rays.votes(2, [&](int64_t vi, int n) { votes[size_t(vi)] = uint8_t(votes[size_t(vi)] + n); });
  }
  return votes;
}

Eigen::Vector3d centre(const Eigen::Vector3d& corner, int64_t vi) {
  const int i = int(vi % kRes), j = int((vi / kRes) % kRes), l = int(vi / (kRes * kRes));
  return corner + (Eigen::Vector3d(i, j, l) + Eigen::Vector3d::Constant(0.5)) / kRes;
}

// The box lo..hi without the faces whose corners all have coordinate `axis` at one of `at`.
PolygonMesh box_without(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int axis,
                        std::vector<double> at) {
  PolygonMesh m = gen::box(lo, hi);
  PolygonMesh o;
  o.vertices = m.vertices;
  o.face_offsets = {0};
  for (int64_t f = 0; f < m.num_faces(); ++f) {
    const double x = m.vertices(m.face_indices[m.face_offsets[f]], axis);
    bool drop = std::find(at.begin(), at.end(), x) != at.end();
    for (int64_t q = m.face_offsets[f]; q < m.face_offsets[f + 1]; ++q)
      drop = drop && m.vertices(m.face_indices[q], axis) == x;
    if (drop) continue;
    for (int64_t q = m.face_offsets[f]; q < m.face_offsets[f + 1]; ++q)
      o.face_indices.push_back(m.face_indices[q]);
    o.face_offsets.push_back(int64_t(o.face_indices.size()));
  }
  return o;
}

// A box without its +z face: open on top.
PolygonMesh open_box(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  return box_without(lo, hi, 2, {hi.z()});
}

// An open square tube along x (four side walls, no ends), inner half-width r around (y, z) = c.
PolygonMesh square_sleeve(double x0, double x1, double c, double r) {
  return box_without({x0, c - r, c - r}, {x1, c + r, c + r}, 0, {x0, x1});
}

}  // namespace

TEST(VoxelInside, AClosedBoxGivesSixVotesInsideAndNoneOutside) {
  // The cell straddles the box's corner; its faces cut through voxels at 0.37 and 0.5 + 1/24
  // (a plane of voxel centres: the rays' jitter keeps the x and z rays off the face, while a
  // voxel centred on it may count the face on either side of itself along y: 0 or 2 votes from
  // y, outside either way).
  const Eigen::Vector3d corner(3, 3, 3);
  const double top = 3.5 + 1.0 / 24;
  const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::box({0.5, 0.5, 0.5}, {3.37, top, 3.6})});
  const std::vector<uint8_t> v = votes_of(m, corner);
  int on_face = 0;
  for (int64_t vi = 0; vi < int64_t(v.size()); ++vi) {
    const Eigen::Vector3d p = centre(corner, vi);
    const bool inside = p.x() < 3.37 && p.y() < top - 1e-9 && p.z() < 3.6;
    if (std::abs(p.y() - top) < 1e-9 && p.x() < 3.37 && p.z() < 3.6) {
      EXPECT_TRUE(v[size_t(vi)] == 0 || v[size_t(vi)] == 2) << vi;
      ++on_face;
    } else {
      EXPECT_EQ(v[size_t(vi)], inside ? 6 : 0) << vi;
    }
  }
  EXPECT_EQ(on_face, 4 * 7);
}

TEST(VoxelInside, AHoleLetsOneRayOut) {
  // A box open on top: voxels inside it get 5 votes (the +z ray leaves through the opening), so
  // they are inside; voxels above it, inside its walls, one (the bottom below them).
  const Eigen::Vector3d corner(1, 1, 1);
  const std::vector<uint8_t> v = votes_of(open_box({0.2, 0.2, 0.2}, {2.8, 2.8, 1.55}), corner);
  for (int64_t vi = 0; vi < int64_t(v.size()); ++vi) {
    const bool below = centre(corner, vi).z() < 1.55;
    EXPECT_EQ(v[size_t(vi)], below ? 5 : 1) << vi;  // above: the bottom is below it
    if (below) EXPECT_GE(v[size_t(vi)], kInsideVotes);
  }
}

TEST(VoxelInside, TheGapInAnOpenSleeveIsNotInside) {
  // A closed bar inside an open sleeve (separate parts) along x, through the whole cell: the gap
  // between them is crossed an odd number of times (by the sleeve) only along y and z: 4 votes.
  const Eigen::Vector3d corner(2, 0, 0);
  const PolygonMesh m =
      gen::concat({square_sleeve(0.0, 5.0, 0.5, 0.45), gen::box({0.0, 0.2, 0.2}, {5.0, 0.8, 0.8})});
  const std::vector<uint8_t> v = votes_of(m, corner);
  int gap = 0;
  for (int64_t vi = 0; vi < int64_t(v.size()); ++vi) {
    const Eigen::Vector3d p = centre(corner, vi);
    const double d = std::max(std::abs(p.y() - 0.5), std::abs(p.z() - 0.5));
    if (d < 0.3)
      EXPECT_EQ(v[size_t(vi)], 6) << vi;  // in the bar
    else if (d < 0.45) {
      EXPECT_EQ(v[size_t(vi)], 4) << vi;  // the gap: not inside
      EXPECT_LT(v[size_t(vi)], kInsideVotes);
      ++gap;
    } else {
      EXPECT_EQ(v[size_t(vi)], 0) << vi;
    }
  }
  EXPECT_GT(gap, 100);
}

TEST(VoxelInside, PartsAreCountedApart) {
  // A small closed box inside a large one (separate parts): a voxel inside both is crossed twice
  // along every ray in all, which a parity over the whole mesh would call outside; each part's
  // own parity calls it inside.
  const Eigen::Vector3d corner(1, 1, 1);
  const PolygonMesh m =
      gen::concat({gen::box({0.0, 0.0, 0.0}, {3.0, 3.0, 3.0}), gen::box({1.2, 1.2, 1.2}, {1.8, 1.8, 1.8})});
  const std::vector<uint8_t> v = votes_of(m, corner);
  for (int64_t vi = 0; vi < int64_t(v.size()); ++vi) EXPECT_EQ(v[size_t(vi)], 6) << vi;
}

TEST(VoxelInside, RaysThroughSharedEdgesCountOnce) {
  // A box whose faces (off the voxel centres' planes) are cut into quads along the voxel centres'
  // lines, as a soup: every ray meets the faces across it at an edge or a vertex, passing it a
  // millionth of a voxel aside (the jitter), so it crosses exactly one quad per face.
  const std::vector<double> ticks = {1.02,           1 + 1.5 / kRes, 1 + 2.5 / kRes, 1 + 3.5 / kRes,
                                     1 + 4.5 / kRes, 1 + 5.5 / kRes, 1 + 6.5 / kRes, 1.58};
  const double lo = ticks.front(), hi = ticks.back();
  const int n = int(ticks.size()) - 1;
  PolygonMesh m;
  std::vector<Eigen::Vector3d> P;
  m.face_offsets = {0};
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side)
      for (int a = 0; a < n; ++a)
        for (int b = 0; b < n; ++b) {
          const int u = (axis + 1) % 3, w = (axis + 2) % 3;
          for (int c = 0; c < 4; ++c) {  // outward: counter-clockwise seen from outside
            const int da = (c == 1 || c == 2), db = (c >= 2);
            Eigen::Vector3d p;
            p[axis] = side ? hi : lo;
            p[u] = ticks[size_t(a + (side ? da : db))];
            p[w] = ticks[size_t(b + (side ? db : da))];
            P.push_back(p);
            m.face_indices.push_back(int64_t(P.size()) - 1);
          }
          m.face_offsets.push_back(int64_t(m.face_indices.size()));
        }
  m.vertices.resize(int64_t(P.size()), 3);
  for (size_t i = 0; i < P.size(); ++i) m.vertices.row(int64_t(i)) = P[i].transpose();
  const Eigen::Vector3d corner(1, 1, 1);
  const std::vector<uint8_t> v = votes_of(m, corner);
  int inside = 0;
  for (int64_t vi = 0; vi < int64_t(v.size()); ++vi) {
    const Eigen::Vector3d p = centre(corner, vi);
    const bool in = (p.array() > lo).all() && (p.array() < hi).all();
    inside += in;
    EXPECT_EQ(v[size_t(vi)], in ? 6 : 0) << vi;
  }
  EXPECT_EQ(inside, 7 * 7 * 7);
}

TEST(VoxelInside, EveryCellOfARowReadsItsOwnVotes) {
  // One row along x through an open-topped box four cells long, its crossings found once: each
  // cell's votes are those of a row that starts at that cell.
  const PolygonMesh m = open_box({0.3, 0.1, 0.2}, {3.7, 0.9, 0.75});
  const std::vector<Eigen::Vector3i> tris = triangulate(m);
  std::vector<int32_t> all(tris.size());
  std::iota(all.begin(), all.end(), 0);
  const std::vector<int32_t> parts = mesh_parts(m);
  RowRays row(0, {0, 0, 0}, 1.0 / kRes, kRes);
  row.cross(all.data(), all.size(), m.vertices, tris, parts);
  int voted = 0;
  for (int cell = 0; cell < 4; ++cell) {
    RowRays own(0, {double(cell), 0, 0}, 1.0 / kRes, kRes);
    own.cross(all.data(), all.size(), m.vertices, tris, parts);
    std::vector<int> mine(size_t(kRes) * kRes * kRes, 0), theirs(mine.size(), 0);
    row.votes(cell, [&](int64_t vi, int n) { mine[size_t(vi)] = n; });
    own.votes(0, [&](int64_t vi, int n) { theirs[size_t(vi)] = n; });
    EXPECT_EQ(mine, theirs) << cell;
    for (int n : mine) voted += n == 2;
  }
  EXPECT_GT(voted, 1000);  // inside the box, along x, both directions vote
}

TEST(VoxelInside, ADuplicatedFaceCountsOnce) {
  // A closed box with one face listed twice, the same way round: the rays through it meet two
  // triangles at one point, one crossing, so the box stays inside (twice would make it even).
  PolygonMesh m = gen::box({0.3, 0.3, 0.3}, {2.7, 2.7, 2.7});
  for (int64_t q = m.face_offsets[0]; q < m.face_offsets[1]; ++q) m.face_indices.push_back(m.face_indices[q]);
  m.face_offsets.push_back(int64_t(m.face_indices.size()));
  const std::vector<uint8_t> v = votes_of(m, {1, 1, 1});
  for (int64_t vi = 0; vi < int64_t(v.size()); ++vi) EXPECT_EQ(v[size_t(vi)], 6) << vi;
}

TEST(VoxelInside, AWallBetweenBoxesJoinedFaceToFaceCountsTwice) {
  // Three boxes along x joined face to face (one part: their corners coincide): each inner wall is
  // two faces at one place facing opposite ways, an exit and an entry, so the middle box is inside.
  const PolygonMesh m =
      gen::concat({gen::box({-1.0, 0.2, 0.2}, {1.0, 2.8, 2.8}), gen::box({1.0, 0.2, 0.2}, {2.0, 2.8, 2.8}),
                   gen::box({2.0, 0.2, 0.2}, {4.0, 2.8, 2.8})});
  const std::vector<int32_t> parts = mesh_parts(m);
  ASSERT_TRUE(std::all_of(parts.begin(), parts.end(), [&](int32_t p) { return p == parts[0]; }));
  const std::vector<uint8_t> v = votes_of(m, {1, 1, 1});
  for (int64_t vi = 0; vi < int64_t(v.size()); ++vi) EXPECT_EQ(v[size_t(vi)], 6) << vi;
}
