// Small exact geometric predicates, and the floor that turns coordinates into cell indices, used by
// the lattice builder.
#pragma once
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace larap::geometry {

// int(std::floor(y)) for a finite y within int's range, by truncation where that is the same
// (y >= 0: every vertex inside the padded grid), saving the long floor sequence of a baseline
// x86-64 build (no SSE4.1 rounding instruction).
inline int floor_int(double y) { return y >= 0.0 ? int(y) : int(std::floor(y)); }

// Does triangle (a, b, c) overlap the axis-aligned box centre +- half? Separating-axis test over
// the 13 candidate axes: the box's 3 face normals, the triangle's normal, and the 9 cross products
// of box axes with triangle edges. Degenerate (zero-area) triangles are handled: a zero axis
// separates nothing and is skipped.
inline bool triangle_box_overlap(const Eigen::Vector3d& centre, const Eigen::Vector3d& half,
                                 const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                 const Eigen::Vector3d& c) {
  const Eigen::Vector3d v0 = a - centre, v1 = b - centre, v2 = c - centre;
  // Box face normals: compare the triangle's extent with the box.
  for (int k = 0; k < 3; ++k) {
    const double lo = std::min({v0[k], v1[k], v2[k]});
    const double hi = std::max({v0[k], v1[k], v2[k]});
    if (lo > half[k] || hi < -half[k]) return false;
  }
  const Eigen::Vector3d e[3] = {v1 - v0, v2 - v1, v0 - v2};
  auto separated = [&](const Eigen::Vector3d& axis) {
    if (axis.squaredNorm() == 0.0) return false;
    const double p0 = axis.dot(v0), p1 = axis.dot(v1), p2 = axis.dot(v2);
    const double r = half.x() * std::abs(axis.x()) + half.y() * std::abs(axis.y()) +
                     half.z() * std::abs(axis.z());
    return std::min({p0, p1, p2}) > r || std::max({p0, p1, p2}) < -r;
  };
  // Triangle normal.
  if (separated(e[0].cross(e[1]))) return false;
  // Edge cross products.
  for (int i = 0; i < 3; ++i)
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3d unit = Eigen::Vector3d::Zero();
      unit[k] = 1.0;
      if (separated(unit.cross(e[i]))) return false;
    }
  return true;
}

// Does segment (a, b) overlap the box? The triangle test on (a, b, b): its zero normal and zero
// edge are skipped, which leaves the segment's own separating axes (the box's 3 normals and the 3
// cross products of the box axes with the segment).
inline bool segment_box_overlap(const Eigen::Vector3d& centre, const Eigen::Vector3d& half,
                                const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return triangle_box_overlap(centre, half, a, b, b);
}

// Rays along axis a (b = a + 1, c = a + 2, mod 3) through the centres of a grid's columns, moved
// by a tiny irrational-looking amount so that rays through the vertices and edges of grid-aligned
// meshes are unlikely: ray (jb, jc) is the line (b, c) = (jb + kRayB, jc + kRayC), in grid units.
constexpr double kRayB = 0.5 + 1.3717e-6, kRayC = 0.5 + 2.9153e-6;

// Twice the signed area of triangle p seen along axis a: zero when it is parallel to the rays,
// its sign which way the triangle faces along them.
inline double seen_area(const Eigen::Vector3d (&p)[3], int a) {
  const int b = (a + 1) % 3, c = (a + 2) % 3;
  return (p[1][b] - p[0][b]) * (p[2][c] - p[0][c]) - (p[2][b] - p[0][b]) * (p[1][c] - p[0][c]);
}

// The rays of an nb x nc grid of them (above) that triangle p's box covers, [jb0, jb1] x [jc0,
// jc1]; false when none (or a coordinate is not finite).
inline bool rays_in_box(const Eigen::Vector3d (&p)[3], int a, int nb, int nc, int& jb0, int& jb1, int& jc0,
                        int& jc1) {
  const int b = (a + 1) % 3, c = (a + 2) % 3;
  const double bmin = std::min({p[0][b], p[1][b], p[2][b]}) - kRayB;
  const double bmax = std::max({p[0][b], p[1][b], p[2][b]}) - kRayB;
  const double cmin = std::min({p[0][c], p[1][c], p[2][c]}) - kRayC;
  const double cmax = std::max({p[0][c], p[1][c], p[2][c]}) - kRayC;
  if (!(bmax >= 0 && bmin <= nb - 1 && cmax >= 0 && cmin <= nc - 1)) return false;  // NaN-safe
  jb0 = int(std::max(0.0, std::ceil(bmin)));
  jb1 = int(std::min(double(nb - 1), std::floor(bmax)));
  jc0 = int(std::max(0.0, std::ceil(cmin)));
  jc1 = int(std::min(double(nc - 1), std::floor(cmax)));
  return jb0 <= jb1 && jc0 <= jc1;
}

// Where the line through (b, c) = (qb, qc) along axis a (b = a + 1, c = a + 2, mod 3) crosses the
// triangle p, edges and corners included: writes the a coordinate into `at`. False when the line
// misses it; a triangle parallel to the line (zero area seen along a) is never crossed.
inline bool axis_line_crossing(const Eigen::Vector3d (&p)[3], int a, double qb, double qc, double& at) {
  const int b = (a + 1) % 3, c = (a + 2) % 3;
  double w[3];
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d& u = p[(k + 1) % 3];
    const Eigen::Vector3d& v = p[(k + 2) % 3];
    w[k] = (u[b] - qb) * (v[c] - qc) - (v[b] - qb) * (u[c] - qc);
  }
  if (!((w[0] >= 0 && w[1] >= 0 && w[2] >= 0) || (w[0] <= 0 && w[1] <= 0 && w[2] <= 0))) return false;
  const double s = w[0] + w[1] + w[2];
  if (s == 0.0) return false;
  at = (w[0] * p[0][a] + w[1] * p[1][a] + w[2] * p[2][a]) / s;
  return true;
}

}  // namespace larap::geometry
