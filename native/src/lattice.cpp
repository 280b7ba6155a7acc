// Lattice::build and the lattice's own methods: the grid is voxelised (voxel_grid.cpp), then the
// kept cells are assembled into a lattice, with copies where a cell holds several pieces
// (cell_pieces.cpp) and the B-spline shell after the real nodes (stencil_shell.cpp).
#include <larap/errors.h>
#include <larap/lattice.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <string>
#include <unordered_map>

#include "branch_copies.h"
#include "cell_pieces.h"
#include "disjoint_sets.h"
#include "mesh_parts.h"
#include "voxel_grid.h"
#include "geometry.h"
#include "stencil_shell.h"
#include "parallel.h"

namespace larap {

int64_t Lattice::estimate_bytes(const Eigen::Vector3i& dims) {
  const double cells = double(dims.x()) * dims.y() * dims.z();
  const double nodes = double(dims.x() + 1) * (dims.y() + 1) * (dims.z() + 1);
  // marks + votes (1 + 1 B/cell), cell map (4 B/cell), node map (4 B/node), crossing lists.
  const double bytes = cells * 6.0 + nodes * 4.0 + 64.0 * (dims.x() * double(dims.y()) +
                                                           dims.y() * double(dims.z()) +
                                                           dims.z() * double(dims.x()));
  return bytes > 9e18 ? std::numeric_limits<int64_t>::max() : static_cast<int64_t>(bytes);
}

int32_t Lattice::node_at(int x, int y, int z) const {
  if (x < 0 || y < 0 || z < 0 || x > dims.x() || y > dims.y() || z > dims.z()) return -1;
  return node_grid_[x + int64_t(dims.x() + 1) * (y + int64_t(dims.y() + 1) * z)];
}

int32_t Lattice::cell_at(int x, int y, int z) const {
  if (x < 0 || y < 0 || z < 0 || x >= dims.x() || y >= dims.y() || z >= dims.z()) return -1;
  return cell_grid_[x + int64_t(dims.x()) * (y + int64_t(dims.y()) * z)];
}

// ------------------------------------------------------------------------------------ assembly
namespace {

Eigen::Vector3i corner_offset(int c) { return Eigen::Vector3i(c & 1, (c >> 1) & 1, c >> 2); }

std::string short_number(double x) {  // 3 significant digits, exponent when needed
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", x);
  return buf;
}

}  // namespace

// Builds a lattice from its cell copies (grid order, copies of a cell consecutive) and the
// classes of their corner slots (slot 8 c + corner; a class = one node, all at one grid point).
class LatticeAssembly {
 public:
  static Lattice fine(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                      const std::vector<uint8_t>& marks, const CellPieces& pieces,
                      const std::vector<int64_t>& vertex_cells);
  static Lattice coarse(const Lattice& finer, std::vector<int32_t>* parent);
  static Lattice from_copies(const Lattice& grid, const LatticeCopies& copies);

 private:
  static Lattice start(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                       const std::vector<int64_t>& copy_cell, const std::vector<uint8_t>& kinds);
  static void finish(Lattice& lat, DisjointSets& slots);
  static int64_t point_index(const Lattice& lat, const Eigen::Vector3i& p) {
    return p.x() + int64_t(lat.dims.x() + 1) * (p.y() + int64_t(lat.dims.y() + 1) * p.z());
  }
  // A ghost: a corner node used by one analysed copy alone (no face of the copy around it holds
  // material, so no link reaches it). It arises where the 2x2x2 block rule flagged cells whose
  // surfaces meet just outside the block (a torus's concave inner wall curving away from a cell
  // face). A ghost joins the node of a face-adjacent copy at its point when the two copies
  // already share the other three corners of their common face (their pieces connect within a
  // cell of it; the ghost would only hinge them along the face), if only one such node is on offer.
  // Only between cells that were analysed but kept whole (one copy each): in a split cell a
  // private corner may be all that keeps two pieces apart, and it stays private.
  static void share_ghost_corners(const Lattice& lat, const std::vector<uint8_t>& plain, DisjointSets& slots);
  // Every corner slot of the copies of cells not split joins the node its grid point already has
  // (the plain lattice's rule).
  static void share_points(const Lattice& lat, const std::vector<uint8_t>& plain, DisjointSets& slots) {
    std::vector<int32_t> first(size_t(int64_t(lat.dims.x() + 1) * (lat.dims.y() + 1) * (lat.dims.z() + 1)), -1);
    for (int64_t c = 0; c < lat.num_cells(); ++c) {
      if (!plain[c]) continue;
      for (int q = 0; q < 8; ++q) {
        int32_t& f = first[size_t(point_index(lat, lat.cell_coords[c] + corner_offset(q)))];
        if (f < 0) f = int32_t(8 * c + q);
        else slots.unite(f, int32_t(8 * c + q));
      }
    }
  }
};

void LatticeAssembly::share_ghost_corners(const Lattice& lat, const std::vector<uint8_t>& plain,
                                          DisjointSets& slots) {
  const int64_t nc = lat.num_cells();
  std::vector<int32_t> members(static_cast<size_t>(8 * nc), 0);  // per class root
  for (int64_t s = 0; s < 8 * nc; ++s) ++members[size_t(slots.find(int32_t(s)))];
  std::vector<std::pair<int32_t, int32_t>> joins;
  auto whole = [&](const Eigen::Vector3i& x) { return lat.cell_copies(x.x(), x.y(), x.z()) == 1; };
  for (int64_t c = 0; c < nc; ++c) {
    if (plain[c] || !whole(lat.cell_coords[c])) continue;
    for (int q = 0; q < 8; ++q) {
      if (members[size_t(slots.find(int32_t(8 * c + q)))] != 1) continue;
      int32_t target = -1;
      bool ambiguous = false;
      for (int axis = 0; axis < 3; ++axis) {  // the three faces of c around corner q
        const int side = (q >> axis) & 1;
        Eigen::Vector3i y = lat.cell_coords[c];
        y[axis] += side ? 1 : -1;
        const int32_t first = lat.cell_at(y.x(), y.y(), y.z()), n = lat.cell_copies(y.x(), y.y(), y.z());
        if (n != 1) continue;
        for (int32_t d = first; d >= 0 && d < first + n; ++d) {
          int shared = 0;
          for (int r = 0; r < 8; ++r)
            if (r != q && ((r >> axis) & 1) == side &&
                slots.find(int32_t(8 * c + r)) == slots.find(int32_t(8 * d + (r ^ (1 << axis)))))
              ++shared;
          if (shared < 3) continue;
          const int32_t other = int32_t(8 * d + (q ^ (1 << axis)));
          if (target < 0) target = other;
          else if (slots.find(target) != slots.find(other)) ambiguous = true;
        }
      }
      if (target >= 0 && !ambiguous) joins.emplace_back(int32_t(8 * c + q), target);
    }
  }
  for (const auto& j : joins) slots.unite(j.first, j.second);
}

Lattice LatticeAssembly::start(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                               const std::vector<int64_t>& copy_cell, const std::vector<uint8_t>& kinds) {
  Lattice lat;
  lat.origin = origin;
  lat.h = h;
  lat.dims = dims;
  const int64_t ncell = int64_t(dims.x()) * dims.y() * dims.z();
  lat.cell_grid_.assign(size_t(ncell), -1);
  lat.cell_count_.assign(size_t(ncell), 0);
  if (copy_cell.size() > size_t(std::numeric_limits<int32_t>::max() / 8))
    throw OutOfMemory("the lattice has too many cells (" + std::to_string(copy_cell.size()) + ")");
  lat.cell_coords.reserve(copy_cell.size());
  for (size_t c = 0; c < copy_cell.size(); ++c) {
    const int64_t id = copy_cell[c];
    if (lat.cell_grid_[id] < 0) lat.cell_grid_[id] = int32_t(c);
    ++lat.cell_count_[id];
    lat.cell_coords.emplace_back(int(id % dims.x()), int((id / dims.x()) % dims.y()),
                                 int(id / (int64_t(dims.x()) * dims.y())));
  }
  lat.cell_kind = kinds;
  return lat;
}

void LatticeAssembly::finish(Lattice& lat, DisjointSets& slots) {
  const int64_t nc = lat.num_cells();
  // Nodes: one per class, ordered by grid point, then by the class's smallest slot.
  std::vector<std::pair<int64_t, int32_t>> roots;
  for (int64_t s = 0; s < 8 * nc; ++s)
    if (slots.find(int32_t(s)) == s)
      roots.emplace_back(point_index(lat, lat.cell_coords[s / 8] + corner_offset(int(s % 8))), int32_t(s));
  std::sort(roots.begin(), roots.end());
  std::vector<int32_t> node_of_slot(static_cast<size_t>(8 * nc), -1);
  const int64_t nn = int64_t(roots.size());
  lat.node_grid_.assign(size_t(int64_t(lat.dims.x() + 1) * (lat.dims.y() + 1) * (lat.dims.z() + 1)), -1);
  lat.node_coords.resize(size_t(nn));
  for (int64_t i = 0; i < nn; ++i) {
    const int32_t s = roots[i].second;
    node_of_slot[s] = int32_t(i);
    lat.node_coords[i] = lat.cell_coords[s / 8] + corner_offset(s % 8);
    if (lat.node_grid_[roots[i].first] < 0) lat.node_grid_[roots[i].first] = int32_t(i);
  }
  lat.real_nodes = int32_t(nn);
  lat.rest.resize(nn, 3);
  for (int64_t i = 0; i < nn; ++i)
    lat.rest.row(i) = (lat.origin + lat.h * lat.node_coords[i].cast<double>()).transpose();
  lat.cell_nodes.resize(size_t(nc));
  for (int64_t c = 0; c < nc; ++c)
    for (int q = 0; q < 8; ++q) lat.cell_nodes[c][q] = node_of_slot[slots.find(int32_t(8 * c + q))];

  // Edges: the 12 edges of every copy, listed by their lower node, then axis, then upper node.
  // An edge weighs half the sum of the weights of the copies it is an edge of: the energy is a
  // sum over cell copies of their 12 edges (docs/method.md), so an edge inside the lattice (4
  // cells) weighs 2, one on the surface 1 or 0.5, and the Laplacian's factor 2 g w_ij is g times
  // the sum over its copies.
  // A branch coupling counts its trunk copy's 12 edges once more, at the coupling's weight.
  const bool weighted = !lat.cell_weight.empty();
  std::vector<int32_t> count(size_t(nn) + 1, 0);
  for (int64_t c = 0; c < nc; ++c)
    for (int q = 0; q < 8; ++q)
      for (int a = 0; a < 3; ++a)
        if (!((q >> a) & 1)) ++count[lat.cell_nodes[c][q] + 1];
  for (const Coupling& k : lat.couplings)
    for (int q = 0; q < 8; ++q)
      for (int a = 0; a < 3; ++a)
        if (!((q >> a) & 1)) ++count[lat.cell_nodes[size_t(k.trunk)][q] + 1];
  for (int64_t i = 0; i < nn; ++i) count[i + 1] += count[i];
  struct Up {
    int32_t axis, upper;
    double w;
    bool operator<(const Up& o) const { return axis != o.axis ? axis < o.axis : upper < o.upper; }
  };
  std::vector<Up> up(static_cast<size_t>(count[nn]));  // per lower node
  {
    std::vector<int32_t> fill(count.begin(), count.end() - 1);
    for (int64_t c = 0; c < nc; ++c)
      for (int q = 0; q < 8; ++q)
        for (int a = 0; a < 3; ++a)
          if (!((q >> a) & 1))
            up[size_t(fill[lat.cell_nodes[c][q]]++)] = {a, lat.cell_nodes[c][q | (1 << a)],
                                                       weighted ? lat.cell_weight[c] : 1.0};
    for (const Coupling& k : lat.couplings) {
      const auto& t = lat.cell_nodes[size_t(k.trunk)];
      for (int q = 0; q < 8; ++q)
        for (int a = 0; a < 3; ++a)
          if (!((q >> a) & 1)) up[size_t(fill[t[q]]++)] = {a, t[q | (1 << a)], k.weight};
    }
  }
  std::vector<std::vector<std::pair<int32_t, double>>> nbrs(static_cast<size_t>(nn));
  for (int64_t i = 0; i < nn; ++i) {
    auto b = up.begin() + count[i], e = up.begin() + count[i + 1];
    std::sort(b, e);  // ties keep no order, but their weights are only summed
    for (auto it = b; it != e;) {
      auto run = it;
      double sum = 0.0;
      for (; run != e && run->axis == it->axis && run->upper == it->upper; ++run) sum += run->w;
      const double w = 0.5 * sum;
      lat.edges.push_back({int32_t(i), it->upper});
      lat.edge_weight.push_back(w);
      nbrs[i].emplace_back(it->upper, w);
      nbrs[it->upper].emplace_back(int32_t(i), w);
      it = run;
    }
  }
  lat.adj_offsets.assign(size_t(nn + 1), 0);
  for (int64_t i = 0; i < nn; ++i) {
    std::sort(nbrs[i].begin(), nbrs[i].end());
    lat.adj_offsets[i + 1] = lat.adj_offsets[i] + int32_t(nbrs[i].size());
  }
  lat.adj.reserve(size_t(lat.adj_offsets[nn]));
  lat.adj_weight.reserve(size_t(lat.adj_offsets[nn]));
  for (int64_t i = 0; i < nn; ++i)
    for (const auto& [j, w] : nbrs[i]) {
      lat.adj.push_back(j);
      lat.adj_weight.push_back(w);
    }

  // Connected components (union-find over edges).
  DisjointSets comp(nn);
  for (const auto& e : lat.edges) comp.unite(e[0], e[1]);
  lat.component.assign(size_t(nn), -1);
  std::vector<int32_t> label(static_cast<size_t>(nn), -1);
  lat.num_components = 0;
  for (int64_t i = 0; i < nn; ++i) {
    const int32_t r = comp.find(int32_t(i));
    if (label[r] < 0) label[r] = lat.num_components++;
    lat.component[i] = label[r];
  }
}

Lattice LatticeAssembly::fine(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                              const std::vector<uint8_t>& marks, const CellPieces& pieces,
                              const std::vector<int64_t>& vertex_cells) {
  // Copies: one per piece of an analysed cell, one for every other kept cell.
  std::vector<int64_t> copy_cell;
  std::vector<uint8_t> kinds, plain;
  size_t next = 0;
  const int64_t ncell = int64_t(marks.size());
  for (int64_t id = 0; id < ncell; ++id) {
    const uint8_t m = marks[id] & kKept;
    if (!m) continue;
    int32_t n = 1;
    bool split = false;
    if (next < pieces.cells.size() && pieces.cells[next] == id) {
      n = pieces.pieces[next++];
      split = true;
    }
    for (int32_t p = 0; p < n; ++p) {
      copy_cell.push_back(id);
      kinds.push_back(m);
      plain.push_back(!split);
    }
  }
  Lattice lat = start(origin, h, dims, copy_cell, kinds);
  // Stiffness of the copies of split cells: their piece's share of the cell's material.
  if (pieces.k > 0) {
    const double k3 = double(pieces.k) * pieces.k * pieces.k, floor = 1.0 / pieces.k;
    size_t first_piece = 0;
    for (size_t a = 0; a < pieces.cells.size(); ++a) {
      const int32_t n = pieces.pieces[a];
      if (n > 1) {
        if (lat.cell_weight.empty()) lat.cell_weight.assign(size_t(lat.num_cells()), 1.0);
        const int32_t c0 = lat.cell_grid_[pieces.cells[a]];
        for (int32_t p = 0; p < n; ++p)
          lat.cell_weight[size_t(c0 + p)] =
              std::clamp(double(pieces.piece_voxels[first_piece + size_t(p)]) / k3, floor, 1.0);
      }
      first_piece += size_t(n);
    }
  }
  DisjointSets slots(8 * lat.num_cells());
  share_points(lat, plain, slots);
  for (const PieceLink& l : pieces.links) {
    const int32_t a = lat.cell_grid_[l.a_cell] + l.a_piece;
    const int32_t b = lat.cell_grid_[l.b_cell] + std::max(l.b_piece, 0);
    const int axis = l.face / 2, side = l.face % 2;
    for (int q = 0; q < 8; ++q) {
      if (((q >> axis) & 1) != side) continue;  // corners of a's face
      slots.unite(8 * a + q, 8 * b + (q ^ (1 << axis)));
    }
  }
  share_ghost_corners(lat, plain, slots);
  finish(lat, slots);
  lat.vertex_cell.resize(vertex_cells.size());
  for (size_t v = 0; v < vertex_cells.size(); ++v)
    lat.vertex_cell[v] = lat.cell_grid_[vertex_cells[v]];
  for (const auto& [v, piece] : pieces.vertex_pieces) lat.vertex_cell[size_t(v)] += piece;
  return lat;
}

Lattice LatticeAssembly::coarse(const Lattice& f, std::vector<int32_t>* parent) {
  const int64_t nfc = f.num_cells(), nfr = f.num_real_nodes();
  const Eigen::Vector3i cd = (f.dims + Eigen::Vector3i::Ones()) / 2;
  auto block = [&](int64_t c) {
    const Eigen::Vector3i b = f.cell_coords[c] / 2;  // coordinates are non-negative
    return b.x() + int64_t(cd.x()) * (b.y() + int64_t(cd.y()) * b.z());
  };
  // Fine copies incident to each real node.
  std::vector<int32_t> off(size_t(nfr) + 1, 0), inc(size_t(8 * nfc));
  for (int64_t c = 0; c < nfc; ++c)
    for (int q = 0; q < 8; ++q) ++off[f.cell_nodes[c][q] + 1];
  for (int64_t i = 0; i < nfr; ++i) off[i + 1] += off[i];
  {
    std::vector<int32_t> fill(off.begin(), off.end() - 1);
    for (int64_t c = 0; c < nfc; ++c)
      for (int q = 0; q < 8; ++q) inc[size_t(fill[f.cell_nodes[c][q]]++)] = int32_t(c);
  }
  // Groups: fine copies of one block joined through shared nodes.
  DisjointSets groups(nfc);
  for (int64_t i = 0; i < nfr; ++i)
    for (int32_t a = off[i]; a < off[i + 1]; ++a)
      for (int32_t b = a + 1; b < off[i + 1]; ++b)
        if (block(inc[a]) == block(inc[b])) groups.unite(inc[a], inc[b]);
  // Coarse copies in block order, then by their smallest fine copy.
  std::vector<std::pair<int64_t, int32_t>> order;
  for (int64_t c = 0; c < nfc; ++c)
    if (groups.find(int32_t(c)) == c) order.emplace_back(block(c), int32_t(c));
  std::sort(order.begin(), order.end());
  std::vector<int32_t> copy_of_root(static_cast<size_t>(nfc), -1);
  std::vector<int64_t> copy_cell;
  std::vector<uint8_t> kinds(order.size(), 0);
  for (size_t k = 0; k < order.size(); ++k) {
    copy_of_root[order[k].second] = int32_t(k);
    copy_cell.push_back(order[k].first);
  }
  std::vector<int32_t> up(static_cast<size_t>(nfc));
  for (int64_t c = 0; c < nfc; ++c) {
    up[c] = copy_of_root[groups.find(int32_t(c))];
    kinds[up[c]] |= f.cell_kind[c];
  }
  Lattice lat = start(f.origin, 2.0 * f.h, cd, copy_cell, kinds);
  // Two coarse copies whose fine copies share a node share their common corners.
  DisjointSets slots(8 * lat.num_cells());
  for (int64_t i = 0; i < nfr; ++i) {
    if (off[i + 1] - off[i] < 2) continue;
    const int32_t c1 = up[inc[off[i]]];
    for (int32_t a = off[i] + 1; a < off[i + 1]; ++a) {
      const int32_t c2 = up[inc[a]];
      if (c2 == c1) continue;
      const Eigen::Vector3i d = lat.cell_coords[c1] - lat.cell_coords[c2];
      for (int q = 0; q < 8; ++q) {
        const Eigen::Vector3i o = corner_offset(q) + d;  // corner q of c1 seen from c2
        if ((o.array() < 0).any() || (o.array() > 1).any()) continue;
        slots.unite(8 * c1 + q, 8 * c2 + (o.x() | (o.y() << 1) | (o.z() << 2)));
      }
    }
  }
  finish(lat, slots);
  lat.vertex_cell.resize(f.vertex_cell.size());
  for (size_t v = 0; v < f.vertex_cell.size(); ++v) lat.vertex_cell[v] = up[f.vertex_cell[v]];
  if (parent) *parent = std::move(up);
  return lat;
}

Lattice Lattice::coarsened(std::vector<int32_t>* parent) const { return LatticeAssembly::coarse(*this, parent); }

void Lattice::replace_copies(const LatticeCopies& k) { *this = LatticeAssembly::from_copies(*this, k); }

Lattice LatticeAssembly::from_copies(const Lattice& grid, const LatticeCopies& k) {
  const size_t nc = k.cell_coords.size();
  if (k.cell_nodes.size() != nc || k.cell_kind.size() != nc || (!k.cell_weight.empty() && k.cell_weight.size() != nc))
    throw InvalidInput("replace_copies: the copies' arrays differ in length");
  if (k.vertex_cell.size() != grid.vertex_cell.size())
    throw InvalidInput("replace_copies: vertex_cell has the wrong length");
  std::vector<int64_t> copy_cell(nc);
  for (size_t c = 0; c < nc; ++c) {
    const Eigen::Vector3i& x = k.cell_coords[c];
    if ((x.array() < 0).any() || (x.array() >= grid.dims.array()).any())
      throw InvalidInput("replace_copies: a copy outside the grid");
    copy_cell[c] = x.x() + int64_t(grid.dims.x()) * (x.y() + int64_t(grid.dims.y()) * x.z());
    if (c > 0 && copy_cell[c] < copy_cell[c - 1])
      throw InvalidInput("replace_copies: copies not in grid order");
  }
  Lattice lat = start(grid.origin, grid.h, grid.dims, copy_cell, k.cell_kind);
  lat.cell_weight = k.cell_weight;
  DisjointSets slots(8 * lat.num_cells());
  std::unordered_map<int32_t, int32_t> first;  // node label -> its first slot
  for (size_t c = 0; c < nc; ++c)
    for (int q = 0; q < 8; ++q) {
      const auto [it, fresh] = first.emplace(k.cell_nodes[c][size_t(q)], int32_t(8 * c + q));
      if (fresh) continue;
      const int32_t s = it->second;
      if (k.cell_coords[size_t(s / 8)] + corner_offset(s % 8) != k.cell_coords[c] + corner_offset(q))
        throw InvalidInput("replace_copies: node label " + std::to_string(k.cell_nodes[c][size_t(q)]) +
                           " names two grid points");
      for (int r = 0; r < q; ++r)
        if (k.cell_nodes[c][size_t(r)] == k.cell_nodes[c][size_t(q)])
          throw InvalidInput("replace_copies: a copy names one node twice");
      slots.unite(s, int32_t(8 * c + q));
    }
  for (const Coupling& cp : k.couplings)
    if (cp.branch < 0 || cp.trunk < 0 || size_t(cp.branch) >= nc || size_t(cp.trunk) >= nc || cp.branch == cp.trunk ||
        !(cp.weight >= 0.0 && std::isfinite(cp.weight)))
      throw InvalidInput("replace_copies: a coupling out of range, between a copy and itself, or of a weight that "
                         "is not finite and non-negative");
  for (double w : k.cell_weight)
    if (!(w > 0.0 && w <= 1.0)) throw InvalidInput("replace_copies: a cell weight outside (0, 1]");
  lat.couplings = k.couplings;
  finish(lat, slots);
  for (size_t v = 0; v < k.vertex_cell.size(); ++v) {
    const int32_t c = k.vertex_cell[v];
    if (c < 0 || c >= lat.num_cells()) throw InvalidInput("replace_copies: vertex_cell out of range");
    // The copy must be of the cell the vertex was in (a vertex binds inside its cell).
    if (lat.cell_coords[size_t(c)] != grid.cell_coords[size_t(grid.vertex_cell[v])])
      throw InvalidInput("replace_copies: vertex " + std::to_string(v) + " given a copy of another cell");
  }
  lat.vertex_cell = k.vertex_cell;
  return lat;
}

int32_t Lattice::cell_copies(int x, int y, int z) const {
  if (x < 0 || y < 0 || z < 0 || x >= dims.x() || y >= dims.y() || z >= dims.z()) return 0;
  return cell_count_[x + int64_t(dims.x()) * (y + int64_t(dims.y()) * z)];
}

void Lattice::fill_shell(RowMatrixX3d& P) const {
  const int64_t ns = num_shell_nodes();
  parallel_for(ns, [&](int64_t s) {
    Eigen::RowVector3d x = Eigen::RowVector3d::Zero();
    for (int32_t e = shell_offsets[s]; e < shell_offsets[s + 1]; ++e) x += shell_weights[e] * P.row(shell_ids[e]);
    P.row(real_nodes + s) = x;
  }, 2048);
}

Lattice Lattice::build(const PolygonMesh& mesh, const LatticeOptions& options) {
  if (mesh.num_vertices() == 0) throw InvalidInput("the mesh has no vertices");
  if (!(options.cell_size >= 0.0) || !std::isfinite(options.cell_size))
    throw InvalidInput("cell_size must be a positive finite number, got " +
                       number_text(options.cell_size));
  if (options.cells < 0)
    throw InvalidInput("cells must be positive, got " + std::to_string(options.cells));
  if (options.split_resolution < 4 || options.split_resolution > 64)
    throw InvalidInput("split_resolution must be between 4 and 64, got " +
                       std::to_string(options.split_resolution));
  if (options.branch_copies && !options.split_cells)
    throw InvalidInput("branch_copies needs split_cells (one copy per branch splits the cells' copies further)");
  if (!(options.branch_coupling >= 0.0 && options.branch_coupling <= 1e6))
    throw InvalidInput("branch_coupling must be between 0 and 1e6, got " + number_text(options.branch_coupling));
  const int64_t max_bytes = options.max_bytes > 0 ? options.max_bytes : physical_memory_bytes() / 2;

  const Eigen::Vector3d lo = mesh.vertices.colwise().minCoeff().transpose();
  const Eigen::Vector3d hi = mesh.vertices.colwise().maxCoeff().transpose();
  const Eigen::Vector3d extent = hi - lo;
  if (!extent.allFinite())
    throw InvalidInput("the mesh spans more than the largest double along an axis (from " + short_number(lo.minCoeff()) +
                       " to " + short_number(hi.maxCoeff()) + "); scale it down");
  const double diag = extent.stableNorm();  // no overflow for coordinates near the double range
  // The solve squares lengths and multiplies them by weights: keep every square far inside the
  // double range (a mesh this large or small would give a non-finite pose, not an error).
  constexpr double kMaxSize = 1e60, kMinSize = 1e-60;
  if (diag > kMaxSize || (diag > 0.0 && diag < kMinSize))
    throw InvalidInput("the mesh's size (bounding-box diagonal " + short_number(diag) +
                       ") is outside what the solver handles, 1e-60 to 1e60; scale it (or check for a stray vertex)");
  if (options.cell_size > kMaxSize)
    throw InvalidInput("cell_size " + short_number(options.cell_size) + " is beyond 1e60; scale the mesh");
  const std::vector<Eigen::Vector3i> tris = triangulate(mesh);
  const std::vector<Eigen::Vector2i> segs = segments(mesh);

  Grid grid;
  if (options.cell_size > 0.0) {
    grid = voxelize(mesh, tris, segs, lo, hi, options.cell_size, max_bytes);
  } else {
    if (!(diag > 0.0))
      throw InvalidInput("all vertices coincide, so the lattice has no extent; give cell_size");
    const int64_t target = options.cells > 0 ? options.cells : kDefaultCells;
    if (target > int64_t(2e9))
      throw OutOfMemory("cells=" + std::to_string(target) + " is beyond what a lattice can hold");
    // Initial guess: the target number of cubes filling the (thickened) bounding box.
    // (diag is within 1e-60..1e60, checked above, so this product of three lengths stays finite.)
    double box = 1.0;
    for (int a = 0; a < 3; ++a) box *= std::max(extent[a], diag / 50.0);
    double h = std::cbrt(box / double(target));
    if (!(h > 0.0) || !std::isfinite(h))
      throw InvalidInput("no cell size fits this mesh's extent (" + short_number(diag) + "); give cell_size");
    // The kept count grows like h^-3 for solids and h^-2 for shells: correct h a few times.
    double best_err = std::numeric_limits<double>::infinity();
    for (int pass = 0; pass < 5; ++pass) {
      check_memory(grid_dims(extent, h), h, max_bytes);
      Grid g = voxelize(mesh, tris, segs, lo, hi, h, max_bytes);
      const int64_t kept = count_kept(g);
      const double ratio = double(kept) / double(target);
      const double err = std::abs(std::log(ratio));
      if (err < best_err) {
        best_err = err;
        grid = std::move(g);
      }
      if (err < std::log(1.15)) break;
      h *= std::pow(ratio, 1.0 / 2.6);
    }
  }

  CellPieces pieces;  // none: the plain lattice
  std::vector<int32_t> parts;
  if (options.split_cells) {
    parts = mesh_parts(mesh);
    pieces = find_cell_pieces(grid.origin, grid.h, grid.dims, grid.marks, mesh.vertices, tris, parts,
                              grid.vertex_cells, options.split_resolution,
                              max_bytes - Lattice::estimate_bytes(grid.dims));
  }
  Lattice lat = LatticeAssembly::fine(grid.origin, grid.h, grid.dims, grid.marks, pieces, grid.vertex_cells);
  if (options.branch_copies) {
    BranchOptions bo;
    bo.k = options.split_resolution;
    bo.coupling = options.branch_coupling;
    LatticeCopies copies;
    if (split_per_branch(lat, mesh.vertices, tris, parts, bo, copies)) lat.replace_copies(copies);
  }
  if (options.edit) options.edit(lat);
  build_stencil_shell(lat);
  return lat;
}


}  // namespace larap
