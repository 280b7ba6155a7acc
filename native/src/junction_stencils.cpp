#include "junction_stencils.h"

#include <larap/errors.h>

#include <algorithm>
#include <array>
#include <limits>
#include <map>
#include <unordered_map>

#include "mesh_parts.h"
#include "stencil_shell.h"

namespace larap {
namespace {

using Row = std::array<int32_t, 27>;

}  // namespace

void resolve_junction_stencils(const Lattice& lat, const PolygonMesh& mesh, Binding& b) {
  if (b.kind != WeightKind::BSpline || lat.stencil27.empty()) return;
  const int64_t nr = lat.num_real_nodes();
  const std::vector<int32_t> cover = stencil_cover(lat, nr);
  std::vector<uint8_t> junction(static_cast<size_t>(nr), 0);
  bool any = false;
  for (int64_t i = 0; i < nr; ++i)
    for (int k = 0; k < 27 && !junction[i]; ++k)
      if (cover[size_t(27 * i + k)] == kStencilAmbiguous) junction[i] = 1, any = true;
  if (!any) return;

  // The copies around each junction node (CSR), with the corner the node is of each.
  std::vector<int32_t> offsets(size_t(nr + 1), 0);
  for (const auto& cn : lat.cell_nodes)
    for (int a = 0; a < 8; ++a)
      if (junction[cn[a]]) ++offsets[cn[a] + 1];
  for (int64_t i = 0; i < nr; ++i) offsets[i + 1] += offsets[i];
  std::vector<std::pair<int32_t, int8_t>> around(static_cast<size_t>(offsets[size_t(nr)]));
  {
    std::vector<int32_t> fill(offsets.begin(), offsets.end() - 1);
    for (int32_t c = 0; c < int32_t(lat.cell_nodes.size()); ++c)
      for (int a = 0; a < 8; ++a) {
        const int32_t n = lat.cell_nodes[c][a];
        if (junction[n]) around[size_t(fill[n]++)] = {c, int8_t(a)};
      }
  }

  // Which parts each copy holds: sorted (copy, part) pairs of the vertices.
  const std::vector<int32_t> part = mesh_parts(mesh);
  const int64_t nv = mesh.num_vertices();
  std::vector<std::pair<int32_t, int32_t>> holds(static_cast<size_t>(nv));
  for (int64_t v = 0; v < nv; ++v) holds[v] = {lat.vertex_cell[v], part[v]};
  std::sort(holds.begin(), holds.end());
  holds.erase(std::unique(holds.begin(), holds.end()), holds.end());
  auto holds_part = [&](int32_t copy, int32_t p) {
    return std::binary_search(holds.begin(), holds.end(), std::make_pair(copy, p));
  };

  // The row of junction node n seen from part p.
  auto row_of = [&](int32_t n, int32_t p) {
    Row row;
    std::copy_n(lat.stencil27.begin() + 27 * int64_t(n), 27, row.begin());
    std::vector<std::pair<int32_t, int8_t>> side;
    for (int32_t q = offsets[n]; q < offsets[n + 1]; ++q)
      if (holds_part(around[q].first, p)) side.push_back(around[q]);
    for (int k = 0; k < 27; ++k) {
      if (cover[size_t(27 * int64_t(n) + k)] != kStencilAmbiguous) continue;
      const int d[3] = {k % 3 - 1, (k / 3) % 3 - 1, k / 9 - 1};
      // 1. The node at n + d of the side's copies: the one, or where the side's copies name
      //    several (one copy per branch: a part's copy on the palm's side and its own beyond,
      //    branch_copies.h), the one most of them name (the lowest id on a tie) -- a node of the
      //    part's side either way, where the node's own item mixes every piece at that point.
      std::map<int32_t, int> named;
      for (const auto& [c, a] : side) {
        const int bc[3] = {(a & 1) + d[0], ((a >> 1) & 1) + d[1], (a >> 2) + d[2]};
        if (bc[0] < 0 || bc[0] > 1 || bc[1] < 0 || bc[1] > 1 || bc[2] < 0 || bc[2] > 1) continue;
        ++named[lat.cell_nodes[c][bc[0] | (bc[1] << 1) | (bc[2] << 2)]];
      }
      if (!named.empty()) {
        int32_t best = named.begin()->first;
        for (const auto& [m, count] : named)
          if (count > named[best]) best = m;
        row[k] = best;
        continue;
      }
      // 2. The item a corner of the side's copies has for the same point, without ambiguity.
      const Eigen::Vector3i point = lat.node_coords[n] + Eigen::Vector3i(d[0], d[1], d[2]);
      int32_t found = kStencilNone;
      bool unique = true;
      for (const auto& [c, a] : side)
        for (int corner = 0; corner < 8; ++corner) {
          const int32_t u = lat.cell_nodes[c][corner];
          if (u == n) continue;
          const Eigen::Vector3i s = point - lat.node_coords[u];
          if (s.cwiseAbs().maxCoeff() > 1) continue;
          const int ku = stencil_offset_index(s[0], s[1], s[2]);
          if (cover[size_t(27 * int64_t(u) + ku)] == kStencilAmbiguous) continue;
          const int32_t m = lat.stencil27[size_t(27 * int64_t(u) + ku)];
          if (found == kStencilNone) found = m;
          else if (found != m) unique = false;
        }
      if (found != kStencilNone && unique) row[k] = found;
    }
    return row;
  };

  // Vertices near junctions, one row per (node, part); rows that differ from the node's own are
  // appended once.
  std::unordered_map<int64_t, int32_t> row_id;  // key n * nv + part -> row (or n itself)
  std::map<Row, int32_t> appended;
  const int64_t rows0 = int64_t(b.node27.size()) / 27;
  std::vector<Row> extra;
  for (int64_t v = 0; v < nv; ++v) {
    const int32_t n = b.base[v];
    if (n < 0 || n >= nr || !junction[n]) continue;
    const int64_t key = int64_t(n) * nv + part[v];
    auto it = row_id.find(key);
    if (it == row_id.end()) {
      const Row row = row_of(n, part[v]);
      int32_t id = n;
      if (!std::equal(row.begin(), row.end(), lat.stencil27.begin() + 27 * int64_t(n))) {
        auto [at, inserted] = appended.emplace(row, int32_t(rows0 + int64_t(extra.size())));
        if (inserted) {
          if (rows0 + int64_t(extra.size()) >= int64_t(std::numeric_limits<int32_t>::max()))
            throw OutOfMemory("too many B-spline stencil rows at junctions");
          extra.push_back(row);
        }
        id = at->second;
      }
      it = row_id.emplace(key, id).first;
    }
    b.base[v] = it->second;
  }
  b.node27.reserve(b.node27.size() + 27 * extra.size());
  for (const Row& r : extra) b.node27.insert(b.node27.end(), r.begin(), r.end());
}

}  // namespace larap
