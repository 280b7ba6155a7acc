// Mesh parts (mesh_parts.h): components through faces and through vertices at one position.
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R MeshParts
#include <gtest/gtest.h>

#include <set>

#include "mesh_parts.h"
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
