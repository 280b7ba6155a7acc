// The per-cell terms of one flip-flop (docs/method.md, "Energy"), written once for the CPU backend
// (double) and the CUDA kernels (float): each backend passes an accessor to its own storage, the
// arithmetic is here (LARAP_HD).
//
// The energy is a sum over cell copies c, each with one rotation R_c, of its 12 edges (a, b)
// (corner q at (q & 1, q >> 1 & 1, q >> 2); an edge joins q and q | 1 << axis), weighted by the
// copy's cell_weight w_c:
//   covariance  S_c = sum_(a,b) (p_a - p_b)(c_a - c_b)^T              -> the rotation fit R_c(S_c)
//   ARAP energy e_c = sum_(a,b) |(p_a - p_b) - R_c (c_a - c_b)|^2     (times w_c by the caller)
//   rhs         b_i = g sum_(c, q: node i is corner q of c) w_c R_c s_cq,
//               s_cq = sum over the 3 edges of c at q of (c_q - c_other)   (node_cells.h)
// and the system's Laplacian has 2 g w_ij = g sum_(c around edge ij) w_c (Lattice::edge_weight).
//
// The accessor `Corners` has
//   void pose(int q, Real (&p)[3]) const;   p of corner q
//   void rest(int q, Real (&c)[3]) const;   c of corner q
#pragma once
#include "host_device.h"

namespace larap {

// S_c (set) and, when want_energy, e_c with the rotation Rc (unweighted); returns e_c (0 when not
// wanted).
template <typename Real, class Corners>
LARAP_HD Real cell_covariance(const Corners& k, bool want_energy, const Real* Rc, Real (&S)[9]) {
  Real p[8][3], c[8][3];
  LARAP_UNROLL
  for (int q = 0; q < 8; ++q) {
    k.pose(q, p[q]);
    k.rest(q, c[q]);
  }
  LARAP_UNROLL
  for (int t = 0; t < 9; ++t) S[t] = Real(0);
  Real e = Real(0);
  LARAP_UNROLL
  for (int axis = 0; axis < 3; ++axis) {
    LARAP_UNROLL
    for (int q = 0; q < 8; ++q) {
      if ((q >> axis) & 1) continue;
      const int u = q | (1 << axis);
      Real dp[3], dc[3];
      LARAP_UNROLL
      for (int a = 0; a < 3; ++a) {
        dp[a] = p[u][a] - p[q][a];
        dc[a] = c[u][a] - c[q][a];
      }
      LARAP_UNROLL
      for (int a = 0; a < 3; ++a) {
        S[3 * a + 0] += dp[a] * dc[0];
        S[3 * a + 1] += dp[a] * dc[1];
        S[3 * a + 2] += dp[a] * dc[2];
      }
      if (want_energy) {
        LARAP_UNROLL
        for (int a = 0; a < 3; ++a) {
          const Real r = dp[a] - (Rc[3 * a] * dc[0] + Rc[3 * a + 1] * dc[1] + Rc[3 * a + 2] * dc[2]);
          e += r * r;
        }
      }
    }
  }
  return e;
}

// acc += R s (R 3x3 row-major): one (cell, corner) entry of a node's right-hand side.
template <typename Real>
LARAP_HD void cell_rhs_add(const Real* R, const Real (&s)[3], Real (&acc)[3]) {
  LARAP_UNROLL
  for (int a = 0; a < 3; ++a) acc[a] += R[3 * a] * s[0] + R[3 * a + 1] * s[1] + R[3 * a + 2] * s[2];
}

}  // namespace larap
