#include "branching_copies.h"

#include "parallel.h"

namespace larap {

std::vector<uint8_t> branching_copies(const Lattice& lat) {
  const int64_t nc = lat.num_cells();
  std::vector<uint8_t> branching(static_cast<size_t>(nc), 0);
  parallel_for(nc, [&](int64_t c) {
    const Eigen::Vector3i& x = lat.cell_coords[size_t(c)];
    const auto& mine = lat.cell_nodes[size_t(c)];
    for (int axis = 0; axis < 3 && !branching[size_t(c)]; ++axis)
      for (int side = 0; side < 2; ++side) {
        Eigen::Vector3i y = x;
        y[axis] += side ? 1 : -1;
        const int32_t n = lat.cell_copies(y.x(), y.y(), y.z());
        if (n < 2) continue;
        const int32_t first = lat.cell_at(y.x(), y.y(), y.z());
        int joined = 0;
        for (int32_t d = first; d < first + n; ++d) {
          const auto& theirs = lat.cell_nodes[size_t(d)];
          bool face = true;
          for (int q = 0; q < 8 && face; ++q)  // my corners on this face against theirs across it
            if (((q >> axis) & 1) == side) face = mine[q] == theirs[q ^ (1 << axis)];
          joined += face;
        }
        if (joined >= 2) {
          branching[size_t(c)] = 1;
          break;
        }
      }
  }, 1024);
  return branching;
}

}  // namespace larap
