// Cell splitting (cell_pieces, surface_patches, the split lattice's assembly) and the stencil
// shell: the fast candidate search against testing every triangle against every cell, pieces of
// generated shapes inside one cell, the plain lattice where nothing needs splitting, and the
// shell's exact affine reproduction on a split lattice.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R 'SurfacePatches|CellPieces|StencilShell'
#include <gtest/gtest.h>
#include <larap/lattice.h>

#include <algorithm>
#include <array>
#include <numeric>
#include <random>
#include <set>

#include "cell_pieces.h"
#include "geometry.h"
#include "mesh_parts.h"
#include "parallel.h"
#include "surface_patches.h"
#include "test_meshes.h"
#include "voxel_grid.h"

using namespace larap;

namespace {

// --------------------------------------------------------------------- the plain reference
// Every triangle against every cell of its range (one-cell ranges without a test, as the builder
// does); any two neighbouring cells a triangle overlaps share it; a cell's triangles joined where
// they meet inside it: at a shared vertex in the cell's closed box, or along a shared edge that
// overlaps the box.
struct Reference {
  std::vector<std::vector<int32_t>> tris;  // per surface cell, ascending
  std::vector<uint32_t> shares;
  std::vector<uint8_t> several;
};

Reference reference(const Grid& g, const SurfacePatches& sp, const RowMatrixX3d& V,
                    const std::vector<Eigen::Vector3i>& tris) {
  const size_t ns = sp.cells.size();
  Reference r{std::vector<std::vector<int32_t>>(ns), std::vector<uint32_t>(ns, 0), std::vector<uint8_t>(ns, 0)};
  const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * g.h * (1.0 + 1e-9));
  std::vector<Eigen::Vector3d> centres(ns);
  for (size_t t = 0; t < tris.size(); ++t) {
    const Eigen::Vector3d a = V.row(tris[t][0]), b = V.row(tris[t][1]), c = V.row(tris[t][2]);
    const Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c), hi = a.cwiseMax(b).cwiseMax(c);
    Eigen::Vector3i c0, c1;
    for (int q = 0; q < 3; ++q) {
      c0[q] = std::max(0, int(std::floor((lo[q] - g.origin[q]) / g.h - 1e-7)));
      c1[q] = std::min(g.dims[q] - 1, int(std::floor((hi[q] - g.origin[q]) / g.h + 1e-7)));
    }
    std::vector<std::pair<int32_t, Eigen::Vector3i>> seen;
    for (int z = c0.z(); z <= c1.z(); ++z)
      for (int y = c0.y(); y <= c1.y(); ++y)
        for (int x = c0.x(); x <= c1.x(); ++x) {
          const int32_t s = sp.surf_of[size_t(g.index(x, y, z))];
          if (s < 0) continue;
          const Eigen::Vector3d centre = g.origin + g.h * Eigen::Vector3d(x + 0.5, y + 0.5, z + 0.5);
          if (c0 != c1 && !geometry::triangle_box_overlap(centre, half, a, b, c)) continue;
          r.tris[size_t(s)].push_back(int32_t(t));
          centres[size_t(s)] = centre;
          seen.emplace_back(s, Eigen::Vector3i(x, y, z));
        }
    for (const auto& [si, ci] : seen)
      for (const auto& [sj, cj] : seen) {
        const Eigen::Vector3i o = cj - ci;
        if (si != sj && o.cwiseAbs().maxCoeff() <= 1) r.shares[size_t(si)] |= 1u << offset_bit(o);
      }
  }
  for (size_t s = 0; s < ns; ++s) {
    const auto& list = r.tris[s];
    const Eigen::Vector3d& centre = centres[s];
    std::vector<int> parent(list.size());
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&](int x) {
      while (parent[size_t(x)] != x) x = parent[size_t(x)] = parent[size_t(parent[size_t(x)])];
      return x;
    };
    for (size_t i = 0; i < list.size(); ++i)
      for (size_t j = i + 1; j < list.size(); ++j) {
        std::vector<int32_t> common;
        for (int p = 0; p < 3; ++p)
          for (int q = 0; q < 3; ++q)
            if (tris[list[i]][p] == tris[list[j]][q]) common.push_back(tris[list[i]][p]);
        bool meet = false;
        for (int32_t v : common)
          meet = meet || ((V.row(v).transpose() - centre).cwiseAbs().array() <= half.array()).all();
        for (size_t p = 0; p < common.size(); ++p)
          for (size_t q = p + 1; q < common.size(); ++q) {
            const Eigen::Vector3d pa = V.row(common[p]), pb = V.row(common[q]);
            meet = meet || geometry::triangle_box_overlap(centre, half, pa, pb, pb);
          }
        if (meet) parent[size_t(find(int(i)))] = find(int(j));
      }
    int roots = 0;
    for (size_t i = 0; i < list.size(); ++i) roots += find(int(i)) == int(i);
    r.several[s] = roots > 1;
  }
  return r;
}

// Runs the fast search and the reference on `mesh` at cell size h; returns the candidates found.
int64_t expect_same_patches(const PolygonMesh& mesh, double h) {
  const std::vector<Eigen::Vector3i> tris = triangulate(mesh);
  const Eigen::Vector3d lo = mesh.vertices.colwise().minCoeff().transpose();
  const Eigen::Vector3d hi = mesh.vertices.colwise().maxCoeff().transpose();
  const Grid g = voxelize(mesh, tris, {}, lo, hi, h, int64_t(1) << 32);
  const SurfacePatches sp = find_surface_patches(g.origin, g.h, g.dims, g.marks, mesh.vertices, tris);
  const Reference r = reference(g, sp, mesh.vertices, tris);
  std::vector<int32_t> all(sp.cells.size());
  std::iota(all.begin(), all.end(), 0);
  std::vector<int32_t> offsets, ids;
  triangles_of(sp, tris, all, offsets, ids);
  int64_t several = 0, listed = 0;
  for (size_t s = 0; s < sp.cells.size(); ++s) {
    const std::vector<int32_t> mine(ids.begin() + offsets[s], ids.begin() + offsets[s + 1]);
    EXPECT_EQ(mine, r.tris[s]) << "triangles of surface cell " << s;
    EXPECT_EQ(sp.shares[s], r.shares[s]) << "neighbours of surface cell " << s;
    EXPECT_EQ(sp.several[s], r.several[s]) << "patches of surface cell " << s;
    several += sp.several[s];
    listed += int64_t(mine.size());
  }
  EXPECT_GE(listed, int64_t(tris.size()));  // every triangle overlaps some surface cell
  return several;
}

PolygonMesh soup_of(const PolygonMesh& m, unsigned seed) {
  const std::vector<Eigen::Vector3i> tris = triangulate(m);
  std::vector<size_t> order(tris.size());
  std::iota(order.begin(), order.end(), size_t(0));
  std::shuffle(order.begin(), order.end(), std::mt19937(seed));
  PolygonMesh s;
  s.vertices.resize(int64_t(3 * tris.size()), 3);
  for (size_t k = 0; k < order.size(); ++k) {
    for (int q = 0; q < 3; ++q) {
      s.vertices.row(int64_t(3 * k + q)) = m.vertices.row(tris[order[k]][q]);
      s.face_indices.push_back(int64_t(3 * k + q));
    }
    s.face_offsets.push_back(static_cast<int64_t>(s.face_indices.size()));
  }
  return s;
}

PolygonMesh random_triangles(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 3.0);
  std::normal_distribution<double> jitter(0.0, 0.2);
  PolygonMesh m;
  m.vertices.resize(3 * n, 3);
  for (int t = 0; t < n; ++t) {
    const Eigen::Vector3d c(u(rng), u(rng), u(rng));
    for (int q = 0; q < 3; ++q) {
      m.vertices.row(3 * t + q) = (c + Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng))).transpose();
      m.face_indices.push_back(3 * t + q);
    }
    m.face_offsets.push_back(static_cast<int64_t>(m.face_indices.size()));
  }
  return m;
}

PolygonMesh triangles_of_points(const std::vector<Eigen::Vector3d>& P, const std::vector<std::array<int, 3>>& T) {
  PolygonMesh m;
  m.vertices.resize(int64_t(P.size()), 3);
  for (size_t i = 0; i < P.size(); ++i) m.vertices.row(int64_t(i)) = P[i].transpose();
  m.face_offsets = {0};
  for (const auto& t : T) {
    m.face_indices.insert(m.face_indices.end(), t.begin(), t.end());
    m.face_offsets.push_back(int64_t(m.face_indices.size()));
  }
  return m;
}

// Joined triangles on a lattice of whole and near-whole coordinates (on cell faces, and 5e-10 to
// 2e-7 off them, on either side), with repeated vertices and duplicate triangles.
PolygonMesh joined_near_faces(std::mt19937& rng) {
  const double offs[] = {0, 0.5, 1e-8, -1e-8, 1e-10, -1e-10, 2e-7, -2e-7, 0.3, 0.7, 5e-10, -5e-10, 0.999999};
  const int nv = 4 + int(rng() % 10);
  std::vector<Eigen::Vector3d> P{Eigen::Vector3d::Zero()};
  for (int v = 0; v < nv; ++v) {
    Eigen::Vector3d p;
    for (int a = 0; a < 3; ++a) p[a] = double(rng() % 5) + offs[rng() % 13];
    P.push_back(p);
  }
  std::vector<std::array<int, 3>> T;
  for (int t = 0, nt = 2 + int(rng() % 20); t < nt; ++t) {
    std::array<int, 3> tri;
    for (int k = 0; k < 3; ++k) tri[k] = 1 + int(rng() % nv);
    if (rng() % 10 == 0) tri[2] = tri[0];
    if (rng() % 10 == 0 && !T.empty()) tri = T[rng() % T.size()];
    T.push_back(tri);
  }
  return triangles_of_points(P, T);
}

// The cell size at which the default lattice of a 1M-vertex torus (1414 x 707) is built.
constexpr double kTorusCell = 0.09474523806783858;

void expect_same_lattice(const Lattice& a, const Lattice& b) {
  EXPECT_EQ(a.cell_coords, b.cell_coords);
  EXPECT_EQ(a.cell_nodes, b.cell_nodes);
  EXPECT_EQ(a.node_coords, b.node_coords);
  EXPECT_EQ(a.edges, b.edges);
  EXPECT_EQ(a.real_nodes, b.real_nodes);
  EXPECT_EQ(a.vertex_cell, b.vertex_cell);
  EXPECT_EQ(a.stencil27, b.stencil27);
  EXPECT_EQ(a.shell_ids, b.shell_ids);
  EXPECT_EQ(a.shell_weights, b.shell_weights);
}

Lattice build(const PolygonMesh& m, double h, bool split) {
  LatticeOptions opt;
  opt.cell_size = h;
  opt.split_cells = split;
  return Lattice::build(m, opt);
}

}  // namespace

// --------------------------------------------------------------------- surface patches
TEST(SurfacePatches, SameAsEveryTriangleAgainstEveryCell) {
  // A fine torus (about 50 triangles inside each surface cell), a coarse one at the 1M torus's
  // cell size, and one at cells smaller than its triangles.
  expect_same_patches(gen::torus(1.0, 0.35, 400, 200), kTorusCell);
  const PolygonMesh torus = gen::torus(1.0, 0.35, 120, 60);
  expect_same_patches(torus, kTorusCell);
  expect_same_patches(torus, 0.02);
  // Triangles far larger than a cell; vertices exactly on cell faces (a box from its corner).
  expect_same_patches(gen::box({0, 0, 0}, {1, 1, 1}), 0.1);
  expect_same_patches(gen::box({0, 0, 0}, {1, 1, 1}), 0.25);
  // Soups and scattered triangles: cells with several patches.
  EXPECT_GT(expect_same_patches(soup_of(gen::sphere({0, 0, 0}, 1.0, 16, 32), 3), 0.2), 20);
  EXPECT_GT(expect_same_patches(random_triangles(300, 5), 0.3), 20);
  // Two triangles that share only a vertex 1e-8 inside a cell face (in no cell's inside, so met
  // only through the box test): one patch in that cell.
  EXPECT_EQ(expect_same_patches(triangles_of_points({{0, 0, 0}, {1 - 1e-8, 1.5, 1.5}, {0.2, 1.2, 1.1}, {0.3, 1.8, 1.2},
                                                     {0.2, 1.2, 1.9}, {0.3, 1.8, 1.8}},
                                                    {{1, 2, 3}, {1, 4, 5}}),
                                1.0),
            0);
  // Joined triangles with vertices on and next to cell faces, repeated vertices, duplicates.
  std::mt19937 rng(12345);
  for (int i = 0; i < 300; ++i) expect_same_patches(joined_near_faces(rng), 1.0);
  // Far from zero (beyond a million cells): every triangle takes the plain path.
  PolygonMesh far = gen::sphere({0, 0, 0}, 1.0, 12, 24);
  far.vertices.col(0).array() += 3e6 * 0.2;
  expect_same_patches(far, 0.2);
}

TEST(SurfacePatches, LargeTrianglesMeetingInsideACellAreOnePatch) {
  // A box of 12 triangles, 60 cells long and 1.8 cells thick: each of its cells holds pieces of
  // two or three faces whose shared vertices lie cells away, but which meet along the box's
  // edges inside the cell. No cell holds two patches, every two neighbouring cells share a
  // triangle (however many cells it spans), so no cell is analysed: the plain lattice, unweighted.
  const PolygonMesh m = gen::box({0.05, 0.55, 0.55}, {29.95, 1.45, 1.45});
  const double h = 0.5;
  const std::vector<Eigen::Vector3i> tris = triangulate(m);
  const Grid g = voxelize(m, tris, {}, m.vertices.colwise().minCoeff().transpose(),
                          m.vertices.colwise().maxCoeff().transpose(), h, int64_t(1) << 32);
  const CellPieces pieces = find_cell_pieces(g.origin, g.h, g.dims, g.marks, m.vertices, tris, mesh_parts(m),
                                             g.vertex_cells, 24);
  EXPECT_EQ(pieces.cells.size(), 0u);
  expect_same_lattice(build(m, h, true), build(m, h, false));
}

TEST(SurfacePatches, LargeTrianglesMeetingOnlyBeyondTheCellAreTwoPatches) {
  // A wedge of four large triangles in one row of cells (z in [2, 3)): two sheets that share
  // their fold at x = 12.95 and open to 0.6 cells apart at x = 1.05. Inside a cell of the row the
  // sheets do not meet (only at the fold, cells away), so the cell holds two patches and, where
  // the air between the sheets reaches, two pieces: the cells from x = 1 to 9, where the sheets
  // are 0.2 to 0.6 cells apart, are split in two.
  PolygonMesh wedge;
  wedge.vertices.resize(6, 3);
  wedge.vertices << 1.05, 1.1, 2.05,  // lower sheet at z = 2.05
      12.95, 1.1, 2.05, 12.95, 2.9, 2.05, 1.05, 2.9, 2.05,
      1.05, 1.1, 2.65, 1.05, 2.9, 2.65;  // the upper sheet's open end at z = 2.65
  wedge.face_offsets = {0};
  for (const auto& t : {std::array<int, 3>{0, 1, 2}, {0, 2, 3}, {1, 4, 2}, {2, 4, 5}}) {
    wedge.face_indices.insert(wedge.face_indices.end(), t.begin(), t.end());
    wedge.face_offsets.push_back(int64_t(wedge.face_indices.size()));
  }
  const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), wedge});
  const Lattice lat = build(m, 1.0, true);
  for (int x = 3; x <= 10; ++x)  // grid index = coordinate + 2
    for (int y : {3, 4}) EXPECT_EQ(lat.cell_copies(x, y, 4), 2) << "cell (" << x << ", " << y << ", 4)";
  // The patches themselves: two in each cell of the open part of the row, one where the fold is.
  const std::vector<Eigen::Vector3i> tris = triangulate(m);
  const Grid g = voxelize(m, tris, {}, m.vertices.colwise().minCoeff().transpose(),
                          m.vertices.colwise().maxCoeff().transpose(), 1.0, int64_t(1) << 32);
  const SurfacePatches sp = find_surface_patches(g.origin, g.h, g.dims, g.marks, m.vertices, tris);
  auto several_at = [&](double x, double y) {
    const Eigen::Vector3i c = g.cell_of(Eigen::Vector3d(x, y, 2.5));
    const int32_t s = sp.surf_of[size_t(g.index(c.x(), c.y(), c.z()))];
    return s >= 0 && sp.several[size_t(s)];
  };
  for (double x = 1.5; x < 10; x += 1.0) EXPECT_TRUE(several_at(x, 1.5)) << x;
  EXPECT_FALSE(several_at(12.5, 1.5));
}

// --------------------------------------------------------------------- pieces of one cell
// Two slabs 0.8 x 0.8 x 0.2, 0.1 apart, inside grid cell (3,3,3): a loose vertex at the origin
// puts the grid's cell faces on whole numbers (cell size 1, two cells of padding).
TEST(CellPieces, TwoSlabsInOneCellAreTwoCopiesSharingNoNode) {
  const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::box({1.1, 1.1, 1.2}, {1.9, 1.9, 1.4}),
                                     gen::box({1.1, 1.1, 1.5}, {1.9, 1.9, 1.7})});
  const Lattice lat = build(m, 1.0, true);
  ASSERT_EQ(lat.cell_at(3, 3, 3), 1);  // the loose vertex's cell (2,2,2) first
  ASSERT_EQ(lat.cell_copies(3, 3, 3), 2);
  const auto& a = lat.cell_nodes[1];
  const auto& b = lat.cell_nodes[2];
  for (int32_t n : a) EXPECT_EQ(std::count(b.begin(), b.end(), n), 0);
  EXPECT_EQ(lat.num_components, 3);
  // Each slab's vertices bind to their own copy.
  for (int v = 1; v <= 8; ++v) EXPECT_EQ(lat.vertex_cell[v], lat.vertex_cell[1]);
  for (int v = 9; v <= 16; ++v) EXPECT_EQ(lat.vertex_cell[v], lat.vertex_cell[9]);
  EXPECT_NE(lat.vertex_cell[1], lat.vertex_cell[9]);
  // Each copy weighs its slab's share of the cell: 0.8 x 0.8 x 0.2 = 0.128, plus the voxels its
  // surface only touches (at most one more voxel layer around it: 22 x 22 x 7 / 24^3 = 0.245); the
  // whole cell of the loose vertex weighs 1; an edge of a slab's copy belongs to it alone, so it
  // weighs half the copy's weight (the energy sums each copy's 12 edges; lattice.h).
  ASSERT_FALSE(lat.cell_weight.empty());
  EXPECT_EQ(lat.cell_weight[0], 1.0);
  for (int c : {1, 2}) {
    EXPECT_GE(lat.cell_weight[c], 0.128) << c;
    EXPECT_LE(lat.cell_weight[c], 0.245) << c;
  }
  for (size_t e = 0; e < lat.edges.size(); ++e) {
    const int32_t i = lat.edges[e][0];
    const int copy = std::count(a.begin(), a.end(), i) ? 1 : std::count(b.begin(), b.end(), i) ? 2 : 0;
    EXPECT_EQ(lat.edge_weight[e], 0.5 * lat.cell_weight[copy]) << e;
  }
  // Without splitting the cell is kept once, and every cell weighs 1.
  const Lattice plain = build(m, 1.0, false);
  EXPECT_EQ(plain.cell_copies(3, 3, 3), 1);
  EXPECT_TRUE(plain.cell_weight.empty());
}

// Two slabs of separate mesh parts in one cell, 0.6 x 0.6 and 0.5 x 0.5 wide (so that no corners
// coincide, which would make them one part), 0.15 thick and `gap` apart across their faces, turned
// `degrees` about the x axis through the cell's centre (cell (3,3,3), as above).
PolygonMesh turned_slabs(double gap, double degrees, double shift = 0.0) {
  PolygonMesh m = gen::concat({gen::box({1.2, 1.2, 1.5 + shift - 0.5 * gap - 0.15}, {1.8, 1.8, 1.5 + shift - 0.5 * gap}),
                               gen::box({1.25, 1.25, 1.5 + shift + 0.5 * gap}, {1.75, 1.75, 1.5 + shift + 0.5 * gap + 0.15})});
  const Eigen::Matrix3d R = Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Eigen::RowVector3d centre(1.5, 1.5, 1.5);
  for (int64_t v = 0; v < m.vertices.rows(); ++v)
    m.vertices.row(v) = (m.vertices.row(v) - centre) * R.transpose() + centre;
  return gen::concat({gen::point({0, 0, 0}), m});
}

TEST(CellPieces, SeparatePartsAtAnAngleSeparateCloserThanOnePart) {
  // Surfaces of different parts separate when no voxel, grown by an eighth of a voxel to every
  // side, meets both and no enclosed voxel lies between them: here 0.085 cells apart (1.5 |n|_1 h /
  // k at k = 24, |n|_1 = 1.37), where surfaces of one part may merge up to 2 |n|_1 h / k (0.114
  // cells). Fingers a tenth of a cell apart at an angle are two copies.
  for (double shift : {0.0, 0.013, 0.027}) {
    const Lattice lat = build(turned_slabs(0.085, 30.0, shift), 1.0, true);
    ASSERT_EQ(lat.cell_at(3, 3, 3), 1) << shift;
    EXPECT_EQ(lat.cell_copies(3, 3, 3), 2) << shift;
    EXPECT_NE(lat.vertex_cell[1], lat.vertex_cell[9]) << shift;
  }
}

TEST(CellPieces, PartsACrackApartOrTouchingStayOneCopy) {
  // A crack narrower than a quarter voxel (0.0104 cells) between two parts never falls between
  // two voxels, wherever it lies across a voxel and at any angle; slabs that touch are one piece.
  for (double degrees : {0.0, 30.0, 45.0})
    for (int j = 0; j < 8; ++j) {
      const double shift = j / (24.0 * 8.0);  // across one voxel
      for (double gap : {0.0, 0.004, 0.0099}) {
        const Lattice lat = build(turned_slabs(gap, degrees, shift), 1.0, true);
        ASSERT_EQ(lat.cell_at(3, 3, 3), 1);
        EXPECT_EQ(lat.cell_copies(3, 3, 3), 1) << degrees << " degrees, shift " << shift << ", gap " << gap;
        EXPECT_EQ(lat.vertex_cell[1], lat.vertex_cell[9]);
      }
    }
}

TEST(CellPieces, PartsACrackApartOnACellFaceStayJoined) {
  // The crack lies on the cell face z = 3, so each side's triangles are in one cell only: the
  // link across the face looks for the other cell's triangles in the grown voxel. A small box in
  // each cell makes both cells analysed (two patches each).
  const std::pair<double, double> cracks[] = {{1e-6, 1e-6}, {0.002, 0.001}, {0.001, 0.004}, {0.005, 0.005}};
  for (const auto& [below, above] : cracks) {
    {
      const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::box({1.2, 1.2, 2.5}, {1.6, 1.6, 3.0 - below}),
                                         gen::box({1.25, 1.25, 3.0 + above}, {1.65, 1.65, 3.5}),
                                         gen::box({1.8, 1.8, 2.2}, {1.9, 1.9, 2.3}),
                                         gen::box({1.8, 1.8, 3.7}, {1.9, 1.9, 3.8})});
      const Lattice lat = build(m, 1.0, true);
      ASSERT_EQ(lat.cell_copies(3, 3, 4), 2);
      // The loose vertex's cell, the two slabs joined, the two small boxes.
      EXPECT_EQ(lat.num_components, 4) << below << " " << above;
    }
  }
}

TEST(CellPieces, AThinPlateLyingOnABodyKeepsItsInside) {
  // A plate of its own part, 0.08 or 0.12 cells thick (2-3 voxels) and wider than the cells, a
  // crack above a body, with or without a rod of a third part pushed half into it: the plate's
  // thin inside stays material and the plate one piece in cell (3, 3, 5): two loose vertices
  // inside it, near its underside and near its top, bind to one copy. (A rule that turned thin
  // enclosed space between parts into air split such plates into top and bottom.)
  for (double gap : {0.01, 0.03})
    for (double thick : {0.08, 0.12})
      for (bool rod : {false, true})
        for (int j = 0; j < 4; ++j) {
          const double bottom = 3.5 + gap + j / 96.0, top = bottom + thick;
          PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::point({1.5, 1.5, bottom + 0.2 * thick}),
                                       gen::point({1.5, 1.5, top - 0.2 * thick}),
                                       gen::box({0.5, 0.5, 0.5}, {4.5, 4.5, 3.5}),
                                       gen::box({0.5, 0.5, bottom}, {4.5, 4.5, top})});
          if (rod) m = gen::concat({m, gen::box({1.7, 1.7, bottom + 0.5 * thick}, {1.9, 1.9, 4.4})});
          const Lattice lat = build(m, 1.0, true);
          EXPECT_EQ(lat.vertex_cell[1], lat.vertex_cell[2]) << gap << " " << thick << " " << rod << " " << j;
        }
}

TEST(CellPieces, UJoinedInsideTheCellIsOneCopy) {
  // The same slabs joined by a wall at their -x end, inside the cell (separate mesh parts that
  // overlap: a soup joint).
  const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::box({1.1, 1.1, 1.2}, {1.9, 1.9, 1.4}),
                                     gen::box({1.1, 1.1, 1.5}, {1.9, 1.9, 1.7}),
                                     gen::box({1.1, 1.1, 1.25}, {1.3, 1.9, 1.65})});
  const Lattice lat = build(m, 1.0, true);
  EXPECT_EQ(lat.cell_copies(3, 3, 3), 1);
  EXPECT_EQ(lat.num_components, 2);
}

TEST(CellPieces, LoneShapesGiveThePlainLattice) {
  const PolygonMesh box = gen::box({0, 0, 0}, {1, 1, 1});
  expect_same_lattice(build(box, 0.1, true), build(box, 0.1, false));
  EXPECT_TRUE(build(box, 0.1, true).cell_weight.empty());  // nothing split: every cell weighs 1
  const PolygonMesh sphere = gen::sphere({0.3, -0.2, 0.1}, 1.0, 24, 48);
  expect_same_lattice(build(sphere, 0.15, true), build(sphere, 0.15, false));
}

TEST(CellPieces, TorusConcaveWallGetsNoGhostNodes) {
  // At this cell size the 2x2x2 block rule analyses cells on the torus's inner wall whose
  // surfaces meet just outside the block; their copies must still share every node.
  const PolygonMesh torus = gen::torus(1.0, 0.35, 120, 60);
  const Lattice split = build(torus, kTorusCell, true), plain = build(torus, kTorusCell, false);
  expect_same_lattice(split, plain);
}

TEST(CellPieces, SameLatticeWhateverTheThreadCount) {
  // The candidate search joins vertices in a union-find shared by the threads, then writes every
  // vertex's root while others read: the lattice must not depend on the schedule. Soups of many
  // small triangles make deep classes (many links per class), where a stale write would show.
  const int before = num_threads();
  const std::vector<std::pair<PolygonMesh, double>> meshes{
      {soup_of(gen::torus(1.0, 0.35, 40, 20), 7), kTorusCell},
      {random_triangles(150, 11), 0.3},
      {gen::torus(1.0, 0.35, 200, 100), kTorusCell}};
  for (const auto& [m, h] : meshes) {
    set_num_threads(1);
    const Lattice one = build(m, h, true);
    for (int n : {2, 8}) {
      set_num_threads(n);
      expect_same_lattice(build(m, h, true), one);
    }
  }
  set_num_threads(before);
}

TEST(CellPieces, AirTravelsAlongAChannelThroughManyCells) {
  // Two slabs of separate parts 0.1 cells apart (two voxels of air at k = 24), walled along
  // their sides and at one end by boxes of their own, L cells long in x: the channel between the
  // slabs opens to the outside only at its other end, and its middle cells (y = 3, 4) hold only
  // the two slabs. Air that reaches the channel's far end separates the slabs in every middle cell
  // but the capped one. Open at the high end, the air travels against the order of the cells
  // (one cell per round of the parallel flood); open at the low end, with it.
  const int L = 12;
  const double x0 = 1.05, x1 = L + 0.95;
  const int before = num_threads();
  for (int threads : {1, 2})
    for (bool open_high : {false, true}) {
      set_num_threads(threads);
      const PolygonMesh cap = open_high ? gen::box({x0, 0.55, 1.2}, {x0 + 0.15, 3.45, 1.8})
                                        : gen::box({x1 - 0.15, 0.55, 1.2}, {x1, 3.45, 1.8});
      const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::box({x0, 0.55, 1.2}, {x1, 3.45, 1.45}),
                                         gen::box({x0, 0.55, 1.55}, {x1, 3.45, 1.8}),
                                         gen::box({x0, 0.55, 1.2}, {x1, 0.7, 1.8}),
                                         gen::box({x0, 3.3, 1.2}, {x1, 3.45, 1.8}), cap});
      const Lattice lat = build(m, 1.0, true);
      const int capped = open_high ? 3 : L + 2;
      for (int x = 3; x <= L + 2; ++x)
        for (int y : {3, 4})
          EXPECT_EQ(lat.cell_copies(x, y, 3), x == capped ? 1 : 2)
              << "cell (" << x << ", " << y << ", 3), open at the " << (open_high ? "high" : "low") << " end, "
              << threads << " threads";
    }
  set_num_threads(before);
}

TEST(CellPieces, SplitCopiesKeepTheirPrivateCorners) {
  // Two slabs 0.1 apart inside one column of cells, joined by a block in the cell below: the
  // column's cells are split in two copies each. The slabs meet only through the block, so the
  // cells of their upper parts share no node (a corner only one copy uses stays its own).
  const PolygonMesh m = gen::concat({gen::point({0, 0, 0}), gen::box({1.1, 1.1, 1.1}, {1.9, 1.9, 2.0}),
                                     gen::box({1.1, 1.1, 2.0}, {1.9, 1.45, 4.9}),
                                     gen::box({1.1, 1.55, 2.0}, {1.9, 1.9, 4.9})});
  const Lattice lat = build(m, 1.0, true);
  std::set<int32_t> a, b;  // nodes of the cells holding each slab's vertices above z = 3
  for (int64_t v = 0; v < m.vertices.rows(); ++v) {
    if (m.vertices(v, 2) < 3.0 - 1e-9) continue;
    const auto& nodes = lat.cell_nodes[size_t(lat.vertex_cell[size_t(v)])];
    (m.vertices(v, 1) < 1.5 ? a : b).insert(nodes.begin(), nodes.end());
  }
  ASSERT_FALSE(a.empty());
  ASSERT_FALSE(b.empty());
  for (int32_t n : a) EXPECT_EQ(b.count(n), 0u) << "node " << n << " shared by both slabs above the block";
}

// --------------------------------------------------------------------- stencil shell
TEST(StencilShell, ReproducesAffineMapsExactlyOnASplitLattice) {
  // A comb: tines 0.1 cells apart joined by a base block, so copies of split cells carry shell
  // nodes of their own.
  std::vector<PolygonMesh> parts{gen::box({-3.0, 0.0, 0.0}, {-0.1, 3.2, 1.0})};
  for (int t = 0; t < 3; ++t) parts.push_back(gen::box({-0.5, 1.1 * t, 0.0}, {6.0, 1.1 * t + 1.0, 1.0}));
  const PolygonMesh comb = gen::concat({parts[0], parts[1], parts[2], parts[3]});
  const Lattice lat = build(comb, 1.0, true);
  int64_t split_cells = 0;
  for (size_t c = 0; c < lat.cell_coords.size(); ++c) {
    const Eigen::Vector3i& x = lat.cell_coords[c];
    split_cells += lat.cell_copies(x.x(), x.y(), x.z()) > 1;
  }
  ASSERT_GT(split_cells, 0);
  ASSERT_GT(lat.num_shell_nodes(), 0);
  Eigen::Matrix3d A;
  A << 1.2, 0.3, -0.1, 0.05, 0.8, 0.4, -0.2, 0.1, 1.1;
  const Eigen::Vector3d t(0.5, -1.0, 2.0);
  RowMatrixX3d P = lat.rest;
  for (int64_t i = 0; i < lat.num_real_nodes(); ++i) P.row(i) = (A * lat.rest.row(i).transpose() + t).transpose();
  P.bottomRows(lat.num_shell_nodes()).setConstant(1e9);  // must be overwritten
  lat.fill_shell(P);
  double worst = 0.0;
  for (int64_t i = lat.num_real_nodes(); i < lat.num_nodes(); ++i)
    worst = std::max(worst, (P.row(i).transpose() - (A * lat.rest.row(i).transpose() + t)).norm());
  EXPECT_LT(worst, 1e-12 * 20.0);  // coordinates up to ~10, a few roundings
  // Weights sum to one per shell node.
  for (int64_t s = 0; s < lat.num_shell_nodes(); ++s) {
    double sum = 0.0;
    for (int32_t e = lat.shell_offsets[s]; e < lat.shell_offsets[s + 1]; ++e) sum += lat.shell_weights[e];
    EXPECT_NEAR(sum, 1.0, 1e-12);
  }
}
