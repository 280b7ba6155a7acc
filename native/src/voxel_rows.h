// A cell's k^3 voxels as bit rows (k <= 64), and 6-connected flood fills on them, for cell
// splitting (cell_pieces.h). Internal to the lattice builder.
//
// Row r = j + k l holds voxel vi = i + k (j + k l) = i + k r as bit i, so a row is the k voxels
// along x and its neighbours are rows r +- 1 (along y) and r +- k (along z). A flood grows a
// region through the open voxels one whole row at a time: within a row by an occluded fill (runs
// of open bits reached by the region), across rows by sweeping forward and backward until a pair
// of sweeps changes nothing. The result is the set of open voxels connected to the region,
// whatever the order, so it equals a voxel-by-voxel flood fill bit for bit; the cost is a few
// word operations per row and sweep instead of a stack push per voxel.
#pragma once
#include <algorithm>
#include <cstdint>
#include <vector>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

namespace larap {

// The open bits connected along the row to a bit of seed (seed's bits outside open stay out).
inline uint64_t fill_row(uint64_t seed, uint64_t open) {
  uint64_t up = seed & open, down = up, pu = open, pd = open;
  for (int s = 1; s < 64; s *= 2) {  // Kogge-Stone occluded fill, both ways
    up |= pu & (up << s);
    pu &= pu << s;
    down |= pd & (down >> s);
    pd &= pd >> s;
  }
  return up | down;
}

// The rows [first, last] that hold bits of a region (first > last: none).
struct RowSpan {
  int first, last;
};

// Grows region (k^2 rows, each within open's, its bits within rows `span`) to every open voxel
// 6-connected to it through open voxels; returns the rows that then hold its bits. A sweep covers
// the region's rows and k rows to either side (the rows it can reach next), so a small region
// costs about its own rows, not the cell's.
inline RowSpan flood_rows(int k, const uint64_t* open, uint64_t* region, RowSpan span) {
  const int rows = k * k;
  if (span.first > span.last) return span;
  auto grow = [&](int r) {  // whether row r changed
    if (!open[r]) return false;
    const int j = r % k;
    uint64_t from = region[r];
    if (j > 0) from |= region[r - 1];
    if (j + 1 < k) from |= region[r + 1];
    if (r >= k) from |= region[r - k];
    if (r + k < rows) from |= region[r + k];
    const uint64_t m = fill_row(from, open[r]);
    if (m == region[r]) return false;
    region[r] = m;
    span.first = std::min(span.first, r);
    span.last = std::max(span.last, r);
    return true;
  };
  for (bool changed = true; changed;) {
    changed = false;
    for (int r = std::max(0, span.first - k); r <= std::min(rows - 1, span.last + k); ++r) changed |= grow(r);
    for (int r = std::min(rows - 1, span.last + k); r >= std::max(0, span.first - k); --r) changed |= grow(r);
  }
  return span;
}

// The same, for a region anywhere in the cell.
inline RowSpan flood_rows(int k, const uint64_t* open, uint64_t* region) {
  RowSpan span{k * k, -1};
  for (int r = 0; r < k * k; ++r)
    if (region[r]) {
      span.first = std::min(span.first, r);
      span.last = r;
    }
  return flood_rows(k, open, region, span);
}

namespace voxel_rows_detail {

// The voxels' bits in voxel order (bit vi % 64 of word vi / 64) for which test(16 bytes) sets a
// byte to 0xff (the SSE2 form) or keep(byte) holds, then cut into rows of k.
template <class Keep, class Test>
void rows_by(const uint8_t* v, int k, Keep&& keep, Test&& test, uint64_t* rows) {
  const int64_t k3 = int64_t(k) * k * k;
  std::vector<uint64_t> flat(size_t((k3 + 63) / 64 + 1), 0);
  int64_t vi = 0;
#ifdef __SSE2__
  for (; vi + 16 <= k3; vi += 16) {
    const __m128i x = _mm_loadu_si128(reinterpret_cast<const __m128i*>(v + vi));
    flat[size_t(vi / 64)] |= uint64_t(uint32_t(_mm_movemask_epi8(test(x)))) << (vi % 64);
  }
#else
  (void)test;
#endif
  for (; vi < k3; ++vi) flat[size_t(vi / 64)] |= uint64_t(keep(v[vi]) ? 1 : 0) << (vi % 64);
  const uint64_t full = k == 64 ? ~uint64_t(0) : (uint64_t(1) << k) - 1;
  for (int r = 0; r < k * k; ++r) {
    const int64_t at = int64_t(r) * k;
    const int off = int(at % 64);
    const size_t w = size_t(at / 64);
    const uint64_t bits = off ? (flat[w] >> off) | (flat[w + 1] << (64 - off)) : flat[w];
    rows[r] = bits & full;
  }
}

}  // namespace voxel_rows_detail

// The rows of the voxels equal to value.
inline void rows_equal(const uint8_t* v, int k, uint8_t value, uint64_t* rows) {
  voxel_rows_detail::rows_by(
      v, k, [value](uint8_t x) { return x == value; },
#ifdef __SSE2__
      [value](__m128i x) { return _mm_cmpeq_epi8(x, _mm_set1_epi8(char(value))); },
#else
      nullptr,
#endif
      rows);
}

// The rows of the voxels below limit (limit >= 1).
inline void rows_below(const uint8_t* v, int k, uint8_t limit, uint64_t* rows) {
  voxel_rows_detail::rows_by(
      v, k, [limit](uint8_t x) { return x < limit; },
#ifdef __SSE2__
      [limit](__m128i x) { return _mm_cmpeq_epi8(_mm_min_epu8(x, _mm_set1_epi8(char(limit - 1))), x); },
#else
      nullptr,
#endif
      rows);
}

// Calls visit(vi) for every voxel whose bit is set in rows.
template <class Visit>
void for_each_bit(const uint64_t* rows, int k, Visit&& visit) {
  const int n = k * k;
  for (int r = 0; r < n; ++r)
    for (uint64_t m = rows[r]; m; m &= m - 1) visit(int64_t(r) * k + __builtin_ctzll(m));
}

// The voxels 6-adjacent to a voxel of rows, within the cell (rows' own voxels included).
inline void dilate_rows(int k, const uint64_t* rows, uint64_t* out) {
  const int n = k * k;
  const uint64_t full = k == 64 ? ~uint64_t(0) : (uint64_t(1) << k) - 1;
  for (int r = 0; r < n; ++r) {
    const int j = r % k;
    uint64_t m = rows[r] | (rows[r] << 1) | (rows[r] >> 1);
    if (j > 0) m |= rows[r - 1];
    if (j + 1 < k) m |= rows[r + 1];
    if (r >= k) m |= rows[r - k];
    if (r + k < n) m |= rows[r + k];
    out[r] = m & full;
  }
}

// Calls visit(piece, span) for each 6-connected piece of the voxels of `left` (k^2 rows, emptied),
// in the order of each piece's first voxel: the piece's bits are piece[span.first..span.last]
// (rows of k^2, zero elsewhere, cleared after the call). Each piece is grown and cleared over its
// own rows only, so that many small pieces cost about their size each, not the cell's.
template <class Visit>
void for_each_piece(int k, uint64_t* left, Visit&& visit) {
  const int rows = k * k;
  std::vector<uint64_t> piece(static_cast<size_t>(rows), 0);
  for (int r0 = 0; r0 < rows; ++r0)
    while (left[r0]) {  // the lowest bit of the first row left starts the next piece
      piece[size_t(r0)] = left[r0] & (~left[r0] + 1);
      const RowSpan span = flood_rows(k, left, piece.data(), RowSpan{r0, r0});
      visit(static_cast<const uint64_t*>(piece.data()), span);
      for (int r = span.first; r <= span.last; ++r) {  // no row before r0 has anything left
        left[r] &= ~piece[size_t(r)];
        piece[size_t(r)] = 0;
      }
    }
}

// Labels the 6-connected pieces of a cell's material (v[vi] < 2) in the order of each piece's
// first voxel: v[vi] = 3 + piece, at most 253 pieces (the rest merge into the last label, 255);
// size[p]: the material voxels of piece p. Returns the number of pieces found.
inline int32_t label_pieces(uint8_t* v, int k, std::vector<int32_t>& size) {
  std::vector<uint64_t> left(static_cast<size_t>(k) * k);
  rows_below(v, k, 2, left.data());
  int32_t np = 0;
  for_each_piece(k, left.data(), [&](const uint64_t* piece, RowSpan span) {
    const uint8_t label = uint8_t(3 + std::min(np, 252));
    ++np;
    if (size.size() < 253) size.push_back(0);
    int64_t n = 0;
    for (int r = span.first; r <= span.last; ++r) {
      const uint64_t m = piece[r];
      n += __builtin_popcountll(m);
      for (uint64_t bits = m; bits; bits &= bits - 1) v[int64_t(r) * k + __builtin_ctzll(bits)] = label;
    }
    size[label - 3] += int32_t(n);
  });
  return np;
}

}  // namespace larap
