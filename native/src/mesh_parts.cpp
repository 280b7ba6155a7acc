#include "mesh_parts.h"

#include <array>
#include <cstring>
#include <unordered_map>

#include "disjoint_sets.h"
#include "parallel.h"

namespace larap {
namespace {

using Position = std::array<double, 3>;

struct PositionHash {
  size_t operator()(const Position& p) const {
    uint64_t h = 0x9E3779B97F4A7C15ull;
    for (double x : p) {
      uint64_t bits;
      std::memcpy(&bits, &x, sizeof bits);
      h ^= bits + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
    }
    return size_t(h);
  }
};

Position position(const RowMatrixX3d& V, int64_t v) {
  return {V(v, 0) + 0.0, V(v, 1) + 0.0, V(v, 2) + 0.0};  // + 0.0: -0.0 and 0.0 are one position
}

}  // namespace

std::vector<int32_t> mesh_parts(const PolygonMesh& mesh) {
  const int64_t nv = mesh.num_vertices();
  ConcurrentSets sets(nv);  // the faces in parallel; the roots do not depend on the order
  parallel_for(
      mesh.num_faces(),
      [&](int64_t f) {
        for (int64_t k = mesh.face_offsets[f] + 1; k < mesh.face_offsets[f + 1]; ++k)
          sets.unite(int32_t(mesh.face_indices[mesh.face_offsets[f]]), int32_t(mesh.face_indices[k]));
      },
      8192);
  // Vertices at one position. Only positions of vertices outside the largest component are
  // hashed (a character's body is not, so a mesh of one part costs one pass); the largest
  // component's vertices are looked up.
  std::vector<int32_t> root(static_cast<size_t>(nv)), size(static_cast<size_t>(nv), 0);
  parallel_for(
      nv, [&](int64_t v) { root[v] = sets.root_of(int32_t(v)); }, 8192);
  for (int64_t v = 0; v < nv; ++v) ++size[root[v]];
  int32_t largest = 0;
  for (int64_t v = 0; v < nv; ++v)
    if (size[v] > size[largest]) largest = int32_t(v);
  if (nv > 0 && size[largest] < nv) {
    std::unordered_map<Position, int32_t, PositionHash> first;
    first.reserve(size_t(nv - size[largest]));
    for (int64_t v = 0; v < nv; ++v) {
      if (root[v] == largest) continue;
      const auto [it, fresh] = first.emplace(position(mesh.vertices, v), int32_t(v));
      if (!fresh) sets.unite(it->second, int32_t(v));
    }
    for (int64_t v = 0; v < nv; ++v) {
      if (root[v] != largest) continue;
      const auto it = first.find(position(mesh.vertices, v));
      if (it != first.end()) sets.unite(it->second, int32_t(v));
    }
  }
  if (nv > 0 && size[largest] == nv) return root;
  std::vector<int32_t> part(static_cast<size_t>(nv));
  parallel_for(
      nv, [&](int64_t v) { part[v] = sets.root_of(int32_t(v)); }, 8192);
  return part;
}

}  // namespace larap
