// Parts that no handle reaches follow the parts they lie along.
//
// A lattice component that no handle row reads would make the system singular; it used to be held
// at rest. Since cells are split by mesh part (cell_pieces.h), a part a tenth of a cell off another
// (a sleeve around an arm, a belt, an eye in its socket) gets cells of its own, and a part without
// handles would then stay behind while the body moves. Instead, the lattice deforms the space
// around a handled part, as the paper's lattice does: a component without handles that has at
// least kCarriedShare of its real nodes at the grid points of a handled component's nodes is
// *carried* by it. Each of its nodes at such a point is glued to one node of its carrier at the
// same point by `mu |x_i - x_j|^2`; its other nodes are free, so it follows by its own ARAP energy.
// The glue is a fixed quadratic with no right-hand side, zero on the rest pose and under every
// affine map (rigid motions stay exact); it joins the handle matrix M in the system and the energy
// (handle_system.h), so the energy still never increases.
//
// Carriers are chosen in rounds, breadth first: first the handled components, then those carried
// by them, and so on, so a chain of parts (a button on a sleeve on an arm) follows. A component is
// carried by the one holding most of its nodes (ties: the lower id) and glued to that one alone,
// so a part lying between two handled parts (a ring between two fingers) never couples them. A
// component that only touches the moving parts along a sliver of itself (a floor under a foot),
// or not at all, is still held at rest.
#pragma once
#include <larap/lattice.h>

#include <array>
#include <cstdint>
#include <vector>

namespace larap {

// Glue weight mu per unit of gamma_eff (docs/method.md, *Parts without handles*: 1 lets a close
// sleeve sink into its arm, 64 changes little more than 8).
constexpr double kGlue = 8.0;

// A component is carried only when at least this share of its nodes lies at its carrier's grid
// points: a sleeve, an eye or a belt, not a floor that a foot touches.
constexpr double kCarriedShare = 0.25;

struct CarriedParts {
  // Per node (all nodes, shell included): the component whose warm start it takes, its own or,
  // for a carried component, that of the handled component at the end of its chain of carriers.
  std::vector<int32_t> node_component;
  std::vector<uint8_t> anchored;                 // per node: 1 = held at rest (nothing carries it)
  std::vector<std::array<int32_t, 2>> glue;      // (carried node, carrier node), real nodes
  std::vector<int32_t> carrier;                  // per component: its carrier, or -1
};

// Carriers of the components without a handle (`has_handle[c] == 0`) of `lattice`.
CarriedParts carried_parts(const Lattice& lattice, const std::vector<uint8_t>& has_handle);

}  // namespace larap
