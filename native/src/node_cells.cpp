#include "node_cells.h"

namespace larap {

NodeCells node_cells(const Lattice& lat) {
  const int64_t nr = lat.num_real_nodes(), nc = lat.num_cells();
  NodeCells t;
  t.offsets.assign(size_t(nr) + 1, 0);
  for (int64_t c = 0; c < nc; ++c)
    for (int q = 0; q < 8; ++q) ++t.offsets[size_t(lat.cell_nodes[c][q]) + 1];
  for (const Coupling& k : lat.couplings)
    for (int q = 0; q < 8; ++q) ++t.offsets[size_t(lat.cell_nodes[size_t(k.trunk)][q]) + 1];
  for (int64_t i = 0; i < nr; ++i) t.offsets[i + 1] += t.offsets[i];
  t.cell.resize(size_t(t.offsets[nr]));
  t.s.resize(t.cell.size());
  std::vector<int32_t> fill(t.offsets.begin(), t.offsets.end() - 1);
  // Copy c's corners (rest edges times w) under rotation `rot`.
  auto add = [&](int64_t c, int32_t rot, double w) {
    for (int q = 0; q < 8; ++q) {
      const int32_t i = lat.cell_nodes[c][q];
      std::array<double, 3> s{0.0, 0.0, 0.0};
      for (int axis = 0; axis < 3; ++axis) {
        const int32_t j = lat.cell_nodes[c][q ^ (1 << axis)];
        for (int a = 0; a < 3; ++a) s[size_t(a)] += lat.rest(i, a) - lat.rest(j, a);
      }
      for (double& v : s) v *= w;
      const int32_t k = fill[size_t(i)]++;
      t.cell[size_t(k)] = rot;
      t.s[size_t(k)] = s;
    }
  };
  for (int64_t c = 0; c < nc; ++c) add(c, int32_t(c), cell_weight_of(lat, c));  // ascending c per node
  for (const Coupling& k : lat.couplings) add(k.trunk, k.branch, k.weight);     // then the couplings
  return t;
}

BranchCouplings couplings_by_branch(const Lattice& lat) {
  BranchCouplings b;
  if (lat.couplings.empty()) return b;
  const int64_t nc = lat.num_cells();
  b.offsets.assign(size_t(nc) + 1, 0);
  for (const Coupling& k : lat.couplings) ++b.offsets[size_t(k.branch) + 1];
  for (int64_t c = 0; c < nc; ++c) b.offsets[size_t(c) + 1] += b.offsets[size_t(c)];
  b.trunk.resize(lat.couplings.size());
  b.weight.resize(lat.couplings.size());
  std::vector<int32_t> fill(b.offsets.begin(), b.offsets.end() - 1);
  for (const Coupling& k : lat.couplings) {
    const int32_t j = fill[size_t(k.branch)]++;
    b.trunk[size_t(j)] = k.trunk;
    b.weight[size_t(j)] = k.weight;
  }
  for (int64_t c = 0; c < nc; ++c)
    if (b.offsets[size_t(c)] < b.offsets[size_t(c) + 1]) b.branches.push_back(int32_t(c));
  return b;
}

}  // namespace larap
