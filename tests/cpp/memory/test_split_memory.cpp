// Cell splitting's memory check against the memory it really takes: this binary replaces the global
// operator new and delete to count the live bytes, so it is kept apart from larap_tests. For each
// mesh, the smallest max_voxel_bytes that find_cell_pieces accepts is its bound; the peak of live
// bytes during a call under that limit, less the peak of a call that stops at the check (the
// surface patches and candidates, held before it), must stay below the bound.
// Run: cmake --build build --target larap_memory_tests && ./build/larap_memory_tests
#include <gtest/gtest.h>
#include <larap/errors.h>
#include <larap/mesh.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <new>

#include "cell_pieces.h"
#include "mesh_parts.h"
#include "parallel.h"
#include "test_meshes.h"
#include "voxel_grid.h"

namespace {

std::atomic<int64_t> g_live{0}, g_peak{0};
constexpr size_t kHeader = alignof(std::max_align_t);  // holds the size, keeps the alignment

void* counted_alloc(size_t n) {
  void* p = std::malloc(n + kHeader);
  if (!p) throw std::bad_alloc();
  *static_cast<size_t*>(p) = n;
  const int64_t live = g_live.fetch_add(int64_t(n), std::memory_order_relaxed) + int64_t(n);
  int64_t peak = g_peak.load(std::memory_order_relaxed);
  while (live > peak && !g_peak.compare_exchange_weak(peak, live, std::memory_order_relaxed)) {
  }
  return static_cast<char*>(p) + kHeader;
}

void counted_free(void* q) {
  if (!q) return;
  void* p = static_cast<char*>(q) - kHeader;
  g_live.fetch_sub(int64_t(*static_cast<size_t*>(p)), std::memory_order_relaxed);
  std::free(p);
}

}  // namespace

void* operator new(size_t n) { return counted_alloc(n); }
void* operator new[](size_t n) { return counted_alloc(n); }
void operator delete(void* p) noexcept { counted_free(p); }
void operator delete[](void* p) noexcept { counted_free(p); }
void operator delete(void* p, size_t) noexcept { counted_free(p); }
void operator delete[](void* p, size_t) noexcept { counted_free(p); }

using namespace larap;

namespace {

struct Measured {
  int64_t bound = 0;  // the smallest limit accepted
  int64_t peak = 0;   // live bytes over those before the call, at the most, under that limit
  int64_t voxels = 0;
  size_t cells = 0;
};

Measured measure(const PolygonMesh& m, double h, int k) {
  const std::vector<Eigen::Vector3i> tris = triangulate(m);
  const Grid g = voxelize(m, tris, {}, m.vertices.colwise().minCoeff().transpose(),
                          m.vertices.colwise().maxCoeff().transpose(), h, int64_t(1) << 34);
  const std::vector<int32_t> parts = mesh_parts(m);
  auto run = [&](int64_t limit) {
    return find_cell_pieces(g.origin, g.h, g.dims, g.marks, m.vertices, tris, parts, g.vertex_cells, k,
                            limit);
  };
  int64_t lo = 0, hi = int64_t(1) << 34;  // run(lo) throws, run(hi) does not
  EXPECT_THROW(run(lo), OutOfMemory);
  while (hi - lo > 1) {
    const int64_t mid = lo + (hi - lo) / 2;
    try {
      run(mid);
      hi = mid;
    } catch (const OutOfMemory&) {
      lo = mid;
    }
  }
  Measured r;
  r.bound = hi;
  // What is held up to the check (the surface patches, the candidates) is the grid's, and not in
  // the bound: the peak of a call that stops at the check is taken off.
  const int64_t before = g_live.load();
  g_peak.store(before);
  EXPECT_THROW(run(lo), OutOfMemory);
  const int64_t to_check = g_peak.load() - before;
  g_peak.store(before);
  const CellPieces pieces = run(hi);
  r.peak = g_peak.load() - before - to_check;
  r.voxels = pieces.voxels;
  r.cells = pieces.cells.size();
  return r;
}

void expect_bounded(const char* what, const Measured& r, int k) {
  const double k3 = double(k) * k * k;
  std::printf("%-40s k %2d: %5lld analysed cells, bound %8.2f MiB, peak %8.2f MiB (%.2f of the bound)\n",
              what, k, static_cast<long long>(r.voxels / int64_t(k3)), r.bound / 1048576.0,
              r.peak / 1048576.0, double(r.peak) / double(r.bound));
  EXPECT_GT(r.voxels, 0) << what;  // cells were analysed
  EXPECT_LE(r.peak, r.bound) << what;
}

// Two boxes, separate parts (no corner shared), resting on each other along z = `contact`: on a plane of cell
// faces (0.5 with cells of 0.125) the cells either side hold one part each; inside a row of cells, each cell
// of the row holds both, and the face voxels along the contact on its side faces are hit by both.
PolygonMesh boxes_in_contact(double contact) {
  return gen::concat(
      {gen::box({0, 0, 0}, {1, 1, contact}), gen::box({0.03, 0.03, contact}, {0.97, 0.97, 1})});
}

// One part: a comb of 6 tines 0.1 cell apart on a bar made of 6 boxes end to end, each tine's
// corners on its bar box's corners, so that every box is joined to the next by position.
PolygonMesh comb(double h) {
  PolygonMesh m;
  for (int t = 0; t < 6; ++t) {
    const double x = t * 0.25 * h;
    m = gen::concat(
        {m, gen::box({x, 0, 0}, {x + 0.25 * h, 0.1, 0.1}), gen::box({x, 0.1, 0}, {x + 0.15 * h, 1.0, 0.1})});
  }
  return m;
}

// Many separate thin slabs 0.05 apart, crossing cells at all positions.
PolygonMesh stacked_slabs(int n) {
  PolygonMesh m;
  for (int i = 0; i < n; ++i) m = gen::concat({m, gen::box({0, 0, 0.08 * i}, {0.9, 0.9, 0.08 * i + 0.03})});
  return m;
}

// Two boxes 0.02 apart in one cell (analysed), then, along the same row of cells along x, n boxes
// each inside a cell of its own (not analysed; the grid's cells start at the mesh's lowest corner
// less two cells of 0.25): the analysed cells' x rays cross 2 n faces, and the inside test's
// crossings outweigh the voxels.
PolygonMesh pair_before_a_row_of_boxes(int n) {
  PolygonMesh m = gen::concat({gen::box({0.04, 0.04, 0.04}, {0.11, 0.2, 0.2}), gen::box({0.13, 0.04, 0.04}, {0.2, 0.2, 0.2})});
  for (int i = 1; i <= n; ++i) m = gen::concat({m, gen::box({0.5 * i + 0.06, 0.06, 0.06}, {0.5 * i + 0.22, 0.2, 0.2})});
  return m;
}

}  // namespace

TEST(SplitMemory, ALongRowOfCellsStaysWithinTheBound) {
  // A row's crossings (the voxels' inside test, voxel_inside.h) are held at once, per worker
  // thread: here they are the most of the memory.
  for (int k : {8, 24})
    expect_bounded("a close pair, then 1000 boxes in its row", measure(pair_before_a_row_of_boxes(1000), 0.25, k), k);
}

TEST(SplitMemory, PartsTouchingStayWithinTheBound) {
  for (int k : {8, 24}) {
    expect_bounded("two boxes touching on a cell-face plane", measure(boxes_in_contact(0.5), 0.125, k), k);
    expect_bounded("two boxes touching inside a row of cells", measure(boxes_in_contact(0.54), 0.125, k), k);
  }
}

TEST(SplitMemory, ManyPartsInOneCellStayWithinTheBound) {
  for (int k : {8, 24}) expect_bounded("ten slabs 0.05 apart", measure(stacked_slabs(10), 0.25, k), k);
}

TEST(SplitMemory, OnePartStaysWithinTheBoundWithoutFaceTables) {
  // One part: no face tables, so the bound is the voxels and the scratch, and no more than twice
  // what is used.
  const int k = 24;
  const PolygonMesh m = comb(0.2);
  const std::vector<int32_t> parts = mesh_parts(m);
  ASSERT_TRUE(std::all_of(parts.begin(), parts.end(), [&](int32_t p) { return p == parts[0]; }));
  const Measured r = measure(m, 0.2, k);
  expect_bounded("comb, one part", r, k);
  EXPECT_LE(r.bound, 2 * r.peak);
}

TEST(SplitMemory, EveryThreadCountStaysWithinTheBound) {
  for (int threads : {1, 2, 8}) {
    set_num_threads(threads);
    expect_bounded("ten slabs, threads varied", measure(stacked_slabs(10), 0.25, 16), 16);
  }
  set_num_threads(0);
}
