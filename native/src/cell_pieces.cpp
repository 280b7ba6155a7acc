#include "cell_pieces.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include "geometry.h"
#include "parallel.h"
#include "surface_patches.h"

namespace larap {
namespace {

// Small union-find over up to 8 entries.
struct TinyUnionFind {
  int p[8];
  explicit TinyUnionFind(int n) { std::iota(p, p + n, 0); }
  int find(int x) {
    while (p[x] != x) x = p[x] = p[p[x]];
    return x;
  }
  void unite(int a, int b) { p[find(a)] = find(b); }
};

// The parts (mesh_parts.h) whose triangles hit each surface voxel of a cell.
struct PartSets {
  std::vector<int32_t> offsets;  // k^3 + 1: the parts hitting each voxel (CSR), ascending
  std::vector<int32_t> parts;
  bool meet(int64_t a, int64_t b) const {  // the two surface voxels share a part
    int32_t i = offsets[a], j = offsets[b];
    while (i < offsets[a + 1] && j < offsets[b + 1]) {
      if (parts[i] == parts[j]) return true;
      parts[i] < parts[j] ? ++i : ++j;
    }
    return false;
  }
};

// Enclosed voxels between two parts that are only a gap (every voxel of the region touches a
// surface voxel, and the surfaces it touches belong to more than one part): a sliver of space the
// air flood did not reach between two surfaces about two voxels apart, not material. They become
// air (v = 2), so that they do not join the parts. A region with a voxel away from every surface
// (a cavity, the solid around a part inside another) stays material.
void clear_gaps_between_parts(uint8_t* v, int k, const PartSets& sets, std::vector<int32_t>& parent) {
  const int64_t k3 = int64_t(k) * k * k;
  parent.resize(size_t(k3));
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&parent](int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  const int64_t step[3] = {1, k, int64_t(k) * k};
  for (int64_t vi = 0; vi < k3; ++vi) {
    if (v[vi] != 0) continue;
    const int c[3] = {int(vi % k), int((vi / k) % k), int(vi / (int64_t(k) * k))};
    for (int axis = 0; axis < 3; ++axis)
      if (c[axis] + 1 < k && v[vi + step[axis]] == 0) {
        const int32_t a = find(int32_t(vi)), b = find(int32_t(vi + step[axis]));
        if (a != b) parent[std::max(a, b)] = std::min(a, b);
      }
  }
  // Per region (by its root): a voxel away from every surface; the one part it touches, or kMany.
  constexpr int32_t kNone = -1, kMany = -2;
  std::vector<uint8_t> deep(static_cast<size_t>(k3), 0);
  std::vector<int32_t> touched(static_cast<size_t>(k3), kNone);
  for (int64_t vi = 0; vi < k3; ++vi) {
    if (v[vi] != 0) continue;
    const int32_t r = find(int32_t(vi));
    const int c[3] = {int(vi % k), int((vi / k) % k), int(vi / (int64_t(k) * k))};
    bool near = false;
    for (int f = 0; f < 6; ++f) {
      const int axis = f / 2, dir = f % 2 ? 1 : -1;
      if (c[axis] + dir < 0 || c[axis] + dir >= k) continue;
      const int64_t ni = vi + dir * step[axis];
      if (v[ni] != 1) continue;
      near = true;
      for (int32_t q = sets.offsets[ni]; q < sets.offsets[ni + 1]; ++q) {
        int32_t& t = touched[r];
        if (t == kNone) t = sets.parts[q];
        else if (t != sets.parts[q]) t = kMany;
      }
    }
    if (!near) deep[r] = 1;
  }
  for (int64_t vi = 0; vi < k3; ++vi)
    if (v[vi] == 0) {
      const int32_t r = find(int32_t(vi));
      if (!deep[r] && touched[r] == kMany) v[vi] = 2;
    }
}

// A cell's pieces when its triangles belong to several parts. v: the cell's k^3 voxels (0
// enclosed, 1 surface, 2 air). Enclosed voxels join whatever they touch (a part inside another's
// solid moves with it); two surface voxels join only when one part hits both. Writes the piece
// labels (>= 3) into v and the voxels per piece into size; returns the number of pieces.
int32_t pieces_by_part(uint8_t* v, int k, const PartSets& sets, std::vector<int32_t>& parent,
                       std::vector<int32_t>& size) {
  const int64_t k3 = int64_t(k) * k * k;
  parent.resize(size_t(k3));
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&parent](int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  const int64_t step[3] = {1, k, int64_t(k) * k};
  for (int64_t vi = 0; vi < k3; ++vi) {
    if (v[vi] == 2) continue;
    const int c[3] = {int(vi % k), int((vi / k) % k), int(vi / (int64_t(k) * k))};
    for (int axis = 0; axis < 3; ++axis) {
      if (c[axis] + 1 >= k) continue;
      const int64_t ni = vi + step[axis];
      if (v[ni] == 2) continue;
      if (v[vi] == 0 || v[ni] == 0 || sets.meet(vi, ni)) {
        const int32_t a = find(int32_t(vi)), b = find(int32_t(ni));
        if (a != b) parent[std::max(a, b)] = std::min(a, b);  // the root is the smallest voxel
      }
    }
  }
  for (int64_t vi = 0; vi < k3; ++vi)
    if (v[vi] != 2) parent[vi] = find(int32_t(vi));
  // Label in the order of each piece's first voxel (its root), as the flood fill does.
  int32_t np = 0;
  for (int64_t vi = 0; vi < k3; ++vi) {
    if (v[vi] == 2) continue;
    uint8_t label;
    if (parent[vi] == vi) {
      label = uint8_t(3 + std::min(np, 252));  // more than 253 pieces: the rest merge
      ++np;
      if (size.size() < 253) size.push_back(0);
    } else {
      label = v[parent[vi]];  // the root comes first
    }
    v[vi] = label;
    ++size[label - 3];
  }
  return np;
}

}  // namespace

CellPieces find_cell_pieces(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                            const std::vector<uint8_t>& marks, const RowMatrixX3d& V,
                            const std::vector<Eigen::Vector3i>& tris,
                            const std::vector<int32_t>& vertex_part,
                            const std::vector<int64_t>& vertex_cells, int k) {
  CellPieces out;
  const GridIndex g{dims};

  // ---------------------------------------------------------------- candidates
  const SurfacePatches sp = find_surface_patches(origin, h, dims, marks, V, tris);
  const std::vector<int32_t>& surf_of = sp.surf_of;
  const std::vector<int64_t>& surf_cells = sp.cells;
  const int64_t ns = int64_t(surf_cells.size());
  if (ns == 0) return out;
  std::vector<uint8_t> candidate = sp.several;
  // Non-candidate cells around a grid point share its node: they must connect within the block.
  auto analysed = [&](int64_t id) { return surf_of[id] >= 0 && candidate[surf_of[id]]; };
  for (bool changed = true; changed;) {
    changed = false;
    std::vector<uint8_t> visited(size_t(int64_t(dims.x() + 1) * (dims.y() + 1) * (dims.z() + 1)), 0);
    for (int64_t s = 0; s < ns; ++s) {
      if (candidate[s]) continue;
      const Eigen::Vector3i X = g.coords(surf_cells[s]);
      for (int corner = 0; corner < 8; ++corner) {
        const Eigen::Vector3i p = X + Eigen::Vector3i(corner & 1, (corner >> 1) & 1, corner >> 2);
        const int64_t pid = p.x() + int64_t(dims.x() + 1) * (p.y() + int64_t(dims.y() + 1) * p.z());
        if (visited[pid]) continue;
        visited[pid] = 1;
        Eigen::Vector3i cells[8];
        int64_t ids[8];
        int n = 0;
        for (int o = 0; o < 8; ++o) {
          const Eigen::Vector3i c = p - Eigen::Vector3i(1 - (o & 1), 1 - ((o >> 1) & 1), 1 - (o >> 2));
          if (!g.contains(c)) continue;
          const int64_t id = g.index(c);
          if (!(marks[id] & kReal) || analysed(id)) continue;
          cells[n] = c;
          ids[n++] = id;
        }
        if (n < 2) continue;
        TinyUnionFind uf(n);
        for (int i = 0; i < n; ++i)
          for (int j = i + 1; j < n; ++j) {
            const Eigen::Vector3i o = cells[j] - cells[i];
            const bool si = surf_of[ids[i]] >= 0, sj = surf_of[ids[j]] >= 0;
            const bool face = o.cwiseAbs().sum() == 1;
            bool linked;
            if (si && sj) linked = (sp.shares[surf_of[ids[i]]] >> offset_bit(o)) & 1u;
            else if (si || sj) linked = face;
            else linked = true;  // two full cells
            if (linked) uf.unite(i, j);
          }
        int roots = 0;
        for (int i = 0; i < n; ++i) roots += uf.find(i) == i;
        if (roots < 2) continue;
        for (int i = 0; i < n; ++i)
          if (surf_of[ids[i]] >= 0 && !candidate[surf_of[ids[i]]]) {
            candidate[surf_of[ids[i]]] = 1;
            changed = true;
          }
      }
    }
  }

  // ---------------------------------------------------------------- voxels of the candidates
  std::vector<int32_t> block_of_surf(static_cast<size_t>(ns), -1);
  std::vector<int32_t> cand_surf;  // surface index of each candidate
  for (int64_t s = 0; s < ns; ++s)
    if (candidate[s]) {
      block_of_surf[s] = int32_t(cand_surf.size());
      cand_surf.push_back(int32_t(s));
    }
  const int64_t nb = int64_t(cand_surf.size());
  if (nb == 0) return out;
  const int64_t k3 = int64_t(k) * k * k;
  out.voxels = nb * k3;
  std::vector<uint8_t> vox(static_cast<size_t>(nb * k3), 0);  // 0 unknown, 1 surface, 2 air, >= 3 piece + 3
  const double hv = h / k;
  const Eigen::Vector3d vhalf = Eigen::Vector3d::Constant(0.5 * hv * (1.0 + 1e-9));
  auto block_of_cell = [&](const Eigen::Vector3i& c) -> int64_t {
    if (!g.contains(c)) return -1;
    const int32_t s = surf_of[g.index(c)];
    return s >= 0 ? block_of_surf[s] : -1;
  };
  auto vindex = [k](int i, int j, int l) { return i + int64_t(k) * (j + int64_t(k) * l); };

  std::vector<int32_t> cand_offsets, cand_tris;  // triangles of each candidate
  triangles_of(sp, tris, cand_surf, cand_offsets, cand_tris);
  parallel_for(nb, [&](int64_t b) {
    const Eigen::Vector3i X = g.coords(surf_cells[cand_surf[b]]);
    const Eigen::Vector3d corner = origin + h * X.cast<double>();
    uint8_t* v = vox.data() + b * k3;
    for (int32_t q = cand_offsets[b]; q < cand_offsets[b + 1]; ++q) {
      const Eigen::Vector3i& t = tris[cand_tris[q]];
      const Eigen::Vector3d a = V.row(t[0]), bb = V.row(t[1]), c = V.row(t[2]);
      const Eigen::Vector3d lo = a.cwiseMin(bb).cwiseMin(c), hi = a.cwiseMax(bb).cwiseMax(c);
      int v0[3], v1[3];
      for (int w = 0; w < 3; ++w) {
        v0[w] = std::clamp(int(std::floor((lo[w] - corner[w]) / hv - 1e-7)), 0, k - 1);
        v1[w] = std::clamp(int(std::floor((hi[w] - corner[w]) / hv + 1e-7)), 0, k - 1);
      }
      for (int l = v0[2]; l <= v1[2]; ++l)
        for (int j = v0[1]; j <= v1[1]; ++j)
          for (int i = v0[0]; i <= v1[0]; ++i) {
            uint8_t& cell = v[vindex(i, j, l)];
            if (cell) continue;
            const Eigen::Vector3d centre = corner + hv * Eigen::Vector3d(i + 0.5, j + 0.5, l + 0.5);
            if (geometry::triangle_box_overlap(centre, vhalf, a, bb, c)) cell = 1;
          }
    }
  }, 4);

  // Air: flood fill through the candidates from faces that border an empty or outside cell.
  std::vector<int64_t> stack;
  auto face_voxel = [&](int axis, int layer, int u, int w) {
    int c[3];
    c[axis] = layer;
    c[(axis + 1) % 3] = u;
    c[(axis + 2) % 3] = w;
    return vindex(c[0], c[1], c[2]);
  };
  for (int64_t b = 0; b < nb; ++b) {
    const Eigen::Vector3i X = g.coords(surf_cells[cand_surf[b]]);
    for (int f = 0; f < 6; ++f) {
      const int axis = f / 2, side = f % 2;
      Eigen::Vector3i Y = X;
      Y[axis] += side ? 1 : -1;
      if (g.contains(Y) && (marks[g.index(Y)] & (kSurface | kInside))) continue;
      for (int w = 0; w < k; ++w)
        for (int u = 0; u < k; ++u) {
          const int64_t vi = face_voxel(axis, side ? k - 1 : 0, u, w);
          if (vox[b * k3 + vi] == 0) {
            vox[b * k3 + vi] = 2;
            stack.push_back(b * k3 + vi);
          }
        }
    }
  }
  while (!stack.empty()) {
    const int64_t id = stack.back();
    stack.pop_back();
    const int64_t b = id / k3, vi = id % k3;
    const int c[3] = {int(vi % k), int((vi / k) % k), int(vi / (int64_t(k) * k))};
    for (int f = 0; f < 6; ++f) {
      const int axis = f / 2, step = f % 2 ? 1 : -1;
      int n[3] = {c[0], c[1], c[2]};
      n[axis] += step;
      int64_t nbk = b;
      if (n[axis] < 0 || n[axis] >= k) {
        Eigen::Vector3i Y = g.coords(surf_cells[cand_surf[b]]);
        Y[axis] += step;
        nbk = block_of_cell(Y);
        if (nbk < 0) continue;
        n[axis] = (n[axis] + k) % k;
      }
      const int64_t nid = nbk * k3 + vindex(n[0], n[1], n[2]);
      if (vox[nid] == 0) {
        vox[nid] = 2;
        stack.push_back(nid);
      }
    }
  }

  // Parts: a cell whose triangles belong to one part keeps the 6-connected flood fill below; one
  // with several tells their surfaces apart (pieces_by_part). part_of[b]: the cell's one part, or
  // kSeveral.
  constexpr int32_t kSeveral = -1;
  std::vector<int32_t> part_of(static_cast<size_t>(nb));
  for (int64_t b = 0; b < nb; ++b) {
    part_of[b] = cand_offsets[b] < cand_offsets[b + 1] ? vertex_part[tris[cand_tris[cand_offsets[b]]][0]] : 0;
    for (int32_t q = cand_offsets[b]; q < cand_offsets[b + 1]; ++q)
      if (vertex_part[tris[cand_tris[q]][0]] != part_of[b]) part_of[b] = kSeveral;
  }
  const bool by_part = std::find(part_of.begin(), part_of.end(), kSeveral) != part_of.end() ||
                       std::adjacent_find(part_of.begin(), part_of.end(), std::not_equal_to<>()) != part_of.end();
  // What the links across faces need of a face voxel when parts are told apart (by_part): kAir,
  // kEnclosed, a part (>= 0), or -3 - i for the i-th entry of the cell's face_sets (a voxel hit
  // by several parts). Face voxel (f, u, w): f * k^2 + w * k + u, as face_voxel names it.
  constexpr int32_t kAir = -1, kEnclosed = -2;
  std::vector<std::vector<int32_t>> face_keys(static_cast<size_t>(by_part ? nb : 0));
  std::vector<std::vector<std::vector<int32_t>>> face_sets(static_cast<size_t>(by_part ? nb : 0));
  // Parts hit a voxel inflated by this much (a fraction of a voxel each side), so that a crack
  // narrower than a quarter voxel between two parts never falls between two voxels.
  constexpr double kContact = 0.125;
  const Eigen::Vector3d vreach = Eigen::Vector3d::Constant(0.5 * hv * (1.0 + 2.0 * kContact));

  // Pieces: 6-connected components of the material voxels of each cell.
  std::vector<int32_t> pieces(static_cast<size_t>(nb), 0);
  std::vector<std::vector<int32_t>> sizes(static_cast<size_t>(nb));  // material voxels per piece
  parallel_for(nb, [&](int64_t b) {
    uint8_t* v = vox.data() + b * k3;
    std::vector<int32_t> todo;
    auto& size = sizes[size_t(b)];
    int32_t np = 0;
    PartSets sets;
    if (by_part) {
      // Which parts hit each surface voxel (the voxels the first pass found, tested again per part).
      const Eigen::Vector3i X = g.coords(surf_cells[cand_surf[b]]);
      const Eigen::Vector3d corner = origin + h * X.cast<double>();
      std::vector<std::pair<int32_t, int32_t>> hits;  // (voxel, part)
      if (part_of[b] == kSeveral) {
        std::vector<int32_t> last(static_cast<size_t>(k3), -1);  // the last part found there
        for (int32_t q = cand_offsets[b]; q < cand_offsets[b + 1]; ++q) {
          const Eigen::Vector3i& t = tris[cand_tris[q]];
          const int32_t part = vertex_part[t[0]];
          const Eigen::Vector3d a = V.row(t[0]), bb = V.row(t[1]), c = V.row(t[2]);
          const Eigen::Vector3d lo = a.cwiseMin(bb).cwiseMin(c), hi = a.cwiseMax(bb).cwiseMax(c);
          int v0[3], v1[3];
          for (int w = 0; w < 3; ++w) {
            v0[w] = std::clamp(int(std::floor((lo[w] - corner[w]) / hv - kContact - 1e-7)), 0, k - 1);
            v1[w] = std::clamp(int(std::floor((hi[w] - corner[w]) / hv + kContact + 1e-7)), 0, k - 1);
          }
          for (int l = v0[2]; l <= v1[2]; ++l)
            for (int j = v0[1]; j <= v1[1]; ++j)
              for (int i = v0[0]; i <= v1[0]; ++i) {
                const int64_t vi = vindex(i, j, l);
                if (v[vi] != 1 || last[vi] == part) continue;
                const Eigen::Vector3d centre = corner + hv * Eigen::Vector3d(i + 0.5, j + 0.5, l + 0.5);
                if (!geometry::triangle_box_overlap(centre, vreach, a, bb, c)) continue;
                last[vi] = part;
                hits.emplace_back(int32_t(vi), part);
              }
        }
        std::sort(hits.begin(), hits.end());
        hits.erase(std::unique(hits.begin(), hits.end()), hits.end());
        sets.offsets.assign(size_t(k3 + 1), 0);
        for (const auto& hp : hits) ++sets.offsets[hp.first + 1];
        for (int64_t vi = 0; vi < k3; ++vi) sets.offsets[vi + 1] += sets.offsets[vi];
        sets.parts.resize(hits.size());
        for (size_t i = 0; i < hits.size(); ++i) sets.parts[i] = hits[i].second;  // hits are sorted
        std::vector<int32_t> scratch;
        clear_gaps_between_parts(v, k, sets, scratch);
      }
      auto& keys = face_keys[b];
      keys.resize(size_t(6) * k * k);
      for (int f = 0; f < 6; ++f)
        for (int w = 0; w < k; ++w)
          for (int u = 0; u < k; ++u) {
            const int64_t vi = face_voxel(f / 2, f % 2 ? k - 1 : 0, u, w);
            int32_t& key = keys[size_t(f) * k * k + size_t(w) * k + u];
            if (v[vi] == 2) key = kAir;
            else if (v[vi] == 0) key = kEnclosed;
            else if (part_of[b] != kSeveral) key = part_of[b];
            else if (sets.offsets[vi + 1] - sets.offsets[vi] == 1) key = sets.parts[sets.offsets[vi]];
            else {
              key = -3 - int32_t(face_sets[b].size());
              face_sets[b].emplace_back(sets.parts.begin() + sets.offsets[vi], sets.parts.begin() + sets.offsets[vi + 1]);
            }
          }
    }
    if (by_part && part_of[b] == kSeveral) {
      std::vector<int32_t> parent;
      np = pieces_by_part(v, k, sets, parent, size);
      pieces[b] = std::max(1, std::min(np, 253));
      return;
    }
    for (int64_t start = 0; start < k3; ++start) {
      if (v[start] >= 2) continue;
      const uint8_t label = uint8_t(3 + std::min(np, 252));  // more than 253 pieces: the rest merge
      ++np;
      if (size.size() < 253) size.push_back(0);
      v[start] = label;
      todo.push_back(int32_t(start));
      while (!todo.empty()) {
        const int32_t vi = todo.back();
        todo.pop_back();
        ++size[label - 3];
        const int c[3] = {vi % k, (vi / k) % k, vi / (k * k)};
        for (int f = 0; f < 6; ++f) {
          int n[3] = {c[0], c[1], c[2]};
          n[f / 2] += f % 2 ? 1 : -1;
          if (n[f / 2] < 0 || n[f / 2] >= k) continue;
          const int64_t ni = vindex(n[0], n[1], n[2]);
          if (v[ni] < 2) {
            v[ni] = label;
            todo.push_back(int32_t(ni));
          }
        }
      }
    }
    pieces[b] = std::max(1, std::min(np, 253));
  }, 4);

  // Links across faces, per analysed cell (deterministic order). When parts are told apart, two
  // touching face voxels link their pieces if either is enclosed or one part hits both; a piece
  // links to an unanalysed surface neighbour (one patch, so one part) through an enclosed voxel
  // or that part's surface (to an unanalysed inside cell through any material).
  auto touch = [&](int64_t b, int32_t ka, int64_t yb, int32_t kc) {
    if (ka == kEnclosed || kc == kEnclosed) return true;
    const int32_t* a0 = ka >= 0 ? &ka : face_sets[b][size_t(-3 - ka)].data();
    const int32_t* a1 = ka >= 0 ? &ka + 1 : a0 + face_sets[b][size_t(-3 - ka)].size();
    const int32_t* c0 = kc >= 0 ? &kc : face_sets[yb][size_t(-3 - kc)].data();
    const int32_t* c1 = kc >= 0 ? &kc + 1 : c0 + face_sets[yb][size_t(-3 - kc)].size();
    while (a0 < a1 && c0 < c1) {
      if (*a0 == *c0) return true;
      *a0 < *c0 ? ++a0 : ++c0;
    }
    return false;
  };
  std::unordered_map<int32_t, int32_t> plain_part;  // unanalysed surface neighbour -> its part
  if (by_part) {
    std::vector<int32_t> plain;
    for (int64_t b = 0; b < nb; ++b) {
      const Eigen::Vector3i X = g.coords(surf_cells[cand_surf[b]]);
      for (int f = 0; f < 6; ++f) {
        Eigen::Vector3i Y = X;
        Y[f / 2] += f % 2 ? 1 : -1;
        if (g.contains(Y) && surf_of[g.index(Y)] >= 0 && block_of_cell(Y) < 0) plain.push_back(surf_of[g.index(Y)]);
      }
    }
    std::sort(plain.begin(), plain.end());
    plain.erase(std::unique(plain.begin(), plain.end()), plain.end());
    std::vector<int32_t> offsets, ids;
    triangles_of(sp, tris, plain, offsets, ids);
    for (size_t i = 0; i < plain.size(); ++i)
      if (offsets[i] < offsets[i + 1]) plain_part[plain[i]] = vertex_part[tris[ids[offsets[i]]][0]];
  }
  std::vector<std::vector<PieceLink>> links(static_cast<size_t>(nb));
  parallel_for(nb, [&](int64_t b) {
    const int64_t xid = surf_cells[cand_surf[b]];
    const Eigen::Vector3i X = g.coords(xid);
    const uint8_t* v = vox.data() + b * k3;
    auto& mine = links[b];
    for (int f = 0; f < 6; ++f) {
      const int axis = f / 2, side = f % 2;
      Eigen::Vector3i Y = X;
      Y[axis] += side ? 1 : -1;
      if (!g.contains(Y)) continue;
      const int64_t yid = g.index(Y);
      if (!(marks[yid] & kReal)) continue;
      const int64_t yb = block_of_cell(Y);
      const int layer = side ? k - 1 : 0;
      if (yb >= 0) {
        if (!side) continue;  // the pair is listed once, from its lower cell
        const uint8_t* w = vox.data() + yb * k3;
        std::vector<std::pair<int32_t, int32_t>> pairs;
        for (int q = 0; q < k; ++q)
          for (int u = 0; u < k; ++u) {
            const uint8_t a = v[face_voxel(axis, layer, u, q)], c = w[face_voxel(axis, 0, u, q)];
            if (a < 3 || c < 3) continue;
            if (by_part && !touch(b, face_keys[b][size_t(f) * k * k + size_t(q) * k + u], yb,
                                  face_keys[yb][size_t(f - 1) * k * k + size_t(q) * k + u]))
              continue;
            pairs.emplace_back(a - 3, c - 3);
          }
        std::sort(pairs.begin(), pairs.end());
        pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
        for (const auto& pr : pairs) mine.push_back({xid, pr.first, f, yid, pr.second});
      } else {
        std::vector<uint8_t> has(static_cast<size_t>(pieces[b]), 0);
        const int32_t ys = surf_of[yid];
        const auto known = ys >= 0 && by_part ? plain_part.find(ys) : plain_part.end();
        for (int q = 0; q < k; ++q)
          for (int u = 0; u < k; ++u) {
            const uint8_t a = v[face_voxel(axis, layer, u, q)];
            if (a < 3) continue;
            if (known != plain_part.end() &&
                !touch(b, face_keys[b][size_t(f) * k * k + size_t(q) * k + u], b, known->second))
              continue;
            has[a - 3] = 1;
          }
        for (int32_t p = 0; p < pieces[b]; ++p)
          if (has[p]) mine.push_back({xid, p, f, yid, -1});
      }
    }
  }, 4);

  // Vertices: the piece of the voxel holding them (the nearest material voxel for a loose vertex).
  const std::vector<int64_t> held = parallel_select(V.rows(), [&](int64_t vtx) {  // in analysed cells
    const int32_t s = surf_of[vertex_cells[vtx]];
    return s >= 0 && block_of_surf[s] >= 0;
  });
  std::vector<int32_t> held_piece(held.size(), 0);
  parallel_for(int64_t(held.size()), [&](int64_t i) {
    const int64_t vtx = held[i], cid = vertex_cells[vtx];
    const int64_t b = block_of_surf[surf_of[cid]];
    const Eigen::Vector3i X = g.coords(cid);
    const Eigen::Vector3d local = (V.row(vtx).transpose() - origin) / h - X.cast<double>();
    int c[3];
    for (int w = 0; w < 3; ++w) c[w] = std::clamp(int(std::floor(local[w] * k)), 0, k - 1);
    const uint8_t* v = vox.data() + b * k3;
    uint8_t label = v[vindex(c[0], c[1], c[2])];
    if (label < 3) {
      int64_t best = -1, best_d = std::numeric_limits<int64_t>::max();
      for (int64_t vi = 0; vi < k3; ++vi) {
        if (v[vi] < 3) continue;
        const int64_t dx = vi % k - c[0], dy = (vi / k) % k - c[1], dz = vi / (int64_t(k) * k) - c[2];
        const int64_t d2 = dx * dx + dy * dy + dz * dz;
        if (d2 < best_d) {
          best_d = d2;
          best = vi;
        }
      }
      label = best >= 0 ? v[best] : 3;
    }
    held_piece[i] = label - 3;
  }, 1024);
  for (size_t i = 0; i < held.size(); ++i)
    if (held_piece[i]) out.vertex_pieces.emplace_back(held[i], held_piece[i]);

  out.k = k;
  for (int64_t b = 0; b < nb; ++b) {
    out.cells.push_back(surf_cells[cand_surf[b]]);
    out.pieces.push_back(pieces[b]);
    if (sizes[size_t(b)].empty()) sizes[size_t(b)].push_back(0);  // a cell without material: one piece
    out.piece_voxels.insert(out.piece_voxels.end(), sizes[size_t(b)].begin(), sizes[size_t(b)].end());
    out.links.insert(out.links.end(), links[b].begin(), links[b].end());
  }
  return out;
}

}  // namespace larap
