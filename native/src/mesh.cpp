#include <larap/errors.h>
#include <larap/mesh.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>
#include <string>

#include "parallel.h"

namespace larap {

// Throws on the first bad vertex, else the first bad face (in index order), serially: called only
// once the parallel checks below have found one.
static void report_first_problem(const PolygonMesh& mesh) {
  const int64_t n = mesh.num_vertices();
  for (int64_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c)
      if (!std::isfinite(mesh.vertices(i, c)))
        throw InvalidInput("vertices[" + std::to_string(i) + "] has a non-finite coordinate (" +
                           number_text(mesh.vertices(i, c)) + ")");
  const int64_t m = mesh.num_faces();
  for (int64_t f = 0; f < m; ++f) {
    const int64_t b = mesh.face_offsets[f], e = mesh.face_offsets[f + 1];
    if (e < b || e > static_cast<int64_t>(mesh.face_indices.size()))
      throw InvalidInput("face " + std::to_string(f) + " has invalid offsets");
    if (e == b) throw InvalidInput("face " + std::to_string(f) + " has no vertices");
    for (int64_t k = b; k < e; ++k) {
      const int64_t v = mesh.face_indices[k];
      if (v < 0 || v >= n)
        throw InvalidInput("face " + std::to_string(f) + " refers to vertex " + std::to_string(v) +
                           ", out of range for " + std::to_string(n) + " vertices");
    }
  }
  throw std::logic_error("validate_mesh: the parallel check found a problem that the serial one did not");
}

void validate_mesh(const PolygonMesh& mesh) {
  const int64_t n = mesh.num_vertices();
  if (n == 0) throw InvalidInput("the mesh has no vertices");
  std::atomic<bool> bad{false};
  const auto check_vertex = [&](int64_t i) {
    const auto row = mesh.vertices.row(i);
    if (!(std::isfinite(row(0)) && std::isfinite(row(1)) && std::isfinite(row(2))))
      bad.store(true, std::memory_order_relaxed);
  };
  parallel_for(n, check_vertex, 65536);
  if (bad.load()) report_first_problem(mesh);
  if (mesh.face_offsets.empty() || mesh.face_offsets.front() != 0)
    throw InvalidInput("face offsets must start at 0");
  const int64_t ni = static_cast<int64_t>(mesh.face_indices.size());
  const auto check_face = [&](int64_t f) {
    const int64_t b = mesh.face_offsets[f], e = mesh.face_offsets[f + 1];
    if (b < 0 || e <= b || e > ni) {  // (b < 0 only after a bad face: the report names that one)
      bad.store(true, std::memory_order_relaxed);
      return;
    }
    for (int64_t k = b; k < e; ++k)
      if (mesh.face_indices[k] < 0 || mesh.face_indices[k] >= n) bad.store(true, std::memory_order_relaxed);
  };
  parallel_for(mesh.num_faces(), check_face, 65536);
  if (bad.load()) report_first_problem(mesh);
}

// Faces in chunks, in parallel: each chunk's output counted, then written at its offset, so the
// order is the faces' (as a serial loop would give).
template <class T, class Emit>
static std::vector<T> per_face(const PolygonMesh& mesh, const Emit& emit) {
  constexpr int64_t kChunk = 65536;
  const int64_t m = mesh.num_faces(), nchunks = (m + kChunk - 1) / kChunk;
  std::vector<int64_t> start(static_cast<size_t>(nchunks) + 1, 0);
  const auto count = [&](int64_t c) {
    int64_t n = 0;
    for (int64_t f = c * kChunk; f < std::min(m, (c + 1) * kChunk); ++f) emit(f, [&](const T&) { ++n; });
    start[size_t(c) + 1] = n;
  };
  parallel_for(nchunks, count, 1);
  for (int64_t c = 0; c < nchunks; ++c) start[size_t(c) + 1] += start[size_t(c)];
  std::vector<T> out(static_cast<size_t>(start.back()));
  const auto fill = [&](int64_t c) {
    int64_t at = start[size_t(c)];
    for (int64_t f = c * kChunk; f < std::min(m, (c + 1) * kChunk); ++f)
      emit(f, [&](const T& x) { out[size_t(at++)] = x; });
  };
  parallel_for(nchunks, fill, 1);
  return out;
}

std::vector<Eigen::Vector3i> triangulate(const PolygonMesh& mesh) {
  return per_face<Eigen::Vector3i>(mesh, [&](int64_t f, const auto& put) {
    const int64_t b = mesh.face_offsets[f], e = mesh.face_offsets[f + 1];
    for (int64_t k = b + 1; k + 1 < e; ++k) {
      const int a = static_cast<int>(mesh.face_indices[b]);
      const int u = static_cast<int>(mesh.face_indices[k]);
      const int w = static_cast<int>(mesh.face_indices[k + 1]);
      if (a == u || u == w || a == w) continue;
      put(Eigen::Vector3i(a, u, w));
    }
  });
}

std::vector<Eigen::Vector2i> segments(const PolygonMesh& mesh) {
  return per_face<Eigen::Vector2i>(mesh, [&](int64_t f, const auto& put) {
    const int64_t b = mesh.face_offsets[f], e = mesh.face_offsets[f + 1];
    const int64_t a = mesh.face_indices[b];
    int64_t other = -1;
    bool two = true;
    for (int64_t k = b + 1; k < e && two; ++k) {
      const int64_t v = mesh.face_indices[k];
      if (v == a || v == other) continue;
      if (other < 0)
        other = v;
      else
        two = false;  // a third distinct vertex: a polygon (triangulate's), not an edge
    }
    if (two && other >= 0) put(Eigen::Vector2i(int(std::min(a, other)), int(std::max(a, other))));
  });
}

}  // namespace larap
