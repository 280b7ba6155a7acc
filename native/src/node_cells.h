// Per real node, the cell copies it is a corner of: what the right-hand side of the global step
// gathers (cell_terms.h), b_i = g sum_k R_{cell[k]} s[k] over k in [offsets[i], offsets[i + 1]),
// with s[k] = w_c sum over the 3 edges of the copy at that corner of (c_i - c_other), the rest
// edge vectors times the copy's cell_weight. A node is a corner of at most 8 copies where nothing
// is split, of more where copies of one cell share it. A branch coupling (Lattice::couplings) adds
// its trunk copy's corners once more, under the branch copy's rotation (`cell` is then the branch
// copy: the rotation's index) and times the coupling's weight.
#pragma once
#include <larap/lattice.h>

#include <array>
#include <cstdint>
#include <vector>

namespace larap {

struct NodeCells {
  std::vector<int32_t> offsets;          // #real nodes + 1
  std::vector<int32_t> cell;             // rotation (cell copy) of each entry, ascending per node before the couplings
  std::vector<std::array<double, 3>> s;  // w_c times the sum of the corner's 3 rest edges
};

NodeCells node_cells(const Lattice& lat);

// The lattice's couplings grouped by branch copy, what the backends' rotation fits read: copy c's
// are trunk[k], weight[k] for k in [offsets[c], offsets[c + 1]), in their order in the lattice;
// branches lists the coupled copies, ascending. Empty when the lattice has none.
struct BranchCouplings {
  std::vector<int32_t> offsets;  // #copies + 1 (empty without couplings)
  std::vector<int32_t> trunk;
  std::vector<double> weight;
  std::vector<int32_t> branches;
  int32_t begin(int64_t c) const { return offsets.empty() ? 0 : offsets[size_t(c)]; }
  int32_t end(int64_t c) const { return offsets.empty() ? 0 : offsets[size_t(c) + 1]; }
};

BranchCouplings couplings_by_branch(const Lattice& lat);

// cell_weight[c], or 1 where the lattice has no weights.
inline double cell_weight_of(const Lattice& lat, int64_t c) {
  return lat.cell_weight.empty() ? 1.0 : lat.cell_weight[size_t(c)];
}

}  // namespace larap
