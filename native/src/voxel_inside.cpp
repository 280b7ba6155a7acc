#include "voxel_inside.h"

#include <cmath>
#include <cassert>
#include <limits>

#include "geometry.h"

namespace larap {
namespace {

constexpr double kSame = 1e-7;  // crossings of one part closer than this (voxels) along a ray are one

// A part's hash: never zero, distinct for distinct parts (splitmix64 is a bijection).
uint64_t part_hash(int32_t part) {
  uint64_t z = uint64_t(int64_t(part)) + 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return z ? z : 1;
}

}  // namespace

int64_t RowRays::max_crossings(const int32_t* ids, size_t n, const RowMatrixX3d& V,
                               const std::vector<Eigen::Vector3i>& tris) const {
  int64_t total = 0;
  for (size_t q = 0; q < n; ++q) {
    const Eigen::Vector3i& t = tris[size_t(ids[q])];
    Eigen::Vector3d p[3];
    for (int i = 0; i < 3; ++i) p[i] = (V.row(t[i]).transpose() - origin_) / hv_;
    int jb0, jb1, jc0, jc1;
    if (geometry::seen_area(p, a_) == 0.0 || !geometry::rays_in_box(p, a_, k_, k_, jb0, jb1, jc0, jc1))
      continue;
    // Scanlines: the rays of each line jc that the triangle's shadow covers, widened by a
    // billionth of a voxel so that what axis_line_crossing takes on an edge is counted.
    const int b = (a_ + 1) % 3, c = (a_ + 2) % 3;
    for (int jc = jc0; jc <= jc1; ++jc) {
      const double qc = jc + geometry::kRayC;
      double lo = std::numeric_limits<double>::infinity(), hi = -lo;
      for (int e = 0; e < 3; ++e) {
        const Eigen::Vector3d& u = p[e];
        const Eigen::Vector3d& v = p[(e + 1) % 3];
        if ((u[c] - qc) * (v[c] - qc) > 0) continue;
        const double at = u[c] == v[c] ? u[b] : u[b] + (qc - u[c]) * (v[b] - u[b]) / (v[c] - u[c]);
        lo = std::min({lo, at, u[c] == v[c] ? v[b] : at});
        hi = std::max({hi, at, u[c] == v[c] ? v[b] : at});
      }
      const int j0 = std::max(jb0, int(std::ceil(lo - geometry::kRayB - 1e-9)));
      const int j1 = std::min(jb1, int(std::floor(hi - geometry::kRayB + 1e-9)));
      if (j1 >= j0) total += j1 - j0 + 1;
    }
  }
  return total;
}

void RowRays::cross(const int32_t* ids, size_t n, const RowMatrixX3d& V,
                    const std::vector<Eigen::Vector3i>& tris, const std::vector<int32_t>& vertex_part,
                    int64_t most) {
  static_assert(sizeof(Crossing) + sizeof(Hit) <= kBytesPerCrossing, "what the memory check counts");
  const int a = a_, k = k_;
  xs_.clear();
  // No growth past what the memory check counts.
  xs_.reserve(size_t(most >= 0 ? most : max_crossings(ids, n, V, tris)));
  for (size_t q = 0; q < n; ++q) {
    const Eigen::Vector3i& t = tris[size_t(ids[q])];
    Eigen::Vector3d p[3];  // in voxels from the row's origin
    for (int i = 0; i < 3; ++i) p[i] = (V.row(t[i]).transpose() - origin_) / hv_;
    const double area = geometry::seen_area(p, a);
    if (area == 0.0) continue;  // parallel to the rays
    int jb0, jb1, jc0, jc1;
    if (!geometry::rays_in_box(p, a, k, k, jb0, jb1, jc0, jc1)) continue;
    const int32_t part = vertex_part[size_t(t[0])];
    const int32_t facing = area > 0;
    for (int jc = jc0; jc <= jc1; ++jc)
      for (int jb = jb0; jb <= jb1; ++jb) {
        double at;
        if (geometry::axis_line_crossing(p, a, jb + geometry::kRayB, jc + geometry::kRayC, at))
          xs_.push_back({2 * (jb + k * jc) + facing, part, at});
      }
  }
  found_ = xs_.size();
  assert(most < 0 || int64_t(found_) <= most);  // tests: VoxelInside's found <= max_crossings
  // Bucketed by ray (the part and facing in x for now), then each ray's crossings by part, facing
  // and place: one crossing per part and facing where a ray meets several of its triangles at one
  // point (a shared edge or vertex, a duplicated face; the same triangle listed twice gives the same
  // point too); then ascending along the ray, with the running XOR of the parts' hashes.
  const size_t nr = size_t(k) * k;
  ray_start_.assign(nr + 1, 0);
  for (const Crossing& x : xs_) ++ray_start_[size_t(x.ray_facing >> 1) + 1];
  for (size_t r = 0; r < nr; ++r) ray_start_[r + 1] += ray_start_[r];
  fill_.assign(ray_start_.begin(), ray_start_.end() - 1);
  hits_.resize(xs_.size());
  for (const Crossing& x : xs_)
    hits_[size_t(fill_[size_t(x.ray_facing >> 1)]++)] = {
        x.at, uint64_t(uint32_t(x.part)) << 1 | uint64_t(x.ray_facing & 1)};
  int32_t kept = 0;
  for (size_t r = 0; r < nr; ++r) {
    Hit* h0 = hits_.data() + ray_start_[r];
    Hit* h1 = hits_.data() + ray_start_[r + 1];
    ray_start_[r] = kept;
    std::sort(h0, h1, [](const Hit& x, const Hit& y) { return x.x != y.x ? x.x < y.x : x.at < y.at; });
    Hit* out = hits_.data() + kept;
    Hit* const first = out;
    for (Hit* h = h0; h < h1; ++h)
      if (out == first || h->x != (out - 1)->x || h->at - (out - 1)->at >= kSame) *out++ = *h;
    for (Hit* h = first; h < out; ++h) h->x = part_hash(int32_t(uint32_t(h->x >> 1)));
    std::sort(first, out, [](const Hit& x, const Hit& y) { return x.at < y.at; });
    for (Hit* h = first + 1; h < out; ++h) h->x ^= (h - 1)->x;
    kept = int32_t(out - hits_.data());
  }
  ray_start_[nr] = kept;
  hits_.resize(size_t(kept));
  xs_.clear();
}

}  // namespace larap
