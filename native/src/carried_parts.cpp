#include "carried_parts.h"

#include <algorithm>
#include <map>
#include <tuple>
#include <utility>

namespace larap {

namespace {

// A real node of a component without handles, ordered by its grid point.
struct FreeNode {
  int32_t x, y, z, node;
  bool operator<(const FreeNode& o) const { return std::tie(x, y, z, node) < std::tie(o.x, o.y, o.z, o.node); }
};

}  // namespace

CarriedParts carried_parts(const Lattice& lat, const std::vector<uint8_t>& has_handle) {
  CarriedParts out;
  const int64_t nn = lat.num_nodes(), nr = lat.num_real_nodes();
  const int32_t nc = lat.num_components;
  out.node_component = lat.component;
  out.carrier.assign(size_t(nc), -1);
  out.anchored.assign(size_t(nn), 0);
  bool any_free = false;
  for (int32_t c = 0; c < nc; ++c) any_free |= !has_handle[c];
  if (!any_free) return out;

  // Pairs (free node, node of another component at the same grid point), ordered.
  std::vector<FreeNode> free_nodes;
  for (int64_t i = 0; i < nr; ++i)
    if (!has_handle[lat.component[i]]) {
      const Eigen::Vector3i& p = lat.node_coords[i];
      free_nodes.push_back({p.x(), p.y(), p.z(), int32_t(i)});
    }
  std::sort(free_nodes.begin(), free_nodes.end());
  std::vector<std::pair<int32_t, int32_t>> pairs;
  for (int64_t j = 0; j < nr; ++j) {
    const Eigen::Vector3i& p = lat.node_coords[j];
    const FreeNode lo{p.x(), p.y(), p.z(), INT32_MIN};
    for (auto it = std::lower_bound(free_nodes.begin(), free_nodes.end(), lo);
         it != free_nodes.end() && it->x == p.x() && it->y == p.y() && it->z == p.z(); ++it)
      if (lat.component[it->node] != lat.component[j]) pairs.emplace_back(it->node, int32_t(j));
  }
  std::sort(pairs.begin(), pairs.end());

  // Rounds: a free component is carried by the resolved component (handled, or carried in an
  // earlier round) it shares most grid points with.
  std::vector<uint8_t> resolved(has_handle.begin(), has_handle.end());
  for (bool grew = true; grew;) {
    grew = false;
    std::map<std::pair<int32_t, int32_t>, int64_t> shared;  // (free, resolved) -> points
    for (const auto& [i, j] : pairs) {
      const int32_t ci = lat.component[i], cj = lat.component[j];
      if (!resolved[ci] && resolved[cj]) ++shared[{ci, cj}];
    }
    std::vector<std::pair<int32_t, int64_t>> best(size_t(nc), {-1, 0});
    for (const auto& [key, count] : shared)  // ascending carrier id: ties keep the lower
      if (count > best[key.first].second) best[key.first] = {key.second, count};
    for (int32_t c = 0; c < nc; ++c)
      if (best[c].first >= 0) {
        out.carrier[c] = best[c].first;
        resolved[c] = 1;
        grew = true;
      }
  }

  // Each carried node is glued to the lowest-numbered node of its carrier at its grid point.
  for (const auto& [i, j] : pairs) {
    if (!out.glue.empty() && out.glue.back()[0] == i) continue;  // pairs are ordered by i
    if (lat.component[j] == out.carrier[lat.component[i]]) out.glue.push_back({i, j});
  }

  std::vector<int32_t> root(static_cast<size_t>(nc));
  for (int32_t c = 0; c < nc; ++c) {
    int32_t r = c;
    while (out.carrier[r] >= 0) r = out.carrier[r];  // chains end at a handled component
    root[c] = r;
  }
  for (int64_t i = 0; i < nn; ++i) {
    const int32_t c = lat.component[i];
    out.node_component[i] = root[c];
    out.anchored[i] = resolved[c] ? 0 : 1;
  }
  return out;
}

}  // namespace larap
