// One copy per branch where separate parts meet (issue 9; docs/method.md, "One copy per branch").
// Internal to the lattice builder; research stage: LatticeOptions::branch_copies, off by default
// (both backends solve the couplings).
//
// Where fingers pushed into a palm leave it, the assembled lattice holds the palm's end and the
// roots of the fingers in one copy (its piece is connected through the palm), and copies of the
// next cells share nodes with it: a turned finger moves them and drags its neighbours. Here:
//
// 1. Material. Near where parts meet (cells that two parts' triangles overlap, and the cells
//    around them), every cell's k^3 voxels are classed per part by ray parity against that part's
//    triangles alone (voxel_inside.h's rows, 5 votes of 6); a cell's copies take the 6-connected
//    components of the voxels inside some part that hold their vertices' parts (a copy with no
//    vertices: what no other copy takes), and a copy's vertices count as its material too. A
//    copy's *trunk* is the largest part (by volume) it holds; the others are its branches, and a
//    branch's *exposed* material is what of it lies outside the trunk.
// 2. Sides. A node is on the branches' side when, over the copies around it, some exposed branch
//    material lies closer to it than kappa (3) times the nearest trunk material (dB < kappa dT); it
//    then belongs to the trunk nearest to it. Every copy to be split keeps its corner most on the
//    trunk's side (the least dT / dB) off the branches' side: a ball joint.
// 3. Copies. A copy holding trunk and exposed branch material, with a node on the branches' side,
//    is split: the trunk keeps it, each exposed branch gets a copy of its own (that part's
//    vertices bind there), weighing its branch's and the trunk's share of the cell (the trunk's
//    copy: the trunk's share; at least 1 / k). A copy of two or more branches and no trunk is split
//    per branch. Other copies are labelled with their trunk, or (too little material) with the one
//    branch of their labelled neighbours.
// 4. Nodes. A node on the branches' side becomes, in the copies labelled with another part than
//    the trunk it belongs to, a node of that part's own at the same point.
// 5. Couplings. Each split-off copy's rotation also answers for the 12 edges of the copy it was
//    split from, weighing `coupling` times that copy's weight (Lattice::couplings): a branch
//    without handles turns with its trunk.
// The reference implementation this follows is scripts/experiments/branch_copies.py (--anchor
// --couple), whose figures are in scripts/experiments/README.md.
#pragma once
#include <larap/lattice.h>
#include <larap/mesh.h>

#include <cstdint>
#include <vector>

namespace larap {

struct BranchOptions {
  // The sides' ratio. 3: at 2 (the reference's first value) a node where three fingers leave the
  // palm at an angle stayed on the palm's side, shared by all three (the character turned 15
  // degrees at 7,000 cells: 2.89% drag; 0.13% at 3).
  double kappa = 3.0;
  double coupling = 10.0;  // lambda: a coupling's weight per unit of its trunk copy's weight
  int k = 24;              // voxels per cell edge
};

// The copies of `lat` (the fine level, before its shell) split per branch; false (and `out`
// untouched) when nothing splits. vertex_part: mesh_parts().
bool split_per_branch(const Lattice& lat, const RowMatrixX3d& V, const std::vector<Eigen::Vector3i>& tris,
                      const std::vector<int32_t>& vertex_part, const BranchOptions& options, LatticeCopies& out);

}  // namespace larap
