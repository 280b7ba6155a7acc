// The parts of a mesh: its connected components through its faces and through vertices at the
// same position (a mesh cut along its seams, or a soup whose triangles share corners, is one
// part); a vertex on no face and at no other vertex's position is a part of its own. A part is
// named by its smallest vertex id. Used where the lattice tells a model's parts apart: cell
// splitting (cell_pieces.h) and the B-spline stencils at junctions (junction_stencils.h).
#pragma once
#include <larap/mesh.h>

#include <cstdint>
#include <vector>

namespace larap {

// The part of every vertex.
std::vector<int32_t> mesh_parts(const PolygonMesh& mesh);

}  // namespace larap
