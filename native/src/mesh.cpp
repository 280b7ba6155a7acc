#include <larap/errors.h>
#include <larap/mesh.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace larap {

void validate_mesh(const PolygonMesh& mesh) {
  const int64_t n = mesh.num_vertices();
  if (n == 0) throw InvalidInput("the mesh has no vertices");
  for (int64_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c)
      if (!std::isfinite(mesh.vertices(i, c)))
        throw InvalidInput("vertices[" + std::to_string(i) + "] has a non-finite coordinate (" +
                           number_text(mesh.vertices(i, c)) + ")");
  if (mesh.face_offsets.empty() || mesh.face_offsets.front() != 0)
    throw InvalidInput("face offsets must start at 0");
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
}

std::vector<Eigen::Vector3i> triangulate(const PolygonMesh& mesh) {
  std::vector<Eigen::Vector3i> tris;
  tris.reserve(static_cast<size_t>(mesh.face_indices.size()));
  const int64_t m = mesh.num_faces();
  for (int64_t f = 0; f < m; ++f) {
    const int64_t b = mesh.face_offsets[f], e = mesh.face_offsets[f + 1];
    for (int64_t k = b + 1; k + 1 < e; ++k) {
      const int a = static_cast<int>(mesh.face_indices[b]);
      const int u = static_cast<int>(mesh.face_indices[k]);
      const int w = static_cast<int>(mesh.face_indices[k + 1]);
      if (a == u || u == w || a == w) continue;
      tris.emplace_back(a, u, w);
    }
  }
  return tris;
}

std::vector<Eigen::Vector2i> segments(const PolygonMesh& mesh) {
  std::vector<Eigen::Vector2i> segs;
  const int64_t m = mesh.num_faces();
  for (int64_t f = 0; f < m; ++f) {
    const int64_t b = mesh.face_offsets[f], e = mesh.face_offsets[f + 1];
    const int64_t a = mesh.face_indices[b];
    int64_t other = -1;
    bool two = true;
    for (int64_t k = b + 1; k < e && two; ++k) {
      const int64_t v = mesh.face_indices[k];
      if (v == a || v == other) continue;
      if (other < 0) other = v;
      else two = false;  // a third distinct vertex: a polygon (triangulate's), not an edge
    }
    if (two && other >= 0) segs.emplace_back(int(std::min(a, other)), int(std::max(a, other)));
  }
  return segs;
}

}  // namespace larap
