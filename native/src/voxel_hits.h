// Which voxels of an analysed cell a triangle overlaps (cell splitting, cell_pieces.h): the same
// voxels as geometry::triangle_box_overlap tested on every voxel of the triangle's bounding box,
// found at a fraction of the cost. Internal to the lattice builder.
//
// The exact test is a separating-axis test over 13 axes, computed afresh per voxel. Here the
// triangle's side of each axis is computed once, and a voxel's centre enters as one dot product
// per axis (Schwarz and Seidel's precomputed triangle/box test, 2010). Rounding makes the two
// differ by far less than `tol` (below), so each axis is decided by this form where its margin is
// wider than tol, and a voxel within tol of any axis's limit goes to the exact test: the hits are
// the exact test's, bit for bit (a reviewer's fuzzing: 5 million triangles, every scale from
// 2^-1080 to 2^1020, cells 1e8 from zero with 1e-3 voxels, planes and edges within 1e-17 of a
// grown voxel's corner). Per column of voxels along the axis the normal is most aligned
// with, the axes that do not vary along it cull the whole column, and the triangle's plane bounds
// the voxels tested to the slab it crosses (a voxel to spare each side), so a large triangle
// costs the columns it covers, not its volume. Per row of columns, those axes bound the columns
// looked at (a column to spare each side), and only the columns from either end up to the first
// whose axes all overlap beyond tol are judged: the columns between are too, by convexity. A
// triangle in a plane across the normal's axis (a grid-aligned face) is decided along that axis
// in the exact test's own arithmetic, so the voxels beside a voxel plane it lies on need no exact
// test.
#pragma once
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "geometry.h"

namespace larap {

namespace voxel_hits_detail {

// One separating axis m: the triangle projects onto [lo, hi] (vertices relative to the cell's
// corner), the box onto centre +- r. A voxel centred at x is separated when
// lo - m.x > r or m.x - hi > r.
struct Axis {
  Eigen::Vector3d m = Eigen::Vector3d::Zero();
  double lo = 0.0, hi = 0.0, r = 0.0, tol = 0.0;
  // 0: a real axis; 1: exactly zero, separates nothing; 2: zero or too short to judge (the exact
  // test decides)
  int zero = 0;
};

// +1: separated by more than tol; -1: overlapping on this axis by more than tol; 0: undecided.
inline int judge(const Axis& x, const Eigen::Vector3d& centre) {
  if (x.zero) return x.zero == 1 ? -1 : 0;
  const double mc = x.m.dot(centre);
  const double s = std::max(x.lo - mc, mc - x.hi) - x.r;
  return s > x.tol ? 1 : s < -x.tol ? -1 : 0;
}

// floor(t) clamped to [lo, hi] before it becomes an int (NaN gives lo).
inline int clamped_floor(double t, int lo, int hi) {
  if (!(t >= lo)) return lo;
  return t >= hi ? hi : int(std::floor(t));
}

// Narrows [x0, x1] to the voxels along a line (a voxel to spare at either end) whose centre
// projects into [lo, hi] on an axis that moves by `step` a voxel: with the projection at voxel x
// being step (x + 1/2) + a constant, lo and hi are the limits less that constant.
inline void narrow(double lo, double hi, double step, int k, int& x0, int& x1) {
  double t0 = lo / step - 0.5, t1 = hi / step - 0.5;
  if (t0 > t1) std::swap(t0, t1);
  x0 = std::max(x0, clamped_floor(t0, -2, k + 1) - 1);
  x1 = std::min(x1, -clamped_floor(-t1, -(k + 1), 2) + 1);  // ceil(t1) + 1
}

inline Axis make_axis(const Eigen::Vector3d& m, const Eigen::Vector3d p[3], double half, double tol) {
  Axis x;
  x.m = m;
  const double q0 = m.dot(p[0]), q1 = m.dot(p[1]), q2 = m.dot(p[2]);
  x.lo = std::min({q0, q1, q2});
  x.hi = std::max({q0, q1, q2});
  x.r = half * m.cwiseAbs().sum();
  x.tol = tol;
  return x;
}

}  // namespace voxel_hits_detail

// Calls hit(vi) for each voxel vi of a cell's k^3 grid (corner: the cell's lowest corner, hv: the
// voxel size; vi = i + k (j + k l)) whose box, grown by `grow` voxels to every side, the triangle
// abc overlaps, exactly as geometry::triangle_box_overlap decides it; skip(vi) true leaves a voxel
// untested. The order of the calls is unspecified.
template <class Skip, class Hit>
void for_each_voxel_hit(const Eigen::Vector3d& corner, double hv, int k, const Eigen::Vector3d& a,
                        const Eigen::Vector3d& b, const Eigen::Vector3d& c, double grow, Skip&& skip,
                        Hit&& hit) {
  using namespace voxel_hits_detail;
  const Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c), hi = a.cwiseMax(b).cwiseMax(c);
  const double half = 0.5 * hv * (1.0 + 2.0 * grow + 1e-9);
  const Eigen::Vector3d halfv = Eigen::Vector3d::Constant(half);
  int v0[3], v1[3];
  // The exact test's centres are rounded at the size of the coordinates: a few of their units
  // of roundoff, in voxels, on top of the voxels' own 1e-9 growth.
  const double Lc =
      std::max({lo.cwiseAbs().maxCoeff(), hi.cwiseAbs().maxCoeff(), corner.cwiseAbs().maxCoeff() + k * hv});
  const double slack = 1e-7 + 8.0 * 2.220446049250313e-16 * (Lc / hv);
  for (int w = 0; w < 3; ++w) {
    v0[w] = clamped_floor((lo[w] - corner[w]) / hv - grow - slack, 0, k - 1);
    v1[w] = clamped_floor((hi[w] - corner[w]) / hv + grow + slack, 0, k - 1);
  }
  auto centre_of = [&](const int* x) {
    return Eigen::Vector3d(hv * (x[0] + 0.5), hv * (x[1] + 0.5), hv * (x[2] + 0.5));
  };
  auto exact = [&](const int* x, int64_t vi) {
    if (geometry::triangle_box_overlap(corner + centre_of(x), halfv, a, b, c)) hit(vi);
  };

  // Vertices relative to the corner; edges from the vertices themselves, so an edge component is
  // exactly zero where the exact test's is (equal coordinates).
  const Eigen::Vector3d p[3] = {a - corner, b - corner, c - corner};
  const Eigen::Vector3d e[3] = {b - a, c - b, a - c};
  const Eigen::Vector3d n = e[0].cross(e[1]);
  // Rounding bound. The exact test works on the vertices minus the voxel's centre. The centre's
  // own rounding (up to roundoff times L, the coordinates' size) shifts all three alike: it
  // cancels from the edges and moves a projection by at most roundoff |m| L. The rest is
  // roundoff at the size D of the vertices relative to the cell: a few units of it times D^2 (edge
  // axes) or D^2 |e| (the normal). tol takes thousands of units of roundoff.
  const double L = std::max({a.cwiseAbs().maxCoeff(), b.cwiseAbs().maxCoeff(), c.cwiseAbs().maxCoeff(),
                             corner.cwiseAbs().maxCoeff() + k * hv});
  const double D =
      std::max({p[0].cwiseAbs().maxCoeff(), p[1].cwiseAbs().maxCoeff(), p[2].cwiseAbs().maxCoeff()}) + k * hv;
  const double emax = std::max({e[0].cwiseAbs().sum(), e[1].cwiseAbs().sum(), e[2].cwiseAbs().sum()});
  constexpr double T = 1e-12;
  // Below this squared length the exact test's own squaredNorm() may underflow to zero (then it
  // skips the axis): such an axis is left to it.
  constexpr double kTiny = 1e-280;
  const bool finite =
      n.allFinite() && std::isfinite(L) && std::isfinite(D) && std::isfinite(emax) && std::isfinite(half);

  int d = 0;
  n.cwiseAbs().maxCoeff(&d);
  const int u = (d + 1) % 3, w = (d + 2) % 3;
  // Constant along d / varying along d; voxel_axes[0] is the normal, judged first: the voxels a
  // column holds beyond the plane's slab are separated by it.
  Axis column_axes[5], voxel_axes[8];
  int nc = 0, nv = 1;
  for (int q = 0; q < 3; ++q) {
    Eigen::Vector3d unit = Eigen::Vector3d::Zero();
    unit[q] = 1.0;
    (q == d ? voxel_axes[nv++] : column_axes[nc++]) = make_axis(unit, p, half, T * L);
    for (int i = 0; i < 3; ++i) {
      const Eigen::Vector3d m = unit.cross(e[i]);
      Axis x = make_axis(m, p, half, T * (D * D + m.cwiseAbs().sum() * L));
      if (m.isZero(0.0))
        x.zero = 1;
      else if (m.squaredNorm() < kTiny)
        x.zero = 2;
      (q == d ? column_axes[nc++] : voxel_axes[nv++]) = x;
    }
  }
  Axis normal = make_axis(n, p, half, T * (4.0 * D * D * emax + n.cwiseAbs().sum() * L));
  if (n.squaredNorm() < kTiny) normal.zero = 2;
  voxel_axes[0] = normal;
  // One voxel along d moves the normal's projection by |n_d| hv: the slab bounds the voxels only
  // when that is well beyond tol.
  const bool slab = finite && !normal.zero && std::abs(n[d]) * hv > 2.0 * normal.tol;

  // A triangle in a plane across d (its vertices' d coordinates equal): its edges have no d
  // component, so every axis the exact test tries is a column axis or parallel to d, and the
  // latter separate nothing that the box's own axis d does not (they project the vertices, all at
  // one d, as that axis does, scaled, and rounding is monotone). Axis d is judged in the exact
  // test's own arithmetic, so its verdict is the exact test's even on a voxel plane, where a
  // grid-aligned face lies and tol leaves every voxel beside it undecided.
  const bool flat = finite && a[d] == b[d] && b[d] == c[d];
  auto flat_overlaps_d = [&](const int* x) {  // the exact test's axis d: |a_d - centre_d| <= half
    const double v = a[d] - (corner[d] + hv * (x[d] + 0.5));
    return !(v > half || v < -half);
  };
  int x[3];
  // The voxels of column (x[u], x[w]) along d; sure: every column axis overlaps beyond tol.
  auto column = [&](bool sure) {
    int x0 = v0[d], x1 = v1[d];
    if (slab) {
      // |n . (p - centre)| <= r where the plane crosses the voxel's box.
      const double s = normal.lo - hv * (n[u] * (x[u] + 0.5) + n[w] * (x[w] + 0.5));
      const double s1 = normal.hi - hv * (n[u] * (x[u] + 0.5) + n[w] * (x[w] + 0.5));
      narrow(s - normal.r, s1 + normal.r, hv * n[d], k, x0, x1);
    }
    for (x[d] = x0; x[d] <= x1; ++x[d]) {
      const int64_t vi = x[0] + int64_t(k) * (x[1] + int64_t(k) * x[2]);
      if (skip(vi)) continue;
      if (flat) {
        if (!flat_overlaps_d(x)) continue;
        if (sure)
          hit(vi);
        else
          exact(x, vi);
        continue;
      }
      if (!sure) {
        exact(x, vi);
        continue;
      }
      const Eigen::Vector3d cv = centre_of(x);
      int verdict = -1;  // -1 overlap, 0 undecided, 1 separated
      for (int q = 0; q < nv; ++q) {
        const int j = judge(voxel_axes[q], cv);
        if (j > 0) {
          verdict = 1;
          break;
        }
        if (j == 0) verdict = 0;
      }
      if (verdict < 0)
        hit(vi);
      else if (verdict == 0)
        exact(x, vi);
    }
  };
  // The column axes at column (x[u], x[w]): +1 separated (a finite triangle misses the column),
  // -1 overlapping beyond tol (sure), 0 otherwise.
  auto judge_column = [&]() {
    x[d] = 0;
    const Eigen::Vector3d c0 = centre_of(x);
    bool sure = finite, out = false;
    for (const Axis& ax : column_axes) {
      const int j = judge(ax, c0);
      out = out || j > 0;
      sure = sure && j < 0;
    }
    return out && finite ? 1 : sure ? -1 : 0;
  };
  for (x[w] = v0[w]; x[w] <= v1[w]; ++x[w]) {
    // Along a row of columns (x[u] varying) a column axis's projection moves by m_u hv per column:
    // where that is well beyond tol, the columns more than one past where the axis starts to
    // separate are separated (as the slab bounds the voxels above), and are not looked at.
    int p0 = v0[u], p1 = v1[u];
    if (finite)
      for (const Axis& ax : column_axes) {
        if (ax.zero || !(std::abs(ax.m[u]) * hv > 2.0 * ax.tol)) continue;
        const double base = ax.m[w] * hv * (x[w] + 0.5);
        narrow(ax.lo - ax.r - base, ax.hi + ax.r - base, hv * ax.m[u], k, p0, p1);
      }
    // A column axis's margin is convex along the row (the larger of two affine functions): between
    // two sure columns every column axis overlaps by tol less the rounding, far inside what the
    // exact test calls an overlap, so the columns between two sure ones are sure unjudged. From
    // each end, columns are judged until a sure one.
    int lo = p0, hi = p1;
    for (; lo <= hi; ++lo) {
      x[u] = lo;
      const int j = judge_column();
      if (j <= 0) column(j < 0);
      if (j < 0) break;
    }
    for (; hi > lo; --hi) {
      x[u] = hi;
      const int j = judge_column();
      if (j <= 0) column(j < 0);
      if (j < 0) break;
    }
    for (x[u] = lo + 1; x[u] < hi; ++x[u]) column(true);
  }
}

}  // namespace larap
