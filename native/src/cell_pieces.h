// Pieces per cell: which kept cells of the lattice grid hold more than one connected piece of the
// solid, and how the pieces of neighbouring cells connect (the virtual node algorithm: Molino,
// Bao and Fedkiw 2004; Nesme et al. 2009). Internal to the lattice builder.
//
// 1. Candidates. Only cells that may hold several pieces are analysed:
//    - a surface cell whose overlapping triangles form more than one connected component where
//      they meet inside the cell (a fork's two tines joined far away are two; found by
//      surface_patches.h);
//    - the non-candidate kept cells around a grid point are about to share that point's node; if
//      their surfaces do not connect within the 2x2x2 block (no triangle overlaps two of them and
//      no inside cell joins them), the surface cells among them are analysed too. Repeated until
//      nothing changes.
// 2. Voxels. Every candidate cell gets k^3 voxels (k = split_resolution). Surface voxels: a
//    triangle overlaps the voxel (the exact test of geometry.h, found per triangle by voxel_hits.h).
//    Inside: voxels that at least 5 of their 6 axis rays find inside the mesh by parity
//    (voxel_inside.h, a row of cells' rays found once) are held out of the flood, so air that enters
//    a solid through a hole in its surface (an eye socket, an open bottom) does not empty it; after
//    the flood, held voxels that reach a surface voxel of their cell through held voxels are
//    material, and the rest (cores the air cut off, where two holes see them) air. Air: the other
//    non-surface voxels reached by a 6-connected flood fill through the candidate cells, started
//    from the faces that border a cell that is neither surface nor inside (each cell floods in
//    parallel, then air crosses the faces of the cells that gained some, in rounds). Air reaches a
//    candidate only through other candidates: space between two surfaces that opens to the outside
//    only through surface cells that are not analysed is material. Material: everything else (so
//    sheets, soups, open and flipped meshes all have material: at least their surface voxels).
// 3. Pieces: 6-connected components of a cell's material voxels. Two pieces of face-adjacent
//    analysed cells connect when material voxels touch across the face; a piece connects to a
//    non-analysed kept neighbour when it has material on the shared face.
// 4. Parts (mesh_parts.h). In a cell whose triangles belong to several parts (part_pieces.h), two
//    touching surface voxels join only when one part's triangles meet both (tested on the voxel
//    grown by an eighth of a voxel to each side, so that a crack under a quarter voxel never falls
//    between voxels); enclosed voxels join whatever they touch. The same rule decides links across
//    faces, with the other cell's triangles also tested against the grown voxel (a crack on a cell
//    face); to an unanalysed surface neighbour (one patch, so one part) through its part.
// Two surfaces of one part facing along an axis more than 2 h / k apart always have a voxel of air
// between them, so they separate (if the air between them reaches a seed); at an angle to the axes
// they must be farther apart, up to 2 sqrt(3) h / k (docs/method.md); closer ones may merge.
// Surfaces of different parts more than 1.25 |n|_1 h / k apart (|n|_1 as in docs/method.md) with
// no voxel between them separate; a pocket of enclosed space between them joins them, as for one
// part (measured: none beyond 1.55 |n|_1 h / k; docs/method.md).
#pragma once
#include <larap/mesh.h>

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace larap {

enum CellMark : uint8_t {
  kSurface = 1,
  kInside = 2,
  kVertex = 4,
  kDilation = 8,  // build-time only: counts towards the target cell count like before
  kOutside = 16,  // reached by the flood fill from the grid border (build-time only)
};
constexpr uint8_t kReal = kSurface | kInside | kVertex;

struct PieceLink {
  int64_t a_cell;   // grid index of an analysed cell
  int32_t a_piece;  // its piece
  int32_t face;     // 2 * axis + (1: towards +axis, 0: towards -axis)
  int64_t b_cell;   // grid index of the neighbour across that face
  int32_t b_piece;  // its piece, or -1 when it is not analysed (its only copy)
};

struct CellPieces {
  std::vector<int64_t> cells;     // analysed cells (grid indices), ascending
  std::vector<int32_t> pieces;    // number of pieces of each analysed cell (>= 1)
  // Material voxels of each piece, pieces of the analysed cells in order (sum of `pieces` long):
  // a piece's share of its cell is piece_voxels / k^3 (surface voxels count, so a sheet's share
  // is about 1/k per layer).
  std::vector<int32_t> piece_voxels;
  int k = 0;                      // voxels per cell edge
  std::vector<PieceLink> links;   // every connection once (a_cell < b_cell when both analysed)
  // (vertex, piece in its cell) of the vertices whose piece is not 0, ascending (a vertex of an
  // unanalysed cell is in piece 0).
  std::vector<std::pair<int64_t, int32_t>> vertex_pieces;
  int64_t voxels = 0;             // voxels analysed (for the record)
};

// Throws OutOfMemory, before allocating them, when an upper bound of what the analysis holds would
// exceed max_voxel_bytes: k^3 bytes of voxels per analysed cell; when parts are told apart, face
// tables of 6 k^2 bytes per cell of one part and 24 k^2 + 6 k^2 (4 + 4 P) per cell of P parts; and
// per worker thread 16 k^3 of scratch or, earlier, the row of rays it is crossing (the inside test:
// its triangles, and 32 bytes per crossing they can give), whichever is more.
// Grid: cells of size h from `origin`, `dims` per axis, marks as above (kSurface, kInside and
// kVertex final). vertex_part: the part of each vertex (mesh_parts.h). vertex_cells: grid index of
// each vertex's cell.
CellPieces find_cell_pieces(const Eigen::Vector3d& origin, double h, const Eigen::Vector3i& dims,
                            const std::vector<uint8_t>& marks, const RowMatrixX3d& V,
                            const std::vector<Eigen::Vector3i>& tris,
                            const std::vector<int32_t>& vertex_part,
                            const std::vector<int64_t>& vertex_cells, int k,
                            int64_t max_voxel_bytes = std::numeric_limits<int64_t>::max());

}  // namespace larap
