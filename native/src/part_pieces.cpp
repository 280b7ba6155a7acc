#include "part_pieces.h"

#include "disjoint_sets.h"

namespace larap {
namespace {

// Calls visit(vi, c) for every voxel of a k^3 grid, c its coordinates (vi = c0 + k (c1 + k c2)),
// without divisions.
template <class F>
void for_each_voxel(int k, F&& visit) {
  int64_t vi = 0;
  for (int l = 0; l < k; ++l)
    for (int j = 0; j < k; ++j)
      for (int i = 0; i < k; ++i, ++vi) {
        const int c[3] = {i, j, l};
        visit(vi, c);
      }
}

// The neighbour of voxel vi (coordinates c) one step along +axis, or -1 outside the cell.
inline int64_t next_along(int64_t vi, const int* c, int axis, int k) {
  const int64_t step = axis == 0 ? 1 : axis == 1 ? k : int64_t(k) * k;
  return c[axis] + 1 < k ? vi + step : -1;
}

}  // namespace

PartSets part_sets(const uint8_t* v, int k, const Eigen::Vector3d& corner, double hv, const RowMatrixX3d& V,
                   const std::vector<Eigen::Vector3i>& tris, const int32_t* ids, int32_t q0, int32_t q1,
                   const std::vector<int32_t>& vertex_part) {
  const int64_t k3 = int64_t(k) * k * k;
  std::vector<std::pair<int32_t, int32_t>> hits;  // (voxel, part)
  std::vector<int32_t> last(static_cast<size_t>(k3), -1);  // the part last found there (saves tests)
  for (int32_t q = q0; q < q1; ++q) {
    const Eigen::Vector3i& t = tris[ids[q]];
    const int32_t part = vertex_part[t[0]];
    for_each_voxel_hit(corner, hv, k, V.row(t[0]).transpose(), V.row(t[1]).transpose(), V.row(t[2]).transpose(),
                       kContact, [&](int64_t vi) { return v[vi] != 1 || last[vi] == part; },
                       [&](int64_t vi) {
                         last[vi] = part;
                         hits.emplace_back(int32_t(vi), part);
                       });
  }
  std::sort(hits.begin(), hits.end());
  hits.erase(std::unique(hits.begin(), hits.end()), hits.end());
  PartSets sets;
  sets.offsets.assign(size_t(k3 + 1), 0);
  for (const auto& hp : hits) ++sets.offsets[hp.first + 1];
  for (int64_t vi = 0; vi < k3; ++vi) sets.offsets[vi + 1] += sets.offsets[vi];
  sets.parts.resize(hits.size());
  for (size_t i = 0; i < hits.size(); ++i) sets.parts[i] = hits[i].second;  // sorted by voxel, then part
  return sets;
}

int32_t pieces_by_part(uint8_t* v, int k, const PartSets& sets, std::vector<int32_t>& size) {
  const int64_t k3 = int64_t(k) * k * k;
  DisjointSets pieces(k3);  // the root of a piece is its smallest voxel
  for_each_voxel(k, [&](int64_t vi, const int* c) {
    if (v[vi] == 2) return;
    for (int axis = 0; axis < 3; ++axis) {
      const int64_t ni = next_along(vi, c, axis, k);
      if (ni < 0 || v[ni] == 2) continue;
      if (v[vi] == 0 || v[ni] == 0 || sets.meet(vi, ni)) pieces.unite(int32_t(vi), int32_t(ni));
    }
  });
  int32_t np = 0;
  for (int64_t vi = 0; vi < k3; ++vi) {
    if (v[vi] == 2) continue;
    const int32_t root = pieces.find(int32_t(vi));
    uint8_t label;
    if (root == vi) {
      label = uint8_t(3 + std::min(np, 252));  // more than 253 pieces: the rest merge
      ++np;
      if (size.size() < 253) size.push_back(0);
    } else {
      label = v[root];  // the root, the smallest voxel, is labelled first
    }
    v[vi] = label;
    ++size[label - 3];
  }
  return np;
}

}  // namespace larap
