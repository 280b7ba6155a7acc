// The per-node terms of one flip-flop (docs/method.md), written once for the CPU backend
// (double, CSR adjacency) and the CUDA kernels (float, fixed 6-slot neighbour table): each
// backend passes an accessor to its own storage, the arithmetic is here (LARAP_HD).
//
// For node i with lattice neighbours j (rest c, deformed p, rotations R, all 3x3 row-major, edge
// weights w_ij: 1 on the plain lattice, lattice.h):
//   covariance  S_i = sum_j w_ij (p_i - p_j)(c_i - c_j)^T           -> the rotation fit R_i(S_i)
//   ARAP energy e_i = sum_j w_ij |(p_i - p_j) - R_i (c_i - c_j)|^2   (with the rotation R_i it has)
//   node energy E_i = g e_i + a |p_i - c_i|^2 [i anchored]
//   rhs         b_i = g sum_j w_ij (R_i + R_j)(c_i - c_j)            (+ (B^T t)_i + a c_i [anchored])
//
// The accessor `Edges` has
//   int size() const;                                             number of edges of node i
//   void edge(int k, Real (&dp)[3], Real (&dc)[3]) const;        p_i - p_j and c_i - c_j
//   void rest_edge(int k, Real (&dc)[3], Real (&Rj)[9]) const;   c_i - c_j and R_j
//   Real weight(int k) const;                                     w_ij
// A missing neighbour may be given as j = i (zero edge vectors add nothing).
#pragma once
#include "host_device.h"

namespace larap {

// S_i (set, not added to) and, when want_energy, e_i with the rotation Ri; returns e_i (0 when
// not wanted).
template <typename Real, class Edges>
LARAP_HD Real node_covariance(const Edges& edges, bool want_energy, const Real* Ri, Real (&S)[9]) {
  LARAP_UNROLL
  for (int q = 0; q < 9; ++q) S[q] = Real(0);
  Real e = Real(0);
  LARAP_UNROLL
  for (int k = 0; k < edges.size(); ++k) {
    Real dp[3], dc[3];
    edges.edge(k, dp, dc);
    const Real w = edges.weight(k);
    LARAP_UNROLL
    for (int a = 0; a < 3; ++a) {
      const Real wp = w * dp[a];
      S[3 * a + 0] += wp * dc[0];
      S[3 * a + 1] += wp * dc[1];
      S[3 * a + 2] += wp * dc[2];
    }
    if (want_energy) {
      Real r2 = Real(0);
      LARAP_UNROLL
      for (int a = 0; a < 3; ++a) {
        const Real r = dp[a] - (Ri[3 * a] * dc[0] + Ri[3 * a + 1] * dc[1] + Ri[3 * a + 2] * dc[2]);
        r2 += r * r;
      }
      e += w * r2;
    }
  }
  return e;
}

// E_i from e_i, accumulated in Acc (the device sums float terms in double).
template <typename Acc, typename Real>
LARAP_HD Acc node_energy(Real g, Real arap, bool anchored, Real a, Real dist2_from_rest) {
  Acc e = Acc(g) * Acc(arap);
  if (anchored) e += Acc(a) * Acc(dist2_from_rest);
  return e;
}

// The ARAP part of the right-hand side, g sum_j (R_i + R_j)(c_i - c_j), into b (set).
template <typename Real, class Edges>
LARAP_HD void node_rhs(const Edges& edges, Real g, const Real* Ri, Real (&b)[3]) {
  Real acc[3] = {Real(0), Real(0), Real(0)};
  LARAP_UNROLL
  for (int k = 0; k < edges.size(); ++k) {
    Real dc[3], Rj[9];
    edges.rest_edge(k, dc, Rj);
    const Real w = edges.weight(k);
    LARAP_UNROLL
    for (int a = 0; a < 3; ++a) {
      const Real m0 = Ri[3 * a] + Rj[3 * a], m1 = Ri[3 * a + 1] + Rj[3 * a + 1],
                 m2 = Ri[3 * a + 2] + Rj[3 * a + 2];
      acc[a] += w * (m0 * dc[0] + m1 * dc[1] + m2 * dc[2]);
    }
  }
  LARAP_UNROLL
  for (int a = 0; a < 3; ++a) b[a] = g * acc[a];
}

}  // namespace larap
