#include "surface_patches.h"

#include <larap/errors.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <string>

#include "cell_pieces.h"
#include "disjoint_sets.h"
#include "geometry.h"
#include "parallel.h"

namespace larap {
namespace {

constexpr uint32_t kNoCell = SurfacePatches::kNoCell;

using geometry::floor_int;

// Union-find over the few hundred vertex ids of one cell, in an open-addressed table that stays
// in cache (one per worker thread, cleared after each cell).
class SmallSets {
 public:
  void reset(size_t n) {
    for (int32_t s : used_) key_[size_t(s)] = -1;
    used_.clear();
    bits_ = 4;
    while ((size_t(1) << bits_) < 2 * n) ++bits_;
    if (key_.size() < (size_t(1) << bits_)) {
      key_.assign(size_t(1) << bits_, -1);
      parent_.resize(size_t(1) << bits_);
    }
  }
  int32_t find(int32_t key) {  // the root's slot
    int32_t s = slot(key);
    while (parent_[size_t(s)] != s) s = parent_[size_t(s)] = parent_[size_t(parent_[size_t(s)])];
    return s;
  }
  void unite(int32_t a, int32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent_[size_t(std::max(a, b))] = std::min(a, b);
  }

 private:
  int32_t slot(int32_t key) {
    const uint32_t mask = (uint32_t(1) << bits_) - 1;
    uint32_t s = (uint32_t(key) * 2654435761u) >> (32 - bits_);
    while (key_[s] != key && key_[s] != -1) s = (s + 1) & mask;
    if (key_[s] == -1) {
      key_[s] = key;
      parent_[s] = int32_t(s);
      used_.push_back(int32_t(s));
    }
    return int32_t(s);
  }
  std::vector<int32_t> key_, parent_, used_;
  int bits_ = 4;
};

// A surface cell overlapped by a crossing triangle: 8 * cell + inner, inner bit k: vertex k of
// the triangle lies inside that cell.
struct Crossing {
  uint32_t cell_inner;
  int32_t tri;
};

}  // namespace

SurfacePatches find_surface_patches(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                                    const std::vector<uint8_t>& marks, const RowMatrixX3d& V,
                                    const std::vector<Eigen::Vector3i>& tris) {
  SurfacePatches sp;
  sp.grid = GridIndex{dims};
  const GridIndex& g = sp.grid;
  const int64_t ncell = int64_t(marks.size());
  const int64_t nt = int64_t(tris.size());
  const int64_t nv = V.rows();
  sp.surf_of.assign(size_t(ncell), -1);
  for (int64_t id = 0; id < ncell; ++id)
    if (marks[id] & kSurface) {
      sp.surf_of[id] = int32_t(sp.cells.size());
      sp.cells.push_back(id);
    }
  const int64_t ns = int64_t(sp.cells.size());
  if (ns >= (int64_t(1) << 28))  // the lattice could not hold them either (Lattice::build)
    throw OutOfMemory("the lattice has too many surface cells (" + std::to_string(ns) + ")");
  sp.shares.assign(size_t(ns), 0);
  sp.several.assign(size_t(ns), 0);
  sp.crossing_offsets.assign(size_t(ns) + 1, 0);
  if (ns == 0) return sp;

  // ------------------------------------------------------------------ cells of the vertices
  // The fast paths rest on two facts: the floor commutes with min and max (so a triangle's cell
  // range is the range of its vertices'), and a vertex more than 1e-7 h inside a cell makes the
  // overlap test pass. The second needs rounding far below 1e-7 h: coordinates within 1e6 cells
  // of zero (a vertex beyond gets no cell; a grid beyond: no vertex does).
  const double reach = 1e6 * h;
  sp.vertex_cell.assign(size_t(nv), kNoCell);
  if (origin.cwiseAbs().maxCoeff() <= reach) {
    parallel_for(nv, [&](int64_t v) {
      Eigen::Vector3i c;
      for (int a = 0; a < 3; ++a) {
        const double x = V(v, a);
        if (!(std::abs(x) <= reach)) return;
        // The same expressions as the cell range of a triangle (plain_range below).
        const int lo = std::max(0, floor_int((x - origin[a]) / h - 1e-7));
        const int hi = std::min(dims[a] - 1, floor_int((x - origin[a]) / h + 1e-7));
        if (lo != hi) return;
        c[a] = lo;
      }
      const int32_t s = sp.surf_of[g.index(c)];
      if (s >= 0) sp.vertex_cell[v] = uint32_t(s);
    }, 8192);
  }
  const std::vector<uint32_t>& code = sp.vertex_cell;
  std::vector<Eigen::Vector3i> cell_coords(static_cast<size_t>(ns));
  for (int64_t s = 0; s < ns; ++s) cell_coords[s] = g.coords(sp.cells[s]);

  // ------------------------------------------------------------------ triangles
  // The plain path: a triangle's cell range and the overlap test per cell (the voxeliser's).
  const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * h * (1.0 + 1e-9));
  auto overlaps = [&](int64_t t, int x, int y, int z) {
    const Eigen::Vector3d a = V.row(tris[t][0]), b = V.row(tris[t][1]), c = V.row(tris[t][2]);
    const Eigen::Vector3d centre = origin + h * Eigen::Vector3d(x + 0.5, y + 0.5, z + 0.5);
    return geometry::triangle_box_overlap(centre, half, a, b, c);
  };
  auto plain_range = [&](int64_t t, Eigen::Vector3i& c0, Eigen::Vector3i& c1) {
    const Eigen::Vector3d a = V.row(tris[t][0]), b = V.row(tris[t][1]), c = V.row(tris[t][2]);
    const Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c), hi = a.cwiseMax(b).cwiseMax(c);
    for (int q = 0; q < 3; ++q) {
      c0[q] = std::max(0, floor_int((lo[q] - origin[q]) / h - 1e-7));
      c1[q] = std::min(dims[q] - 1, floor_int((hi[q] - origin[q]) / h + 1e-7));
    }
  };
  // Vertices of the triangles inside one cell, joined (each class stays in that cell).
  ConcurrentSets sets(nv);
  std::vector<uint8_t> in_single(static_cast<size_t>(nv), 0);
  // Crossing triangles: per chunk of triangles, in triangle order.
  const int64_t chunk = 16384, nchunks = (nt + chunk - 1) / chunk;
  std::vector<std::vector<Crossing>> found(static_cast<size_t>(nchunks));
  parallel_for(nchunks, [&](int64_t ci) {
    std::vector<Crossing>& out = found[ci];
    std::vector<std::pair<int32_t, Eigen::Vector3i>> seen;  // the surface cells a triangle overlaps
    std::vector<int64_t> ids;
    const int64_t t1 = std::min(nt, (ci + 1) * chunk);
    for (int64_t t = ci * chunk; t < t1; ++t) {
      const Eigen::Vector3i& tri = tris[t];
      const uint32_t p[3] = {code[tri[0]], code[tri[1]], code[tri[2]]};
      if (p[0] != kNoCell && p[0] == p[1] && p[1] == p[2]) {  // inside one cell
        for (int k = 0; k < 3; ++k)
          if (!__atomic_load_n(&in_single[tri[k]], __ATOMIC_RELAXED))
            __atomic_store_n(&in_single[tri[k]], uint8_t(1), __ATOMIC_RELAXED);
        sets.unite(tri[0], tri[1]);
        sets.unite(tri[0], tri[2]);
        continue;
      }
      Eigen::Vector3i c0, c1;
      if (p[0] != kNoCell && p[1] != kNoCell && p[2] != kNoCell) {  // the range of the vertices' cells
        c0 = c1 = cell_coords[p[0]];
        for (int k = 1; k < 3; ++k) {
          const Eigen::Vector3i& c = cell_coords[p[k]];
          c0 = c0.cwiseMin(c);
          c1 = c1.cwiseMax(c);
        }
      } else {
        plain_range(t, c0, c1);
      }
      seen.clear();
      for (int z = c0.z(); z <= c1.z(); ++z)
        for (int y = c0.y(); y <= c1.y(); ++y)
          for (int x = c0.x(); x <= c1.x(); ++x) {
            const int32_t s = sp.surf_of[g.index(x, y, z)];
            if (s < 0) continue;
            uint32_t inner = 0;
            for (int k = 0; k < 3; ++k)
              if (p[k] == uint32_t(s)) inner |= 1u << k;
            // A one-cell range overlaps without a test, as does a cell holding a vertex.
            if (c0 != c1 && !inner && !overlaps(t, x, y, z)) continue;
            out.push_back({8 * uint32_t(s) + inner, int32_t(t)});
            seen.push_back({s, Eigen::Vector3i(x, y, z)});
          }
      // Every two neighbouring cells the triangle overlaps share it.
      auto share = [&](int32_t s, const Eigen::Vector3i& o) {
        const uint32_t bit = 1u << offset_bit(o);
        if (!(__atomic_load_n(&sp.shares[s], __ATOMIC_RELAXED) & bit)) __atomic_fetch_or(&sp.shares[s], bit, __ATOMIC_RELAXED);
      };
      if (seen.size() <= 8) {  // every pair
        for (const auto& [si, ci] : seen)
          for (const auto& [sj, cj] : seen) {
            const Eigen::Vector3i o = cj - ci;
            if (si != sj && o.cwiseAbs().maxCoeff() <= 1) share(si, o);
          }
        continue;
      }
      // A large triangle: its cells are in ascending grid order (the loop above), so each
      // neighbour is looked up by binary search (no map of the range).
      ids.clear();
      for (const auto& sc : seen) ids.push_back(g.index(sc.second));
      for (const auto& [si, ci] : seen)
        for (int o = 0; o < 27; ++o) {
          const Eigen::Vector3i d(o % 3 - 1, (o / 3) % 3 - 1, o / 9 - 1);
          const Eigen::Vector3i cj = ci + d;
          if (o == 13 || (cj.array() < c0.array()).any() || (cj.array() > c1.array()).any()) continue;
          if (std::binary_search(ids.begin(), ids.end(), g.index(cj))) share(si, d);
        }
    }
  }, 1);
  // Grouped by cell, in triangle order.
  for (const auto& f : found)
    for (const Crossing& c : f) ++sp.crossing_offsets[size_t(c.cell_inner / 8) + 1];
  for (int64_t s = 0; s < ns; ++s) sp.crossing_offsets[s + 1] += sp.crossing_offsets[s];
  sp.crossing.resize(size_t(sp.crossing_offsets[ns]));
  std::vector<uint8_t> crossing_inner(sp.crossing.size());
  {
    std::vector<int32_t> fill(sp.crossing_offsets.begin(), sp.crossing_offsets.end() - 1);
    for (const auto& f : found)
      for (const Crossing& c : f) {
        const int32_t q = fill[c.cell_inner / 8]++;
        sp.crossing[q] = c.tri;
        crossing_inner[q] = uint8_t(c.cell_inner % 8);
      }
  }
  found.clear();

  // ------------------------------------------------------------------ patches
  // The classes' roots (their smallest members), per cell. Every vertex's entry is written by its
  // own iteration only (root_of never writes), so afterwards each one holds its root, whatever
  // the threads' timing.
  parallel_for(nv, [&](int64_t v) { __atomic_store_n(&sets.parent[v], sets.root_of(int32_t(v)), __ATOMIC_RELAXED); }, 8192);
  const std::vector<int64_t> all_roots =
      parallel_select(nv, [&](int64_t v) { return in_single[v] && sets.parent[v] == v; });
  std::vector<int32_t> root_offsets(static_cast<size_t>(ns) + 1, 0), roots(all_roots.size());
  for (int64_t v : all_roots) ++root_offsets[size_t(code[v]) + 1];
  for (int64_t s = 0; s < ns; ++s) root_offsets[s + 1] += root_offsets[s];
  {
    std::vector<int32_t> fill(root_offsets.begin(), root_offsets.end() - 1);
    for (int64_t v : all_roots) roots[size_t(fill[code[v]]++)] = int32_t(v);
  }
  // Per cell: its classes and its crossing triangles, joined where they meet inside the cell (the
  // closed box, as the overlap test): a crossing triangle joins the class of each of its vertices
  // inside the cell, any other vertex of it in the box (shared with a triangle that has it too),
  // and any of its edges that overlaps the box (shared with the triangle on its other side).
  // Triangles that meet only beyond the cell (a fork's two tines joined far away, a coarse
  // mesh's two sides joined at a vertex outside) are two patches.
  parallel_for(ns, [&](int64_t s) {
    const int32_t r0 = root_offsets[s], r1 = root_offsets[s + 1];
    const int32_t q0 = sp.crossing_offsets[s], q1 = sp.crossing_offsets[s + 1];
    if (q0 == q1) {
      sp.several[s] = r1 - r0 > 1;
      return;
    }
    const Eigen::Vector3d centre = origin + h * (cell_coords[s].cast<double>() + Eigen::Vector3d::Constant(0.5));
    auto in_box = [&](int32_t v) { return ((V.row(v).transpose() - centre).cwiseAbs().array() <= half.array()).all(); };
    thread_local SmallSets local;
    thread_local std::vector<std::pair<uint64_t, int32_t>> edges;  // (edge, its triangle's key)
    local.reset(size_t(4 * (q1 - q0) + (r1 - r0)));
    edges.clear();
    // Keys: a vertex id (its class root for a vertex inside the cell), or -2 - (q - q0) for
    // crossing triangle q.
    for (int32_t q = q0; q < q1; ++q) {
      // The crossing triangles of a cell lie scattered over the triangle array.
      if (q + 16 < q1) __builtin_prefetch(&tris[sp.crossing[q + 16]]);
      if (q + 8 < q1)
        for (int k = 0; k < 3; ++k)
          if ((crossing_inner[q + 8] >> k) & 1) __builtin_prefetch(&sets.parent[tris[sp.crossing[q + 8]][k]]);
      const Eigen::Vector3i& t = tris[sp.crossing[q]];
      const int32_t me = -2 - (q - q0);
      const uint8_t inner = crossing_inner[q];
      local.find(me);  // a triangle meeting no other in the cell is a patch of its own
      for (int k = 0; k < 3; ++k) {
        if ((inner >> k) & 1) local.unite(me, sets.parent[t[k]]);
        else if (in_box(t[k])) local.unite(me, t[k]);
      }
      for (int k = 0; k < 3; ++k) {
        const int32_t a = t[k], b = t[(k + 1) % 3];
        if (((inner >> k) & 1) || ((inner >> ((k + 1) % 3)) & 1)) continue;  // joined through that vertex
        const Eigen::Vector3d pa = V.row(a), pb = V.row(b);
        if (!geometry::triangle_box_overlap(centre, half, pa, pb, pb)) continue;  // the edge as a segment
        edges.emplace_back(uint64_t(uint32_t(std::min(a, b))) << 32 | uint32_t(std::max(a, b)), me);
      }
    }
    std::sort(edges.begin(), edges.end());
    for (size_t i = 1; i < edges.size(); ++i)
      if (edges[i].first == edges[i - 1].first) local.unite(edges[i].second, edges[i - 1].second);
    const int32_t first = r1 > r0 ? local.find(roots[r0]) : local.find(-2);
    bool more = false;
    for (int32_t r = r0 + 1; r < r1 && !more; ++r) more = local.find(roots[r]) != first;
    for (int32_t q = q0; q < q1 && !more; ++q) more = local.find(-2 - (q - q0)) != first;
    sp.several[s] = more;
  }, 16);
  return sp;
}

void triangles_of(const SurfacePatches& sp, const std::vector<Eigen::Vector3i>& tris,
                  const std::vector<int32_t>& which, std::vector<int32_t>& offsets,
                  std::vector<int32_t>& ids) {
  std::vector<int32_t> slot(sp.cells.size(), -1);
  for (size_t i = 0; i < which.size(); ++i) slot[size_t(which[i])] = int32_t(i);
  // Triangles inside one cell, in triangle order.
  const std::vector<uint32_t>& code = sp.vertex_cell;
  auto inside_slot = [&](const Eigen::Vector3i& t) {
    const uint32_t c = code[t[0]];
    if (c == kNoCell || slot[c] < 0 || code[t[1]] != c || code[t[2]] != c) return -1;
    return slot[c];
  };
  const std::vector<int64_t> hits =
      parallel_select(int64_t(tris.size()), [&](int64_t t) { return inside_slot(tris[t]) >= 0; });
  std::vector<int32_t> count(which.size() + 1, 0), inside(hits.size());
  for (int64_t t : hits) ++count[size_t(inside_slot(tris[t])) + 1];
  for (size_t i = 0; i < which.size(); ++i) count[i + 1] += count[i];
  {
    std::vector<int32_t> fill(count.begin(), count.end() - 1);
    for (int64_t t : hits) inside[size_t(fill[size_t(inside_slot(tris[t]))]++)] = int32_t(t);
  }
  // Merged with the crossing ones (both ascending).
  offsets.assign(which.size() + 1, 0);
  for (size_t i = 0; i < which.size(); ++i)
    offsets[i + 1] = offsets[i] + (count[i + 1] - count[i]) +
                     (sp.crossing_offsets[size_t(which[i]) + 1] - sp.crossing_offsets[size_t(which[i])]);
  ids.resize(size_t(offsets.back()));
  for (size_t i = 0; i < which.size(); ++i) {
    const int32_t s = which[i];
    std::merge(inside.begin() + count[i], inside.begin() + count[i + 1],
               sp.crossing.begin() + sp.crossing_offsets[s], sp.crossing.begin() + sp.crossing_offsets[s + 1],
               ids.begin() + offsets[i]);
  }
}

}  // namespace larap
