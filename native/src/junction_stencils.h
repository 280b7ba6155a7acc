// B-spline stencils at junctions: the nodes where pieces meet (a cell copy holding the palm's end,
// with one copy per finger above it; a fork's joint and its tines).
//
// At such a node n some stencil items have one node per piece at the point n + d, and a stencil
// per node must pick one: the stencil shell gives the item a private node extrapolated along the
// mean over all the pieces (stencil_shell.h). So a vertex near a junction followed the average of
// the pieces there: a turned finger pulled its neighbours' roots along, and along a finger the
// stencil of the junction node and the stencil of the node above it disagreed, a step in the
// surface half a cell above the junction (measured on a generated hand of separate finger parts:
// the final pose of the neighbouring fingers moved 1.61 % of the hand, against 0.36 % with the
// trilinear weights on the same lattice pose).
//
// A vertex near a junction reads the junction from its own side. Its side: the cell copies around
// n that hold vertices of its part (mesh_parts.h: the connected component of the mesh it belongs
// to, through faces and coincident vertices). An ambiguous item becomes
//   1. the one node at n + d of those copies, or, when they do not reach n + d,
//   2. the item that a corner of those copies has for the same point without ambiguity (a real
//      node or a shared shell node of that piece), so that the vertex's stencil agrees with the
//      stencils of the part's vertices farther from the junction;
// and keeps the node's own item when neither is unique. Vertices of one part near one node share
// one row. Rows that differ from the node's own are appended to Binding::node27 after the per-node
// rows, and Binding::base names the row: the transfer (CPU and GPU, Binding::weights_of) reads
// them unchanged. Handles are bound trilinearly with either weight kind, so the lattice's pose is
// not affected: only what the B-spline makes of it. Affine maps are still reproduced exactly
// (every item is a node at its own point or an affine-exact shell).
// One connected mesh branching inside a cell finds every copy around the node on its side and keeps
// the node's stencil (the step included: telling its branches apart needs a finer partition of
// that copy). A copy the part crosses only with large triangles, no vertex of it inside, is not
// counted as its side.
#pragma once
#include <larap/binding.h>
#include <larap/lattice.h>
#include <larap/mesh.h>

namespace larap {

// Rewrites the B-spline binding `b` of `mesh`'s vertices (bind_vertices) at the lattice's junction
// nodes. No-op for a trilinear binding or a lattice without junctions.
void resolve_junction_stencils(const Lattice& lattice, const PolygonMesh& mesh, Binding& b);

}  // namespace larap
