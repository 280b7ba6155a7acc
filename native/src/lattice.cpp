#include <larap/errors.h>
#include <larap/lattice.h>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <string>

#include "cell_pieces.h"
#include "geometry.h"
#include "stencil_shell.h"
#include "parallel.h"

namespace larap {
namespace {

constexpr uint8_t kKept = kReal;  // dilation cells only count towards the target (no cells)
constexpr int kPad = 2;  // empty border cells around the bounding box (dilation + flood fill)

int64_t physical_memory_bytes() {
  const long pages = sysconf(_SC_PHYS_PAGES);
  const long page = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page <= 0) return int64_t(8) << 30;
  return static_cast<int64_t>(pages) * page;
}

std::string mib(double bytes) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.0f MiB", bytes / (1024.0 * 1024.0));
  return buf;
}

struct Grid {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  double h = 0.0;
  Eigen::Vector3i dims = Eigen::Vector3i::Zero();
  std::vector<uint8_t> marks;
  std::vector<int64_t> vertex_cells;  // grid index of each vertex's cell
  int64_t index(int x, int y, int z) const {
    return x + int64_t(dims.x()) * (y + int64_t(dims.y()) * z);
  }
  int64_t size() const { return int64_t(dims.x()) * dims.y() * dims.z(); }
  Eigen::Vector3i cell_of(const Eigen::Vector3d& p) const {
    Eigen::Vector3i c;
    for (int a = 0; a < 3; ++a) {
      const double f = std::floor((p[a] - origin[a]) / h);
      c[a] = static_cast<int>(std::clamp(f, 0.0, double(dims[a] - 1)));
    }
    return c;
  }
};

Eigen::Vector3i grid_dims(const Eigen::Vector3d& extent, double h) {
  Eigen::Vector3i d;
  for (int a = 0; a < 3; ++a) {
    const double n = std::floor(extent[a] / h) + 1 + 2 * kPad;
    if (!(n < 1e9)) {
      d[a] = std::numeric_limits<int>::max();
    } else {
      d[a] = static_cast<int>(n);
    }
  }
  return d;
}

void check_memory(const Eigen::Vector3i& dims, double h, int64_t max_bytes) {
  const double cells = double(dims.x()) * dims.y() * dims.z();
  const double bytes = double(Lattice::estimate_bytes(dims));
  const bool too_many = dims.maxCoeff() >= (1 << 20) || cells > 2.0e9;
  if (too_many || bytes > double(max_bytes)) {
    throw OutOfMemory("the lattice grid at cell size " + std::to_string(h) + " would be " +
                      std::to_string(dims.x()) + " x " + std::to_string(dims.y()) + " x " +
                      std::to_string(dims.z()) + " cells and need about " + mib(bytes) +
                      " (limit " + mib(double(max_bytes)) +
                      "); use fewer cells or a larger cell size");
  }
}

// Marks the cells every triangle overlaps (exact separating-axis test).
void mark_surface(Grid& g, const RowMatrixX3d& V, const std::vector<Eigen::Vector3i>& tris) {
  const double h = g.h;
  const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * h * (1.0 + 1e-9));
  const int64_t nt = static_cast<int64_t>(tris.size());
  parallel_for(nt, [&](int64_t t) {
    const Eigen::Vector3d a = V.row(tris[t][0]), b = V.row(tris[t][1]), c = V.row(tris[t][2]);
    const Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c), hi = a.cwiseMax(b).cwiseMax(c);
    Eigen::Vector3i c0, c1;
    for (int k = 0; k < 3; ++k) {
      c0[k] = std::max(0, int(std::floor((lo[k] - g.origin[k]) / h - 1e-7)));
      c1[k] = std::min(g.dims[k] - 1, int(std::floor((hi[k] - g.origin[k]) / h + 1e-7)));
    }
    for (int z = c0.z(); z <= c1.z(); ++z)
      for (int y = c0.y(); y <= c1.y(); ++y)
        for (int x = c0.x(); x <= c1.x(); ++x) {
          const int64_t id = g.index(x, y, z);
          if (__atomic_load_n(&g.marks[id], __ATOMIC_RELAXED) & kSurface) continue;
          const Eigen::Vector3d center = g.origin + h * Eigen::Vector3d(x + 0.5, y + 0.5, z + 0.5);
          if (geometry::triangle_box_overlap(center, half, a, b, c)) {
            __atomic_fetch_or(&g.marks[id], uint8_t(kSurface), __ATOMIC_RELAXED);
          }
        }
  }, 2048);
}

// 6-connected flood fill from the border through cells no triangle touches.
void mark_outside(Grid& g) {
  std::vector<int64_t> stack;
  auto push = [&](int x, int y, int z) {
    const int64_t id = g.index(x, y, z);
    if (g.marks[id] & (kSurface | kOutside)) return;
    g.marks[id] |= kOutside;
    stack.push_back(id);
  };
  const Eigen::Vector3i& d = g.dims;
  for (int z = 0; z < d.z(); ++z)
    for (int y = 0; y < d.y(); ++y)
      for (int x = 0; x < d.x(); ++x)
        if (x == 0 || y == 0 || z == 0 || x == d.x() - 1 || y == d.y() - 1 || z == d.z() - 1)
          push(x, y, z);
  const int64_t sy = d.x();
  while (!stack.empty()) {
    const int64_t id = stack.back();
    stack.pop_back();
    const int x = int(id % d.x()), y = int((id / sy) % d.y()), z = int(id / (sy * d.y()));
    if (x > 0) push(x - 1, y, z);
    if (x + 1 < d.x()) push(x + 1, y, z);
    if (y > 0) push(x, y - 1, z);
    if (y + 1 < d.y()) push(x, y + 1, z);
    if (z > 0) push(x, y, z - 1);
    if (z + 1 < d.z()) push(x, y, z + 1);
  }
}

// Ray parity votes: for each axis, rays through the cell-centre columns; a cell collects one vote
// per ray direction (+ and -) that crosses the surface an odd number of times before reaching it.
std::vector<uint8_t> parity_votes(const Grid& g, const RowMatrixX3d& V,
                                  const std::vector<Eigen::Vector3i>& tris) {
  std::vector<uint8_t> votes(static_cast<size_t>(g.size()), 0);
  // Columns are offset from cell centres by a tiny irrational-looking amount so that rays through
  // vertices and edges of grid-aligned meshes (a cube exactly on cell centres) are unlikely.
  const double jitter_b = 0.5 + 1.3717e-6, jitter_c = 0.5 + 2.9153e-6;
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    const int nb = g.dims[b], nc = g.dims[c], na = g.dims[a];
    std::vector<std::vector<double>> cols(static_cast<size_t>(nb) * nc);
    for (const auto& t : tris) {
      Eigen::Vector3d p[3];
      for (int k = 0; k < 3; ++k) p[k] = (V.row(t[k]).transpose() - g.origin) / g.h;
      const double bmin = std::min({p[0][b], p[1][b], p[2][b]}) - jitter_b;
      const double bmax = std::max({p[0][b], p[1][b], p[2][b]}) - jitter_b;
      const double cmin = std::min({p[0][c], p[1][c], p[2][c]}) - jitter_c;
      const double cmax = std::max({p[0][c], p[1][c], p[2][c]}) - jitter_c;
      const int jb0 = std::max(0, int(std::ceil(bmin))), jb1 = std::min(nb - 1, int(std::floor(bmax)));
      const int jc0 = std::max(0, int(std::ceil(cmin))), jc1 = std::min(nc - 1, int(std::floor(cmax)));
      if (jb0 > jb1 || jc0 > jc1) continue;
      // Signed area in the (b, c) plane.
      const double area = (p[1][b] - p[0][b]) * (p[2][c] - p[0][c]) -
                          (p[2][b] - p[0][b]) * (p[1][c] - p[0][c]);
      if (area == 0.0) continue;  // parallel to the ray
      for (int jc = jc0; jc <= jc1; ++jc)
        for (int jb = jb0; jb <= jb1; ++jb) {
          const double qb = jb + jitter_b, qc = jc + jitter_c;
          double w[3];
          for (int k = 0; k < 3; ++k) {
            const Eigen::Vector3d& u = p[(k + 1) % 3];
            const Eigen::Vector3d& v = p[(k + 2) % 3];
            w[k] = (u[b] - qb) * (v[c] - qc) - (v[b] - qb) * (u[c] - qc);
          }
          const bool inside = (w[0] >= 0 && w[1] >= 0 && w[2] >= 0) ||
                              (w[0] <= 0 && w[1] <= 0 && w[2] <= 0);
          if (!inside) continue;
          const double s = w[0] + w[1] + w[2];
          const double ta = (w[0] * p[0][a] + w[1] * p[1][a] + w[2] * p[2][a]) / s;
          cols[size_t(jc) * nb + jb].push_back(ta);
        }
    }
    parallel_for(int64_t(cols.size()), [&](int64_t col) {
      auto& xs = cols[col];
      if (xs.empty()) return;
      std::sort(xs.begin(), xs.end());
      // Coincident crossings (duplicated faces in a soup, a ray through a shared edge) count once.
      xs.erase(std::unique(xs.begin(), xs.end(),
                           [](double u, double v) { return std::abs(u - v) < 1e-9; }),
               xs.end());
      const int jb = int(col % nb), jc = int(col / nb);
      const int total = int(xs.size());
      int below = 0;
      for (int k = 0; k < na; ++k) {
        const double centre = k + 0.5;
        while (below < total && xs[below] < centre) ++below;
        Eigen::Vector3i cell;
        cell[a] = k;
        cell[b] = jb;
        cell[c] = jc;
        const int64_t id = g.index(cell.x(), cell.y(), cell.z());
        votes[id] += uint8_t((below & 1) + ((total - below) & 1));
      }
    }, 64);
  }
  return votes;
}

Grid voxelize(const PolygonMesh& mesh, const std::vector<Eigen::Vector3i>& tris,
              const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double h, int64_t max_bytes) {
  Grid g;
  g.h = h;
  g.dims = grid_dims(hi - lo, h);
  check_memory(g.dims, h, max_bytes);
  g.origin = lo - Eigen::Vector3d::Constant(kPad * h);
  g.marks.assign(static_cast<size_t>(g.size()), 0);

  mark_surface(g, mesh.vertices, tris);
  const int64_t n = mesh.num_vertices();
  g.vertex_cells.resize(static_cast<size_t>(n));
  parallel_for(n, [&](int64_t i) {
    const Eigen::Vector3i c = g.cell_of(mesh.vertices.row(i).transpose());
    g.vertex_cells[i] = g.index(c.x(), c.y(), c.z());
  }, 8192);
  for (int64_t id : g.vertex_cells) g.marks[id] |= kVertex;

  mark_outside(g);
  const std::vector<uint8_t> votes = parity_votes(g, mesh.vertices, tris);
  const int64_t size = g.size();
  for (int64_t id = 0; id < size; ++id) {
    const bool enclosed = !(g.marks[id] & (kOutside | kSurface));
    if (enclosed || votes[id] >= 4) g.marks[id] |= kInside;
  }

  // Dilation: the 3x3x3 block around every vertex cell, so B-spline stencils are complete.
  const Eigen::Vector3i& d = g.dims;
  for (int z = 1; z + 1 < d.z(); ++z)
    for (int y = 1; y + 1 < d.y(); ++y)
      for (int x = 1; x + 1 < d.x(); ++x) {
        if (!(g.marks[g.index(x, y, z)] & kVertex)) continue;
        for (int dz = -1; dz <= 1; ++dz)
          for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) g.marks[g.index(x + dx, y + dy, z + dz)] |= kDilation;
      }
  return g;
}

// Cells that count towards the `cells` target: the real cells and the 3x3x3 blocks around the
// vertices' cells (the B-spline's reach), as before the stencil shell stopped being cells, so a
// given `cells` gives the same cell size as before (split copies count once).
int64_t count_kept(const Grid& g) {
  int64_t k = 0;
  for (uint8_t m : g.marks) k += (m & (kKept | kDilation)) != 0;
  return k;
}

}  // namespace

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

// Disjoint sets whose root is the smallest member.
struct DisjointSets {
  std::vector<int32_t> parent;
  explicit DisjointSets(int64_t n) : parent(size_t(n)) { std::iota(parent.begin(), parent.end(), 0); }
  int32_t find(int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void unite(int32_t a, int32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

Eigen::Vector3i corner_offset(int c) { return Eigen::Vector3i(c & 1, (c >> 1) & 1, c >> 2); }

}  // namespace

// Builds a lattice from its cell copies (grid order, copies of a cell consecutive) and the
// classes of their corner slots (slot 8 c + corner; a class = one node, all at one grid point).
class LatticeAssembly {
 public:
  static Lattice fine(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                      const std::vector<uint8_t>& marks, const CellPieces& pieces,
                      const std::vector<int64_t>& vertex_cells);
  static Lattice coarse(const Lattice& finer, std::vector<int32_t>* parent);

 private:
  static Lattice start(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                       const std::vector<int64_t>& copy_cell, const std::vector<uint8_t>& kinds);
  static void finish(Lattice& lat, DisjointSets& slots);
  static int64_t point_index(const Lattice& lat, const Eigen::Vector3i& p) {
    return p.x() + int64_t(lat.dims.x() + 1) * (p.y() + int64_t(lat.dims.y() + 1) * p.z());
  }
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
  std::vector<int32_t> count(size_t(nn) + 1, 0);
  for (int64_t c = 0; c < nc; ++c)
    for (int q = 0; q < 8; ++q)
      for (int a = 0; a < 3; ++a)
        if (!((q >> a) & 1)) ++count[lat.cell_nodes[c][q] + 1];
  for (int64_t i = 0; i < nn; ++i) count[i + 1] += count[i];
  std::vector<std::pair<int32_t, int32_t>> up(static_cast<size_t>(count[nn]));  // (axis, upper) per lower node
  {
    std::vector<int32_t> fill(count.begin(), count.end() - 1);
    for (int64_t c = 0; c < nc; ++c)
      for (int q = 0; q < 8; ++q)
        for (int a = 0; a < 3; ++a)
          if (!((q >> a) & 1)) up[size_t(fill[lat.cell_nodes[c][q]]++)] = {a, lat.cell_nodes[c][q | (1 << a)]};
  }
  std::vector<std::vector<int32_t>> nbrs(static_cast<size_t>(nn));
  for (int64_t i = 0; i < nn; ++i) {
    auto b = up.begin() + count[i], e = up.begin() + count[i + 1];
    std::sort(b, e);
    e = std::unique(b, e);
    for (auto it = b; it != e; ++it) {
      lat.edges.push_back({int32_t(i), it->second});
      nbrs[i].push_back(it->second);
      nbrs[it->second].push_back(int32_t(i));
    }
  }
  lat.adj_offsets.assign(size_t(nn + 1), 0);
  for (int64_t i = 0; i < nn; ++i) {
    std::sort(nbrs[i].begin(), nbrs[i].end());
    lat.adj_offsets[i + 1] = lat.adj_offsets[i] + int32_t(nbrs[i].size());
  }
  lat.adj.reserve(size_t(lat.adj_offsets[nn]));
  for (int64_t i = 0; i < nn; ++i) lat.adj.insert(lat.adj.end(), nbrs[i].begin(), nbrs[i].end());

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
  finish(lat, slots);
  lat.vertex_cell.resize(vertex_cells.size());
  for (size_t v = 0; v < vertex_cells.size(); ++v)
    lat.vertex_cell[v] = lat.cell_grid_[vertex_cells[v]] + pieces.vertex_piece[v];
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
                       std::to_string(options.cell_size));
  if (options.cells < 0)
    throw InvalidInput("cells must be positive, got " + std::to_string(options.cells));
  if (options.split_resolution < 4 || options.split_resolution > 64)
    throw InvalidInput("split_resolution must be between 4 and 64, got " +
                       std::to_string(options.split_resolution));
  const int64_t max_bytes = options.max_bytes > 0 ? options.max_bytes : physical_memory_bytes() / 2;

  const Eigen::Vector3d lo = mesh.vertices.colwise().minCoeff().transpose();
  const Eigen::Vector3d hi = mesh.vertices.colwise().maxCoeff().transpose();
  const Eigen::Vector3d extent = hi - lo;
  const double diag = extent.norm();
  const std::vector<Eigen::Vector3i> tris = triangulate(mesh);

  Grid grid;
  if (options.cell_size > 0.0) {
    grid = voxelize(mesh, tris, lo, hi, options.cell_size, max_bytes);
  } else {
    if (!(diag > 0.0))
      throw InvalidInput("all vertices coincide, so the lattice has no extent; give cell_size");
    const int64_t target = options.cells > 0 ? options.cells : kDefaultCells;
    if (target > int64_t(2e9))
      throw OutOfMemory("cells=" + std::to_string(target) + " is beyond what a lattice can hold");
    // Initial guess: the target number of cubes filling the (thickened) bounding box.
    double box = 1.0;
    for (int a = 0; a < 3; ++a) box *= std::max(extent[a], diag / 50.0);
    double h = std::cbrt(box / double(target));
    // The kept count grows like h^-3 for solids and h^-2 for shells: correct h a few times.
    double best_err = std::numeric_limits<double>::infinity();
    for (int pass = 0; pass < 5; ++pass) {
      check_memory(grid_dims(extent, h), h, max_bytes);
      Grid g = voxelize(mesh, tris, lo, hi, h, max_bytes);
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

  CellPieces pieces;
  if (options.split_cells) {
    pieces = find_cell_pieces(grid.origin, grid.h, grid.dims, grid.marks, mesh.vertices, tris,
                              grid.vertex_cells, options.split_resolution);
  } else {
    pieces.vertex_piece.assign(size_t(mesh.num_vertices()), 0);
  }
  Lattice lat = LatticeAssembly::fine(grid.origin, grid.h, grid.dims, grid.marks, pieces, grid.vertex_cells);
  build_stencil_shell(lat);
  return lat;
}


}  // namespace larap
