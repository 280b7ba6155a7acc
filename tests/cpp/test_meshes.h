// Meshes the tests generate: boxes, spheres, tori, parts put together, loose points.
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

// Torus around the z axis, all quads (the formula of larap.shapes.torus).
inline PolygonMesh torus(double major, double minor, int n_major, int n_minor) {
  PolygonMesh m;
  m.vertices.resize(int64_t(n_major) * n_minor, 3);
  for (int i = 0; i < n_major; ++i)
    for (int j = 0; j < n_minor; ++j) {
      const double u = 2 * M_PI * i / n_major, v = 2 * M_PI * j / n_minor, rho = major + minor * std::cos(v);
      m.vertices.row(int64_t(i) * n_minor + j) << rho * std::cos(u), rho * std::sin(u), minor * std::sin(v);
    }
  m.face_offsets = {0};
  for (int i = 0; i < n_major; ++i)
    for (int j = 0; j < n_minor; ++j) {
      const int i1 = (i + 1) % n_major, j1 = (j + 1) % n_minor;
      for (int64_t v : {int64_t(i) * n_minor + j, int64_t(i1) * n_minor + j, int64_t(i1) * n_minor + j1,
                        int64_t(i) * n_minor + j1})
        m.face_indices.push_back(v);
      m.face_offsets.push_back(static_cast<int64_t>(m.face_indices.size()));
    }
  return m;
}

// The parts as one mesh (vertex indices shifted, nothing welded).
inline PolygonMesh concat(std::initializer_list<PolygonMesh> parts) {
  PolygonMesh m;
  for (const PolygonMesh& p : parts) {
    const int64_t base = m.num_vertices();
    m.vertices.conservativeResize(base + p.num_vertices(), 3);
    m.vertices.bottomRows(p.num_vertices()) = p.vertices;
    for (int64_t f = 0; f < p.num_faces(); ++f) {
      for (int64_t k = p.face_offsets[f]; k < p.face_offsets[f + 1]; ++k) m.face_indices.push_back(p.face_indices[k] + base);
      m.face_offsets.push_back(static_cast<int64_t>(m.face_indices.size()));
    }
  }
  return m;
}

// One loose vertex (binds, has no face): fixes where a generated mesh's bounding box starts.
inline PolygonMesh point(const Eigen::Vector3d& p) {
  PolygonMesh m;
  m.vertices = p.transpose();
  return m;
}

// Displacements that move points `rest` (#N by 3) by x -> A x + t: a lattice posed by an affine map.
inline RowMatrixX3d affine_displacement(const RowMatrixX3d& rest, const Eigen::Matrix3d& A,
                                        const Eigen::Vector3d& t) {
  RowMatrixX3d disp(rest.rows(), 3);
  for (int64_t i = 0; i < rest.rows(); ++i)
    disp.row(i) = (A * rest.row(i).transpose() + t - rest.row(i).transpose()).transpose();
  return disp;
}

}  // namespace larap::gen
