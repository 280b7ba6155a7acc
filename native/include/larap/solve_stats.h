// What one solve did: energies per iteration and milliseconds per stage. Filled by the Deformer
// and its backends; read through Deformer::stats() (Python: Deformer.stats).
#pragma once
#include <vector>

namespace larap {

struct SolveStats {
  std::vector<double> energy;  // energy after each flip-flop iteration (normalised, see deformer.h)
  int iterations = 0;          // flip-flop iterations run on the finest level
  bool rigid_carry = false;    // some part of the previous pose was carried by its handles' rigid motion
  double ms_rotations = 0;     // local step: per-node rotations
  double ms_rhs = 0;           // right-hand side of the global step
  double ms_solve = 0;         // global step: the linear solve
  double ms_transfer = 0;      // lattice to mesh vertices
  double ms_total = 0;         // the whole solve call
  double ms_energy = 0;        // evaluating the energy after each iteration
  double ms_start = 0;         // choosing the start (rigid carry, rest candidate)
  double ms_coarse = 0;        // the coarser levels of a hierarchy
  double ms_factorize = 0;     // last set_handles
  double ms_lattice = 0;       // construction: the lattice
  double ms_binding = 0;       // construction: binding the vertices

  // Forget the figures of the last solve (construction and factorisation times stay).
  void clear_solve() {
    energy.clear();
    iterations = 0;
    rigid_carry = false;
    ms_rotations = ms_rhs = ms_solve = ms_transfer = ms_total = ms_energy = ms_start = ms_coarse = 0;
  }
};

}  // namespace larap
