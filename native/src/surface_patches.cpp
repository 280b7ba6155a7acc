#include "surface_patches.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>

#include "cell_pieces.h"
#include "geometry.h"
#include "parallel.h"

namespace larap {
namespace {

// A vertex's cells, packed in 64 bits: per axis a, the lowest cell within 1e-7 h of it (20 bits
// at 20 a) and whether the next cell is within 1e-7 h too (bit 60 + a). kPlain: the fast paths
// do not apply (coordinates beyond what the packing or the exactness argument covers), so every
// triangle through the vertex takes the plain path (cell range and overlap test per cell).
constexpr uint64_t kPlain = uint64_t(1) << 63;
inline int packed_lo(uint64_t p, int a) { return int((p >> (20 * a)) & 0xFFFFF); }
inline int packed_hi(uint64_t p, int a) { return packed_lo(p, a) + int((p >> (60 + a)) & 1); }
// Inside one cell, farther than 1e-7 h from its faces: every triangle through it overlaps that cell.
inline bool packed_inner(uint64_t p) { return (p >> 60) == 0; }
inline int64_t packed_cell(const GridIndex& g, uint64_t p) {
  return g.index(packed_lo(p, 0), packed_lo(p, 1), packed_lo(p, 2));
}

// Union-find over vertex ids shared by the threads: a class's root is its smallest member (links
// go from the larger root to the smaller; path halving only points a vertex further up).
struct ConcurrentSets {
  std::vector<int32_t> parent;
  explicit ConcurrentSets(int64_t n) : parent(size_t(n)) { std::iota(parent.begin(), parent.end(), 0); }
  int32_t find(int32_t x) {
    for (;;) {
      const int32_t px = __atomic_load_n(&parent[x], __ATOMIC_RELAXED);
      if (px == x) return x;
      const int32_t gx = __atomic_load_n(&parent[px], __ATOMIC_RELAXED);
      if (gx != px) __atomic_store_n(&parent[x], gx, __ATOMIC_RELAXED);
      x = gx;
    }
  }
  void unite(int32_t a, int32_t b) {
    for (;;) {
      a = find(a);
      b = find(b);
      if (a == b) return;
      if (a < b) std::swap(a, b);
      int32_t expected = a;
      if (__atomic_compare_exchange_n(&parent[a], &expected, b, false, __ATOMIC_ACQ_REL, __ATOMIC_RELAXED)) return;
    }
  }
};

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

// A surface cell overlapped by a crossing triangle; inner bit k: vertex k lies inside that cell.
struct Crossing {
  int32_t cell;
  int32_t tri;
  uint8_t inner;
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
  sp.shares.assign(size_t(ns), 0);
  sp.several.assign(size_t(ns), 0);
  sp.crossing_offsets.assign(size_t(ns) + 1, 0);
  if (ns == 0) return sp;

  // ------------------------------------------------------------------ cells of the vertices
  // The fast paths rest on two facts: the floor commutes with min and max (so a triangle's cell
  // range is the range of its vertices'), and a vertex more than 1e-7 h inside a cell makes the
  // overlap test pass. The second needs rounding far below 1e-7 h: coordinates within 1e6 cells
  // of zero (beyond, every triangle takes the plain path).
  const double reach = 1e6 * h;
  const bool fast = origin.cwiseAbs().maxCoeff() <= reach && dims.maxCoeff() < (1 << 20);
  sp.vertex_cells.assign(size_t(nv), kPlain);
  if (fast) {
    parallel_for(nv, [&](int64_t v) {
      uint64_t p = 0;
      for (int a = 0; a < 3; ++a) {
        const double x = V(v, a);
        if (!(std::abs(x) <= reach)) return;
        // The same expressions as the plain path's cell range.
        const int lo = std::max(0, int(std::floor((x - origin[a]) / h - 1e-7)));
        const int hi = std::min(dims[a] - 1, int(std::floor((x - origin[a]) / h + 1e-7)));
        if (hi != lo && hi != lo + 1) return;
        p |= uint64_t(lo) << (20 * a) | uint64_t(hi - lo) << (60 + a);
      }
      sp.vertex_cells[v] = p;
    }, 8192);
  }
  const std::vector<uint64_t>& packed = sp.vertex_cells;

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
      c0[q] = std::max(0, int(std::floor((lo[q] - origin[q]) / h - 1e-7)));
      c1[q] = std::min(dims[q] - 1, int(std::floor((hi[q] - origin[q]) / h + 1e-7)));
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
    const int64_t t1 = std::min(nt, (ci + 1) * chunk);
    for (int64_t t = ci * chunk; t < t1; ++t) {
      const Eigen::Vector3i& tri = tris[t];
      const uint64_t p[3] = {packed[tri[0]], packed[tri[1]], packed[tri[2]]};
      if (p[0] == p[1] && p[1] == p[2] && packed_inner(p[0])) {  // inside one cell
        if (sp.surf_of[packed_cell(g, p[0])] < 0) continue;
        for (int k = 0; k < 3; ++k)
          if (!__atomic_load_n(&in_single[tri[k]], __ATOMIC_RELAXED))
            __atomic_store_n(&in_single[tri[k]], uint8_t(1), __ATOMIC_RELAXED);
        sets.unite(tri[0], tri[1]);
        sets.unite(tri[0], tri[2]);
        continue;
      }
      Eigen::Vector3i c0, c1;
      const bool plain = (p[0] | p[1] | p[2]) & kPlain;
      if (plain) {
        plain_range(t, c0, c1);
      } else {
        for (int a = 0; a < 3; ++a) {
          c0[a] = std::min({packed_lo(p[0], a), packed_lo(p[1], a), packed_lo(p[2], a)});
          c1[a] = std::max({packed_hi(p[0], a), packed_hi(p[1], a), packed_hi(p[2], a)});
        }
      }
      std::array<std::pair<int32_t, Eigen::Vector3i>, 8> seen;
      int nseen = 0;
      for (int z = c0.z(); z <= c1.z(); ++z)
        for (int y = c0.y(); y <= c1.y(); ++y)
          for (int x = c0.x(); x <= c1.x(); ++x) {
            const int64_t id = g.index(x, y, z);
            const int32_t s = sp.surf_of[id];
            if (s < 0) continue;
            uint8_t inner = 0;
            for (int k = 0; k < 3; ++k)
              if (packed_inner(p[k]) && packed_cell(g, p[k]) == id) inner |= uint8_t(1u << k);
            // One cell (plain path only) overlaps without a test, as do cells holding a vertex.
            if (c0 != c1 && !inner && !overlaps(t, x, y, z)) continue;
            out.push_back({s, int32_t(t), inner});
            // A triangle over more than 8 cells links its first 8 (its other cells see it
            // through their own overlaps with their neighbours).
            if (nseen < 8) seen[nseen++] = {s, Eigen::Vector3i(x, y, z)};
          }
      for (int i = 0; i < nseen; ++i)
        for (int j = 0; j < nseen; ++j) {
          if (i == j) continue;
          const Eigen::Vector3i o = seen[j].second - seen[i].second;
          if (o.cwiseAbs().maxCoeff() > 1) continue;
          __atomic_fetch_or(&sp.shares[seen[i].first], 1u << offset_bit(o), __ATOMIC_RELAXED);
        }
    }
  }, 1);
  // Grouped by cell, in triangle order.
  for (const auto& f : found)
    for (const Crossing& c : f) ++sp.crossing_offsets[size_t(c.cell) + 1];
  for (int64_t s = 0; s < ns; ++s) sp.crossing_offsets[s + 1] += sp.crossing_offsets[s];
  sp.crossing.resize(size_t(sp.crossing_offsets[ns]));
  std::vector<uint8_t> crossing_inner(sp.crossing.size());
  {
    std::vector<int32_t> fill(sp.crossing_offsets.begin(), sp.crossing_offsets.end() - 1);
    for (const auto& f : found)
      for (const Crossing& c : f) {
        const int32_t q = fill[c.cell]++;
        sp.crossing[q] = c.tri;
        crossing_inner[q] = c.inner;
      }
  }
  found.clear();

  // ------------------------------------------------------------------ patches
  // The classes' roots (their smallest members), per cell.
  parallel_for(nv, [&](int64_t v) { __atomic_store_n(&sets.parent[v], sets.find(int32_t(v)), __ATOMIC_RELAXED); }, 8192);
  std::vector<int32_t> root_offsets(static_cast<size_t>(ns) + 1, 0), roots;
  for (int64_t v = 0; v < nv; ++v)
    if (in_single[v] && sets.parent[v] == v) ++root_offsets[size_t(sp.surf_of[packed_cell(g, packed[v])]) + 1];
  for (int64_t s = 0; s < ns; ++s) root_offsets[s + 1] += root_offsets[s];
  roots.resize(size_t(root_offsets[ns]));
  {
    std::vector<int32_t> fill(root_offsets.begin(), root_offsets.end() - 1);
    for (int64_t v = 0; v < nv; ++v)
      if (in_single[v] && sets.parent[v] == v) roots[size_t(fill[sp.surf_of[packed_cell(g, packed[v])]]++)] = int32_t(v);
  }
  // Per cell: its classes and the vertices of its crossing triangles (a vertex inside the cell
  // stands for its class), joined by the crossing triangles.
  parallel_for(ns, [&](int64_t s) {
    const int32_t r0 = root_offsets[s], r1 = root_offsets[s + 1];
    const int32_t q0 = sp.crossing_offsets[s], q1 = sp.crossing_offsets[s + 1];
    if (q0 == q1) {
      sp.several[s] = r1 - r0 > 1;
      return;
    }
    thread_local SmallSets local;
    local.reset(size_t(3 * (q1 - q0) + (r1 - r0)));
    auto key = [&](int32_t q, int k) {
      const int32_t v = tris[sp.crossing[q]][k];
      return (crossing_inner[q] >> k) & 1 ? sets.parent[v] : v;
    };
    for (int32_t q = q0; q < q1; ++q) {
      const int32_t k0 = key(q, 0);
      local.unite(k0, key(q, 1));
      local.unite(k0, key(q, 2));
    }
    const int32_t first = r1 > r0 ? local.find(roots[r0]) : local.find(key(q0, 0));
    bool more = false;
    for (int32_t r = r0 + 1; r < r1 && !more; ++r) more = local.find(roots[r]) != first;
    for (int32_t q = q0; q < q1 && !more; ++q) more = local.find(key(q, 0)) != first;
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
  const std::vector<uint64_t>& packed = sp.vertex_cells;
  auto inside_slot = [&](const Eigen::Vector3i& t) {
    const uint64_t p = packed[t[0]];
    if (!packed_inner(p) || packed[t[1]] != p || packed[t[2]] != p) return -1;
    const int32_t s = sp.surf_of[packed_cell(sp.grid, p)];
    return s >= 0 ? slot[size_t(s)] : -1;
  };
  std::vector<int32_t> count(which.size() + 1, 0);
  std::vector<int32_t> inside;
  const int64_t nt = int64_t(tris.size());
  for (int64_t t = 0; t < nt; ++t) {
    const int32_t i = inside_slot(tris[t]);
    if (i >= 0) ++count[size_t(i) + 1];
  }
  for (size_t i = 0; i < which.size(); ++i) count[i + 1] += count[i];
  inside.resize(size_t(count.back()));
  {
    std::vector<int32_t> fill(count.begin(), count.end() - 1);
    for (int64_t t = 0; t < nt; ++t) {
      const int32_t i = inside_slot(tris[t]);
      if (i >= 0) inside[size_t(fill[size_t(i)]++)] = int32_t(t);
    }
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
