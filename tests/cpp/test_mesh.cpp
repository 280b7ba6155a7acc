// The mesh's own checks and views (mesh.h): validate_mesh names the first problem, triangulate
// and segments keep the faces' order, whatever the number of worker threads (they run on chunks
// of faces in parallel).
// Run: cmake --build build --target larap_tests && ctest --test-dir build -R 'Mesh\.'
#include <gtest/gtest.h>
#include <larap/errors.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "parallel.h"
#include "test_meshes.h"

using namespace larap;

namespace {

// A torus of quads whose faces are, in turn, a quad, its two triangles, a pentagon (the quad with
// a repeated corner), a triangle that is an edge there and back (u v u), an edge, an edge with a
// repeated first corner (u u v), one vertex, and one vertex twice: every kind of face triangulate
// and segments tell apart, in a mesh large enough for two chunks.
PolygonMesh mixed_faces(int n_major, int n_minor) {
  const PolygonMesh t = gen::torus(1.0, 0.35, n_major, n_minor);
  PolygonMesh m;
  m.vertices = t.vertices;
  m.face_offsets = {0};
  // The faces made of each quad of the torus, by its index mod 8, as corners of the quad.
  const std::vector<std::vector<std::vector<int>>> kinds = {
      {{0, 1, 2, 3}}, {{0, 1, 2}, {0, 2, 3}}, {{0, 1, 1, 2, 3}}, {{0, 1, 0}}, {{0, 1}}, {{2, 2, 3}}, {{1}},
      {{3, 3}}};
  for (int64_t f = 0; f < t.num_faces(); ++f)
    for (const std::vector<int>& corners : kinds[size_t(f % 8)]) {
      for (int c : corners) m.face_indices.push_back(t.face_indices[size_t(t.face_offsets[f] + c)]);
      m.face_offsets.push_back(int64_t(m.face_indices.size()));
    }
  return m;
}

// What a loop over the faces in order gives (the definitions in mesh.h).
std::vector<Eigen::Vector3i> serial_triangles(const PolygonMesh& m) {
  std::vector<Eigen::Vector3i> out;
  for (int64_t f = 0; f < m.num_faces(); ++f) {
    const int64_t b = m.face_offsets[f], e = m.face_offsets[f + 1];
    for (int64_t k = b + 1; k + 1 < e; ++k) {
      const int a = int(m.face_indices[b]), u = int(m.face_indices[k]), w = int(m.face_indices[k + 1]);
      if (a != u && u != w && a != w) out.emplace_back(a, u, w);
    }
  }
  return out;
}

std::vector<Eigen::Vector2i> serial_segments(const PolygonMesh& m) {
  std::vector<Eigen::Vector2i> out;
  for (int64_t f = 0; f < m.num_faces(); ++f) {
    std::vector<int64_t> distinct;
    for (int64_t k = m.face_offsets[f]; k < m.face_offsets[f + 1]; ++k)
      if (std::find(distinct.begin(), distinct.end(), m.face_indices[k]) == distinct.end())
        distinct.push_back(m.face_indices[k]);
    if (distinct.size() == 2)
      out.emplace_back(int(std::min(distinct[0], distinct[1])), int(std::max(distinct[0], distinct[1])));
  }
  return out;
}

std::string message_of(const PolygonMesh& m) {
  try {
    validate_mesh(m);
  } catch (const InvalidInput& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Mesh, TriangulateAndSegmentsKeepTheFaceOrderWhateverTheThreadCount) {
  const PolygonMesh m = mixed_faces(400, 200);  // 90,000 faces: two chunks
  ASSERT_GT(m.num_faces(), 65536);
  const std::vector<Eigen::Vector3i> tris = serial_triangles(m);
  const std::vector<Eigen::Vector2i> segs = serial_segments(m);
  ASSERT_EQ(tris.size(), 60000u);  // 6 per 8 faces of the torus
  ASSERT_EQ(segs.size(), 30000u);  // 3 per 8
  const int before = num_threads();
  for (int n : {1, 2, 8}) {
    set_num_threads(n);
    EXPECT_EQ(triangulate(m), tris) << n << " threads";
    EXPECT_EQ(segments(m), segs) << n << " threads";
  }
  set_num_threads(before);
}

TEST(Mesh, ValidationNamesTheFirstProblem) {
  const PolygonMesh good = mixed_faces(400, 200);
  ASSERT_EQ(good.num_faces(), 90000);
  EXPECT_EQ(message_of(good), "");
  const auto with_two_corners = [&](int64_t from) {  // the first face from `from` on with 2 corners
    while (good.face_offsets[from + 1] - good.face_offsets[from] < 2) ++from;
    return from;
  };
  const int64_t f1 = with_two_corners(20), f2 = with_two_corners(85000);
  const int before = num_threads();
  for (int n : {1, 2, 8}) {
    set_num_threads(n);
    PolygonMesh m = good;
    m.vertices(70001, 2) = std::numeric_limits<double>::infinity();
    m.vertices(150, 1) = std::nan("");
    m.face_indices[size_t(m.face_offsets[f2] + 1)] = -3;  // a bad vertex is named before any face
    EXPECT_NE(message_of(m).find("vertices[150] has a non-finite coordinate"), std::string::npos)
        << message_of(m);
    m.vertices = good.vertices;
    m.face_indices[size_t(m.face_offsets[f1] + 1)] = m.num_vertices();
    EXPECT_NE(message_of(m).find("face " + std::to_string(f1) + " refers to vertex " +
                                 std::to_string(m.num_vertices())),
              std::string::npos)
        << message_of(m);
    m.face_indices = good.face_indices;
    // An offset that goes back makes the next face start before the indices: it is named, and no
    // face is read from there.
    m.face_offsets[80001] = -7;
    EXPECT_NE(message_of(m).find("face 80000 has invalid offsets"), std::string::npos) << message_of(m);
    m.face_offsets = good.face_offsets;
    m.face_offsets[60001] = m.face_offsets[60000];
    EXPECT_NE(message_of(m).find("face 60000 has no vertices"), std::string::npos) << message_of(m);
    m.face_offsets.back() += 1;  // past the indices, but after the empty face
    EXPECT_NE(message_of(m).find("face 60000 has no vertices"), std::string::npos) << message_of(m);
    m.face_offsets = good.face_offsets;
    m.face_offsets.back() += 1;
    EXPECT_NE(message_of(m).find("face 89999 has invalid offsets"), std::string::npos) << message_of(m);
  }
  set_num_threads(before);
}
