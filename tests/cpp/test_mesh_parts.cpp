// Mesh parts (mesh_parts.h): components through faces and through vertices at one position.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R MeshParts
#include <gtest/gtest.h>

#include <initializer_list>
#include <set>

#include "mesh_parts.h"
#include "parallel.h"
#include "test_meshes.h"

using namespace larap;

namespace {

// Every face of `m` with vertices of its own (a mesh cut along every edge, as a soup is).
PolygonMesh unwelded(const PolygonMesh& m) {
  PolygonMesh s;
  s.vertices.resize(int64_t(m.face_indices.size()), 3);
  for (int64_t i = 0; i < int64_t(m.face_indices.size()); ++i) {
    s.vertices.row(i) = m.vertices.row(m.face_indices[size_t(i)]);
    s.face_indices.push_back(i);
  }
  s.face_offsets = m.face_offsets;
  return s;
}

size_t count(const std::vector<int32_t>& part) { return std::set<int32_t>(part.begin(), part.end()).size(); }

}  // namespace

TEST(MeshParts, FacesAndSharedPositionsJoin) {
  const PolygonMesh two = gen::concat({gen::box({0, 0, 0}, {1, 1, 1}), gen::box({2, 0, 0}, {3, 1, 1})});
  const std::vector<int32_t> part = mesh_parts(two);
  EXPECT_EQ(count(part), 2u);
  EXPECT_EQ(part[7], 0);  // named by the smallest vertex
  EXPECT_EQ(part[8], 8);
  EXPECT_EQ(count(mesh_parts(unwelded(two))), 2u);  // each box's faces meet at their corners
}

TEST(MeshParts, ALooseVertexAtABodysCornerJoinsIt) {
  // The body (the largest component) is looked up against the other parts' positions, -0.0 is 0.0.
  PolygonMesh m = gen::concat({gen::box({0, 0, 0}, {1, 1, 1}), gen::point({1, 1, 1}), gen::point({5, 5, 5})});
  EXPECT_EQ(count(mesh_parts(m)), 2u);
  m.vertices.row(8) << -0.0, 1.0, 1.0;  // the point moves to the corner (0, 1, 1)
  EXPECT_EQ(mesh_parts(m)[8], 0);
  m.vertices.row(8) << 0.0, 1.0, 1.0 + 1e-12;  // ... and just off it
  EXPECT_EQ(mesh_parts(m)[8], 8);
  const PolygonMesh loose = gen::concat({gen::point({0, 0, 0}), gen::point({1, 0, 0})});
  EXPECT_EQ(count(mesh_parts(loose)), 2u);
}

TEST(MeshParts, SameWhateverTheThreadCount) {
  // The faces are joined by several threads at once (a union-find whose roots are the smallest
  // members, so the order does not matter): a soup of many small triangles (every part a class of
  // many links), two tori, a loose point and a long polyline, with 1, 2 and 8 threads (TBB may run
  // fewer: at most the machine's cores).
  const PolygonMesh soup = unwelded(gen::torus(1.0, 0.35, 120, 60));
  // The polyline's edges are listed from its far end: each union links a fresh root, so the links
  // form one chain through all its vertices (reading the roots off must not walk it from every
  // vertex: that took 2.5 s at 80,000 vertices).
  PolygonMesh line;
  const int nl = 100000;
  line.vertices.resize(nl, 3);
  line.face_offsets = {0};
  for (int i = 0; i < nl; ++i) line.vertices.row(i) << 10.0 + 1e-3 * i, 0.0, 0.0;
  for (int i = nl - 2; i >= 0; --i) {
    line.face_indices.insert(line.face_indices.end(), {int64_t(i), int64_t(i + 1)});
    line.face_offsets.push_back(int64_t(line.face_indices.size()));
  }
  const PolygonMesh m = gen::concat(
      {soup, gen::torus(3.0, 0.35, 200, 100), gen::torus(3.0, 0.2, 30, 10), gen::point({9, 9, 9}), line});
  const int before = num_threads();
  set_num_threads(1);
  const std::vector<int32_t> one = mesh_parts(m);
  EXPECT_EQ(count(one), 5u);  // the soup is one part through its shared positions
  for (int64_t v = 0; v < int64_t(one.size()); ++v) ASSERT_LE(one[size_t(v)], v);  // named by the smallest
  EXPECT_EQ(one[0], 0);
  EXPECT_EQ(one[size_t(soup.num_vertices())], int32_t(soup.num_vertices()));
  EXPECT_EQ(one.back(), int32_t(m.num_vertices() - nl));  // the polyline, named by its first vertex
  for (int n : {2, 8}) {
    set_num_threads(n);
    EXPECT_EQ(mesh_parts(m), one) << n << " threads";
  }
  set_num_threads(before);
}
