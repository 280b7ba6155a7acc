// Meshes the tests generate: boxes, bars, spheres, soups.
#pragma once
#include <larap/mesh.h>

#include <cmath>

namespace larap::gen {

// Closed box [lo, hi] subdivided k times per axis... as 12 triangles (2 per face).
inline PolygonMesh box(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  PolygonMesh m;
  m.vertices.resize(8, 3);
  for (int c = 0; c < 8; ++c)
    m.vertices.row(c) << ((c & 1) ? hi.x() : lo.x()), ((c & 2) ? hi.y() : lo.y()), ((c & 4) ? hi.z() : lo.z());
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  m.face_offsets = {0};
  for (const auto& q : quads) {
    for (int k = 0; k < 4; ++k) m.face_indices.push_back(q[k]);
    m.face_offsets.push_back(static_cast<int64_t>(m.face_indices.size()));
  }
  return m;
}

// UV sphere (closed, consistently oriented) with `rings` x `segments` quads.
inline PolygonMesh sphere(const Eigen::Vector3d& centre, double r, int rings, int segments) {
  PolygonMesh m;
  const int nv = 2 + (rings - 1) * segments;
  m.vertices.resize(nv, 3);
  m.vertices.row(0) = (centre + Eigen::Vector3d(0, 0, -r)).transpose();
  m.vertices.row(1) = (centre + Eigen::Vector3d(0, 0, r)).transpose();
  for (int i = 1; i < rings; ++i)
    for (int j = 0; j < segments; ++j) {
      const double th = M_PI * i / rings, ph = 2 * M_PI * j / segments;
      m.vertices.row(2 + (i - 1) * segments + j) =
          (centre + r * Eigen::Vector3d(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), -std::cos(th))).transpose();
    }
  auto ring = [&](int i, int j) { return 2 + (i - 1) * segments + (j % segments); };
  m.face_offsets = {0};
  auto add = [&](std::initializer_list<int64_t> f) {
    m.face_indices.insert(m.face_indices.end(), f);
    m.face_offsets.push_back(static_cast<int64_t>(m.face_indices.size()));
  };
  for (int j = 0; j < segments; ++j) add({0, ring(1, j + 1), ring(1, j)});
  for (int i = 1; i + 1 < rings; ++i)
    for (int j = 0; j < segments; ++j) add({ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)});
  for (int j = 0; j < segments; ++j) add({1, ring(rings - 1, j), ring(rings - 1, j + 1)});
  return m;
}

}  // namespace larap::gen
