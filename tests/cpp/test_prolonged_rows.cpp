// The CUDA multigrid's rows of A P (native/cuda/multigrid.h, prolonged_rows): the coarse
// correction's gather reads the coarse vector through them (solvers.cu, mg_c_node). Host code,
// built with the CUDA backend only.
// Run: build/larap_tests --gtest_filter='ProlongedRows*'
#ifdef LARAP_WITH_CUDA
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <random>
#include <set>
#include <vector>

#include "multigrid.h"

namespace {

using larap::cuda::ProlongedRows;
using larap::cuda::SparseRows;

// A random symmetric sparse matrix of n rows with about `per_row` off-diagonal entries a row and
// a random grouping of its rows into nc aggregates.
struct Case {
  SparseRows A;
  std::vector<int> agg;
  int nc = 0;
};

Case random_case(int n, int nc, int per_row, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> col(0, n - 1), group(0, nc - 1);
  std::uniform_real_distribution<double> val(-1.0, 1.0);
  std::vector<Eigen::Triplet<double>> t;
  for (int i = 0; i < n; ++i) {
    t.emplace_back(i, i, 10.0 + val(rng));
    for (int k = 0; k < per_row / 2; ++k) {
      const int j = col(rng);
      const double v = val(rng);
      t.emplace_back(i, j, v);
      t.emplace_back(j, i, v);
    }
  }
  Case c;
  c.A.resize(n, n);
  c.A.setFromTriplets(t.begin(), t.end());
  c.A.makeCompressed();
  c.nc = nc;
  c.agg.resize(size_t(n));
  for (int i = 0; i < n; ++i) c.agg[size_t(i)] = group(rng);
  return c;
}

// The rows as a dense n x nc matrix.
Eigen::MatrixXd dense(const ProlongedRows& ap, int n, int nc, int slots) {
  Eigen::MatrixXd D = Eigen::MatrixXd::Zero(n, nc);
  for (int i = 0; i < n; ++i) {
    for (int d = 0; d < slots; ++d) D(i, ap.col[size_t(d) * n + i]) += ap.val[size_t(d) * n + i];
    for (int q = ap.rem_off[size_t(i)]; q < ap.rem_off[size_t(i) + 1]; ++q)
      D(i, ap.rem_col[size_t(q)]) += ap.rem_val[size_t(q)];
  }
  return D;
}

}  // namespace

// The slots and the remainder together are A P (to float rounding of each sum), every aggregate
// appears once in a row, the own aggregate is slot 0, and padding is (own aggregate, 0): so the
// gather (A P) zc is A (P zc).
TEST(ProlongedRows, SlotsAndRemainderAreAP) {
  for (const int per_row : {2, 6, 20}) {
    const int n = 300, nc = 40, slots = 4;
    const Case c = random_case(n, nc, per_row, 7u + unsigned(per_row));
    const ProlongedRows ap = larap::cuda::prolonged_rows(c.A, c.agg, slots);
    ASSERT_EQ(ap.col.size(), size_t(slots) * n);
    ASSERT_EQ(ap.rem_off.size(), size_t(n) + 1);
    Eigen::MatrixXd P = Eigen::MatrixXd::Zero(n, nc);
    for (int i = 0; i < n; ++i) P(i, c.agg[size_t(i)]) = 1.0;
    const Eigen::MatrixXd AP = Eigen::MatrixXd(c.A) * P;
    const Eigen::MatrixXd D = dense(ap, n, nc, slots);
    EXPECT_LE((D - AP).cwiseAbs().maxCoeff(), 1e-5 * AP.cwiseAbs().maxCoeff()) << per_row;
    Eigen::VectorXd zc = Eigen::VectorXd::LinSpaced(nc, -1.0, 2.0);
    EXPECT_LE((D * zc - Eigen::MatrixXd(c.A) * (P * zc)).cwiseAbs().maxCoeff(), 1e-4) << per_row;
    int spilled = 0;
    for (int i = 0; i < n; ++i) {
      const int own = c.agg[size_t(i)];
      EXPECT_EQ(ap.col[size_t(i)], own);
      std::set<int> seen;
      int used = 0;
      for (int d = 0; d < slots; ++d) {
        const int a = ap.col[size_t(d) * n + i];
        const float v = ap.val[size_t(d) * n + i];
        if (d > 0 && a == own) {  // padding
          EXPECT_EQ(v, 0.f);
          continue;
        }
        EXPECT_TRUE(seen.insert(a).second) << i;
        ++used;
      }
      for (int q = ap.rem_off[size_t(i)]; q < ap.rem_off[size_t(i) + 1]; ++q) {
        EXPECT_TRUE(seen.insert(ap.rem_col[size_t(q)]).second) << i;
        ++spilled;
      }
      if (ap.rem_off[size_t(i) + 1] > ap.rem_off[size_t(i)]) EXPECT_EQ(used, slots) << i;
    }
    // Rows with more aggregates than slots (the long rows) go on in the remainder.
    if (per_row >= 20) EXPECT_GT(spilled, 0);
  }
}

#endif  // LARAP_WITH_CUDA
