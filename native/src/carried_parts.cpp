#include "carried_parts.h"

#include <algorithm>
#include <tuple>
#include <utility>

namespace larap {

namespace {

// A real node of a component without handles, ordered by its grid point.
struct FreeNode {
  int32_t x, y, z, node;
  bool operator<(const FreeNode& o) const { return std::tie(x, y, z, node) < std::tie(o.x, o.y, o.z, o.node); }
};

// Free component `free` has `nodes` real nodes at grid points of component `other`'s nodes.
struct Link {
  int32_t other, free;
  int64_t nodes;
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

  // Links between components: (other component, free component, the free component's nodes at a
  // grid point of the other's), ordered by the other component.
  std::vector<std::pair<int32_t, int32_t>> node_links;  // (free node, other component), once each
  node_links.reserve(pairs.size());
  for (const auto& [i, j] : pairs) node_links.emplace_back(i, lat.component[j]);
  std::sort(node_links.begin(), node_links.end());
  node_links.erase(std::unique(node_links.begin(), node_links.end()), node_links.end());
  std::vector<std::pair<int32_t, int32_t>> comp_pairs;  // (other, free) per free node
  comp_pairs.reserve(node_links.size());
  for (const auto& [i, other] : node_links) comp_pairs.emplace_back(other, lat.component[i]);
  std::sort(comp_pairs.begin(), comp_pairs.end());
  std::vector<Link> links;
  for (size_t k = 0; k < comp_pairs.size(); ++k) {
    if (k > 0 && comp_pairs[k] == comp_pairs[k - 1]) {
      ++links.back().nodes;
      continue;
    }
    links.push_back({comp_pairs[k].first, comp_pairs[k].second, 1});
  }
  std::vector<int64_t> link_offsets(size_t(nc) + 1, 0);
  for (const Link& l : links) ++link_offsets[size_t(l.other) + 1];
  for (int32_t c = 0; c < nc; ++c) link_offsets[size_t(c) + 1] += link_offsets[size_t(c)];
  std::vector<int64_t> size(size_t(nc), 0);  // real nodes per component
  for (int64_t i = 0; i < nr; ++i) ++size[size_t(lat.component[i])];

  // Rounds, breadth first: a free component is carried by the component resolved in the last
  // round (handled, in the first) that holds most of its nodes at its grid points (ties: the lower
  // id), when that is at least kCarriedShare of its nodes. A component resolved earlier has no
  // unresolved neighbour left, so only the last round's count.
  std::vector<uint8_t> resolved(has_handle.begin(), has_handle.end());
  std::vector<int32_t> frontier;
  for (int32_t c = 0; c < nc; ++c)
    if (has_handle[c]) frontier.push_back(c);
  std::vector<int64_t> best_nodes(size_t(nc), 0);
  while (!frontier.empty()) {
    std::vector<int32_t> next;
    for (const int32_t r : frontier)  // ascending: ties keep the lower carrier
      for (int64_t k = link_offsets[r]; k < link_offsets[size_t(r) + 1]; ++k) {
        const Link& l = links[size_t(k)];
        if (resolved[l.free] || !(double(l.nodes) >= kCarriedShare * double(size[size_t(l.free)]))) continue;
        if (out.carrier[l.free] < 0) next.push_back(l.free);
        if (l.nodes > best_nodes[l.free]) {
          best_nodes[l.free] = l.nodes;
          out.carrier[l.free] = r;
        }
      }
    for (const int32_t c : next) resolved[c] = 1;
    frontier = std::move(next);
    std::sort(frontier.begin(), frontier.end());
  }

  // Each carried node is glued to the carrier's node at its grid point whose cells lie in most of
  // the same places as its own (a ring around one of two fingers that a split cell keeps apart
  // glues to that finger's copy), ties to the lower id.
  std::vector<uint8_t> octants(size_t(nr), 0);  // bit k: a cell copy has the node as its corner k
  for (const auto& corners : lat.cell_nodes)
    for (int k = 0; k < 8; ++k)
      if (corners[k] < nr) octants[size_t(corners[k])] |= uint8_t(1u << k);
  for (size_t k = 0; k < pairs.size();) {
    const int32_t i = pairs[k].first, carrier = out.carrier[lat.component[i]];
    int32_t best = -1, best_common = -1;
    for (; k < pairs.size() && pairs[k].first == i; ++k) {
      const int32_t j = pairs[k].second;
      if (carrier < 0 || lat.component[j] != carrier) continue;
      const int common = __builtin_popcount(unsigned(octants[size_t(i)] & octants[size_t(j)]));
      if (common > best_common) {
        best = j;
        best_common = common;
      }
    }
    if (best >= 0) out.glue.push_back({i, best});
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
