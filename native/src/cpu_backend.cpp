// CPU backend: parallel loops over cell copies for rotations and energy and over nodes for the
// right-hand side (parallel.h; the maths is cell_terms.h's, shared with the CUDA kernels), CHOLMOD
// (simplicial Cholesky) for the global step, factorised once per handle set.
#include <larap/errors.h>

#ifdef LARAP_WITH_CHOLMOD
#include <Eigen/CholmodSupport>
#else
#include <Eigen/SparseCholesky>  // fallback when CHOLMOD is not installed
#endif
#include <Eigen/Sparse>
#include <chrono>

#include "backend.h"
#include "cell_terms.h"
#include "node_cells.h"
#include "parallel.h"
#include "rigid_fit.h"

namespace larap {
namespace {

#ifdef LARAP_WITH_CHOLMOD
// Simplicial: with Debian's reference BLAS the supernodal factor's solves with 3 right-hand
// sides were 2-4x slower (docs/results.md), and the simplicial solve calls no BLAS, so the result
// does not depend on the thread count.
using Factor = Eigen::CholmodSimplicialLLT<Eigen::SparseMatrix<double>>;
#else
using Factor = Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>>;
#endif

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// Row-major, so that data() is the 9 entries cell_terms.h reads.
using Rotation = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;

// Cell copy c's corners, as cell_terms.h's Corners accessor.
struct CellCorners {
  const double* P;  // pose, #N by 3 row-major
  const double* C;  // rest
  const std::array<int32_t, 8>& ids;
  void pose(int q, double (&p)[3]) const {
    for (int a = 0; a < 3; ++a) p[a] = P[3 * int64_t(ids[size_t(q)]) + a];
  }
  void rest(int q, double (&c)[3]) const {
    for (int a = 0; a < 3; ++a) c[a] = C[3 * int64_t(ids[size_t(q)]) + a];
  }
};

// Why a factorisation failed, in the user's terms (the solved weights are rescaled internally:
// only their ratio means something to the user).
std::string not_factorised(const HandleSystem& hs) {
  double lo = 0.0, hi = 0.0;
  for (double a : hs.alpha)
    if (a > 0.0) {
      lo = lo > 0.0 ? std::min(lo, a) : a;
      hi = std::max(hi, a);
    }
  return "the lattice system could not be factorised (not positive definite): the stiffness (gamma) and the "
         "handles' pull are too far apart in size for double precision" +
         (lo > 0.0 ? " (the pull per handle vertex varies by a factor of " + number_text(hi / lo) + ")" : std::string()) +
         "; use handle weights nearer each other and gamma nearer its default";
}

class CpuBackend final : public Backend {
 public:
  CpuBackend(const Lattice& lattice, const RowMatrixX3d& vertices)
      : lat_(lattice), V_(vertices), nr_(lattice.num_real_nodes()), pose_(lattice.rest),
        R_(size_t(lattice.num_cells()), Rotation::Identity()), node_cells_(node_cells(lattice)),
        couplings_(couplings_by_branch(lattice)) {
    cell_energy_.resize(size_t(lattice.num_cells()));
  }

  std::string name() const override { return "cpu"; }

  void set_handles(const HandleSystem& hs) override {
    hs_ = hs;
    const int64_t n = nr_;  // the system is over the real nodes; the shell follows them
    const auto trip = arap_triplets(lat_, hs);
    Eigen::SparseMatrix<double> A(n, n);
    A.setFromTriplets(trip.begin(), trip.end());
    M_ = handle_matrix(hs, n);
    rest_pc_ = lat_.rest.topRows(n).rowwise() - hs.origin.transpose();  // the rest's moments: per handle set
    rest_mp_ = M_ * rest_pc_;
    G_ = tie_matrix(hs, n);  // the glue of carried parts and the junction braces (may be empty)
    A += M_ + G_;
    A.makeCompressed();
    llt_ = std::make_unique<Factor>();
#ifdef LARAP_WITH_CHOLMOD
    llt_->cholmod().print = 0;  // the failure is our exception, not a CHOLMOD warning on stdout
#endif
    llt_->compute(A);
    if (llt_->info() != Eigen::Success) throw DeviceError(not_factorised(hs));
    rhs_.resize(n, 3);
    H_.setZero(n, 3);
    K_.assign(size_t(hs.num_components), 0.0);
    targets_set_ = false;
  }

  void set_targets(const HandleTargets& targets) override {
    handle_rhs(hs_, targets, H_, K_);
    targets_set_ = true;
  }

  void set_pose(const RowMatrixX3d& nodes) override {
    pose_ = nodes;
    lat_.fill_shell(pose_);
  }
  void get_pose(RowMatrixX3d& nodes) const override { nodes = pose_; }

  void moments(std::vector<ComponentMoments>& now, std::vector<ComponentMoments>& rest) override {
    const RowMatrixX3d Pc = pose_.topRows(nr_).rowwise() - hs_.origin.transpose();
    moments_of(Pc, M_ * Pc, now);  // M is symmetric
    moments_of(rest_pc_, rest_mp_, rest);
  }

  void apply_rigid(const std::vector<ComponentMotion>& motions, bool from_rest) override {
    const int64_t n = lat_.num_nodes();
    for (int64_t i = 0; i < n; ++i) {
      const ComponentMotion& mo = motions[hs_.node_component[i]];
      if (!mo.active || hs_.anchored[i]) continue;
      // The motion maps centred coordinates (the moments are centred at origin).
      const Eigen::Vector3d x = (from_rest ? lat_.rest : pose_).row(i).transpose() - hs_.origin;
      pose_.row(i) = (mo.R * x + mo.t + hs_.origin).transpose();
    }
    lat_.fill_shell(pose_);
  }

  void iterate(int iterations, SolveStats& stats) override {
    if (!llt_ || !targets_set_) throw StateError("set_handles and set_targets must come before iterate");
    const Eigen::Map<const Eigen::VectorXd> q(hs_.q.data(), Eigen::Index(hs_.q.size()));
    const RowMatrixX3d Bt = H_ + q * hs_.origin.transpose();  // B^T alpha t, fixed for this solve
    for (int it = 0; it < iterations; ++it) {
      auto t0 = Clock::now();
      // The pass that fits the new rotations also sums the ARAP energy of the previous
      // iteration's pose with its rotations, so the energy costs no extra pass over the lattice.
      rotations(/*with_energy=*/it > 0);
      stats.ms_rotations += ms_since(t0);
      if (it > 0) {
        t0 = Clock::now();
        stats.energy.push_back(finish_energy());
        stats.ms_energy += ms_since(t0);
      }

      t0 = Clock::now();
      right_hand_side(Bt);
      stats.ms_rhs += ms_since(t0);

      t0 = Clock::now();
      const Eigen::MatrixX3d sol = llt_->solve(rhs_);
      pose_.topRows(nr_) = sol;
      lat_.fill_shell(pose_);
      stats.ms_solve += ms_since(t0);
    }
    if (iterations > 0) {
      const auto t0 = Clock::now();
      stats.energy.push_back(evaluate());
      stats.ms_energy += ms_since(t0);
    }
  }

  double energy() override {
    rotations(false);
    return evaluate();
  }

  void transfer(const Binding& b, double* out, SolveStats& stats) override { transfer_any(b, out, stats); }
  void transfer(const Binding& b, float* out, SolveStats& stats) override { transfer_any(b, out, stats); }

 private:
  // The moments of the handle rows for a pose: Pc its real rows less hs_.origin, MP = M Pc.
  void moments_of(const RowMatrixX3d& Pc, const RowMatrixX3d& MP, std::vector<ComponentMoments>& out) const {
    out.assign(size_t(hs_.num_components), ComponentMoments{});
    for (int64_t i = 0; i < nr_; ++i) {
      if (hs_.q[i] == 0.0) continue;
      ComponentMoments& m = out[hs_.node_component[i]];
      const Eigen::Vector3d p = Pc.row(i).transpose(), h = H_.row(i).transpose();
      m.w += hs_.q[i];
      m.p += hs_.q[i] * p;
      m.t += h;
      m.pt += p * h.transpose();
      m.pp += p * MP.row(i);
    }
    for (size_t c = 0; c < out.size(); ++c) out[c].tt = K_[c];
  }

  template <typename T>
  void transfer_any(const Binding& b, T* out, SolveStats& stats) {
    const auto t0 = Clock::now();
    const RowMatrixX3d disp = pose_ - lat_.rest;
    larap::transfer(lat_, b, V_, disp, out);
    stats.ms_transfer += ms_since(t0);
  }

  CellCorners corners_of(int64_t c) const { return {pose_.data(), lat_.rest.data(), lat_.cell_nodes[size_t(c)]}; }

  // New rotations from the current pose. with_energy: first store in cell_energy_ each copy's
  // energy of the current pose with the rotation it had (the state after the last global step).
  // A coupled branch copy fits its rotation to w_b S_b plus each coupling's weight times its trunk
  // copy's S, and its energy counts the trunk's edges under its rotation too.
  void rotations(bool with_energy) {
    parallel_for(lat_.num_cells(), [&](int64_t c) {
      if (couplings_.begin(c) < couplings_.end(c)) return;  // below
      double S[9];
      const double e = cell_covariance(corners_of(c), with_energy, R_[size_t(c)].data(), S);
      if (with_energy) cell_energy_[size_t(c)] = cell_weight_of(lat_, c) * e;
      R_[size_t(c)] = best_rotation_fast(Eigen::Map<const Rotation>(S));
    }, 256);
    parallel_for(int64_t(couplings_.branches.size()), [&](int64_t k) {
      const int32_t b = couplings_.branches[size_t(k)];
      double S[9], St[9], total[9];
      const double wb = cell_weight_of(lat_, b);
      double e = wb * cell_covariance(corners_of(b), with_energy, R_[size_t(b)].data(), S);
      for (int t = 0; t < 9; ++t) total[t] = wb * S[t];
      for (int32_t j = couplings_.begin(b); j < couplings_.end(b); ++j) {
        const double w = couplings_.weight[size_t(j)];
        e += w * cell_covariance(corners_of(couplings_.trunk[size_t(j)]), with_energy, R_[size_t(b)].data(), St);
        for (int t = 0; t < 9; ++t) total[t] += w * St[t];
      }
      if (with_energy) cell_energy_[size_t(b)] = e;
      R_[size_t(b)] = best_rotation_fast(Eigen::Map<const Rotation>(total));
    }, 64);
  }

  // Scaled total: node energies summed in a fixed order (deterministic) plus the handle term and
  // the ties, c~^T (M + T) c~ - 2 c~ . H~ + K~ (handle_system.h).
  double finish_energy() {
    double arap = 0.0;
    for (double e : cell_energy_) arap += e;
    double total = hs_.gamma_eff * arap;
    for (int64_t i = 0; i < nr_; ++i)
      if (hs_.anchored[i]) total += hs_.anchor_weight * (pose_.row(i) - lat_.rest.row(i)).squaredNorm();
    const RowMatrixX3d Pc = pose_.topRows(nr_).rowwise() - hs_.origin.transpose();
    RowMatrixX3d MP = M_ * Pc;
    if (G_.nonZeros() > 0) MP += G_ * Pc;
    double handles = (Pc.array() * (MP - 2.0 * H_.topRows(nr_)).array()).sum();
    for (double k : K_) handles += k;
    return (total + std::max(handles, 0.0)) * hs_.energy_scale;
  }

  void right_hand_side(const RowMatrixX3d& Btt) {
    const auto& C = lat_.rest;
    const double g = hs_.gamma_eff, a = hs_.anchor_weight;
    parallel_for(nr_, [&](int64_t i) {
      double arap[3] = {0.0, 0.0, 0.0};
      for (int32_t k = node_cells_.offsets[size_t(i)]; k < node_cells_.offsets[size_t(i) + 1]; ++k) {
        const auto& sk = node_cells_.s[size_t(k)];
        const double sv[3] = {sk[0], sk[1], sk[2]};
        cell_rhs_add(R_[size_t(node_cells_.cell[size_t(k)])].data(), sv, arap);
      }
      Eigen::Vector3d b = g * Eigen::Vector3d(arap[0], arap[1], arap[2]) + Btt.row(i).transpose();
      if (hs_.anchored[i]) b += a * C.row(i).transpose();
      rhs_.row(i) = b.transpose();
    }, 1024);
  }

  // Energy of the current pose with the current rotations (scaled).
  double evaluate() {
    parallel_for(lat_.num_cells(), [&](int64_t c) {
      double S[9];
      double e = cell_weight_of(lat_, c) * cell_covariance(corners_of(c), true, R_[size_t(c)].data(), S);
      for (int32_t j = couplings_.begin(c); j < couplings_.end(c); ++j)
        e += couplings_.weight[size_t(j)] *
             cell_covariance(corners_of(couplings_.trunk[size_t(j)]), true, R_[size_t(c)].data(), S);
      cell_energy_[size_t(c)] = e;
    }, 1024);
    return finish_energy();
  }

  const Lattice& lat_;
  const RowMatrixX3d& V_;
  const int64_t nr_;  // real nodes: the unknowns of the system
  RowMatrixX3d pose_;  // #N by 3: real nodes, then the stencil shell (Lattice::fill_shell)
  std::vector<Rotation> R_;            // per cell copy
  NodeCells node_cells_;               // the right-hand side's gather (node_cells.h)
  std::vector<double> cell_energy_;    // w_c e_c per cell copy (with its couplings' terms)
  BranchCouplings couplings_;          // the couplings by branch copy (node_cells.h)
  HandleSystem hs_;
  Eigen::SparseMatrix<double> M_;  // B^T diag(alpha) B (the warm start's moments)
  Eigen::SparseMatrix<double> G_;  // the ties: glue and braces (the system and the energy)
  RowMatrixX3d rest_pc_, rest_mp_;  // the rest lattice's real rows less hs_.origin, and M times them
  RowMatrixX3d H_;                 // H~ of the current targets
  std::vector<double> K_;          // K~ per component
  bool targets_set_ = false;
  std::unique_ptr<Factor> llt_;
  Eigen::MatrixX3d rhs_;
};

}  // namespace

std::unique_ptr<Backend> make_cpu_backend(const Lattice& lattice, const RowMatrixX3d& vertices) {
  return std::make_unique<CpuBackend>(lattice, vertices);
}

}  // namespace larap
