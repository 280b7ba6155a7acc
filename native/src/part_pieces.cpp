#include "part_pieces.h"

#include "disjoint_sets.h"
#include "voxel_rows.h"

namespace larap {
namespace {

// Calls visit(vi, c) for every voxel of a k^3 grid, c its coordinates (vi = c0 + k (c1 + k c2)),
// without divisions.
template <class F>
void for_each_voxel(int k, F&& visit) {
  int64_t vi = 0;
  for (int l = 0; l < k; ++l)
    for (int j = 0; j < k; ++j)
      for (int i = 0; i < k; ++i, ++vi) {
        const int c[3] = {i, j, l};
        visit(vi, c);
      }
}

// The neighbour of voxel vi (coordinates c) one step along +axis, or -1 outside the cell.
inline int64_t next_along(int64_t vi, const int* c, int axis, int k) {
  const int64_t step = axis == 0 ? 1 : axis == 1 ? k : int64_t(k) * k;
  return c[axis] + 1 < k ? vi + step : -1;
}

}  // namespace

PartSets part_sets(const uint8_t* v, int k, const Eigen::Vector3d& corner, double hv, const RowMatrixX3d& V,
                   const std::vector<Eigen::Vector3i>& tris, const int32_t* ids, int32_t q0, int32_t q1,
                   const std::vector<int32_t>& vertex_part, int max_mask_parts) {
  const int64_t k3 = int64_t(k) * k * k;
  PartSets sets;
  for (int32_t q = q0; q < q1; ++q) sets.parts.push_back(vertex_part[tris[ids[q]][0]]);
  std::sort(sets.parts.begin(), sets.parts.end());
  sets.parts.erase(std::unique(sets.parts.begin(), sets.parts.end()), sets.parts.end());
  auto rasterise = [&](auto&& skip, auto&& hit) {  // skip(vi, part, i), hit(vi, part, i): i = part's index
    for (int32_t q = q0; q < q1; ++q) {
      const Eigen::Vector3i& t = tris[ids[q]];
      const int32_t part = vertex_part[t[0]];
      const int32_t i =
          int32_t(std::lower_bound(sets.parts.begin(), sets.parts.end(), part) - sets.parts.begin());
      for_each_voxel_hit(
          corner, hv, k, V.row(t[0]).transpose(), V.row(t[1]).transpose(), V.row(t[2]).transpose(), kContact,
          [&](int64_t vi) { return skip(vi, part, i); }, [&](int64_t vi) { hit(vi, part, i); });
    }
  };
  if (int64_t(sets.parts.size()) <= std::min(max_mask_parts, kMaskParts)) {
    sets.masks.assign(size_t(k3), 0);
    uint64_t* m = sets.masks.data();
    rasterise([&](int64_t vi, int32_t, int32_t i) { return v[vi] != 1 || ((m[vi] >> i) & 1u); },
              [&](int64_t vi, int32_t, int32_t i) { m[vi] |= uint64_t(1) << i; });
    return sets;
  }
  std::vector<std::pair<int32_t, int32_t>> hits;  // (voxel, part)
  std::vector<int32_t> last(static_cast<size_t>(k3), -1);  // the part last found there (saves tests)
  rasterise([&](int64_t vi, int32_t part, int32_t) { return v[vi] != 1 || last[vi] == part; },
            [&](int64_t vi, int32_t part, int32_t) {
              last[vi] = part;
              hits.emplace_back(int32_t(vi), part);
            });
  std::sort(hits.begin(), hits.end());
  hits.erase(std::unique(hits.begin(), hits.end()), hits.end());
  sets.offsets.assign(size_t(k3 + 1), 0);
  for (const auto& hp : hits) ++sets.offsets[hp.first + 1];
  for (int64_t vi = 0; vi < k3; ++vi) sets.offsets[vi + 1] += sets.offsets[vi];
  sets.lists.resize(hits.size());
  for (size_t i = 0; i < hits.size(); ++i) sets.lists[i] = hits[i].second;  // sorted by voxel, then part
  return sets;
}

namespace {

// Writes the labels of the pieces (3 + piece, in the order of each piece's first voxel, at most
// 253 pieces) into v from the class of each material voxel, root(vi) in [0, roots): two voxels of
// a piece have one root, of two pieces two.
template <class Root>
int32_t write_labels(uint8_t* v, int64_t k3, int64_t roots, Root&& root, std::vector<int32_t>& size) {
  int32_t np = 0;
  std::vector<uint8_t> label_of(static_cast<size_t>(roots), 0);  // 0: not met yet
  for (int64_t vi = 0; vi < k3; ++vi) {
    if (v[vi] == 2) continue;
    uint8_t& label = label_of[size_t(root(vi))];
    if (!label) {  // more than 253 pieces: the rest merge
      label = uint8_t(3 + std::min(np, 252));
      ++np;
      if (size.size() < 253) size.push_back(0);
    }
    v[vi] = label;
    ++size[label - 3];
  }
  return np;
}

// With masks: the pieces of the enclosed voxels, and of each part's surface voxels, by bit-row
// floods; a class per such piece, joined where a voxel is in two (a surface voxel of two parts)
// and where an enclosed voxel touches a surface voxel. A surface voxel of no part (the grown
// rasterisation missing a voxel that the plain one hit) is a class of its own, joined to the
// enclosed voxels it touches only, as the rule says.
int32_t pieces_by_mask(uint8_t* v, int k, const PartSets& sets, std::vector<int32_t>& size) {
  const int rows = k * k;
  const int64_t k3 = int64_t(rows) * k;
  std::vector<int32_t> cls(static_cast<size_t>(k3), -1);
  DisjointSets classes(0);
  auto add_pieces = [&](uint64_t* left) {  // a class per piece of left (emptied)
    for_each_piece(k, left, [&](const uint64_t* piece, RowSpan span) {
      const int32_t c = classes.add();
      for (int r = span.first; r <= span.last; ++r)
        for (uint64_t m = piece[r]; m; m &= m - 1) {
          int32_t& x = cls[size_t(int64_t(r) * k + __builtin_ctzll(m))];
          if (x < 0)
            x = c;
          else
            classes.unite(x, c);
        }
    });
  };
  std::vector<uint64_t> enclosed(static_cast<size_t>(rows)), surface(static_cast<size_t>(rows)),
      left(static_cast<size_t>(rows));
  rows_equal(v, k, 0, enclosed.data());
  rows_equal(v, k, 1, surface.data());
  left = enclosed;
  add_pieces(left.data());
  const int np = int(sets.parts.size());
  std::vector<uint64_t> by_part(static_cast<size_t>(np) * rows, 0);
  for (int r = 0; r < rows; ++r)
    for (uint64_t m = surface[size_t(r)]; m; m &= m - 1) {
      const int i = __builtin_ctzll(m);
      const int64_t vi = int64_t(r) * k + i;
      const uint64_t parts = sets.masks[size_t(vi)];
      if (!parts) cls[size_t(vi)] = classes.add();
      for (uint64_t q = parts; q; q &= q - 1)
        by_part[size_t(__builtin_ctzll(q)) * rows + r] |= uint64_t(1) << i;
    }
  for (int p = 0; p < np; ++p) add_pieces(by_part.data() + size_t(p) * rows);
  // Enclosed voxels beside surface voxels, along each axis both ways.
  const uint64_t full = k == 64 ? ~uint64_t(0) : (uint64_t(1) << k) - 1;
  for (int r = 0; r < rows; ++r) {
    const uint64_t e = enclosed[size_t(r)];
    if (!e) continue;
    const int j = r % k;
    auto join = [&](uint64_t m, int64_t step) {  // enclosed voxel vi with a surface voxel at vi + step
      for (; m; m &= m - 1) {
        const int64_t vi = int64_t(r) * k + __builtin_ctzll(m);
        classes.unite(cls[size_t(vi)], cls[size_t(vi + step)]);
      }
    };
    join(e & (surface[size_t(r)] >> 1), 1);
    join(e & ((surface[size_t(r)] << 1) & full), -1);
    if (j > 0) join(e & surface[size_t(r - 1)], -int64_t(k));
    if (j + 1 < k) join(e & surface[size_t(r + 1)], k);
    if (r >= k) join(e & surface[size_t(r - k)], -int64_t(rows));
    if (r + k < rows) join(e & surface[size_t(r + k)], rows);
  }
  return write_labels(
      v, k3, int64_t(classes.parent.size()), [&](int64_t vi) { return classes.find(cls[size_t(vi)]); }, size);
}

}  // namespace

int32_t pieces_by_part(uint8_t* v, int k, const PartSets& sets, std::vector<int32_t>& size) {
  if (!sets.masks.empty()) return pieces_by_mask(v, k, sets, size);
  const int64_t k3 = int64_t(k) * k * k;
  DisjointSets pieces(k3);  // the root of a piece is its smallest voxel
  for_each_voxel(k, [&](int64_t vi, const int* c) {
    if (v[vi] == 2) return;
    for (int axis = 0; axis < 3; ++axis) {
      const int64_t ni = next_along(vi, c, axis, k);
      if (ni < 0 || v[ni] == 2) continue;
      if (v[vi] == 0 || v[ni] == 0 || sets.meet(vi, ni)) pieces.unite(int32_t(vi), int32_t(ni));
    }
  });
  return write_labels(
      v, k3, k3, [&](int64_t vi) { return pieces.find(int32_t(vi)); }, size);
}

}  // namespace larap
