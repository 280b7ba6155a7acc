// Which voxels of the analysed cells lie inside the mesh, by ray parity, so that air entering a
// solid through a hole in its surface (a missing face, an eye socket, an open bottom) does not
// empty the solid's cells and split them into sheets (cell_pieces.h).
//
// From each voxel's centre, six rays (+ and - along each axis) count the crossings with each
// part's triangles; a direction votes when it crosses some part an odd number of times. A voxel is
// inside when at least 5 of the 6 directions vote. A hole lets at most one of the six rays out of
// a solid (a voxel under a missing face: 5 votes), while the gap between a body and an open sleeve
// around it is crossed an odd number of times only along the four radial directions (4 votes), so
// the sleeve stays apart. Parities are per part, so an eye inside a head is inside both (each
// crossed once on every side), where one parity over the whole mesh (twice: even) would call it
// outside. A direction's parts are summed as the XOR of a 64-bit hash per part: it is zero when
// every part is crossed an even number of times, and not zero when one or two parts are odd; with
// three or more odd parts it could be zero by chance (about 2^-64).
//
// The voxels' rays run the length of the grid, and every cell of a row of cells along an axis
// shares the same k^2 of them: RowRays finds a row's crossings once (sorted along each ray, with
// their running XOR), and each analysed cell of the row reads its voxels' votes by binary search.
//
// Rays pass through the voxel centres moved by a millionth of a voxel, so that grid-aligned meshes
// rarely put a vertex or edge on one; coincident crossings of one part facing the same way (a ray
// through a shared edge, a duplicated face) count once, while two facing opposite ways (the wall
// between two boxes joined face to face, one part by position) count twice: an exit and an entry.
#pragma once
#include <larap/mesh.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace larap {

// The fewest votes that make a voxel inside.
constexpr int kInsideVotes = 5;

class RowRays {
 public:
  // The k^2 rays along axis a of the row of cells whose first cell (index 0 along a) has its
  // lowest corner at `origin`, voxels of size hv: ray jb + k jc passes through the centres of the
  // voxels (jb, jc) across the row (b = a + 1, c = a + 2, mod 3).
  RowRays(int a, const Eigen::Vector3d& origin, double hv, int k) : a_(a), k_(k), hv_(hv), origin_(origin) {}

  // Finds the rays' crossings with the triangles ids[0, n) (repeats allowed): every triangle that
  // overlaps a cell of the row. Replaces the crossings found before. `most`: max_crossings() of
  // exactly these ids when the caller has it already (negative: counted here); the reservation
  // is what the memory check charges, so a smaller count would let the crossings grow past it
  // (asserted in debug builds; the tests check max_crossings against what is found).
  void cross(const int32_t* ids, size_t n, const RowMatrixX3d& V, const std::vector<Eigen::Vector3i>& tris,
             const std::vector<int32_t>& vertex_part, int64_t most = -1);

  // The most crossings cross() can find among ids[0, n): the rays in each triangle's shadow
  // (what it holds per crossing, 32 bytes, and 8 (k^2 + 1) bytes per row are the memory it
  // needs).
  int64_t max_crossings(const int32_t* ids, size_t n, const RowMatrixX3d& V,
                        const std::vector<Eigen::Vector3i>& tris) const;
  static constexpr int kBytesPerCrossing = 32;
  // The crossings cross() found, before those of one part at one point were merged: at most
  // max_crossings(), which the memory this needs is counted from.
  size_t crossings_found() const { return found_; }

  // Calls visit(vi, votes) for the voxels of the row's cell `cell` (its index along a; voxel
  // vi = i + k (j + k l) of the cell) that this axis's two directions vote for (votes 1 or 2).
  template <class F>
  void votes(int cell, F&& visit) const;

 private:
  struct Hit {
    double at;   // along a, in voxels from origin
    uint64_t x;  // the XOR of the part hashes of this ray's crossings up to this one, inclusive
  };
  struct Crossing {
    int32_t ray_facing;  // 2 ray + which way the triangle faces along the ray (0 or 1)
    int32_t part;
    double at;
  };
  int a_, k_;
  double hv_;
  Eigen::Vector3d origin_;
  std::vector<Crossing> xs_;
  std::vector<Hit> hits_;           // per ray, ascending along it
  std::vector<int32_t> ray_start_;  // k^2 + 1 offsets into hits_
  std::vector<int32_t> fill_;       // k^2: scratch of cross()
  size_t found_ = 0;
};

template <class F>
void RowRays::votes(int cell, F&& visit) const {
  if (hits_.empty()) return;
  const int k = k_, b = (a_ + 1) % 3, c = (a_ + 2) % 3;
  const double first = double(cell) * k + 0.5;  // the first voxel centre along the ray
  int64_t stride[3] = {1, k, int64_t(k) * k};
  for (int jc = 0; jc < k; ++jc)
    for (int jb = 0; jb < k; ++jb) {
      const int r = jb + k * jc;
      const Hit* h0 = hits_.data() + ray_start_[size_t(r)];
      const Hit* h1 = hits_.data() + ray_start_[size_t(r) + 1];
      if (h0 == h1) continue;
      const uint64_t total = (h1 - 1)->x;
      const Hit* next = std::lower_bound(h0, h1, first, [](const Hit& h, double at) { return h.at < at; });
      uint64_t below = next > h0 ? (next - 1)->x : 0;
      const int64_t base = jb * stride[b] + jc * stride[c];
      // Runs of voxels between crossings: voxel ia is past a crossing at `at` when its centre
      // first + ia is beyond it, from ia = floor(at - first) + 1 on.
      for (int ia = 0; ia < k;) {
        int end = k;
        if (next < h1) {
          const double e = std::floor(next->at - first) + 1;
          end = e < k ? int(e) : k;
        }
        const int n = (below != 0) + ((below ^ total) != 0);
        if (n && a_ == 0)  // voxels next to one another: a loop the compiler can widen
          for (; ia < end; ++ia) visit(base + ia, n);
        else if (n)
          for (; ia < end; ++ia) visit(base + ia * stride[a_], n);
        else
          ia = std::max(ia, end);
        if (next == h1) break;
        below = next->x;
        ++next;
      }
    }
}

}  // namespace larap
