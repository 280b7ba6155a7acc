// The lattice stencils of native/src/stencil.h (host build of the header the CUDA kernels use).
// Run: ctest --test-dir build -R Stencil   (or build/larap_tests --gtest_filter='Stencil*')
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "stencil.h"

namespace {

using larap::bspline_weights;
using larap::trilinear_weights;

// Weight of 1D lattice node k (integer position) for a point at x under the quadratic B-spline
// binding: nearest node c = floor(x + 1/2), offset t = x - c, nodes c - 1, c, c + 1.
double bspline_basis(int k, double x) {
  const int c = int(std::floor(x + 0.5));
  double w[3];
  bspline_weights(x - c, w);
  const int q = k - c + 1;
  return q >= 0 && q < 3 ? w[q] : 0.0;
}

TEST(Stencil, TrilinearPartitionOfUnityAndAffineReproduction) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 1000; ++trial) {
    const double f[3] = {u(rng), u(rng), u(rng)};
    double w[8];
    trilinear_weights(f[0], f[1], f[2], w);
    double sum = 0.0, p[3] = {0, 0, 0};
    for (int c = 0; c < 8; ++c) {
      EXPECT_GE(w[c], 0.0);
      sum += w[c];
      p[0] += w[c] * (c & 1);
      p[1] += w[c] * ((c >> 1) & 1);
      p[2] += w[c] * (c >> 2);
    }
    EXPECT_NEAR(sum, 1.0, 1e-14);
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(p[a], f[a], 1e-14);  // corners' coordinates -> the point
  }
}

TEST(Stencil, TrilinearIsOneAtItsCornerAndFloatMatchesDouble) {
  for (int c = 0; c < 8; ++c) {
    double w[8];
    trilinear_weights<double>(c & 1, (c >> 1) & 1, c >> 2, w);
    for (int q = 0; q < 8; ++q) EXPECT_EQ(w[q], q == c ? 1.0 : 0.0);
  }
  float wf[8];
  double wd[8];
  trilinear_weights(0.25f, 0.5f, 0.875f, wf);
  trilinear_weights(0.25, 0.5, 0.875, wd);
  for (int q = 0; q < 8; ++q) EXPECT_EQ(double(wf[q]), wd[q]);  // exact in binary
}

TEST(Stencil, BSplinePartitionOfUnityAndAffineReproduction) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (int trial = 0; trial < 1000; ++trial) {
    const double t[3] = {u(rng), u(rng), u(rng)};
    double w[27];
    bspline_weights(t[0], t[1], t[2], w);
    double sum = 0.0, p[3] = {0, 0, 0};
    for (int z = 0; z < 3; ++z)
      for (int y = 0; y < 3; ++y)
        for (int x = 0; x < 3; ++x) {
          const double wk = w[9 * z + 3 * y + x];
          EXPECT_GE(wk, 0.0);
          sum += wk;
          p[0] += wk * (x - 1);
          p[1] += wk * (y - 1);
          p[2] += wk * (z - 1);
        }
    EXPECT_NEAR(sum, 1.0, 1e-14);
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(p[a], t[a], 1e-14);
  }
}

TEST(Stencil, BSplineIsC1AcrossCells) {
  // Where the nearest node changes (x = k + 1/2) every node's weight is continuous and so is
  // its derivative (one-sided differences from both sides agree); a kink would show as a jump
  // of the slope of order 1.
  const double h = 1e-6;
  for (int cell = -2; cell <= 2; ++cell) {
    const double x0 = cell + 0.5;
    for (int k = cell - 2; k <= cell + 3; ++k) {
      const double left = bspline_basis(k, x0 - h), right = bspline_basis(k, x0 + h);
      EXPECT_NEAR(left, right, 1e-5) << "node " << k << " at " << x0;
      const double slope_l = (bspline_basis(k, x0 - h) - bspline_basis(k, x0 - 2 * h)) / h;
      const double slope_r = (bspline_basis(k, x0 + 2 * h) - bspline_basis(k, x0 + h)) / h;
      EXPECT_NEAR(slope_l, slope_r, 1e-4) << "node " << k << " at " << x0;
    }
  }
  // The trilinear stencil, for contrast, is only C0: its slope jumps at a cell face.
  auto hat = [](int k, double x) { return std::max(0.0, 1.0 - std::abs(x - k)); };
  EXPECT_GT(std::abs((hat(0, 1e-6) - hat(0, 0)) - (hat(0, 0) - hat(0, -1e-6))) / 1e-6, 1.0);
}

TEST(Stencil, BSplineWeightsMatchTheClosedForm) {
  double w[3];
  bspline_weights(0.0, w);
  EXPECT_DOUBLE_EQ(w[0], 0.125);
  EXPECT_DOUBLE_EQ(w[1], 0.75);
  EXPECT_DOUBLE_EQ(w[2], 0.125);
  bspline_weights(0.5, w);
  EXPECT_DOUBLE_EQ(w[0], 0.0);
  EXPECT_DOUBLE_EQ(w[1], 0.5);
  EXPECT_DOUBLE_EQ(w[2], 0.5);
}

}  // namespace
