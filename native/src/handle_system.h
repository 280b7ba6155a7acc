// The handle term of the energy, as the backends see it: which lattice nodes each handle reads
// (the rows of B), how strongly the ARAP term weighs against the handles (gamma_eff), and which
// nodes are held at rest because their lattice component has no handle.
//
//   E(c', R) = gamma_eff * sum_i sum_{j in N(i)} |(c'_i - c'_j) - R_i (c_i - c_j)|^2
//            + sum_j |B_j c' - t_j|^2 + a * sum_{i anchored} |c'_i - c_i|^2
//
// Scale-free gamma (docs/method.md): E/m = gamma * s^2 * mean_e(|r_e|^2 / h^2) + mean_j |B_j c' - t_j|^2
// with s the radius of gyration of the rest vertices, so gamma_eff = gamma * m * s^2 / (h^2 * #directed
// edges). The same definition on every level of a hierarchy makes the levels solve one problem.
#pragma once
#include <larap/lattice.h>

#include <Eigen/SparseCore>
#include <cstdint>
#include <vector>

namespace larap {

struct HandleSystem {
  int64_t m = 0;                 // number of handles
  int stencil = 8;               // entries per row of B
  std::vector<int32_t> ids;      // m * stencil node ids
  std::vector<double> weights;   // m * stencil weights
  double gamma_eff = 0.0;        // ARAP weight in the form above
  std::vector<uint8_t> anchored; // #N, 1 = held at rest
  double anchor_weight = 0.0;    // a
  double energy_scale = 1.0;     // reported energy = E * energy_scale (= 1 / (m s^2))
};

// The handle system of `lattice` for m = ids.size() / stencil handles whose rows of B are
// (ids, weights); gamma is the user's scale-free gamma and `size` the model's length scale s.
HandleSystem make_handle_system(const Lattice& lattice, int stencil, std::vector<int32_t> ids,
                                std::vector<double> weights, double gamma, double size);

// Triplets of 2 gamma_eff L + a I_anchored (the ARAP part of the system matrix), shared by the
// backends so that both assemble exactly the same system.
std::vector<Eigen::Triplet<double>> arap_triplets(const Lattice& lattice, const HandleSystem& hs);

// Triplets of B (m by #N): handle j's stencil weights.
std::vector<Eigen::Triplet<double>> handle_triplets(const HandleSystem& hs);

}  // namespace larap
