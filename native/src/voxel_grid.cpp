#include "voxel_grid.h"

#include <larap/errors.h>
#include <unistd.h>

#include <limits>
#include <string>

#include "geometry.h"
#include "parallel.h"

namespace larap {

int64_t physical_memory_bytes() {
  const long pages = sysconf(_SC_PHYS_PAGES);
  const long page = sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page <= 0) return int64_t(8) << 30;
  return static_cast<int64_t>(pages) * page;
}


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
    throw OutOfMemory("the lattice grid at cell size " + number_text(h) + " would be " +
                      std::to_string(dims.x()) + " x " + std::to_string(dims.y()) + " x " +
                      std::to_string(dims.z()) + " cells and need about " + memory_text(bytes) +
                      " (limit " + memory_text(double(max_bytes)) +
                      "); use fewer cells or a larger cell size");
  }
}

// The cells [c0, c1] along axis k that the interval [lo, hi] (grid units) touches, a ten-millionth
// of a cell to spare each side, clamped to the grid.
static void cell_span(const Grid& g, double lo, double hi, int k, int& c0, int& c1) {
  c0 = std::max(0, geometry::floor_int(lo - 1e-7));
  c1 = std::min(g.dims[k] - 1, geometry::floor_int(hi + 1e-7));
}

// Sets `bit` on the cells of the block [c0, c1] whose box `overlaps(centre)` says a primitive
// overlaps; cells that have it already are not tested again. Safe from several threads.
template <class Overlaps>
static void mark_overlapped(Grid& g, const Eigen::Vector3i& c0, const Eigen::Vector3i& c1, uint8_t bit,
                            const Overlaps& overlaps) {
  for (int z = c0.z(); z <= c1.z(); ++z)
    for (int y = c0.y(); y <= c1.y(); ++y)
      for (int x = c0.x(); x <= c1.x(); ++x) {
        const int64_t id = g.index(x, y, z);
        if (__atomic_load_n(&g.marks[id], __ATOMIC_RELAXED) & bit) continue;
        if (overlaps(g.origin + g.h * Eigen::Vector3d(x + 0.5, y + 0.5, z + 0.5)))
          __atomic_fetch_or(&g.marks[id], bit, __ATOMIC_RELAXED);
      }
}

// Marks the cells every triangle overlaps (exact separating-axis test).
static void mark_surface(Grid& g, const RowMatrixX3d& V, const std::vector<Eigen::Vector3i>& tris) {
  const double h = g.h;
  const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * h * (1.0 + 1e-9));
  const int64_t nt = static_cast<int64_t>(tris.size());
  parallel_for(nt, [&](int64_t t) {
    const Eigen::Vector3d a = V.row(tris[t][0]), b = V.row(tris[t][1]), c = V.row(tris[t][2]);
    const Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c), hi = a.cwiseMax(b).cwiseMax(c);
    Eigen::Vector3i c0, c1;
    for (int k = 0; k < 3; ++k)
      cell_span(g, (lo[k] - g.origin[k]) / h, (hi[k] - g.origin[k]) / h, k, c0[k], c1[k]);
    mark_overlapped(g, c0, c1, kSurface, [&](const Eigen::Vector3d& centre) {
      return geometry::triangle_box_overlap(centre, half, a, b, c);
    });
  }, 2048);
}

// Marks kVertex on the cells every segment (loose edge) overlaps (the exact test), walking the
// segment's slabs along its longest axis so that a long diagonal edge costs its length in cells,
// not its bounding box. The cells join the lattice as a vertex's cell does (never analysed for
// splitting), so a wire's cells are face-connected in a chain however long its edges are.
static void mark_segments(Grid& g, const RowMatrixX3d& V, const std::vector<Eigen::Vector2i>& segs) {
  const double h = g.h;
  const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * h * (1.0 + 1e-9));
  parallel_for(int64_t(segs.size()), [&](int64_t s) {
    const Eigen::Vector3d a = V.row(segs[s][0]), b = V.row(segs[s][1]);
    const Eigen::Vector3d pa = (a - g.origin) / h, pb = (b - g.origin) / h;  // grid units
    const Eigen::Vector3d d = pb - pa;
    int axis = 0;
    d.cwiseAbs().maxCoeff(&axis);
    int s0, s1;
    cell_span(g, std::min(pa[axis], pb[axis]), std::max(pa[axis], pb[axis]), axis, s0, s1);
    for (int slab = s0; slab <= s1; ++slab) {
      // The part of the segment within this slab (a little wider), its box on the other axes.
      double t0 = 0.0, t1 = 1.0;
      if (d[axis] != 0.0) {
        const double u = (slab - 1e-7 - pa[axis]) / d[axis], w = (slab + 1 + 1e-7 - pa[axis]) / d[axis];
        t0 = std::max(0.0, std::min(u, w));
        t1 = std::min(1.0, std::max(u, w));
        if (t0 > t1) continue;
      }
      const Eigen::Vector3d q0 = pa + t0 * d, q1 = pa + t1 * d;
      Eigen::Vector3i c0, c1;
      for (int k = 0; k < 3; ++k) cell_span(g, std::min(q0[k], q1[k]), std::max(q0[k], q1[k]), k, c0[k], c1[k]);
      c0[axis] = c1[axis] = slab;
      mark_overlapped(g, c0, c1, kVertex, [&](const Eigen::Vector3d& centre) {
        return geometry::segment_box_overlap(centre, half, a, b);
      });
    }
  }, 2048);
}

// 6-connected flood fill from the border through cells no triangle touches.
static void mark_outside(Grid& g) {
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
// The crossings are gathered from chunks of triangles in parallel (each triangle's corners in grid
// units once, for all three axes), then bucketed by column; a column's crossings are sorted before
// they are used, so the votes do not depend on the order they were found in.
static std::vector<uint8_t> parity_votes(const Grid& g, const RowMatrixX3d& V,
                                  const std::vector<Eigen::Vector3i>& tris) {
  std::vector<uint8_t> votes(static_cast<size_t>(g.size()), 0);
  // Columns: the rays of geometry.h (off the cell centres by a millionth of a cell); those of axis
  // a, (jb, jc) with b = a + 1, c = a + 2 (mod 3), are numbered from col0[a].
  int64_t col0[4] = {0, 0, 0, 0};
  for (int a = 0; a < 3; ++a) col0[a + 1] = col0[a] + int64_t(g.dims[(a + 1) % 3]) * g.dims[(a + 2) % 3];
  struct Crossing {
    int64_t col;
    double at;
  };
  constexpr int64_t kChunk = 16384;
  const int64_t nt = int64_t(tris.size()), nchunks = (nt + kChunk - 1) / kChunk;
  std::vector<std::vector<Crossing>> found(static_cast<size_t>(nchunks));
  const auto cross_chunk = [&](int64_t chunk) {
    std::vector<Crossing>& out = found[size_t(chunk)];
    const int64_t end = std::min(nt, (chunk + 1) * kChunk);
    for (int64_t t = chunk * kChunk; t < end; ++t) {
      Eigen::Vector3d p[3];
      for (int k = 0; k < 3; ++k) p[k] = (V.row(tris[t][k]).transpose() - g.origin) / g.h;
      for (int a = 0; a < 3; ++a) {
        const int nb = g.dims[(a + 1) % 3], nc = g.dims[(a + 2) % 3];
        int jb0, jb1, jc0, jc1;
        if (!geometry::rays_in_box(p, a, nb, nc, jb0, jb1, jc0, jc1)) continue;
        if (geometry::seen_area(p, a) == 0.0) continue;  // parallel to the ray
        for (int jc = jc0; jc <= jc1; ++jc)
          for (int jb = jb0; jb <= jb1; ++jb) {
            double ta;
            if (geometry::axis_line_crossing(p, a, jb + geometry::kRayB, jc + geometry::kRayC, ta))
              out.push_back({col0[a] + int64_t(jc) * nb + jb, ta});
          }
      }
    }
  };
  parallel_for(nchunks, cross_chunk, 1);
  // Bucket by column (CSR).
  std::vector<int64_t> start(static_cast<size_t>(col0[3] + 1), 0);
  for (const auto& part : found)
    for (const Crossing& x : part) ++start[size_t(x.col) + 1];
  for (int64_t col = 0; col < col0[3]; ++col) start[size_t(col) + 1] += start[size_t(col)];
  std::vector<double> at(static_cast<size_t>(start.back()));
  {
    std::vector<int64_t> fill(start.begin(), start.end() - 1);
    for (const auto& part : found)
      for (const Crossing& x : part) at[size_t(fill[size_t(x.col)]++)] = x.at;
  }
  std::vector<std::vector<Crossing>>().swap(found);
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    const int nb = g.dims[b], nc = g.dims[c], na = g.dims[a];
    const auto vote_column = [&](int64_t col) {
      double* xs = at.data() + start[size_t(col0[a] + col)];
      double* xs_end = at.data() + start[size_t(col0[a] + col) + 1];
      if (xs == xs_end) return;
      std::sort(xs, xs_end);
      // Coincident crossings (duplicated faces in a soup, a ray through a shared edge) count once.
      xs_end = std::unique(xs, xs_end, [](double u, double v) { return std::abs(u - v) < 1e-9; });
      const int jb = int(col % nb), jc = int(col / nb);
      const int total = int(xs_end - xs);
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
    };
    parallel_for(int64_t(nb) * nc, vote_column, 64);
  }
  return votes;
}

Grid voxelize(const PolygonMesh& mesh, const std::vector<Eigen::Vector3i>& tris,
              const std::vector<Eigen::Vector2i>& segs, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double h, int64_t max_bytes) {
  Grid g;
  g.h = h;
  g.dims = grid_dims(hi - lo, h);
  check_memory(g.dims, h, max_bytes);
  g.origin = lo - Eigen::Vector3d::Constant(kPad * h);
  const Eigen::Vector3d far_corner = g.origin + h * g.dims.cast<double>();
  if (!g.origin.allFinite() || !far_corner.allFinite())
    throw InvalidInput("the lattice's grid (cell size " + number_text(h) +
                       ") reaches beyond the largest double; scale the mesh down");
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
  // After the dilation: a loose edge's cells between its vertices bind nothing, so they need no
  // B-spline reach.
  mark_segments(g, mesh.vertices, segs);
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

}  // namespace larap
