#include "junction_braces.h"

#include <algorithm>

#include "parallel.h"

namespace larap {

namespace {

// Whether copy `c` and copy `d` (the next cell along `axis`, on side `side` of c) share the four
// nodes of the face between them.
bool share_face(const Lattice& lat, int32_t c, int32_t d, int axis, int side) {
  const auto& mine = lat.cell_nodes[size_t(c)];
  const auto& theirs = lat.cell_nodes[size_t(d)];
  for (int q = 0; q < 8; ++q)
    if (((q >> axis) & 1) == side && mine[q] != theirs[q ^ (1 << axis)]) return false;
  return true;
}

}  // namespace

std::vector<std::array<int32_t, 3>> junction_braces(const Lattice& lat) {
  const int64_t nc = lat.num_cells();
  std::vector<std::vector<std::array<int32_t, 3>>> per_cell(static_cast<size_t>(nc));
  parallel_for(nc, [&](int64_t c) {
    const Eigen::Vector3i& x = lat.cell_coords[size_t(c)];
    for (int axis = 0; axis < 3; ++axis)
      for (int side = 0; side < 2; ++side) {
        Eigen::Vector3i y = x;
        y[axis] += side ? 1 : -1;
        const int32_t n = lat.cell_copies(y.x(), y.y(), y.z());
        if (n < 2) continue;
        const int32_t first = lat.cell_at(y.x(), y.y(), y.z());
        int joined = 0;
        for (int32_t d = first; d < first + n; ++d) joined += share_face(lat, int32_t(c), d, axis, side);
        if (joined < 2) continue;
        // c branches towards `side`: brace its columns through the copies on the other side that
        // share its near face (the palm).
        Eigen::Vector3i z = x;
        z[axis] -= side ? 1 : -1;
        const int32_t back = lat.cell_at(z.x(), z.y(), z.z());
        if (back < 0) continue;
        const int32_t nb = lat.cell_copies(z.x(), z.y(), z.z());
        const auto& mine = lat.cell_nodes[size_t(c)];
        // Exactly one trunk copy: a copy that branches on both sides (an X) would otherwise tie
        // the branches behind it to one another through its columns.
        int32_t trunk = -1, trunks = 0;
        for (int32_t d = back; d < back + nb; ++d)
          if (share_face(lat, int32_t(c), d, axis, 1 - side)) {
            trunk = d;
            ++trunks;
          }
        if (trunks == 1) {
          const auto& theirs = lat.cell_nodes[size_t(trunk)];
          // q: a corner of c's near face; the trunk's corner q is the node one cell farther from
          // the branching face, on the same column.
          for (int q = 0; q < 8; ++q)
            if (((q >> axis) & 1) != side) {
              std::array<int32_t, 3> s{theirs[q], mine[q], mine[q ^ (1 << axis)]};
              if (s[0] > s[2]) std::swap(s[0], s[2]);  // one orientation: a column braced twice is one brace
              per_cell[size_t(c)].push_back(s);
            }
        }
      }
  }, 1024);
  std::vector<std::array<int32_t, 3>> out;
  for (auto& v : per_cell) out.insert(out.end(), v.begin(), v.end());
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

}  // namespace larap
