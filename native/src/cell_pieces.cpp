#include "cell_pieces.h"

#include <larap/errors.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>
#include <string>
#include <unordered_map>

#include "geometry.h"
#include "parallel.h"
#include "part_pieces.h"
#include "surface_patches.h"
#include "voxel_inside.h"
#include "voxel_rows.h"

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

}  // namespace

CellPieces find_cell_pieces(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                            const std::vector<uint8_t>& marks, const RowMatrixX3d& V,
                            const std::vector<Eigen::Vector3i>& tris,
                            const std::vector<int32_t>& vertex_part,
                            const std::vector<int64_t>& vertex_cells, int k, int64_t max_voxel_bytes) {
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
  // Rows: the voxels' inside test (voxel_inside.h) casts rays the length of the grid along the
  // rows of cells through each analysed cell, one row per axis; every cell of a row shares its
  // rays, so each row's crossings are found once, with the triangles of the row's surface cells.
  // rows[a]: the analysed cells of axis a's rows, by row (the grid index of its cell 0) and place.
  struct RowCell {
    int64_t row;
    int32_t along;  // the cell's index along the row
    int32_t b;      // the analysed cell
  };
  std::vector<RowCell> rows[3];
  std::vector<std::vector<int32_t>> row_start(3);  // per axis: where each row begins in rows[a]
  for (int a = 0; a < 3; ++a) {
    rows[a].resize(size_t(nb));
    parallel_for(nb, [&](int64_t b) {
      Eigen::Vector3i S = g.coords(surf_cells[cand_surf[b]]);
      const int32_t along = S[a];
      S[a] = 0;
      rows[a][size_t(b)] = {g.index(S), along, int32_t(b)};
    }, 4096);
    std::sort(rows[a].begin(), rows[a].end(), [](const RowCell& x, const RowCell& y) {
      return x.row != y.row ? x.row < y.row : x.along < y.along;
    });
    for (int32_t i = 0; i < int32_t(nb); ++i)
      if (i == 0 || rows[a][size_t(i)].row != rows[a][size_t(i) - 1].row) row_start[a].push_back(i);
    row_start[a].push_back(int32_t(nb));
  }
  // The surface cells along every row (CSR per row, axis by axis, as indices into row_surf) and
  // the triangles of each.
  std::vector<int32_t> row_offsets{0}, row_cells, row_surf;
  for (int a = 0; a < 3; ++a)
    for (size_t r = 0; r + 1 < row_start[a].size(); ++r) {
      Eigen::Vector3i C = g.coords(rows[a][size_t(row_start[a][r])].row);
      for (C[a] = 0; C[a] < dims[a]; ++C[a]) {
        const int32_t s = surf_of[g.index(C)];
        if (s >= 0) row_cells.push_back(s);
      }
      row_offsets.push_back(int32_t(row_cells.size()));
    }
  row_surf = row_cells;
  std::sort(row_surf.begin(), row_surf.end());
  row_surf.erase(std::unique(row_surf.begin(), row_surf.end()), row_surf.end());
  parallel_for(int64_t(row_cells.size()), [&](int64_t i) {
    row_cells[size_t(i)] =
        int32_t(std::lower_bound(row_surf.begin(), row_surf.end(), row_cells[size_t(i)]) - row_surf.begin());
  }, 4096);
  std::vector<int32_t> rs_offsets, rs_tris;
  triangles_of(sp, tris, row_surf, rs_offsets, rs_tris);
  // The analysed cells are among the rows' surface cells: their triangles are copied from there.
  std::vector<int32_t> cand_offsets{0}, cand_tris;  // triangles of each candidate
  for (int64_t b = 0; b < nb; ++b) {
    const size_t i =
        size_t(std::lower_bound(row_surf.begin(), row_surf.end(), cand_surf[size_t(b)]) - row_surf.begin());
    cand_tris.insert(cand_tris.end(), rs_tris.begin() + rs_offsets[i], rs_tris.begin() + rs_offsets[i + 1]);
    cand_offsets.push_back(int32_t(cand_tris.size()));
  }
  // Parts: a cell whose triangles belong to one part keeps the 6-connected flood fill below; one
  // with several tells their surfaces apart (part_pieces.h). part_of[b]: the cell's one part,
  // kSeveral, or kNoPart (no triangle: no surface voxel).
  constexpr int32_t kSeveral = -1, kNoPart = -2;
  std::vector<int32_t> part_of(static_cast<size_t>(nb), kNoPart);
  bool by_part = false;  // some cell holds several parts, or two cells different ones
  int32_t seen = kNoPart;
  for (int64_t b = 0; b < nb; ++b) {
    for (int32_t q = cand_offsets[b]; q < cand_offsets[b + 1]; ++q) {
      const int32_t p = vertex_part[tris[cand_tris[q]][0]];
      part_of[b] = part_of[b] == kNoPart || part_of[b] == p ? p : kSeveral;
    }
    if (part_of[b] == kSeveral)
      by_part = true;
    else if (part_of[b] != kNoPart) {
      if (seen != kNoPart && seen != part_of[b]) by_part = true;
      seen = part_of[b];
    }
  }
  const double hv = h / k;
  auto row_rays = [&](int a, int64_t row) {
    return RowRays(a, origin + h * g.coords(row).cast<double>(), hv, k);
  };
  auto row_triangles = [&](size_t row) {  // the triangles of a row's surface cells, ascending
    std::vector<int32_t> ids;
    size_t n = 0;
    for (int32_t q = row_offsets[row]; q < row_offsets[row + 1]; ++q)
      n += size_t(rs_offsets[size_t(row_cells[size_t(q)]) + 1] - rs_offsets[size_t(row_cells[size_t(q)])]);
    ids.reserve(n);
    for (int32_t q = row_offsets[row]; q < row_offsets[row + 1]; ++q) {
      const int32_t i = row_cells[size_t(q)];
      ids.insert(ids.end(), rs_tris.begin() + rs_offsets[size_t(i)], rs_tris.begin() + rs_offsets[size_t(i) + 1]);
    }
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    return ids;
  };
  // Calls visit(a, r, row) for every row in parallel, axis by axis: r counts the rows of all axes
  // (row_offsets' index), row is the row's index among axis a's (row_start[a]'s).
  auto for_each_row = [&](auto&& visit) {
    size_t r0 = 0;
    for (int a = 0; a < 3; ++a) {
      const int64_t nr = int64_t(row_start[a].size()) - 1;
      parallel_for(nr, [&](int64_t row) { visit(a, r0 + size_t(row), size_t(row)); }, 1);
      r0 += size_t(nr);
    }
  };
  // Each row's scratch: its triangles and the crossings they can give (kept for cross() to
  // reserve, so that it never grows past what is counted here).
  std::vector<int64_t> row_crossings(row_offsets.size() - 1);
  std::vector<double> row_bytes(row_offsets.size() - 1);
  for_each_row([&](int a, size_t r, size_t row) {
    const RowRays rays = row_rays(a, rows[a][size_t(row_start[a][row])].row);
    const std::vector<int32_t> ids = row_triangles(r);
    row_crossings[r] = rays.max_crossings(ids.data(), ids.size(), V, tris);
    row_bytes[r] = 8.0 * (double(k) * k + 1) + 4.0 * double(ids.capacity()) +
                   RowRays::kBytesPerCrossing * double(row_crossings[r]);
  });
  // Memory, an upper bound before anything of the size of the voxels is allocated: per analysed
  // cell its k^3 voxels; when parts are told apart, a byte per face voxel (6 k^2) for a cell of one
  // part, and for a cell of P parts a 4-byte key per face voxel plus the face sets, at most one per
  // face voxel (a 4-byte offset and P parts of 4 bytes); per worker thread, the scratch of one cell
  // (a few rows of bits; or the part sets' masks and the voxels' classes, 12 k^3, and each part's
  // rows, 8 P k^2 for P <= 64 parts, counted below; or their offsets, last-part table and
  // union-find: 16 k^3), or before that, of the row it is finding crossings for (the largest
  // rows), whichever is more; and the bookkeeping: 1 KiB per analysed cell (neighbours,
  // seeds, piece sizes, links twice over; the rows' tables alive with the voxels, at most 3 rows per cell:
  // about 100 bytes), 32 bytes per vertex in one (its piece, found and returned).
  const double k2d = double(k) * k;
  const std::vector<int64_t> held = parallel_select(V.rows(), [&](int64_t vtx) {  // in analysed cells
    const int32_t s = surf_of[vertex_cells[vtx]];
    return s >= 0 && block_of_surf[s] >= 0;
  });
  const int threads = std::max(1, num_threads());
  double bytes = double(nb) * (double(k3) + 1024.0) + 32.0 * double(held.size());
  {
    const size_t top = std::min(row_bytes.size(), size_t(threads));
    std::partial_sort(row_bytes.begin(), row_bytes.begin() + top, row_bytes.end(), std::greater<double>());
    double rows_scratch = 0;
    for (size_t i = 0; i < top; ++i) rows_scratch += row_bytes[i];
    bytes += std::max(16.0 * double(k3) * threads, rows_scratch);  // the rows' is freed before the cells'
    std::vector<double>().swap(row_bytes);
  }
  std::vector<int32_t> ps;  // the parts of a cell
  double most_parts = 0;    // in a cell of several
  if (by_part)
    for (int64_t b = 0; b < nb; ++b) {
      if (part_of[b] != kSeveral) {
        bytes += 6.0 * k2d;
        continue;
      }
      ps.clear();
      for (int32_t q = cand_offsets[b]; q < cand_offsets[b + 1]; ++q) ps.push_back(vertex_part[tris[cand_tris[q]][0]]);
      std::sort(ps.begin(), ps.end());
      const double np = double(std::unique(ps.begin(), ps.end()) - ps.begin());
      most_parts = std::max(most_parts, np);
      // Distinct face sets: at most one per face voxel, and at most the 2^P - P sets of parts
      // other than the single parts; each 4 bytes of offset and up to P parts, held twice while
      // they are gathered.
      const double nsets = std::min(6.0 * k2d, std::ldexp(1.0, int(std::min(np, 60.0))) - np);
      bytes += 24.0 * k2d + 2.0 * nsets * (4.0 + 4.0 * np);
    }
  // Per worker, a cell of several parts by masks has a row of bits per part and voxel row too.
  if (most_parts <= kMaskParts) bytes += 8.0 * most_parts * k2d * threads;
  if (bytes > double(max_voxel_bytes)) {
    throw OutOfMemory("cell splitting would analyse " + std::to_string(nb) + " cells: up to " + memory_text(bytes) +
                      " of voxels and face tables, over the " +
                      memory_text(double(std::max<int64_t>(max_voxel_bytes, 0))) +
                      " the grid leaves of the memory limit; use a lower split_resolution (" + std::to_string(k) +
                      " now), a larger cell size, or split_cells=False");
  }
  out.voxels = nb * k3;
  std::vector<uint8_t> vox(static_cast<size_t>(nb * k3), 0);  // 0 unknown, 1 surface, 2 air, >= 3 piece + 3
  auto block_of_cell = [&](const Eigen::Vector3i& c) -> int64_t {
    if (!g.contains(c)) return -1;
    const int32_t s = surf_of[g.index(c)];
    return s >= 0 ? block_of_surf[s] : -1;
  };
  auto vindex = [k](int i, int j, int l) { return i + int64_t(k) * (j + int64_t(k) * l); };

  // Inside: voxels that ray parity puts inside the mesh (voxel_inside.h) are held out of the air's
  // flood (kHeld), so air entering a solid through a hole in its surface does not empty it. Row by
  // row, axis by axis (a cell is in one row per axis, so no two rows of an axis write one cell),
  // the votes add up in the voxels themselves, before the surface's are marked.
  constexpr uint8_t kHeld = 255;
  {
    for_each_row([&](int a, size_t r, size_t row) {
      std::vector<int32_t> ids = row_triangles(r);
      RowRays rays = row_rays(a, rows[a][size_t(row_start[a][row])].row);
      rays.cross(ids.data(), ids.size(), V, tris, vertex_part, row_crossings[r]);
      std::vector<int32_t>().swap(ids);
      for (int32_t i = row_start[a][row]; i < row_start[a][row + 1]; ++i) {
        uint8_t* v = vox.data() + int64_t(rows[a][size_t(i)].b) * k3;
        rays.votes(rows[a][size_t(i)].along, [v](int64_t vi, int n) {
          v[vi] = uint8_t(v[vi] + n);
        });
      }
    });
    std::vector<int64_t>().swap(row_crossings);
    parallel_for(nb, [&](int64_t b) {
      uint8_t* v = vox.data() + b * k3;
      for (int64_t vi = 0; vi < k3; ++vi)
        v[vi] = v[vi] >= kInsideVotes ? kHeld : 0;
    }, 4);
  }
  for (int a = 0; a < 3; ++a) std::vector<RowCell>().swap(rows[a]);
  for (std::vector<int32_t>* scratch : {&rs_tris, &rs_offsets, &row_cells, &row_surf, &row_offsets})
    std::vector<int32_t>().swap(*scratch);

  parallel_for(nb, [&](int64_t b) {
    const Eigen::Vector3i X = g.coords(surf_cells[cand_surf[b]]);
    const Eigen::Vector3d corner = origin + h * X.cast<double>();
    uint8_t* v = vox.data() + b * k3;
    for (int32_t q = cand_offsets[b]; q < cand_offsets[b + 1]; ++q) {
      const Eigen::Vector3i& t = tris[cand_tris[q]];
      for_each_voxel_hit(corner, hv, k, V.row(t[0]).transpose(), V.row(t[1]).transpose(), V.row(t[2]).transpose(),
                         0.0, [v](int64_t vi) { return v[vi] == 1; }, [v](int64_t vi) { v[vi] = 1; });
    }
  }, 4);

  // Air: flood fill through the candidates from faces that border an empty or outside cell. Each
  // cell floods its own voxels in parallel; then, in rounds, air on a face of a cell that gained
  // some seeds the voxel across it in the neighbouring cell, until no cell gains any. A cell reads
  // its neighbours' faces while they may be flooding (relaxed atomics), so how many rounds it
  // takes, and which cell gains air in which, depend on the schedule; the result does not: the
  // air is the set of non-surface voxels connected to a seed, however it is reached.
  auto face_voxel = [&](int axis, int layer, int u, int w) {
    int c[3];
    c[axis] = layer;
    c[(axis + 1) % 3] = u;
    c[(axis + 2) % 3] = w;
    return vindex(c[0], c[1], c[2]);
  };
  std::vector<int64_t> across(static_cast<size_t>(6 * nb));  // the analysed neighbour over each face, or -1
  auto find_across = [&](int64_t b) {
    const Eigen::Vector3i X = g.coords(surf_cells[cand_surf[b]]);
    for (int f = 0; f < 6; ++f) {
      Eigen::Vector3i Y = X;
      Y[f / 2] += f % 2 ? 1 : -1;
      across[size_t(6 * b + f)] = block_of_cell(Y);
    }
  };
  parallel_for(nb, find_across, 256);

  std::vector<std::vector<int32_t>> seeds(static_cast<size_t>(nb));  // unflooded air, per cell
  const int64_t k2 = int64_t(k) * k;
  // From the cell's seeds (already air), inside the cell, on its bit rows (voxel_rows.h): the
  // voxels the flood reaches are written afterwards, each store atomic, as neighbours read the
  // faces while it runs.
  auto flood = [&](int64_t b) {
    std::vector<int32_t>& stack = seeds[size_t(b)];
    if (stack.empty()) return;
    uint8_t* v = vox.data() + b * k3;
    std::vector<uint64_t> open(static_cast<size_t>(k2)), air(static_cast<size_t>(k2), 0);
    rows_equal(v, k, 0, open.data());
    for (const int32_t vi : stack) {
      open[size_t(vi / k)] |= uint64_t(1) << (vi % k);
      air[size_t(vi / k)] |= uint64_t(1) << (vi % k);
    }
    flood_rows(k, open.data(), air.data());
    for_each_bit(air.data(), k, [v](int64_t vi) { __atomic_store_n(&v[vi], uint8_t(2), __ATOMIC_RELAXED); });
    std::vector<int32_t>().swap(stack);
  };
  std::vector<uint8_t> gained(static_cast<size_t>(nb), 0);
  parallel_for(nb, [&](int64_t b) {
    const Eigen::Vector3i X = g.coords(surf_cells[cand_surf[b]]);
    uint8_t* v = vox.data() + b * k3;
    for (int f = 0; f < 6; ++f) {
      const int axis = f / 2, side = f % 2;
      Eigen::Vector3i Y = X;
      Y[axis] += side ? 1 : -1;
      if (g.contains(Y) && (marks[g.index(Y)] & (kSurface | kInside))) continue;
      for (int w = 0; w < k; ++w)
        for (int u = 0; u < k; ++u) {
          const int64_t vi = face_voxel(axis, side ? k - 1 : 0, u, w);
          if (v[vi] == 0) {
            v[vi] = 2;
            seeds[size_t(b)].push_back(int32_t(vi));
          }
        }
    }
    gained[size_t(b)] = !seeds[size_t(b)].empty();
    flood(b);
  }, 4);
  std::vector<int64_t> changed = parallel_select(nb, [&](int64_t b) { return gained[size_t(b)] != 0; }, 4096);
  while (!changed.empty()) {
    // Cells next to a changed one take the air across their shared face (each cell writes only
    // its own voxels and seeds).
    std::vector<int64_t> touched;
    for (int64_t b : changed)
      for (int f = 0; f < 6; ++f)
        if (across[size_t(6 * b + f)] >= 0) touched.push_back(across[size_t(6 * b + f)]);
    std::sort(touched.begin(), touched.end());
    touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
    parallel_for(int64_t(touched.size()), [&](int64_t i) {
      const int64_t b = touched[size_t(i)];
      uint8_t* v = vox.data() + b * k3;
      for (int f = 0; f < 6; ++f) {
        const int64_t y = across[size_t(6 * b + f)];
        if (y < 0) continue;
        const int axis = f / 2, side = f % 2;
        const uint8_t* w = vox.data() + y * k3;
        for (int q = 0; q < k; ++q)
          for (int u = 0; u < k; ++u) {
            const int64_t mine = face_voxel(axis, side ? k - 1 : 0, u, q);
            // The neighbour may be flooding in this round: what it has not yet written, it
            // passes on in the next (it has then gained air).
            if (v[mine] == 0 && __atomic_load_n(&w[face_voxel(axis, side ? 0 : k - 1, u, q)], __ATOMIC_RELAXED) == 2) {
              __atomic_store_n(&v[mine], uint8_t(2), __ATOMIC_RELAXED);
              seeds[size_t(b)].push_back(int32_t(mine));
            }
          }
      }
      gained[size_t(b)] = !seeds[size_t(b)].empty();
      flood(b);
    }, 4);
    changed.clear();
    for (int64_t b : touched)
      if (gained[size_t(b)]) changed.push_back(b);
  }

  // Held voxels that touch the surface in their cell, directly or through other held voxels, are
  // enclosed material. The rest are cores that the air cut off from the cell's surface where two
  // holes see them (4 votes let it in around them): air. A core that reaches the surface only
  // through a neighbouring cell becomes air too; keeping it would make it a piece of its own in
  // its cell (a copy holding no vertex), joined to the skin's copy only far away. A cell with no
  // surface voxel at all (a triangle grazes it closer than the cell test's tolerance and farther
  // than the voxels') keeps its held voxels: they are the inside of the solid it lies in.
  static_assert(kHeld > 2, "kHeld is gone before the pieces are labelled (3 + piece)");
  parallel_for(nb, [&](int64_t b) {
    uint8_t* v = vox.data() + b * k3;
    std::vector<uint64_t> held(static_cast<size_t>(k2)), surface(static_cast<size_t>(k2)),
        near(static_cast<size_t>(k2));
    rows_equal(v, k, 1, surface.data());
    if (std::all_of(surface.begin(), surface.end(), [](uint64_t m) { return m == 0; })) {
      std::replace(v, v + k3, kHeld, uint8_t(0));
      return;
    }
    rows_equal(v, k, kHeld, held.data());
    dilate_rows(k, surface.data(), near.data());
    for (int64_t r = 0; r < k2; ++r) near[size_t(r)] &= held[size_t(r)];  // held, next to the surface
    flood_rows(k, held.data(), near.data());  // the held voxels that reach the surface
    for_each_bit(near.data(), k, [v](int64_t vi) { v[vi] = 0; });
    for (int64_t vi = 0; vi < k3; ++vi)
      if (v[vi] == kHeld) v[vi] = 2;
  }, 4);

  // What the links across faces need of a face voxel when parts are told apart (by_part). Face
  // voxel (f, u, w) is f * k^2 + w * k + u, as face_voxel names it. Cells of one part keep a byte
  // per face voxel (face_kind: kAirVoxel, kSurfaceVoxel, kEnclosedVoxel); cells of several a key
  // (face_key: kAir, kEnclosed, a part >= 0, or -3 - i for the i-th of the cell's face sets, a
  // voxel hit by several parts: parts[offsets[i], offsets[i + 1]) of its FaceSets).
  constexpr uint8_t kAirVoxel = 0, kSurfaceVoxel = 1, kEnclosedVoxel = 2;
  constexpr int32_t kAir = -1, kEnclosed = -2;
  std::vector<std::vector<uint8_t>> face_kind(static_cast<size_t>(by_part ? nb : 0));
  std::vector<std::vector<int32_t>> face_key(static_cast<size_t>(by_part ? nb : 0));
  struct FaceSets {
    std::vector<int32_t> offsets, parts;
  };
  std::vector<FaceSets> face_sets(static_cast<size_t>(by_part ? nb : 0));
  auto for_face_voxels = [&](auto&& visit) {  // visit(face voxel index f * k^2 + w * k + u, voxel)
    for (int f = 0; f < 6; ++f)
      for (int w = 0; w < k; ++w)
        for (int u = 0; u < k; ++u) visit(f * k2 + w * k + u, face_voxel(f / 2, f % 2 ? k - 1 : 0, u, w));
  };

  // Pieces: 6-connected components of the material voxels of each cell.
  std::vector<int32_t> pieces(static_cast<size_t>(nb), 0);
  std::vector<std::vector<int32_t>> sizes(static_cast<size_t>(nb));  // material voxels per piece
  auto find_pieces = [&](int64_t b) {
    uint8_t* v = vox.data() + b * k3;
    auto& size = sizes[size_t(b)];
    int32_t np = 0;
    if (by_part && part_of[b] == kSeveral) {
      const Eigen::Vector3d corner = origin + h * g.coords(surf_cells[cand_surf[b]]).cast<double>();
      const PartSets sets = part_sets(v, k, corner, hv, V, tris, cand_tris.data(), cand_offsets[b],
                                      cand_offsets[b + 1], vertex_part);
      auto& keys = face_key[b];
      keys.resize(size_t(6 * k2));
      // The distinct sets of the face voxels hit by several parts, each kept once (two or three
      // parts meeting along a face give one or a few): the memory bound above counts on it.
      FaceSets fs;
      fs.offsets.push_back(0);
      int32_t last = -1;  // the set found last (neighbouring voxels mostly repeat it)
      auto same = [&](int32_t i, const int32_t* p0, const int32_t* p1) {
        return fs.offsets[i + 1] - fs.offsets[i] == p1 - p0 && std::equal(p0, p1, fs.parts.begin() + fs.offsets[i]);
      };
      std::vector<int32_t> scratch;
      for_face_voxels([&](int64_t idx, int64_t vi) {
        int32_t& key = keys[size_t(idx)];
        if (v[vi] == 2) key = kAir;
        else if (v[vi] == 0) key = kEnclosed;
        else if (const auto [p0, p1] = sets.of(vi, scratch); p1 - p0 == 1)
          key = *p0;
        else {
          const int32_t n = int32_t(fs.offsets.size() - 1);
          int32_t i = last >= 0 && same(last, p0, p1) ? last : 0;
          while (i < n && !same(i, p0, p1)) ++i;
          if (i == n) {
            fs.parts.insert(fs.parts.end(), p0, p1);
            fs.offsets.push_back(int32_t(fs.parts.size()));
          }
          key = -3 - i;
          last = i;
        }
      });
      fs.offsets.shrink_to_fit();
      fs.parts.shrink_to_fit();
      face_sets[b] = std::move(fs);
      np = pieces_by_part(v, k, sets, size);
      pieces[b] = std::max(1, std::min(np, 253));
      return;
    }
    if (by_part) {
      auto& kind = face_kind[b];
      kind.resize(size_t(6 * k2));
      for_face_voxels([&](int64_t idx, int64_t vi) {
        kind[size_t(idx)] = v[vi] == 2 ? kAirVoxel : v[vi] == 1 ? kSurfaceVoxel : kEnclosedVoxel;
      });
    }
    np = label_pieces(v, k, size);
    pieces[b] = std::max(1, std::min(np, 253));
  };
  parallel_for(nb, find_pieces, 4);

  // Links across faces, per analysed cell (deterministic order). When parts are told apart, two
  // touching face voxels link their pieces if either is enclosed or one part hits both; a piece
  // links to an unanalysed surface neighbour (one patch, so one part) through an enclosed voxel
  // or that part's surface (to an unanalysed inside cell through any material).
  auto key_of = [&](int64_t b, int64_t idx) -> int32_t {  // face voxel idx of analysed cell b
    if (part_of[b] == kSeveral) return face_key[b][size_t(idx)];
    const uint8_t x = face_kind[b][size_t(idx)];
    return x == kAirVoxel ? kAir : x == kEnclosedVoxel ? kEnclosed : part_of[b];
  };
  // The parts of a surface voxel's key as a range: *key itself when it names one part (so the
  // range lives as long as the caller's key), else the cell's face set.
  auto parts_of = [&](int64_t b, const int32_t* key) -> std::pair<const int32_t*, const int32_t*> {
    if (*key >= 0) return {key, key + 1};
    const FaceSets& fs = face_sets[b];
    const size_t i = size_t(-3 - *key);
    return {fs.parts.data() + fs.offsets[i], fs.parts.data() + fs.offsets[i + 1]};
  };
  auto touch = [&](int64_t b, int32_t ka, int64_t yb, int32_t kc) {  // enclosed, or a part in common
    if (ka == kEnclosed || kc == kEnclosed) return true;
    const auto [a0, a1] = parts_of(b, &ka);
    const auto [c0, c1] = parts_of(yb, &kc);
    return sorted_sets_meet(a0, a1, c0, c1);
  };
  // Two surface voxels across a face also join when a part of one is within the other's grown
  // voxel (a crack under a quarter voxel that lies on a cell face, whose two sides are in two
  // cells). face_reach: the parts of the other cell's triangles ids[q0, q1) that overlap a voxel of
  // the face layer `layer` (0 or k - 1) along `axis` of the cell at `corner`, the voxel grown by
  // kContact, as sorted (face voxel q * k + u, part); only triangles within the growth of the face
  // plane are rasterised (a few of the cell's), and only when a pair of face voxels needs it.
  using Reach = std::vector<std::pair<int32_t, int32_t>>;
  auto face_reach = [&](const int32_t* ids, int32_t q0, int32_t q1, const Eigen::Vector3d& corner, int axis,
                        int layer) {
    Reach out;
    const double plane = corner[axis] + (layer ? h : 0.0), margin = (kContact + 1e-6) * hv;
    const int64_t step = axis == 0 ? 1 : axis == 1 ? k : k2;
    for (int32_t q = q0; q < q1; ++q) {
      const Eigen::Vector3i& t = tris[ids[q]];
      const Eigen::Vector3d a = V.row(t[0]), bb = V.row(t[1]), c = V.row(t[2]);
      if (std::min({a[axis], bb[axis], c[axis]}) > plane + margin ||
          std::max({a[axis], bb[axis], c[axis]}) < plane - margin)
        continue;
      const int32_t part = vertex_part[t[0]];
      for_each_voxel_hit(corner, hv, k, a, bb, c, kContact, [&](int64_t vi) { return (vi / step) % k != layer; },
                         [&](int64_t vi) {
                           const int cc[3] = {int(vi % k), int((vi / k) % k), int(vi / k2)};
                           out.emplace_back(int32_t(cc[(axis + 2) % 3] * k + cc[(axis + 1) % 3]), part);
                         });
    }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
  };
  // Whether a part reaching face voxel idx is in [p0, p1).
  auto reach_meets = [](const Reach& r, int32_t idx, const int32_t* p0, const int32_t* p1) {
    for (auto it = std::lower_bound(r.begin(), r.end(), std::make_pair(idx, std::numeric_limits<int32_t>::min()));
         it != r.end() && it->first == idx; ++it)
      if (std::binary_search(p0, p1, it->second)) return true;
    return false;
  };
  std::vector<int32_t> plain, plain_offsets, plain_ids;  // unanalysed surface neighbours, their triangles
  std::unordered_map<int32_t, int32_t> plain_part;  // unanalysed surface neighbour -> its part
  if (by_part) {
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
    triangles_of(sp, tris, plain, plain_offsets, plain_ids);
    for (size_t i = 0; i < plain.size(); ++i)
      if (plain_offsets[i] < plain_offsets[i + 1]) plain_part[plain[i]] = vertex_part[tris[plain_ids[plain_offsets[i]]][0]];
  }
  std::vector<std::vector<PieceLink>> links(static_cast<size_t>(nb));
  parallel_for(nb, [&](int64_t b) {
    const int64_t xid = surf_cells[cand_surf[b]];
    const Eigen::Vector3i X = g.coords(xid);
    const Eigen::Vector3d x_corner = origin + h * X.cast<double>();
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
        Reach into_x, into_y;  // Y's triangles reaching X's face voxels, X's reaching Y's
        bool reached = false;
        for (int q = 0; q < k; ++q)
          for (int u = 0; u < k; ++u) {
            const uint8_t a = v[face_voxel(axis, layer, u, q)], c = w[face_voxel(axis, 0, u, q)];
            if (a < 3 || c < 3) continue;
            if (by_part) {
              const int32_t idx = q * k + u;
              const int32_t ka = key_of(b, f * k2 + idx), kc = key_of(yb, (f - 1) * k2 + idx);
              if (!touch(b, ka, yb, kc)) {
                if (!reached) {
                  reached = true;
                  into_x = face_reach(cand_tris.data(), cand_offsets[yb], cand_offsets[yb + 1], x_corner, axis, k - 1);
                  into_y = face_reach(cand_tris.data(), cand_offsets[b], cand_offsets[b + 1],
                                      origin + h * Y.cast<double>(), axis, 0);
                }
                const auto [a0, a1] = parts_of(b, &ka);
                const auto [c0, c1] = parts_of(yb, &kc);
                if (!reach_meets(into_x, idx, c0, c1) && !reach_meets(into_y, idx, a0, a1)) continue;
              }
            }
            pairs.emplace_back(a - 3, c - 3);
          }
        std::sort(pairs.begin(), pairs.end());
        pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
        for (const auto& pr : pairs) mine.push_back({xid, pr.first, f, yid, pr.second});
      } else {
        std::vector<uint8_t> has(static_cast<size_t>(pieces[b]), 0);
        const int32_t ys = surf_of[yid];
        const auto known = ys >= 0 && by_part ? plain_part.find(ys) : plain_part.end();
        Reach into_x;  // the neighbour's triangles reaching X's face voxels
        bool reached = false;
        for (int q = 0; q < k; ++q)
          for (int u = 0; u < k; ++u) {
            const uint8_t a = v[face_voxel(axis, layer, u, q)];
            if (a < 3) continue;
            if (known != plain_part.end()) {
              const int32_t ka = key_of(b, f * k2 + q * k + u);
              if (!touch(b, ka, b, known->second)) {
                if (!reached) {
                  reached = true;
                  const size_t i = size_t(std::lower_bound(plain.begin(), plain.end(), ys) - plain.begin());
                  into_x = face_reach(plain_ids.data(), plain_offsets[i], plain_offsets[i + 1], x_corner, axis, layer);
                }
                const int32_t part = known->second;
                if (!reach_meets(into_x, q * k + u, &part, &part + 1)) continue;
              }
            }
            has[a - 3] = 1;
          }
        for (int32_t p = 0; p < pieces[b]; ++p)
          if (has[p]) mine.push_back({xid, p, f, yid, -1});
      }
    }
  }, 4);

  // Vertices: the piece of the voxel holding them (the nearest material voxel for a loose vertex).
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
