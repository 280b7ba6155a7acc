// Disjoint sets (union-find with path halving) whose root is the smallest member: DisjointSets
// joins lattice nodes into shared points (lattice.cpp) and voxels into a cell's pieces
// (part_pieces.cpp); ConcurrentSets is the same for several threads at once, joining mesh vertices
// into parts (mesh_parts.cpp) and into a cell's surface patches (surface_patches.cpp). A class's
// root does not depend on the order of the unions, so neither does the result. Links go from a
// larger root to a smaller one, so every element's parent is at most itself.
#pragma once
#include <algorithm>
#include <cstdint>
#include <numeric>
#include <vector>

namespace larap {

struct DisjointSets {
  std::vector<int32_t> parent;
  explicit DisjointSets(int64_t n) : parent(size_t(n)) { std::iota(parent.begin(), parent.end(), 0); }
  // A new member in a class of its own; returns it.
  int32_t add() {
    parent.push_back(int32_t(parent.size()));
    return parent.back();
  }
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

// Union-find shared by the threads: a class's root is its smallest member (links go from the
// larger root to the smaller, by compare-and-swap; path halving only points an element further up).
struct ConcurrentSets {
  std::vector<int32_t> parent;
  explicit ConcurrentSets(int64_t n) : parent(size_t(n)) { std::iota(parent.begin(), parent.end(), 0); }
  int32_t find(int32_t x) {
    for (;;) {
      const int32_t px = __atomic_load_n(&parent[x], __ATOMIC_RELAXED);
      if (px == x) return x;
      const int32_t gx = __atomic_load_n(&parent[px], __ATOMIC_RELAXED);
      if (gx != px) __atomic_store_n(&parent[x], gx, __ATOMIC_RELAXED);
      x = gx;
    }
  }
  // The root, without path halving: for the pass that writes every vertex's root while other
  // threads read (a halving store could put a non-root ancestor back after that write).
  int32_t root_of(int32_t x) const {
    for (;;) {
      const int32_t px = __atomic_load_n(&parent[x], __ATOMIC_RELAXED);
      if (px == x) return x;
      x = px;
    }
  }
  void unite(int32_t a, int32_t b) {
    for (;;) {
      a = find(a);
      b = find(b);
      if (a == b) return;
      if (a < b) std::swap(a, b);
      int32_t expected = a;
      if (__atomic_compare_exchange_n(&parent[a], &expected, b, false, __ATOMIC_ACQ_REL, __ATOMIC_RELAXED))
        return;
    }
  }
};

}  // namespace larap
