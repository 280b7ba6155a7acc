// Host set-up of the CUDA backend's multilevel preconditioner (once per set_handles, double
// precision), everything the device needs as plain arrays for the backend to upload.
//
// Level 1: aggregates = fine nodes with equal (node_coords >> shift), P piecewise constant,
// Ac = P^T A P. Two levels (mg_levels 2, or automatic when the 2x2x2 aggregation has at most
// mg_coarse_max nodes): the smallest shift >= 1 within that bound, Ac inverted densely. Three
// levels (3, or automatic when 2x2x2 gives more): level 1 = 2x2x2 aggregates with Ac1 kept sparse
// on the device and smoothed by damped Jacobi; level 2 = the smallest shift >= 2 within the
// bound, Ac2 = P2^T Ac1 P2 inverted densely. Smoothing weights 4 / (3 lambda_max(D^-1 A)).
// The cycle itself: solvers.cu; the maths and measurements: docs/cuda.md.
#pragma once
#include <larap/lattice.h>

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <vector>

namespace larap {
namespace cuda {

using SparseRows = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

// An upper bound of lambda_max(D^-1 A) (D = diag): 1.05 x 40 steps of power iteration from a
// positive start vector (Eigen's Random, so the sequence of calls fixes it).
double jacobi_lambda_max(const SparseRows& A, const Eigen::VectorXd& diag);

// Coarse id of each of the first n nodes (the real nodes: the rows of A) when they are grouped
// by (coords >> shift) and, inside one such block, by connection through lattice edges that stay
// in the block: copies of split cells (lattice.h) and parts that merely share a block are not
// joined. Returns the count. A larger shift only merges groups of a smaller one (nested levels).
int aggregate(const Lattice& lattice, int n, int shift, std::vector<int>& agg);

// Dense inverse of a small SPD matrix, symmetrised, row-major float: one Cholesky factorisation,
// then the triangular solves for blocks of 64 identity columns in parallel (parallel.h).
// Throws DeviceError when the matrix is not positive definite.
std::vector<float> dense_inverse(const Eigen::MatrixXd& A);

// Slots of a row of A P stored beside each other per fine node (system.h, kApSlots); the rest of
// the row is a CSR remainder.
struct ProlongedRows {
  std::vector<int> col;      // kApSlots * n, slot-major: level-1 node of each slot (padding: own)
  std::vector<float> val;    // the same: (A P)_ia (padding: 0)
  std::vector<int> rem_off;  // n + 1
  std::vector<int> rem_col;  // level-1 nodes of the entries beyond the slots
  std::vector<float> rem_val;
};

// The rows of A P (P: fine node i -> its level-1 node agg[i]): (A P)_ia = sum of A_ij over the j
// with agg[j] = a, summed in double; each row's own aggregate first (slot 0), the others in order
// of first appearance. Away from handles and split cells a row has at most 4 (its own block and
// one per axis); a handle node's, up to 8 with trilinear binding.
ProlongedRows prolonged_rows(const SparseRows& A, const std::vector<int>& agg, int slots);

struct Multigrid {
  bool three_levels = false;
  int shift = 1;            // level 1 = fine nodes grouped by coords >> shift
  int nc = 0;               // level-1 nodes
  std::vector<int> agg;     // #N: level-1 id of each fine node
  float omega = 0.6f;       // fine smoothing weight
  std::vector<float> ainv;  // dense inverse of the coarsest level (nc or nc2 squared), row-major
  ProlongedRows ap;         // A P, for the coarse correction's gather (solvers.cu, mg_c_node)
  // Three levels only:
  int nc2 = 0;                       // level-2 nodes
  std::vector<int> agg2;             // nc: level-2 id of each level-1 node
  std::vector<int> c_off, c_col;     // Ac1, CSR with its diagonal
  std::vector<float> c_val, c_minv;  // its values, 1 / diag(Ac1)
  float omega1 = 0.6f;               // level-1 smoothing weight
};

// The preconditioner of A (the fine system, #N rows) with lam_max = jacobi_lambda_max(A, ...).
// mg_levels: 0 automatic, 2 or 3.
// ap_slots: the slots of ProlongedRows.
Multigrid build_multigrid(const Lattice& lattice, const SparseRows& A, double lam_max, int mg_coarse_max,
                          int mg_levels, int ap_slots);

}  // namespace cuda
}  // namespace larap
