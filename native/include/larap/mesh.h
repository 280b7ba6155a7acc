// Polygon meshes as the engine sees them: vertex positions plus faces of any size (CSR layout).
#pragma once
#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace larap {

using RowMatrixX3d = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;

struct PolygonMesh {
  RowMatrixX3d vertices;               // #V by 3 positions
  std::vector<int64_t> face_offsets;   // #F+1 offsets into face_indices (face f = [offsets[f], offsets[f+1]))
  std::vector<int64_t> face_indices;   // concatenated vertex indices of all faces

  PolygonMesh() : face_offsets{0} {}
  int64_t num_vertices() const { return vertices.rows(); }
  int64_t num_faces() const { return static_cast<int64_t>(face_offsets.size()) - 1; }
};

// Checks that the mesh is usable by the engine; throws InvalidInput naming the first problem:
// no vertices, non-finite coordinates, face indices out of range or negative, faces with fewer
// than one vertex. Repeated indices within a face and degenerate faces are allowed (they are
// handled, see docs/robustness.md).
void validate_mesh(const PolygonMesh& mesh);

// Fan triangulation of every face with 3 or more vertices, skipping triangles with repeated
// indices. Faces with 1 or 2 distinct vertices contribute no triangle (their vertices still bind).
std::vector<Eigen::Vector3i> triangulate(const PolygonMesh& mesh);

// The loose edges: every face with exactly 2 distinct vertices (an OBJ `l` element, a Blender
// edge on no face), as a segment (lower id first). The lattice keeps the cells a segment passes
// through, so the vertices of a wire mesh (a Skin modifier's skeleton, guide curves) stay
// connected however long its edges are.
std::vector<Eigen::Vector2i> segments(const PolygonMesh& mesh);

}  // namespace larap
