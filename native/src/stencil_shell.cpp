#include "stencil_shell.h"

#include <larap/errors.h>

#include <algorithm>
#include <limits>
#include <numeric>

namespace larap {
namespace {

struct ItemSets {
  std::vector<int32_t> parent, real;  // real: the real node a root stands for, or kStencilNone
  int32_t find(int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
};

}  // namespace

std::vector<int32_t> stencil_cover(const Lattice& lat, int64_t nodes) {
  std::vector<int32_t> cover(static_cast<size_t>(27 * nodes), kStencilNone);
  for (const auto& cn : lat.cell_nodes)
    for (int a = 0; a < 8; ++a)
      for (int b = 0; b < 8; ++b) {
        const int k =
            stencil_offset_index((b & 1) - (a & 1), ((b >> 1) & 1) - ((a >> 1) & 1), (b >> 2) - (a >> 2));
        int32_t& c = cover[size_t(27 * int64_t(cn[a]) + k)];
        if (c == kStencilNone) c = cn[b];
        else if (c != cn[b]) c = kStencilAmbiguous;
      }
  return cover;
}

void build_stencil_shell(Lattice& lat) {
  const int64_t nr = lat.num_nodes();
  if (int64_t(27) * nr > int64_t(std::numeric_limits<int32_t>::max()))
    throw OutOfMemory("the lattice has too many nodes for B-spline stencils (" + std::to_string(nr) + ")");
  const int64_t ni = 27 * nr;
  // Real nodes that share a cell copy with n, per offset.
  const std::vector<int32_t> cover = stencil_cover(lat, nr);
  ItemSets sets;
  sets.parent.resize(size_t(ni));
  std::iota(sets.parent.begin(), sets.parent.end(), 0);
  sets.real.resize(size_t(ni));
  for (int64_t i = 0; i < ni; ++i) sets.real[i] = cover[i] >= 0 ? cover[i] : kStencilNone;
  // Items of the two ends of an edge that name the same grid point are one node.
  for (const auto& e : lat.edges) {
    const int32_t u = e[0], v = e[1];
    const Eigen::Vector3i step = lat.node_coords[v] - lat.node_coords[u];
    int axis = 0;
    while (axis < 2 && step[axis] == 0) ++axis;
    (void)step;  // edges run from the lower node up one step along `axis`
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          int d[3] = {dx, dy, dz};
          if (d[axis] < 0) continue;
          const int32_t iu = int32_t(27 * u + stencil_offset_index(d[0], d[1], d[2]));
          d[axis] -= 1;
          const int32_t iv = int32_t(27 * v + stencil_offset_index(d[0], d[1], d[2]));
          if (cover[iu] == kStencilAmbiguous || cover[iv] == kStencilAmbiguous) continue;
          const int32_t ru = sets.find(iu), rv = sets.find(iv);
          if (ru == rv) continue;
          const int32_t pu = sets.real[ru], pv = sets.real[rv];
          if (pu >= 0 && pv >= 0 && pu != pv) continue;  // would join two different real nodes
          const int32_t root = std::min(ru, rv), other = std::max(ru, rv);
          sets.parent[other] = root;
          sets.real[root] = pu >= 0 ? pu : pv;
        }
  }

  // Extrapolation of item (n, d) as (node, weight) terms.
  auto neighbours = [&](int32_t n, int axis, int dir, std::vector<int32_t>& out) {
    out.clear();
    for (int32_t k = lat.adj_offsets[n]; k < lat.adj_offsets[n + 1]; ++k) {
      const int32_t m = lat.adj[k];
      const Eigen::Vector3i s = lat.node_coords[m] - lat.node_coords[n];
      if (s[axis] == dir) out.push_back(m);
    }
  };
  std::vector<int32_t> fw, bw;
  auto extrapolate = [&](int32_t n, int k, double scale, std::vector<std::pair<int32_t, double>>& terms) {
    const int d[3] = {k % 3 - 1, (k / 3) % 3 - 1, k / 9 - 1};
    terms.emplace_back(n, scale);
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0) continue;
      neighbours(n, a, d[a], fw);
      if (!fw.empty()) {
        for (int32_t m : fw) {
          terms.emplace_back(m, scale / double(fw.size()));
          terms.emplace_back(n, -scale / double(fw.size()));
        }
      } else {
        neighbours(n, a, -d[a], bw);
        for (int32_t m : bw) {
          terms.emplace_back(n, scale / double(bw.size()));
          terms.emplace_back(m, -scale / double(bw.size()));
        }
      }
    }
  };

  // Shell nodes: classes without a real node, in order of their first item.
  lat.stencil27.assign(size_t(ni), -1);
  std::vector<int32_t> shell_of_root(static_cast<size_t>(ni), -1);
  std::vector<int32_t> shell_item;       // first item of each shell node
  std::vector<int32_t> members;          // per shell node, its member count
  for (int64_t i = 0; i < ni; ++i) {
    const int32_t r = sets.find(int32_t(i));
    if (sets.real[r] >= 0) {
      lat.stencil27[i] = sets.real[r];
      continue;
    }
    const int32_t key = cover[i] == kStencilAmbiguous ? int32_t(i) : r;
    if (shell_of_root[key] < 0) {
      shell_of_root[key] = int32_t(shell_item.size());
      shell_item.push_back(int32_t(i));
      members.push_back(0);
    }
    const int32_t s = shell_of_root[key];
    lat.stencil27[i] = int32_t(nr) + s;
    ++members[s];
  }
  const int64_t ns = int64_t(shell_item.size());
  std::vector<std::vector<std::pair<int32_t, double>>> terms(static_cast<size_t>(ns));
  for (int64_t i = 0; i < ni; ++i) {
    const int32_t node = lat.stencil27[i];
    if (node < nr) continue;
    const int32_t s = node - int32_t(nr);
    extrapolate(int32_t(i / 27), int(i % 27), 1.0 / members[s], terms[s]);
  }
  lat.shell_offsets.assign(size_t(ns + 1), 0);
  lat.shell_ids.clear();
  lat.shell_weights.clear();
  for (int64_t s = 0; s < ns; ++s) {
    auto& t = terms[s];
    std::sort(t.begin(), t.end());
    for (size_t q = 0; q < t.size();) {
      double w = 0.0;
      size_t r = q;
      for (; r < t.size() && t[r].first == t[q].first; ++r) w += t[r].second;
      if (w != 0.0) {
        lat.shell_ids.push_back(t[q].first);
        lat.shell_weights.push_back(w);
      }
      q = r;
    }
    lat.shell_offsets[s + 1] = int32_t(lat.shell_ids.size());
  }
  // The shell nodes themselves: their point, no edges, the component of their piece.
  lat.node_coords.resize(size_t(nr + ns));
  lat.component.resize(size_t(nr + ns));
  for (int64_t s = 0; s < ns; ++s) {
    const int32_t item = shell_item[s], n = item / 27, k = item % 27;
    lat.node_coords[nr + s] = lat.node_coords[n] + Eigen::Vector3i(k % 3 - 1, (k / 3) % 3 - 1, k / 9 - 1);
    lat.component[nr + s] = lat.component[n];
  }
  lat.rest.conservativeResize(nr + ns, 3);
  for (int64_t s = 0; s < ns; ++s)
    lat.rest.row(nr + s) = (lat.origin + lat.h * lat.node_coords[nr + s].cast<double>()).transpose();
  lat.adj_offsets.resize(size_t(nr + ns + 1), lat.adj_offsets[nr]);
}

}  // namespace larap
