// One copy per branch where separate parts meet: branch_copies.h says what and why.
#include "branch_copies.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <unordered_map>

#include "geometry.h"
#include "parallel.h"
#include "voxel_inside.h"
#include "voxel_rows.h"

namespace larap {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// The mesh's parts with triangles, numbered densely: their triangles, boxes and volumes.
struct Parts {
  std::vector<int32_t> of_vertex;  // dense part of each vertex (-1: a part without triangles)
  std::vector<std::vector<int32_t>> tris;
  std::vector<Eigen::AlignedBox3d> box;
  std::vector<double> volume;  // |signed volume| of its triangles
  int32_t count() const { return int32_t(tris.size()); }
};

Parts parts_of(const RowMatrixX3d& V, const std::vector<Eigen::Vector3i>& tris, const std::vector<int32_t>& part) {
  Parts P;
  std::unordered_map<int32_t, int32_t> dense;
  P.of_vertex.assign(size_t(V.rows()), -1);
  std::vector<int32_t> tri_part(tris.size());
  for (size_t t = 0; t < tris.size(); ++t) {
    const auto [it, fresh] = dense.emplace(part[size_t(tris[t][0])], int32_t(dense.size()));
    if (fresh) {
      P.tris.emplace_back();
      P.box.emplace_back();
    }
    tri_part[t] = it->second;
    P.tris[size_t(it->second)].push_back(int32_t(t));
    for (int i = 0; i < 3; ++i) P.box[size_t(it->second)].extend(V.row(tris[t][i]).transpose());
  }
  for (int64_t v = 0; v < V.rows(); ++v) {
    const auto it = dense.find(part[size_t(v)]);
    if (it != dense.end()) P.of_vertex[size_t(v)] = it->second;
  }
  P.volume.assign(P.tris.size(), 0.0);
  for (size_t t = 0; t < tris.size(); ++t) {
    const int32_t p = tri_part[t];
    const Eigen::Vector3d o = P.box[size_t(p)].min();
    const Eigen::Vector3d a = V.row(tris[t][0]).transpose() - o, b = V.row(tris[t][1]).transpose() - o,
                          c = V.row(tris[t][2]).transpose() - o;
    P.volume[size_t(p)] += a.dot(b.cross(c));
  }
  for (double& x : P.volume) x = std::abs(x) / 6.0;
  return P;
}

// What a copy near where parts meet holds.
struct Material {
  int32_t trunk = -1;
  std::vector<int32_t> exposed;       // its branches with material outside the trunk, ascending
  std::vector<double> branch_share;   // per exposed branch: its and the trunk's voxels / k^3
  std::vector<double> mask_share;     // per exposed branch: its voxels / k^3
  int32_t parts = 0;                  // parts it holds any material of
  bool within_voxels = false;         // trunk material among its voxels
  bool within_any = false;            // trunk material, its vertices included
  double within_share = 0.0;          // trunk voxels / k^3
  std::array<double, 8> dT{}, dB{};   // per corner: nearest trunk and exposed material
};

}  // namespace

bool split_per_branch(const Lattice& lat, const RowMatrixX3d& V, const std::vector<Eigen::Vector3i>& tris,
                      const std::vector<int32_t>& vertex_part, const BranchOptions& o, LatticeCopies& out) {
  if (tris.empty()) return false;
  bool several = false;  // two parts with triangles, before anything is built
  for (size_t t = 1; t < tris.size() && !several; ++t)
    several = vertex_part[size_t(tris[t][0])] != vertex_part[size_t(tris[0][0])];
  if (!several) return false;
  const Parts P = parts_of(V, tris, vertex_part);
  const Eigen::Vector3i dims = lat.dims;
  const int64_t ngrid = int64_t(dims.x()) * dims.y() * dims.z();
  const double h = lat.h;
  auto grid_index = [&](const Eigen::Vector3i& c) { return c.x() + int64_t(dims.x()) * (c.y() + int64_t(dims.y()) * c.z()); };
  auto cell_lo = [&](const Eigen::Vector3i& c) { return Eigen::Vector3d(lat.origin + h * c.cast<double>()); };

  // Triangles per grid cell (exact overlap), as CSR over the grid.
  std::vector<int32_t> tri_offsets(size_t(ngrid) + 1, 0), tri_ids;
  {
    std::vector<std::pair<int64_t, int32_t>> hits;
    const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * h);
    for (size_t t = 0; t < tris.size(); ++t) {
      Eigen::Vector3d v[3];
      for (int i = 0; i < 3; ++i) v[i] = V.row(tris[t][i]).transpose();
      Eigen::Vector3i c0, c1;
      for (int a = 0; a < 3; ++a) {
        const double lo = (std::min({v[0][a], v[1][a], v[2][a]}) - lat.origin[a]) / h;
        const double hi = (std::max({v[0][a], v[1][a], v[2][a]}) - lat.origin[a]) / h;
        c0[a] = std::clamp(geometry::floor_int(std::max(lo, 0.0)), 0, dims[a] - 1);
        c1[a] = std::clamp(geometry::floor_int(std::max(hi, 0.0)), 0, dims[a] - 1);
      }
      for (int z = c0.z(); z <= c1.z(); ++z)
        for (int y = c0.y(); y <= c1.y(); ++y)
          for (int x = c0.x(); x <= c1.x(); ++x) {
            const Eigen::Vector3i c(x, y, z);
            if (geometry::triangle_box_overlap(cell_lo(c) + half, half, v[0], v[1], v[2]))
              hits.emplace_back(grid_index(c), int32_t(t));
          }
    }
    for (const auto& [g, t] : hits) ++tri_offsets[size_t(g) + 1];
    for (int64_t g = 0; g < ngrid; ++g) tri_offsets[size_t(g) + 1] += tri_offsets[size_t(g)];
    tri_ids.resize(hits.size());
    std::vector<int32_t> fill(tri_offsets.begin(), tri_offsets.end() - 1);
    for (const auto& [g, t] : hits) tri_ids[size_t(fill[size_t(g)]++)] = t;
  }
  auto parts_in = [&](int64_t g) {
    std::vector<int32_t> ps;
    for (int32_t q = tri_offsets[size_t(g)]; q < tri_offsets[size_t(g) + 1]; ++q)
      ps.push_back(P.of_vertex[size_t(tris[size_t(tri_ids[size_t(q)])][0])]);
    std::sort(ps.begin(), ps.end());
    ps.erase(std::unique(ps.begin(), ps.end()), ps.end());
    return ps;
  };

  // Vertices per copy.
  const int64_t nc = lat.num_cells();
  std::vector<int32_t> vert_offsets(size_t(nc) + 1, 0), verts(lat.vertex_cell.size());
  for (int32_t c : lat.vertex_cell) ++vert_offsets[size_t(c) + 1];
  for (int64_t c = 0; c < nc; ++c) vert_offsets[size_t(c) + 1] += vert_offsets[size_t(c)];
  {
    std::vector<int32_t> fill(vert_offsets.begin(), vert_offsets.end() - 1);
    for (size_t v = 0; v < lat.vertex_cell.size(); ++v) verts[size_t(fill[size_t(lat.vertex_cell[v])]++)] = int32_t(v);
  }

  // Cells near where parts meet: those two parts' triangles overlap, and the kept cells around
  // them. (Narrowing this to cells where a copy can hold two parts -- a copy with vertices of two,
  // or more parts than copies -- saved rows of boxes that split nothing, but missed a junction
  // whose trunk fills two copies of a cell and whose branch has no vertex beside the trunk's.)
  std::vector<uint8_t> todo(size_t(ngrid), 0);
  bool any = false;
  for (int64_t c = 0; c < nc; ++c) {
    const Eigen::Vector3i x = lat.cell_coords[size_t(c)];
    if (parts_in(grid_index(x)).size() < 2) continue;
    any = true;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const Eigen::Vector3i y = x + Eigen::Vector3i(dx, dy, dz);
          if (lat.cell_copies(y.x(), y.y(), y.z()) > 0) todo[size_t(grid_index(y))] = 1;
        }
  }
  if (!any) return false;
  std::vector<int64_t> cells;
  for (int64_t g = 0; g < ngrid; ++g)
    if (todo[size_t(g)]) cells.push_back(g);

  // 1. Material. Each candidate cell's parts (those whose box meets it) and, per part, the voxels
  // inside it by ray parity against its triangles alone (5 votes of 6). The cells of a row along
  // an axis share that row's rays (voxel_inside.h), so each (axis, row, part) is crossed once for
  // the cells of a batch that lie in it; a batch holds at most kBatchBytes of votes.
  const int k = o.k;
  const int64_t k3 = int64_t(k) * k * k;
  const double hv = h / k;
  std::vector<Material> material(static_cast<size_t>(nc));
  std::vector<uint8_t> has(size_t(nc), 0);
  auto coords_of = [&](int64_t g) {
    return Eigen::Vector3i(int(g % dims.x()), int((g / dims.x()) % dims.y()), int(g / (int64_t(dims.x()) * dims.y())));
  };
  std::vector<std::vector<int32_t>> present_of(cells.size());
  parallel_for(int64_t(cells.size()), [&](int64_t ci) {
    const Eigen::Vector3d lo = cell_lo(coords_of(cells[size_t(ci)]));
    const Eigen::AlignedBox3d box(lo, lo + Eigen::Vector3d::Constant(h));
    for (int32_t p = 0; p < P.count(); ++p)
      if (P.box[size_t(p)].intersects(box)) present_of[size_t(ci)].push_back(p);
  }, 64);
  // The rest of a cell's analysis, from its present parts' votes: the copies' material.
  auto analyse_cell = [&](int64_t g, const std::vector<int32_t>& present, uint8_t* votes) {
    const Eigen::Vector3i x = coords_of(g);
    const Eigen::Vector3d lo = cell_lo(x);
    std::vector<const uint8_t*> inside(present.size());  // per present part, 1 where inside (the votes, in place)
    for (size_t j = 0; j < present.size(); ++j) {
      uint8_t* v = votes + int64_t(j) * k3;
      for (int64_t vi = 0; vi < k3; ++vi) v[vi] = v[vi] >= kInsideVotes;
      inside[j] = v;
    }
    // The voxels inside some part; where the cell has several copies, their 6-connected components.
    std::vector<uint8_t> solid(size_t(k3), 0);
    for (const auto& in : inside)
      for (int64_t vi = 0; vi < k3; ++vi) solid[size_t(vi)] |= in[size_t(vi)];
    const int32_t first = lat.cell_at(x.x(), x.y(), x.z()), ncopies = lat.cell_copies(x.x(), x.y(), x.z());
    std::vector<int32_t> comp;
    int32_t ncomp = 0;
    if (ncopies > 1) {
      comp.assign(size_t(k3), -1);  // the pieces' flood on bit rows (voxel_rows.h), in voxel order
      std::vector<uint64_t> left(static_cast<size_t>(k) * k);
      rows_equal(solid.data(), k, 1, left.data());
      for_each_piece(k, left.data(), [&](const uint64_t* piece, RowSpan span) {
        for (int r = span.first; r <= span.last; ++r)
          for (uint64_t bits = piece[r]; bits; bits &= bits - 1)
            comp[size_t(int64_t(r) * k + __builtin_ctzll(bits))] = ncomp;
        ++ncomp;
      });
    }
    // The copies take components: those holding their vertices' parts (a copy without vertices:
    // what no other copy takes). One copy takes everything.
    std::vector<std::vector<uint8_t>> held(size_t(ncopies), std::vector<uint8_t>(size_t(ncomp), 0));
    if (ncopies > 1) {
      std::vector<uint8_t> taken(size_t(ncomp), 0);
      for (int32_t X = 0; X < ncopies; ++X) {
        std::vector<size_t> js;  // the present parts of its vertices
        for (int32_t q = vert_offsets[size_t(first + X)]; q < vert_offsets[size_t(first + X) + 1]; ++q) {
          const auto it = std::find(present.begin(), present.end(), P.of_vertex[size_t(verts[size_t(q)])]);
          if (it != present.end()) js.push_back(size_t(it - present.begin()));
        }
        std::sort(js.begin(), js.end());
        js.erase(std::unique(js.begin(), js.end()), js.end());
        for (size_t j : js)
          for (int64_t vi = 0; vi < k3; ++vi)
            if (inside[j][size_t(vi)]) held[size_t(X)][size_t(comp[size_t(vi)])] = 1;
        for (int32_t c = 0; c < ncomp; ++c) taken[size_t(c)] |= held[size_t(X)][size_t(c)];
      }
      for (int32_t X = 0; X < ncopies; ++X) {
        bool none = true;
        for (uint8_t t : held[size_t(X)]) none = none && !t;
        if (!none) continue;
        for (int32_t c = 0; c < ncomp; ++c) held[size_t(X)][size_t(c)] = !taken[size_t(c)];
        break;
      }
    }
    Eigen::Vector3d corner[8];
    for (int q = 0; q < 8; ++q) corner[q] = lo + h * Eigen::Vector3d(double(q & 1), double((q >> 1) & 1), double(q >> 2));
    auto voxel_of = [&](const Eigen::Vector3d& p) {
      int c[3];
      for (int a = 0; a < 3; ++a) c[a] = std::clamp(geometry::floor_int(std::max((p[a] - lo[a]) / hv, 0.0)), 0, k - 1);
      return c[0] + int64_t(k) * (c[1] + int64_t(k) * c[2]);
    };
    // d[q] = min over the voxels of `set` of the squared distance from corner q to their centres.
    // Only voxels with a face on the set's border count: one with its neighbour towards a corner
    // in the set is farther from that corner than the neighbour.
    auto nearest = [&](const std::vector<uint8_t>& set, std::array<double, 8>& d) {
      for (int l = 0; l < k; ++l)
        for (int jj = 0; jj < k; ++jj)
          for (int i = 0; i < k; ++i) {
            const int64_t vi = i + int64_t(k) * (jj + int64_t(k) * l);
            if (!set[size_t(vi)]) continue;
            if (i > 0 && i < k - 1 && jj > 0 && jj < k - 1 && l > 0 && l < k - 1 && set[size_t(vi - 1)] &&
                set[size_t(vi + 1)] && set[size_t(vi - k)] && set[size_t(vi + k)] && set[size_t(vi - k * k)] &&
                set[size_t(vi + k * k)])
              continue;
            const Eigen::Vector3d c = lo + hv * Eigen::Vector3d(i + 0.5, jj + 0.5, l + 0.5);
            for (int q = 0; q < 8; ++q) d[size_t(q)] = std::min(d[size_t(q)], (c - corner[q]).squaredNorm());
          }
    };
    auto nearest_point = [&](const Eigen::Vector3d& p, std::array<double, 8>& d) {
      for (int q = 0; q < 8; ++q) d[size_t(q)] = std::min(d[size_t(q)], (p - corner[q]).squaredNorm());
    };
    // Per copy: its parts' material (voxels and vertices), the trunk, the exposed branches.
    std::vector<uint8_t> mine(static_cast<size_t>(k3)), within(static_cast<size_t>(k3)), exposed(static_cast<size_t>(k3));
    for (int32_t X = 0; X < ncopies; ++X) {
      const int32_t cX = first + X;
      for (int64_t vi = 0; vi < k3; ++vi)
        mine[size_t(vi)] = solid[size_t(vi)] && (ncopies == 1 || held[size_t(X)][size_t(comp[size_t(vi)])]);
      std::vector<int64_t> count(present.size(), 0);  // each present part's voxels in the copy
      for (size_t j = 0; j < present.size(); ++j)
        for (int64_t vi = 0; vi < k3; ++vi) count[j] += inside[j][size_t(vi)] && mine[size_t(vi)];
      std::map<int32_t, std::vector<int32_t>> vtx;  // part -> its vertices in the copy
      for (int32_t q = vert_offsets[size_t(cX)]; q < vert_offsets[size_t(cX) + 1]; ++q) {
        const int32_t p = P.of_vertex[size_t(verts[size_t(q)])];
        if (p >= 0) vtx[p].push_back(verts[size_t(q)]);
      }
      std::vector<int32_t> parts;
      for (size_t j = 0; j < present.size(); ++j)
        if (count[j] > 0) parts.push_back(present[j]);
      for (const auto& [p, l] : vtx) parts.push_back(p);
      std::sort(parts.begin(), parts.end());
      parts.erase(std::unique(parts.begin(), parts.end()), parts.end());
      if (parts.empty()) continue;
      Material m;
      m.parts = int32_t(parts.size());
      m.trunk = *std::max_element(parts.begin(), parts.end(), [&](int32_t a, int32_t b) {
        return P.volume[size_t(a)] < P.volume[size_t(b)];
      });
      const auto tj = std::find(present.begin(), present.end(), m.trunk);
      const uint8_t* in_trunk = tj == present.end() ? nullptr : inside[size_t(tj - present.begin())];
      // The trunk's material: its voxels, its vertices, and other parts' vertices inside it.
      int64_t nwithin = 0;
      for (int64_t vi = 0; vi < k3; ++vi) {
        within[size_t(vi)] = in_trunk && in_trunk[vi] && mine[size_t(vi)];
        nwithin += within[size_t(vi)];
      }
      m.within_voxels = nwithin > 0;
      m.within_share = double(nwithin) / double(k3);
      std::array<double, 8> dT, dB;
      dT.fill(kInf);
      dB.fill(kInf);
      nearest(within, dT);
      bool trunk_vertex = false;
      for (const auto& [p, l] : vtx)
        for (int32_t v : l)
          if (p == m.trunk || (in_trunk && in_trunk[voxel_of(V.row(v).transpose())])) {
            nearest_point(V.row(v).transpose(), dT);
            trunk_vertex = true;
          }
      m.within_any = m.within_voxels || trunk_vertex;
      for (int32_t p : parts) {
        if (p == m.trunk) continue;
        const auto pj = std::find(present.begin(), present.end(), p);
        int64_t n_exposed = 0, n_mask = 0;
        if (pj != present.end()) {
          const uint8_t* in = inside[size_t(pj - present.begin())];
          for (int64_t vi = 0; vi < k3; ++vi) {
            const bool b = in[size_t(vi)] && mine[size_t(vi)];
            n_mask += b;
            exposed[size_t(vi)] = b && !within[size_t(vi)];
            n_exposed += exposed[size_t(vi)];
          }
          if (n_exposed > 0) nearest(exposed, dB);
        }
        bool exposed_vertex = false;
        if (vtx.count(p))
          for (int32_t v : vtx[p])
            if (!(in_trunk && in_trunk[voxel_of(V.row(v).transpose())])) {
              exposed_vertex = true;
              nearest_point(V.row(v).transpose(), dB);
            }
        if (n_exposed == 0 && !exposed_vertex) continue;
        m.exposed.push_back(p);
        m.branch_share.push_back(double(nwithin + n_exposed) / double(k3));
        m.mask_share.push_back(double(n_mask) / double(k3));
      }
      for (int q = 0; q < 8; ++q) {
        m.dT[size_t(q)] = std::sqrt(dT[size_t(q)]);
        m.dB[size_t(q)] = std::sqrt(dB[size_t(q)]);
      }
      material[size_t(cX)] = std::move(m);
      has[size_t(cX)] = 1;
    }
  };
  constexpr int64_t kBatchBytes = int64_t(64) << 20;
  for (size_t b0 = 0; b0 < cells.size();) {
    size_t b1 = b0;
    std::vector<int64_t> offset(1, 0);  // of each batch cell's votes, part after part
    while (b1 < cells.size() && (b1 == b0 || offset.back() + int64_t(present_of[b1].size()) * k3 <= kBatchBytes)) {
      offset.push_back(offset.back() + int64_t(present_of[b1].size()) * k3);
      ++b1;
    }
    std::vector<uint8_t> votes(size_t(offset.back()), 0);
    for (int a = 0; a < 3; ++a) {  // axis by axis: a (cell, part) is in one row per axis
      std::map<std::pair<int64_t, int32_t>, std::vector<std::pair<int32_t, int32_t>>> rows;  // (row, part) -> (cell, j)
      for (size_t ci = b0; ci < b1; ++ci) {
        Eigen::Vector3i row = coords_of(cells[ci]);
        row[a] = 0;
        for (size_t j = 0; j < present_of[ci].size(); ++j)
          rows[{grid_index(row), present_of[ci][j]}].emplace_back(int32_t(ci - b0), int32_t(j));
      }
      std::vector<const decltype(rows)::value_type*> tasks;
      for (const auto& r : rows) tasks.push_back(&r);
      parallel_for(int64_t(tasks.size()), [&](int64_t t) {
        const auto& [key, members] = *tasks[size_t(t)];
        const Eigen::Vector3i row = coords_of(key.first);
        const int32_t p = key.second;
        std::vector<int32_t> ids;
        Eigen::Vector3i y = row;
        for (y[a] = 0; y[a] < dims[a]; ++y[a]) {
          const int64_t gy = grid_index(y);
          for (int32_t q = tri_offsets[size_t(gy)]; q < tri_offsets[size_t(gy) + 1]; ++q)
            if (P.of_vertex[size_t(tris[size_t(tri_ids[size_t(q)])][0])] == p) ids.push_back(tri_ids[size_t(q)]);
        }
        std::sort(ids.begin(), ids.end());
        ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
        RowRays rays(a, cell_lo(row), hv, k);
        rays.cross(ids.data(), ids.size(), V, tris, vertex_part);
        for (const auto& [c, j] : members) {
          uint8_t* v = votes.data() + offset[size_t(c)] + int64_t(j) * k3;
          rays.votes(coords_of(cells[b0 + size_t(c)])[a], [v](int64_t vi, int n) { v[vi] = uint8_t(v[vi] + n); });
        }
      }, 1);
    }
    parallel_for(int64_t(b1 - b0), [&](int64_t bc) {
      analyse_cell(cells[b0 + size_t(bc)], present_of[b0 + size_t(bc)], votes.data() + offset[size_t(bc)]);
    }, 1);
    b0 = b1;
  }

  // 2. Sides: per node, over the copies around it.
  const int64_t nn = lat.num_real_nodes();
  std::vector<int32_t> side(size_t(nn), -1);  // the trunk a node on the branches' side belongs to
  std::vector<double> ratio(size_t(nn), 0.0);
  {
    std::vector<double> dT(size_t(nn), kInf), dB(size_t(nn), kInf);
    for (int64_t c = 0; c < nc; ++c) {
      if (!has[size_t(c)]) continue;
      const Material& m = material[size_t(c)];
      for (int q = 0; q < 8; ++q) {
        const int32_t n = lat.cell_nodes[size_t(c)][size_t(q)];
        if (m.dT[size_t(q)] < dT[size_t(n)]) {
          dT[size_t(n)] = m.dT[size_t(q)];
          side[size_t(n)] = m.trunk;  // provisional: the nearest trunk
        }
        dB[size_t(n)] = std::min(dB[size_t(n)], m.dB[size_t(q)]);
      }
    }
    for (int64_t n = 0; n < nn; ++n) {
      if (dB[size_t(n)] < o.kappa * dT[size_t(n)] && side[size_t(n)] >= 0)
        ratio[size_t(n)] = dB[size_t(n)] > 0.0 ? dT[size_t(n)] / dB[size_t(n)] : kInf;
      else
        side[size_t(n)] = -1;
    }
  }
  // Each copy to be split keeps its corner most on the trunk's side: a ball joint.
  for (int64_t c = 0; c < nc; ++c) {
    if (!has[size_t(c)]) continue;
    const Material& m = material[size_t(c)];
    if (m.exposed.empty() || !m.within_voxels) continue;
    const auto& cn = lat.cell_nodes[size_t(c)];
    bool all = true;
    for (int q = 0; q < 8; ++q) all = all && side[size_t(cn[size_t(q)])] >= 0;
    if (!all) continue;
    int best = 0;
    for (int q = 1; q < 8; ++q)
      if (ratio[size_t(cn[size_t(q)])] < ratio[size_t(cn[size_t(best)])]) best = q;
    side[size_t(cn[size_t(best)])] = -1;
  }

  // 3. Copies: split, labelled.
  std::vector<int32_t> label(size_t(nc), -1);
  struct NewCopy {
    int32_t from, part;
    double weight;
  };
  std::vector<NewCopy> added;
  std::vector<double> weight(size_t(nc), 1.0);
  if (!lat.cell_weight.empty()) weight = lat.cell_weight;
  const double floor = 1.0 / k;
  for (int64_t c = 0; c < nc; ++c) {
    if (!has[size_t(c)]) continue;
    const Material& m = material[size_t(c)];
    bool on_side = false;
    for (int q = 0; q < 8; ++q) on_side = on_side || side[size_t(lat.cell_nodes[size_t(c)][size_t(q)])] >= 0;
    if (!m.exposed.empty() && on_side && m.within_voxels) {
      label[size_t(c)] = m.trunk;
      weight[size_t(c)] = std::max(m.within_share, floor);
      for (size_t b = 0; b < m.exposed.size(); ++b)
        added.push_back({int32_t(c), m.exposed[b], std::max(m.branch_share[b], floor)});
    } else if (m.exposed.size() >= 2 && on_side) {
      label[size_t(c)] = m.exposed[0];
      weight[size_t(c)] = std::max(m.mask_share[0], floor);
      for (size_t b = 1; b < m.exposed.size(); ++b)
        added.push_back({int32_t(c), m.exposed[b], std::max(m.mask_share[b], floor)});
    } else if (m.within_any || m.parts == 1) {
      label[size_t(c)] = m.trunk;
    } else if (m.exposed.size() == 1) {
      label[size_t(c)] = m.exposed[0];
    }
  }
  if (added.empty()) return false;
  // Copies with too little material for the voxels: the one branch of their labelled neighbours.
  std::vector<int32_t> around_offsets(size_t(nn) + 1, 0), around(size_t(8 * nc));
  for (int64_t c = 0; c < nc; ++c)
    for (int q = 0; q < 8; ++q) ++around_offsets[size_t(lat.cell_nodes[size_t(c)][size_t(q)]) + 1];
  for (int64_t n = 0; n < nn; ++n) around_offsets[size_t(n) + 1] += around_offsets[size_t(n)];
  {
    std::vector<int32_t> fill(around_offsets.begin(), around_offsets.end() - 1);
    for (int64_t c = 0; c < nc; ++c)
      for (int q = 0; q < 8; ++q) around[size_t(fill[size_t(lat.cell_nodes[size_t(c)][size_t(q)])]++)] = int32_t(c);
  }
  for (int64_t c = 0; c < nc; ++c) {  // in copy order, each seeing the labels given before it
    if (label[size_t(c)] >= 0) continue;
    int32_t found = -1;
    bool one = true;
    for (int q = 0; q < 8 && one; ++q) {
      const int32_t n = lat.cell_nodes[size_t(c)][size_t(q)];
      if (side[size_t(n)] < 0) continue;
      for (int32_t j = around_offsets[size_t(n)]; j < around_offsets[size_t(n) + 1]; ++j) {
        const int32_t l = label[size_t(around[size_t(j)])];
        if (l < 0 || l == side[size_t(n)]) continue;
        if (found < 0) found = l;
        else if (found != l) one = false;
      }
    }
    if (one && found >= 0) label[size_t(c)] = found;
  }

  // 4. Copies in grid order (the new ones after their cell's), nodes of a branch's own.
  std::vector<std::vector<int32_t>> added_after(static_cast<size_t>(nc));
  for (size_t a = 0; a < added.size(); ++a) {
    const int32_t f = added[a].from;
    const Eigen::Vector3i x = lat.cell_coords[size_t(f)];
    const int32_t last = lat.cell_at(x.x(), x.y(), x.z()) + lat.cell_copies(x.x(), x.y(), x.z()) - 1;
    added_after[size_t(last)].push_back(int32_t(a));
  }
  out = LatticeCopies{};
  std::vector<int32_t> new_of_old(static_cast<size_t>(nc)), new_of_added(added.size());
  std::map<std::pair<int32_t, int32_t>, int32_t> own;  // (node, part) -> its own node's label
  int32_t next_label = int32_t(nn);
  auto corners = [&](const std::array<int32_t, 8>& cn, int32_t part) {
    std::array<int32_t, 8> r = cn;
    if (part < 0) return r;
    for (int q = 0; q < 8; ++q) {
      const int32_t n = cn[size_t(q)];
      if (side[size_t(n)] < 0 || side[size_t(n)] == part) continue;
      const auto [it, fresh] = own.emplace(std::make_pair(n, part), next_label);
      if (fresh) ++next_label;
      r[size_t(q)] = it->second;
    }
    return r;
  };
  for (int64_t c = 0; c < nc; ++c) {
    new_of_old[size_t(c)] = int32_t(out.cell_coords.size());
    out.cell_coords.push_back(lat.cell_coords[size_t(c)]);
    out.cell_nodes.push_back(corners(lat.cell_nodes[size_t(c)], label[size_t(c)]));
    out.cell_kind.push_back(lat.cell_kind[size_t(c)]);
    out.cell_weight.push_back(weight[size_t(c)]);
    for (int32_t a : added_after[size_t(c)]) {
      const NewCopy& nw = added[size_t(a)];
      new_of_added[size_t(a)] = int32_t(out.cell_coords.size());
      out.cell_coords.push_back(lat.cell_coords[size_t(nw.from)]);
      out.cell_nodes.push_back(corners(lat.cell_nodes[size_t(nw.from)], nw.part));
      out.cell_kind.push_back(lat.cell_kind[size_t(nw.from)]);
      out.cell_weight.push_back(nw.weight);
    }
  }
  // Vertices: a branch's go to its own copy.
  out.vertex_cell.resize(lat.vertex_cell.size());
  std::map<std::pair<int32_t, int32_t>, int32_t> copy_of;  // (old copy, part) -> new copy
  for (size_t a = 0; a < added.size(); ++a) copy_of[{added[a].from, added[a].part}] = new_of_added[a];
  for (size_t v = 0; v < lat.vertex_cell.size(); ++v) {
    const int32_t c = lat.vertex_cell[v];
    const auto it = copy_of.find({c, P.of_vertex[v]});
    out.vertex_cell[v] = it != copy_of.end() ? it->second : new_of_old[size_t(c)];
  }
  for (size_t a = 0; a < added.size(); ++a) {
    const int32_t t = new_of_old[size_t(added[a].from)];
    out.couplings.push_back({new_of_added[a], t, o.coupling * out.cell_weight[size_t(t)]});
  }
  return true;
}

}  // namespace larap
