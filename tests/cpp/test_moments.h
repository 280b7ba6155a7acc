// Comparing the warm start's moments of one lattice component (warm_start.h) in the tests.
#pragma once
#include <gtest/gtest.h>

#include "warm_start.h"

namespace larap::test {

// Every moment of `got` within `tol` of `want`.
inline void expect_moments_near(const ComponentMoments& got, const ComponentMoments& want, double tol) {
  EXPECT_NEAR(got.w, want.w, tol);
  EXPECT_LE((got.p - want.p).norm(), tol);
  EXPECT_LE((got.t - want.t).norm(), tol);
  EXPECT_LE((got.pt - want.pt).norm(), tol);
  EXPECT_LE((got.pp - want.pp).norm(), tol);
  EXPECT_NEAR(got.tt, want.tt, tol);
}

}  // namespace larap::test
