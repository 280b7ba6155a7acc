// The voxels a triangle overlaps in an analysed cell (voxel_hits.h) are exactly those that the
// plain separating-axis test finds on every voxel of the cell: random, grid-snapped, degenerate,
// sliver, far-away and tiny triangles, triangles larger than the cell and tilted, planes through
// or within 1e-17 voxels of a grown voxel's corner; grown and plain voxels, several resolutions,
// with and without skipped voxels.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R VoxelHits
#include <gtest/gtest.h>

#include <random>
#include <set>
#include <vector>

#include "geometry.h"
#include "part_pieces.h"
#include "voxel_hits.h"

using namespace larap;

namespace {

// Every voxel of the cell against the exact test, as the builder did before (grown boxes as
// for_each_voxel_hit grows them).
std::set<int64_t> every_voxel(const Eigen::Vector3d& corner, double hv, int k, const Eigen::Vector3d& a,
                              const Eigen::Vector3d& b, const Eigen::Vector3d& c, double grow) {
  std::set<int64_t> out;
  const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * hv * (1.0 + 2.0 * grow + 1e-9));
  for (int l = 0; l < k; ++l)
    for (int j = 0; j < k; ++j)
      for (int i = 0; i < k; ++i) {
        const Eigen::Vector3d centre = corner + hv * Eigen::Vector3d(i + 0.5, j + 0.5, l + 0.5);
        if (geometry::triangle_box_overlap(centre, half, a, b, c))
          out.insert(i + int64_t(k) * (j + int64_t(k) * l));
      }
  return out;
}

struct Tally {
  int cases = 0, with_hits = 0, partial = 0;  // partial: some but not all of the bounding box hit
};

void expect_same(const Eigen::Vector3d& corner, double hv, int k, const Eigen::Vector3d& a,
                 const Eigen::Vector3d& b, const Eigen::Vector3d& c, double grow, Tally& tally,
                 const char* what) {
  const std::set<int64_t> want = every_voxel(corner, hv, k, a, b, c, grow);
  std::vector<int64_t> got;
  for_each_voxel_hit(
      corner, hv, k, a, b, c, grow, [](int64_t) { return false; }, [&](int64_t vi) { got.push_back(vi); });
  const std::set<int64_t> got_set(got.begin(), got.end());
  ASSERT_EQ(got_set.size(), got.size()) << what << ": a voxel reported twice";
  ASSERT_EQ(got_set, want) << what << " k " << k << " grow " << grow << "\n a " << a.transpose() << "\n b "
                           << b.transpose() << "\n c " << c.transpose() << "\n corner " << corner.transpose()
                           << " hv " << hv;
  // Skipping every third voxel leaves the others.
  std::set<int64_t> kept;
  for_each_voxel_hit(
      corner, hv, k, a, b, c, grow, [](int64_t vi) { return vi % 3 == 0; },
      [&](int64_t vi) { kept.insert(vi); });
  std::set<int64_t> want_kept;
  for (int64_t vi : want)
    if (vi % 3) want_kept.insert(vi);
  ASSERT_EQ(kept, want_kept) << what;
  ++tally.cases;
  tally.with_hits += !want.empty();
  tally.partial += !want.empty() && want.size() < size_t(k) * k * k / 2;
}

}  // namespace

TEST(VoxelHits, SameAsTestingEveryVoxel) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Tally tally;
  for (int k : {4, 7, 24, 64}) {
    for (double grow : {0.0, kContact}) {
      const int rounds = k == 64 ? 90 : 450;
      for (int r = 0; r < rounds; ++r) {
        const double h = 0.5 + unit(rng);
        const double hv = h / k;
        const Eigen::Vector3d corner(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5);
        // A triangle of a random size around the cell: from a tenth of a voxel to three cells.
        const double size = hv * std::pow(30.0 * k, unit(rng)) * 0.1;
        const Eigen::Vector3d centre = corner + h * Eigen::Vector3d(unit(rng), unit(rng), unit(rng)) * 1.4 -
                                       Eigen::Vector3d::Constant(0.2 * h);
        auto near = [&]() -> Eigen::Vector3d {
          return centre + size * Eigen::Vector3d(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5);
        };
        auto snap = [&](Eigen::Vector3d p) {  // onto the voxel lattice
          for (int w = 0; w < 3; ++w) p[w] = corner[w] + hv * std::round((p[w] - corner[w]) / hv);
          return p;
        };
        Eigen::Vector3d a = near(), b = near(), c = near();
        switch (r % 9) {
          case 1: {  // on voxel boundaries: snapped to the voxel lattice, often axis-aligned
            a = snap(a), b = snap(b), c = snap(c);
            if (r % 12 == 1) b[0] = a[0], c[0] = a[0];  // in a voxel face plane
            break;
          }
          case 2:  // a sliver: c almost on ab
            c = a + (b - a) * unit(rng) + 1e-9 * hv * Eigen::Vector3d(unit(rng), unit(rng), unit(rng));
            break;
          case 3:  // degenerate: collinear, or two vertices one
            if (r % 12 == 3)
              c = a + 0.3 * (b - a);
            else
              b = a;
            break;
          case 4: {  // far from the origin, where rounding reaches the voxels' 1e-9 growth: on voxel planes
            const Eigen::Vector3d far = Eigen::Vector3d::Constant(r % 12 == 4 ? 1e4 : 3e6) + corner;
            auto snap_far = [&](Eigen::Vector3d p) {
              for (int w = 0; w < 3; ++w) p[w] = far[w] + hv * std::round((p[w] - corner[w]) / hv);
              return p;
            };
            a = snap_far(a), b = snap_far(b), c = snap_far(c);
            if (r % 24 == 10) b[1] = a[1], c[1] = a[1];
            expect_same(far, hv, k, a, b, c, grow, tally, "far");
            continue;
          }
          case 5:  // one edge along an axis
            b = a;
            b[r % 3] += size;
            break;
          case 6: {  // larger than the cell, tilted: the plane's slab bounds each column
            auto spread = [&] {
              return snap(corner + h * Eigen::Vector3d(3 * unit(rng) - 1, 3 * unit(rng) - 1, unit(rng)));
            };
            a = spread(), b = spread(), c = spread();
            if (r % 18 == 6) b[r % 3] = a[r % 3], c[r % 3] = std::nextafter(a[r % 3], 1e300);
            break;
          }
          case 7: {  // a plane through a grown voxel's corner, or within 1e-5 to 1e-17 voxels of it
            const Eigen::Vector3d sign(r & 1 ? 1 : -1, r & 2 ? 1 : -1, r & 4 ? 1 : -1);
            const Eigen::Vector3d corner_point =
                corner +
                hv * (Eigen::Vector3d(int(unit(rng) * k), int(unit(rng) * k), int(unit(rng) * k)) +
                      Eigen::Vector3d::Constant(0.5)) +
                0.5 * hv * (1.0 + 2.0 * grow + 1e-9) * sign;
            const Eigen::Vector3d normal =
                (Eigen::Vector3d(unit(rng), unit(rng), unit(rng)) + Eigen::Vector3d::Constant(0.05))
                    .cwiseProduct(sign)
                    .normalized();
            const double offset =
                r % 4 == 3 ? 0.0 : hv * std::pow(10.0, -5.0 - 12.0 * unit(rng)) * (r & 8 ? 1 : -1);
            const Eigen::Vector3d t1 = normal.unitOrthogonal(), t2 = normal.cross(t1);
            const Eigen::Vector3d q = corner_point + offset * normal;
            const double radius = hv * (0.5 + 3 * k * unit(rng) * unit(rng)),
                         th = 6.283185307179586 * unit(rng);
            a = q + radius * (std::cos(th) * t1 + std::sin(th) * t2);
            b = q + radius * (std::cos(th + 2.1) * t1 + std::sin(th + 2.1) * t2);
            c = q + radius * (std::cos(th + 4.2) * t1 + std::sin(th + 4.2) * t2);
            break;
          }
          case 8: {  // everything tiny, where the exact test's squared lengths underflow, or huge,
                     // where tol overflows
            const double s = r % 18 == 8    ? std::ldexp(1.0, -300)
                             : r % 36 == 17 ? std::ldexp(1.0, 510)
                                            : std::ldexp(1.0, -535);
            expect_same(s * corner, s * hv, k, s * a, s * b, s * c, grow, tally, "tiny or huge");
            continue;
          }
          default:
            break;
        }
        expect_same(corner, hv, k, a, b, c, grow, tally, "random");
      }
    }
  }
  // The cases reached what they are meant to: hits, and partial hits.
  EXPECT_GT(tally.with_hits, tally.cases / 3);
  EXPECT_GT(tally.partial, tally.cases / 4);
}

// Triangles exactly on the planes between voxels, the grid-aligned boxes that generated meshes
// are made of: every voxel on both sides of the plane that the face touches.
TEST(VoxelHits, FacesOnVoxelPlanesHitBothSides) {
  const int k = 8;
  const double hv = 0.125;
  const Eigen::Vector3d corner(0, 0, 0);
  for (int axis = 0; axis < 3; ++axis)
    for (int plane = 0; plane <= k; ++plane) {
      Eigen::Vector3d a = Eigen::Vector3d::Constant(0.25), b = a, c = a;
      a[axis] = b[axis] = c[axis] = plane * hv;
      b[(axis + 1) % 3] = 0.75;
      c[(axis + 2) % 3] = 0.75;
      std::set<int64_t> got;
      for_each_voxel_hit(
          corner, hv, k, a, b, c, 0.0, [](int64_t) { return false; }, [&](int64_t vi) { got.insert(vi); });
      EXPECT_EQ(got, every_voxel(corner, hv, k, a, b, c, 0.0));
      // Both layers next to the plane (one at the cell's faces).
      std::set<int> layers;
      for (int64_t vi : got) layers.insert(int(axis == 0 ? vi % k : axis == 1 ? (vi / k) % k : vi / (k * k)));
      std::set<int> want;
      if (plane > 0) want.insert(plane - 1);
      if (plane < k) want.insert(plane);
      EXPECT_EQ(layers, want) << "axis " << axis << " plane " << plane;
    }
}

// Triangles in a plane across an axis (their vertices' coordinate along it equal), the faces of
// grid-aligned models: on a voxel plane, within 1e-17 to 1e-5 voxels of one, anywhere between,
// near zero and far from it, small and larger than the cell, every axis, grown and plain voxels.
// The voxels beside such a plane are decided in the exact test's own arithmetic (voxel_hits.h).
TEST(VoxelHits, FlatTrianglesOnAndNearVoxelPlanes) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Tally tally;
  int on_plane_hits = 0;
  for (int k : {5, 24}) {
    for (double grow : {0.0, kContact}) {
      for (int r = 0; r < 600; ++r) {
        const double h = r % 5 == 0 ? 0.5 : 0.5 + unit(rng);
        const double hv = h / k;
        Eigen::Vector3d corner(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5);
        if (r % 7 == 3) corner += Eigen::Vector3d::Constant(r % 2 ? 1e4 : 3e6);
        if (r % 5 == 0) corner = hv * Eigen::Vector3d(std::round(corner.x() / hv), 3.0, -2.0);
        const int d = r % 3, u = (d + 1) % 3, w = (d + 2) % 3;
        // The plane: a voxel boundary (or the cell's face), moved by nothing, a tiny amount or a
        // random fraction of a voxel.
        const int layer = int(unit(rng) * (k + 1));
        double at = corner[d] + hv * layer;
        switch (r % 4) {
          case 1:
            at += hv * std::pow(10.0, -5.0 - 12.0 * unit(rng)) * (r & 8 ? 1 : -1);
            break;
          case 2:
            at = corner[d] + hv * (k + 2) * unit(rng) - hv;
            break;
          case 3:
            at = std::nextafter(at, r & 16 ? 1e300 : -1e300);
            break;
          default:
            break;
        }
        const double size = h * (r % 3 == 2 ? 2.5 : 0.6);
        auto vertex = [&] {
          Eigen::Vector3d p;
          p[d] = at;
          p[u] = corner[u] + h * 0.5 + size * (unit(rng) - 0.5);
          p[w] = corner[w] + h * 0.5 + size * (unit(rng) - 0.5);
          if (r % 6 == 1) {  // on the voxel lattice across the plane too
            p[u] = corner[u] + hv * std::round((p[u] - corner[u]) / hv);
            p[w] = corner[w] + hv * std::round((p[w] - corner[w]) / hv);
          }
          return p;
        };
        const Eigen::Vector3d a = vertex(), b = vertex(), c = vertex();
        expect_same(corner, hv, k, a, b, c, grow, tally, "flat");
        on_plane_hits += r % 4 == 0 && !every_voxel(corner, hv, k, a, b, c, grow).empty();
      }
    }
  }
  EXPECT_GT(tally.with_hits, tally.cases / 3);
  EXPECT_GT(on_plane_hits, 100);
}

// Flat triangles whose plane is on a grown voxel's face exactly as the exact test rounds it
// (centre +- half), and 1 or 2 units of roundoff either side, where the decision along the
// normal's axis in the exact test's arithmetic is all that tells the voxels apart (a review's
// test: it catches >= for >, a half larger by 1e-15, and the centre summed in another order).
TEST(VoxelHits, FlatTrianglesOnGrownVoxelFaces) {
  std::mt19937 rng(13);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int cases = 0, flips = 0;
  for (int k : {1, 6, 23})
    for (double grow : {0.0, 0.125})
      for (int r = 0; r < 60; ++r) {
        const double hv = (0.3 + unit(rng)) / k;
        const Eigen::Vector3d corner(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5);
        const double half = 0.5 * hv * (1.0 + 2.0 * grow + 1e-9);
        const int d = r % 3, u = (d + 1) % 3, w = (d + 2) % 3;
        const int x = int(unit(rng) * k);
        const double face =
            corner[d] + hv * (x + 0.5) + (r & 4 ? half : -half);  // as the exact test rounds it
        std::set<int64_t> last;
        for (int ulps = -2; ulps <= 2; ++ulps) {
          double at = face;
          for (int i = 0; i < std::abs(ulps); ++i) at = std::nextafter(at, ulps > 0 ? 1e300 : -1e300);
          auto vertex = [&](double fu, double fw) {
            Eigen::Vector3d p;
            p[d] = at;
            p[u] = corner[u] + k * hv * fu;
            p[w] = corner[w] + k * hv * fw;
            return p;
          };
          // Large enough that many columns are sure, small enough that some are not.
          const Eigen::Vector3d a = vertex(-0.2, 0.1 + 0.2 * unit(rng)), b = vertex(1.1, -0.1),
                                c = vertex(0.4 * unit(rng), 1.2);
          std::set<int64_t> got;
          for_each_voxel_hit(
              corner, hv, k, a, b, c, grow, [](int64_t) { return false; },
              [&](int64_t vi) { got.insert(vi); });
          ASSERT_EQ(got, every_voxel(corner, hv, k, a, b, c, grow))
              << "k " << k << " grow " << grow << " r " << r << " ulps " << ulps;
          flips += ulps > -2 && got != last;
          last = got;
          ++cases;
        }
      }
  EXPECT_GT(flips, cases / 20);  // the planes do cross the grown faces
}
