// Braces where the solid branches (issue 9; docs/method.md, "Junction braces").
//
// Where fingers leave a palm less than a cell apart, one cell copy holds the palm's end and every
// root: it is joined across one of its faces to two or more copies of the next cell (a *branching*
// copy), and the nodes of that face belong to every finger. A finger turned about its root moves
// them, the branching copy tilts, and the neighbouring fingers tilt with it: the drag that split
// cells alone leave (1-2 % of the hand at some lattice sizes).
//
// A brace holds each corner column of a branching copy straight along its branching axis: for the
// node a one cell on the palm's side (in the copy across the opposite face that shares the
// branching copy's near face), the near node b and the far node c,
//   beta * |x_a - 2 x_b + x_c|^2.
// It is a fixed quadratic with no right-hand side, zero on the rest pose and under every affine map
// (rigid motions and affine maps stay exact), and it needs no rotation: it joins the glue of
// carried parts in the system and the energy (handle_system.h), so the energy still never
// increases. Making the branching copy stiffer instead was tried and reverted: its rotation, fitted
// to its own barely changing shape, lagged its neighbours by about 1/k per flip-flop, and a hand
// bent at the wrist left its fingers behind.
#pragma once
#include <larap/lattice.h>

#include <array>
#include <cstdint>
#include <vector>

namespace larap {

// The weight beta is DeformerOptions::junction_brace per unit of gamma_eff times the lattice's mean
// edge weight, as the anchors and the glue (handle_system.h). Its default 50 is 100 gamma_eff in a
// plain lattice (mean edge weight 2), where the reference solver measured it
// (scripts/experiments/junction_brace.py: 100 and 1000 give the same drag).

// The braces (a, b, c) of `lattice`'s branching copies, with a < c (the end on the trunk's side
// may be either), sorted and without repeats; real nodes only. A copy braces its columns only
// when exactly one copy shares its face on the trunk's side. Only copies next to a split cell can branch: a plain lattice has none.
std::vector<std::array<int32_t, 3>> junction_braces(const Lattice& lattice);

}  // namespace larap
