// Stencil weights of the lattice, written once for the host and the device (LARAP_HD).
//
// Trilinear (8 corners of a cell): f = (fx, fy, fz) in [0,1]^3 is the position in the cell;
// corner c has bits (x = c & 1, y = (c >> 1) & 1, z = c >> 2) and weight
//   w_c = (x ? fx : 1 - fx) (y ? fy : 1 - fy) (z ? fz : 1 - fz).
// Uniform quadratic B-spline (27 nodes around the nearest node): t in [-1/2, 1/2] is the offset
// from the nearest node along one axis (in cells); the nodes at -1, 0, +1 get
//   b_0 = (1/2 - t)^2 / 2,  b_1 = 3/4 - t^2,  b_2 = (1/2 + t)^2 / 2,
// and node (x, y, z) of the 3x3x3 block (x fastest, k = 9 z + 3 y + x) gets b_x(tx) (b_y(ty)
// b_z(tz)). Both weight sets sum to one and reproduce affine maps exactly; the B-spline is C1
// across the cell faces where the nearest node changes (tests/cpp/test_stencil.cpp).
#pragma once
#include "host_device.h"

namespace larap {

// The 8 trilinear weights of the corners of a cell (order above).
template <typename Real>
LARAP_HD void trilinear_weights(Real fx, Real fy, Real fz, Real (&w)[8]) {
  const Real wx[2] = {Real(1) - fx, fx}, wy[2] = {Real(1) - fy, fy}, wz[2] = {Real(1) - fz, fz};
  LARAP_UNROLL
  for (int c = 0; c < 8; ++c) w[c] = wx[c & 1] * wy[(c >> 1) & 1] * wz[c >> 2];
}

// The 3 quadratic B-spline weights of the nodes at -1, 0, +1 for an offset t in [-1/2, 1/2].
template <typename Real>
LARAP_HD void bspline_weights(Real t, Real (&w)[3]) {
  const Real h = Real(0.5);
  w[0] = h * (h - t) * (h - t);
  w[1] = Real(0.75) - t * t;
  w[2] = h * (h + t) * (h + t);
}

// The 27 B-spline weights of the 3x3x3 block around the nearest node (order above).
template <typename Real>
LARAP_HD void bspline_weights(Real tx, Real ty, Real tz, Real (&w)[27]) {
  Real wx[3], wy[3], wz[3];
  bspline_weights(tx, wx);
  bspline_weights(ty, wy);
  bspline_weights(tz, wz);
  LARAP_UNROLL
  for (int z = 0; z < 3; ++z) LARAP_UNROLL
  for (int y = 0; y < 3; ++y) {
    const Real wyz = wy[y] * wz[z];
    LARAP_UNROLL
    for (int x = 0; x < 3; ++x) w[9 * z + 3 * y + x] = wx[x] * wyz;
  }
}

}  // namespace larap
