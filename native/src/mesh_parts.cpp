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

// Every element's root, in one ascending pass: links go from a larger root to a smaller one and
// path halving only points an element further up, so an element's parent is never larger than
// itself and is settled before it. (Walking each element's chain instead costs the square of a
// chain's length, and a polyline whose edges are listed backwards makes one chain of them all.)
std::vector<int32_t> roots(const ConcurrentSets& sets) {
  std::vector<int32_t> root(sets.parent.size());
  for (size_t v = 0; v < root.size(); ++v) {
    const int32_t p = sets.parent[v];
    root[v] = p == int32_t(v) ? p : root[size_t(p)];
  }
  return root;
}

}  // namespace

std::vector<int32_t> mesh_parts(const PolygonMesh& mesh) {
  const int64_t nv = mesh.num_vertices();
  ConcurrentSets sets(nv);  // the faces in parallel; the roots do not depend on the order
  const auto join_face = [&](int64_t f) {
    for (int64_t k = mesh.face_offsets[f] + 1; k < mesh.face_offsets[f + 1]; ++k)
      sets.unite(int32_t(mesh.face_indices[mesh.face_offsets[f]]), int32_t(mesh.face_indices[k]));
  };
  parallel_for(mesh.num_faces(), join_face, 8192);
  // Vertices at one position. Only positions of vertices outside the largest component are
  // hashed (a character's body is not, so a mesh of one part costs one pass); the largest
  // component's vertices are looked up.
  std::vector<int32_t> root = roots(sets), size(static_cast<size_t>(nv), 0);
  for (int64_t v = 0; v < nv; ++v) ++size[root[v]];
  int32_t largest = 0;
  for (int64_t v = 0; v < nv; ++v)
    if (size[v] > size[largest]) largest = int32_t(v);
  if (nv == 0 || size[largest] == nv) return root;  // one part
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
  return roots(sets);
}

}  // namespace larap
