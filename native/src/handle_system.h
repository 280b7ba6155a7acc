// The handle term of the energy, as the backends see it: which lattice nodes each handle vertex
// reads (the rows of B), how much each row pulls (alpha), the handle groups with what a pose
// needs of them precomputed, how strongly the ARAP term weighs against the handles (gamma_eff),
// which lattice components without a handle follow a handled one (carried_parts.h), which are
// held at rest because nothing carries them, and the braces where the solid branches
// (junction_braces.h).
//
//   E(c', R) = gamma_eff * sum_c w_c sum_{edges (a,b) of c} |(c'_a - c'_b) - R_c (c_a - c_b)|^2
//            + sum_j alpha_j |B_j c' - t_j|^2 + a * sum_{i anchored} |c'_i - c_i|^2
//            + mu * sum_{(i, k) glued} |c'_i - c'_k|^2 + beta * sum_{(a, b, c) braced} |c'_a - 2 c'_b + c'_c|^2
//
// Rows come in groups g = 1..G (a vertex group driven by one transform). Row j of group g pulls
// alpha_j = (w_g / G) * omega_j / sum_{k in g} omega_k: every group pulls with its own weight w_g
// (default 1) whatever its size, and inside a group the vertex weights omega (default 1) spread
// that pull. set_handles(ids) is G = m groups of one vertex, so alpha_j = 1/m.
//
// (w_c: the copies' weights, 1 except for copies of split cells; lattice.h.)
// Scale-free gamma (docs/method.md): E = gamma * s^2 * wmean_(c, edge)(|r|^2 / h^2) + handle term,
// with s the radius of gyration of the rest vertices, so gamma_eff = gamma * s^2 / (h^2 * 12 sum_c
// w_c) (= twice the lattice's edge weights' sum). The anchors, the glue and the braces weigh per
// unit of the mean edge weight, as stiff against the lattice as with the paper's node energy. The same
// definition on every level of a hierarchy makes the levels solve one problem, up to the fine
// level's weights (coarser levels weigh every cell 1: they only give the fine level its starting
// pose).
//
// Per pose nothing costs in proportion to the handle vertices. With M = B^T diag(alpha) B (fixed
// per handle set) and, in coordinates centred at `origin` (x~ = x - origin, which keeps the sums
// below free of cancellation),
//   H~ = B^T diag(alpha) t~                       (#N by 3: the handles' part of the right-hand side)
//   K~ = sum_j alpha_j |t~_j|^2                   (a number per lattice component)
//   handle term = c~^T M c~ - 2 c~ . H~ + K~.
// For targets t_j = A_g v_j + b_g (a group's affine map of its rest positions v_j),
//   H~_i = sum_g P_g[i] A_g^T + q_g[i] b~_g^T,   P_g[i] = sum_{j in g} alpha_j B_ji v~_j^T,
//   q_g[i] = sum_{j in g} alpha_j B_ji,           b~_g = A_g origin + b_g - origin,
// and K~ from each group's moments (s0, s1, S2) of alpha v~: both O(nodes the groups touch).
// The glue and the braces (the *ties*: fixed quadratics, zero under every affine map) add
// mu G^T G + beta S^T S to M in the system and the energy (tie_matrix), and nothing to H~ or K~;
// the warm start's moments use M alone.
#pragma once
#include <larap/lattice.h>

#include <Eigen/SparseCore>
#include <array>
#include <cstdint>
#include <vector>

namespace larap {

using Affine34 = Eigen::Matrix<double, 3, 4>;  // [A | b]: x -> A x + b

struct HandleSystem {
  // ---------------------------------------------------------------- rows of B
  int64_t m = 0;                       // handle rows (vertices of all groups, group by group)
  int stencil = 8;                     // entries per row of B
  std::vector<int32_t> ids;            // m * stencil node ids
  std::vector<double> weights;         // m * stencil weights
  std::vector<double> alpha;           // m row weights (see above)
  // ---------------------------------------------------------------- groups
  std::vector<int64_t> group_offsets;  // G + 1: rows of group g are [offsets[g], offsets[g+1])
  // Per node, the groups that touch it (CSR by node): q_g[i] and P_g[i] of the header.
  std::vector<int32_t> node_offsets;   // #N + 1
  std::vector<int32_t> entry_group;    // group of each entry
  std::vector<double> entry_q;         // q_g[i]
  std::vector<double> entry_P;         // 3 per entry: P_g[i] (row vector)
  std::vector<double> q;               // #N: B^T alpha (sum over all rows)
  // Moments of alpha v~ per (group, component) the group touches: K~ of a pose without the rows.
  struct Moments {
    int32_t group = 0, component = 0;
    double s0 = 0;                     // sum alpha
    Eigen::Vector3d s1 = Eigen::Vector3d::Zero();  // sum alpha v~
    Eigen::Matrix3d s2 = Eigen::Matrix3d::Zero();  // sum alpha v~ v~^T
  };
  std::vector<Moments> moments;
  std::vector<int32_t> row_component;  // m: the lattice component row j reads
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  // ---------------------------------------------------------------- weights of the energy
  double gamma_eff = 0.0;              // ARAP weight in the form above
  std::vector<uint8_t> anchored;       // #N, 1 = held at rest
  double anchor_weight = 0.0;          // a
  std::vector<std::array<int32_t, 2>> glue;  // (carried node, carrier node) pairs
  double glue_weight = 0.0;            // mu
  std::vector<std::array<int32_t, 3>> braces;  // (a, b, c) columns of branching copies (none when beta is 0)
  double brace_weight = 0.0;           // beta
  std::vector<int32_t> node_component; // #N: the component whose warm start a node takes
  double energy_scale = 1.0;           // reported energy = E * energy_scale (= 1 / s^2)
  int32_t num_components = 0;          // of the lattice

  int64_t num_groups() const { return static_cast<int64_t>(group_offsets.size()) - 1; }
  bool has_ties() const { return !glue.empty() || !braces.empty(); }
};

// The handles as the user gave them, independent of any lattice.
struct HandleSpec {
  std::vector<int64_t> vertices;       // m vertex ids, group by group
  std::vector<int64_t> group_offsets;  // G + 1
  std::vector<double> omega;           // m vertex weights (empty: all 1)
  std::vector<double> group_weights;   // G group weights (empty: all 1)
  RowMatrixX3d rest;                   // m by 3 rest positions of the rows
};

// The handle system of `lattice` for rows (ids, weights) of `stencil` entries each (the handle
// vertices of `spec` bound to this lattice); gamma is the user's scale-free gamma, `braces` the
// lattice's junction braces (computed once with the lattice: junction_braces.h) and `brace` their
// weight per unit of gamma_eff times the mean edge weight (0: none); `size` is the model's length
// scale s; `origin` centres the handle sums.
HandleSystem make_handle_system(const Lattice& lattice, int stencil, std::vector<int32_t> ids,
                                std::vector<double> weights, const HandleSpec& spec, double gamma,
                                const std::vector<std::array<int32_t, 3>>& braces, double brace,
                                double size, const Eigen::Vector3d& origin);

// What one pose asks of the handles: a target per row, or one affine map per group.
struct HandleTargets {
  const double* rows = nullptr;       // m by 3 row-major, or
  const Affine34* groups = nullptr;   // G maps (applied to the rows' rest positions)
};

// H~ (#N by 3) and K~ (one per lattice component) of `targets`, on the host: O(m) for row
// targets, O(nodes the groups touch + groups) for group maps.
void handle_rhs(const HandleSystem& hs, const HandleTargets& targets, RowMatrixX3d& H,
                std::vector<double>& K);

// The groups' maps as the handle sums use them: A_g and b~_g = A_g origin + b_g - origin.
struct GroupMaps {
  std::vector<Eigen::Matrix3d> A;
  std::vector<Eigen::Vector3d> b;
};
GroupMaps group_maps(const HandleSystem& hs, const Affine34* maps);
// K~ per lattice component of the group maps, from the groups' moments: O(groups x components).
void group_constants(const HandleSystem& hs, const GroupMaps& maps, std::vector<double>& K);

// Each (group, component) whose moments `hs` keeps: which lattice components a group's rows read.
std::vector<std::array<int32_t, 2>> group_components(const HandleSystem& hs);

// M = B^T diag(alpha) B (#N by #N).
Eigen::SparseMatrix<double> handle_matrix(const HandleSystem& hs, int64_t num_nodes);
// mu G^T G + beta S^T S: the glue of carried parts and the junction braces (empty without ties).
// The system and the energy use M plus this, the warm start's moments M alone.
Eigen::SparseMatrix<double> tie_matrix(const HandleSystem& hs, int64_t num_nodes);

// Triplets of 2 gamma_eff L + a I_anchored (the ARAP part of the system matrix), shared by the
// backends so that both assemble exactly the same system.
std::vector<Eigen::Triplet<double>> arap_triplets(const Lattice& lattice, const HandleSystem& hs);

}  // namespace larap
