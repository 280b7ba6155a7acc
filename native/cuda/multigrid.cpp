#include "multigrid.h"

#include <larap/errors.h>

#include <Eigen/Cholesky>
#include <Eigen/SparseCore>
#include <algorithm>
#include <cstdint>
#include <utility>

#include "parallel.h"

namespace larap {
namespace cuda {

double jacobi_lambda_max(const SparseRows& A, const Eigen::VectorXd& diag) {
  const Eigen::Index n = A.rows();
  Eigen::VectorXd v = Eigen::VectorXd::Random(n).cwiseAbs() + Eigen::VectorXd::Constant(n, 0.1);
  double lam = 2.0;
  for (int it = 0; it < 40; ++it) {
    Eigen::VectorXd w = (A * v).cwiseQuotient(diag);
    lam = w.norm() / std::max(v.norm(), 1e-300);
    v = w / std::max(w.norm(), 1e-300);
  }
  return 1.05 * lam;
}

int aggregate(const Lattice& lattice, int n, int shift, std::vector<int>& agg) {
  const auto key = [&](int i) {
    const Eigen::Vector3i& c = lattice.node_coords[size_t(i)];
    return (int64_t(c.x() >> shift) << 42) | (int64_t(c.y() >> shift) << 21) | int64_t(c.z() >> shift);
  };
  // Union-find over the edges inside each block (the smaller root wins: deterministic).
  std::vector<int> up(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) up[size_t(i)] = i;
  const auto find = [&](int i) {
    while (up[size_t(i)] != i) i = up[size_t(i)] = up[size_t(up[size_t(i)])];
    return i;
  };
  for (int i = 0; i < n; ++i) {
    const int64_t ki = key(i);
    for (int k = lattice.adj_offsets[size_t(i)]; k < lattice.adj_offsets[size_t(i) + 1]; ++k) {
      const int j = lattice.adj[size_t(k)];
      if (j <= i || j >= n || key(j) != ki) continue;
      const int a = find(i), b = find(j);
      if (a != b) up[size_t(std::max(a, b))] = std::min(a, b);
    }
  }
  agg.assign(size_t(n), 0);
  std::vector<int> id(static_cast<size_t>(n), -1);
  int count = 0;
  for (int i = 0; i < n; ++i) {
    int& r = id[size_t(find(i))];
    if (r < 0) r = count++;
    agg[size_t(i)] = r;
  }
  return count;
}

std::vector<float> dense_inverse(const Eigen::MatrixXd& A) {
  const int nc = int(A.rows());
  Eigen::LLT<Eigen::MatrixXd> llt(A);
  if (llt.info() != Eigen::Success) throw DeviceError("the coarse lattice system is not positive definite");
  Eigen::MatrixXd inv(nc, nc);
  constexpr int kCols = 64;
  const int nb = (nc + kCols - 1) / kCols;
  const auto solve_block = [&](int64_t b) {  // columns [64 b, 64 b + 64) of the inverse
    const int c0 = int(b) * kCols, w = std::min(kCols, nc - c0);
    Eigen::MatrixXd X = Eigen::MatrixXd::Zero(nc, w);
    for (int k = 0; k < w; ++k) X(c0 + k, k) = 1.0;
    llt.matrixL().solveInPlace(X);
    llt.matrixU().solveInPlace(X);
    inv.middleCols(c0, w) = X;
  };
  parallel_for(nb, solve_block, 1);
  std::vector<float> out(size_t(nc) * nc);
  for (int r = 0; r < nc; ++r)
    for (int c = 0; c < nc; ++c) out[size_t(r) * nc + c] = float(0.5 * (inv(r, c) + inv(c, r)));
  return out;
}

ProlongedRows prolonged_rows(const SparseRows& A, const std::vector<int>& agg, int slots) {
  const int n = int(A.rows());
  ProlongedRows ap;
  ap.col.assign(size_t(slots) * n, 0);
  ap.val.assign(size_t(slots) * n, 0.f);
  ap.rem_off.assign(size_t(n) + 1, 0);
  std::vector<std::pair<int, double>> row;  // (aggregate, sum), own aggregate first
  for (int i = 0; i < n; ++i) {
    const int own = agg[size_t(i)];
    row.assign(1, {own, 0.0});
    for (SparseRows::InnerIterator it(A, i); it; ++it) {
      const int a = agg[size_t(it.col())];
      auto e = std::find_if(row.begin(), row.end(), [&](const auto& r) { return r.first == a; });
      if (e == row.end()) {
        row.emplace_back(a, 0.0);
        e = row.end() - 1;
      }
      e->second += it.value();
    }
    for (int d = 0; d < slots; ++d) {
      const bool in = d < int(row.size());
      ap.col[size_t(d) * n + i] = in ? row[size_t(d)].first : own;
      ap.val[size_t(d) * n + i] = in ? float(row[size_t(d)].second) : 0.f;
    }
    for (size_t e = size_t(slots); e < row.size(); ++e) {
      ap.rem_col.push_back(row[e].first);
      ap.rem_val.push_back(float(row[e].second));
    }
    ap.rem_off[size_t(i) + 1] = int(ap.rem_col.size());
  }
  return ap;
}

Multigrid build_multigrid(const Lattice& lattice, const SparseRows& A, double lam_max, int mg_coarse_max,
                          int mg_levels, int ap_slots) {
  const int n = int(A.rows());  // the real nodes (the stencil shell is not in the system)
  Multigrid mg;
  int nc = aggregate(lattice, n, 1, mg.agg);
  mg.shift = 1;
  mg.three_levels = mg_levels == 3 || (mg_levels != 2 && nc > mg_coarse_max);
  if (!mg.three_levels) {
    for (int shift = 2; nc > mg_coarse_max && shift < 31; ++shift) {
      nc = aggregate(lattice, n, shift, mg.agg);
      mg.shift = shift;
    }
  }
  mg.nc = nc;
  mg.omega = float(4.0 / (3.0 * lam_max));
  mg.ap = prolonged_rows(A, mg.agg, ap_slots);
  // Ac = P^T A P (sparse, double)
  SparseRows Ac(nc, nc);
  {
    std::vector<Eigen::Triplet<double>> tr;
    tr.reserve(size_t(A.nonZeros()));
    for (int i = 0; i < n; ++i)
      for (SparseRows::InnerIterator it(A, i); it; ++it)
        tr.emplace_back(mg.agg[size_t(i)], mg.agg[size_t(it.col())], it.value());
    Ac.setFromTriplets(tr.begin(), tr.end());
    Ac.makeCompressed();
  }
  if (!mg.three_levels) {
    mg.ainv = dense_inverse(Eigen::MatrixXd(Ac));
    return mg;
  }
  // Level 2: level-1 nodes grouped by fine coord >> shift2 (nested in level 1).
  std::vector<int> aggf2;
  int nc2 = 0;
  for (int shift = 2; shift < 31; ++shift) {
    nc2 = aggregate(lattice, n, shift, aggf2);
    if (nc2 <= mg_coarse_max) break;
  }
  mg.nc2 = nc2;
  mg.agg2.assign(size_t(nc), 0);
  for (int i = 0; i < n; ++i) mg.agg2[size_t(mg.agg[size_t(i)])] = aggf2[size_t(i)];
  Eigen::MatrixXd Ac2 = Eigen::MatrixXd::Zero(nc2, nc2);
  mg.c_val.resize(size_t(Ac.nonZeros()));
  mg.c_minv.assign(size_t(nc), 1.f);
  Eigen::VectorXd cd = Eigen::VectorXd::Ones(nc);
  for (int c = 0; c < nc; ++c)
    for (int q = Ac.outerIndexPtr()[c]; q < Ac.outerIndexPtr()[c + 1]; ++q) {
      const int j = Ac.innerIndexPtr()[q];
      const double v = Ac.valuePtr()[q];
      mg.c_val[size_t(q)] = float(v);
      if (j == c) cd[c] = v;
      Ac2(mg.agg2[size_t(c)], mg.agg2[size_t(j)]) += v;
    }
  for (int c = 0; c < nc; ++c) {
    if (!(cd[c] > 0.0)) throw DeviceError("the coarse lattice system is not positive definite");
    mg.c_minv[size_t(c)] = float(1.0 / cd[c]);
  }
  mg.omega1 = float(4.0 / (3.0 * jacobi_lambda_max(Ac, cd)));
  mg.ainv = dense_inverse(Ac2);
  mg.c_off.assign(Ac.outerIndexPtr(), Ac.outerIndexPtr() + nc + 1);
  mg.c_col.assign(Ac.innerIndexPtr(), Ac.innerIndexPtr() + Ac.nonZeros());
  return mg;
}

}  // namespace cuda
}  // namespace larap
