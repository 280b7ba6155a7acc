// Disjoint sets (union-find with path halving) whose root is the smallest member: used to join
// lattice nodes into shared points (lattice.cpp) and mesh vertices into parts
// (mesh_parts.cpp).
#pragma once
#include <algorithm>
#include <cstdint>
#include <numeric>
#include <vector>

namespace larap {

struct DisjointSets {
  std::vector<int32_t> parent;
  explicit DisjointSets(int64_t n) : parent(size_t(n)) { std::iota(parent.begin(), parent.end(), 0); }
  int32_t find(int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void unite(int32_t a, int32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

}  // namespace larap
