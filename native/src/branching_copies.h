// Copies where the solid branches (issue 9, docs/method.md "Stiff branchings"): a cell copy joined
// across one of its faces to two or more copies of the neighbouring cell, sharing all four face
// nodes with each. Where two fingers leave a palm 0.1 cell apart, the copy that holds the palm's
// end and both roots is one, and its far face's nodes are every root's: a finger turned about its
// root moves them, and they tilt the neighbours. The lattice makes such copies stiffer
// (LatticeOptions::junction_stiffness) so that their far nodes follow the copy's own rotation,
// held by the palm, and a turned finger bends in its own cells.
#pragma once
#include <larap/lattice.h>

#include <cstdint>
#include <vector>

namespace larap {

// Per cell copy, 1 where it branches (needs cell_nodes; edges may be missing). Only copies next
// to a split cell can branch: a plain lattice has none.
std::vector<uint8_t> branching_copies(const Lattice& lat);

}  // namespace larap
