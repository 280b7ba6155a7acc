// CUDA backend, host side: the lattice system on the device (set up once per set_handles), the
// per-pose handle work (O(groups) on the host and in uploads: handles.h), the flip-flop loop
// (one cooperative kernel, a CUDA graph, or plain launches), and the transfer with its copy back
// into the caller's array. Around it, one file per concept: device memory and errors
// (device_memory.h), options (cuda_options.h), the multigrid set-up (multigrid.h), the kernels
// (flip_flop.h, handles.h, solvers.h, transfer.h). Design and figures: docs/cuda.md,
// docs/results-gpu.md.
#ifdef LARAP_WITH_CUDA
#include <cuda_runtime.h>
#include <larap/errors.h>

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <atomic>
#include <mutex>
#include <vector>

#include "backend.h"
#include "cuda_options.h"
#include "device_memory.h"
#include "flip_flop.h"
#include "handles.h"
#include "multigrid.h"
#include "parallel.h"
#include "solvers.h"
#include "transfer.h"
#ifdef LARAP_CUDA_EXPERIMENTS
#include "experiments/experiments.h"
#endif

namespace larap {
namespace {

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// memcpy of large blocks in pieces of 1 MiB over the engine's threads (parallel.h).
void parallel_copy(void* dst, const void* src, size_t bytes) {
  constexpr size_t piece = size_t(1) << 20;
  if (bytes < 4 * piece) {
    std::memcpy(dst, src, bytes);
    return;
  }
  const int64_t pieces = int64_t((bytes + piece - 1) / piece);
  const auto copy_piece = [&](int64_t k) {
    const size_t off = size_t(k) * piece;
    std::memcpy(static_cast<char*>(dst) + off, static_cast<const char*>(src) + off,
                std::min(piece, bytes - off));
  };
  parallel_for(pieces, copy_piece, 1);
}

// ------------------------------------------------------------------ the backend
class CudaBackend final : public Backend {
 public:
  CudaBackend(const Lattice& lattice, const RowMatrixX3d& vertices) : lat_(lattice), V_(vertices) {
    n_all_ = int(lattice.num_nodes());
    n_ = int(lattice.num_real_nodes());  // the unknowns; the stencil shell follows them
    origin_ = 0.5 * (lattice.rest.colwise().minCoeff() + lattice.rest.colwise().maxCoeff()).transpose();
    std::vector<float4> rest(static_cast<size_t>(n_all_));
    for (int i = 0; i < n_all_; ++i) rest[i] = to_f4(lattice.rest.row(i).transpose());
    sys_.n = n_;
    sys_.n_all = n_all_;
    sys_.rest = rest_.upload(rest.data(), rest.size(), stream_);
    sys_.x = x_.upload(rest.data(), rest.size(), stream_);
    {  // neighbour table: the first neighbour in each direction in its slot, the others (split
       // cells) in the extra list (lattice edges are axis-aligned unit steps)
      nbr_host_.assign(size_t(6) * n_, 0);
      for (int i = 0; i < n_; ++i)
        for (int d = 0; d < 6; ++d) nbr_host_[size_t(d) * n_ + i] = i;
      std::vector<int> xoff(size_t(n_) + 1, 0), extra;
      for (int i = 0; i < n_; ++i) {
        for (int k = lattice.adj_offsets[i]; k < lattice.adj_offsets[i + 1]; ++k) {
          const int j = lattice.adj[k];
          if (j < 0 || j >= n_) throw DeviceError("lattice edge to a node that is not real");
          const int d = nbr_slot(lattice.node_coords[size_t(i)], lattice.node_coords[size_t(j)]);
          if (d < 0) throw DeviceError("lattice edge is not an axis-aligned unit step");
          int& slot = nbr_host_[size_t(d) * n_ + i];
          if (slot == i)
            slot = j;
          else
            extra.push_back(j);
        }
        xoff[size_t(i) + 1] = int(extra.size());
      }
      sys_.nbr = nbr_.upload(nbr_host_.data(), nbr_host_.size(), stream_);
      sys_.nbx_off = nbx_off_.upload(xoff.data(), xoff.size(), stream_);
      sys_.nbx = nbx_.upload(extra.data(), extra.size(), stream_);
    }
    {  // the stencil shell's weights (Lattice::fill_shell)
      std::vector<float> w(lattice.shell_weights.size());
      for (size_t e = 0; e < w.size(); ++e) w[e] = float(lattice.shell_weights[e]);
      shell_off_.upload(lattice.shell_offsets.data(), lattice.shell_offsets.size(), stream_);
      shell_ids_.upload(lattice.shell_ids.data(), lattice.shell_ids.size(), stream_);
      shell_w_.upload(w.data(), w.size(), stream_);
      LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));  // `w` may go
    }
    comp_.upload(lattice.component.data(), lattice.component.size(), stream_);
    sys_.p = p_.reserve(n_);
    sys_.r[0] = r_[0].reserve(n_);
    sys_.r[1] = r_[1].reserve(n_);
    sys_.w[0] = w_[0].reserve(n_);
    sys_.w[1] = w_[1].reserve(n_);
    sys_.s[0] = s_[0].reserve(n_);
    sys_.s[1] = s_[1].reserve(n_);
    sys_.x_tmp = xtmp_.reserve(n_);
    sys_.rot = rot_.reserve(size_t(9) * n_);
    disp_.reserve(n_all_);
    sys_.iter = iter_.reserve(1);
    configure();
    LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.p, 0, sizeof(float4) * n_, stream_));
    std::vector<float> eye(static_cast<size_t>(9 * n_), 0.f);
    for (int i = 0; i < n_; ++i)
      eye[0 * size_t(n_) + i] = eye[4 * size_t(n_) + i] = eye[8 * size_t(n_) + i] = 1.f;
    LARAP_CUDA_CHECK(
        cudaMemcpyAsync(sys_.rot, eye.data(), eye.size() * sizeof(float), cudaMemcpyHostToDevice, stream_));
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
  }

  ~CudaBackend() override {
    graph_.reset();
    cudaStreamSynchronize(stream_);
    cudaGetLastError();
  }

  std::string name() const override { return "cuda"; }

  // The options (cuda_options.h, from the environment) at construction and at every
  // set_handles, so that a benchmark can switch them without rebuilding the lattice.
  void configure() {
    opt_ = cuda::cuda_options_from_environment();
    inner_ = opt_.inner > 0 ? opt_.inner : (opt_.solver == cuda::Solver::Multigrid ? 2 : 8);
    graph_.reset();
    sys_.inner = inner_;
    sys_.exact_residual = opt_.exact_residual;
    sys_.dots = dots_.reserve(size_t(inner_ + 1) * 6);
    sys_.coef = coef_.reserve(size_t(inner_ + 2) * 8);
    sys_.counters = counters_.reserve(size_t(inner_ + 1));
    LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.counters, 0, sizeof(unsigned) * (inner_ + 1), stream_));
    LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.coef, 0, sizeof(float) * (inner_ + 2) * 8, stream_));
  }

  void set_handles(const HandleSystem& hs) override {
    configure();
    ready_ = false;
    targets_set_ = false;
    recentre(hs.origin);
    hs_ = hs;
    const int n = n_;
    using SpR = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;
    const auto trip = arap_triplets(lat_, hs);
    SpR A(n, n);
    A.setFromTriplets(trip.begin(), trip.end());
    SpR M = handle_matrix(hs, n);  // B^T diag(alpha) B
    M.makeCompressed();
    A = SpR(A + M);
    A.makeCompressed();

    std::vector<float> aval(A.nonZeros()), minv(size_t(n), 1.f);
    Eigen::VectorXd diag = Eigen::VectorXd::Ones(n);
    for (int i = 0; i < n; ++i)
      for (int q = A.outerIndexPtr()[i]; q < A.outerIndexPtr()[i + 1]; ++q) {
        aval[q] = float(A.valuePtr()[q]);
        if (A.innerIndexPtr()[q] == i) diag[i] = A.valuePtr()[q];
      }
    for (int i = 0; i < n; ++i) {
      if (!(diag[i] > 0.0)) throw DeviceError("the lattice system is not positive definite");
      minv[i] = float(1.0 / diag[i]);
    }
    {  // A split: diagonal, 6 lattice slots, remainder CSR (see system.h)
      std::vector<float> adiag(static_cast<size_t>(n), 1.f), anb(static_cast<size_t>(6) * n, 0.f), rval;
      std::vector<int> roff(size_t(n) + 1, 0), rcol;
      for (int i = 0; i < n; ++i) {
        for (int q = A.outerIndexPtr()[i]; q < A.outerIndexPtr()[i + 1]; ++q) {
          const int j = A.innerIndexPtr()[q];
          const float v = float(A.valuePtr()[q]);
          if (j == i) {
            adiag[size_t(i)] = v;
            continue;
          }
          // In a slot only if j is the neighbour the slot names (split cells: a second
          // neighbour in the same direction, or a handle coupling, goes to the remainder).
          const int d = nbr_slot(lat_.node_coords[size_t(i)], lat_.node_coords[size_t(j)]);
          if (d >= 0 && nbr_host_[size_t(d) * n + i] == j) {
            anb[size_t(d) * n + i] = v;
          } else {
            rcol.push_back(j);
            rval.push_back(v);
          }
        }
        roff[size_t(i) + 1] = int(rcol.size());
      }
      sys_.a_diag = a_diag_.upload(adiag.data(), adiag.size(), stream_);
      sys_.a_nb = a_nb_.upload(anb.data(), anb.size(), stream_);
      sys_.rem_off = rem_off_.upload(roff.data(), roff.size(), stream_);
      sys_.rem_col = rem_col_.upload(rcol.data(), rcol.size(), stream_);
      sys_.rem_val = rem_val_.upload(rval.data(), rval.size(), stream_);
    }

    graph_.reset();
    sys_.a_off = a_off_.upload(A.outerIndexPtr(), size_t(n) + 1, stream_);
    sys_.a_col = a_col_.upload(A.innerIndexPtr(), A.nonZeros(), stream_);
    sys_.a_val = a_val_.upload(aval.data(), aval.size(), stream_);
    sys_.minv = minv_.upload(minv.data(), minv.size(), stream_);
    // The handle term: M in double, q, the per-node group entries; H zero until set_targets.
    sys_.m_off = m_off_.upload(M.outerIndexPtr(), size_t(n) + 1, stream_);
    sys_.m_col = m_col_.upload(M.innerIndexPtr(), size_t(M.nonZeros()), stream_);
    sys_.m_val = m_val_.upload(M.valuePtr(), size_t(M.nonZeros()), stream_);
    sys_.q = q_.upload(hs.q.data(), hs.q.size(), stream_);
    entries_.node_off = e_off_.upload(hs.node_offsets.data(), hs.node_offsets.size(), stream_);
    entries_.group = e_group_.upload(hs.entry_group.data(), hs.entry_group.size(), stream_);
    entries_.q = e_q_.upload(hs.entry_q.data(), hs.entry_q.size(), stream_);
    entries_.P = e_P_.upload(hs.entry_P.data(), hs.entry_P.size(), stream_);
    maps_.reserve(size_t(12) * std::max<int64_t>(hs.num_groups(), 1));
    float4* h = h_.reserve(size_t(n));
    double* hd = hd_.reserve(size_t(3) * n);
    LARAP_CUDA_CHECK(cudaMemsetAsync(h, 0, sizeof(float4) * n, stream_));
    LARAP_CUDA_CHECK(cudaMemsetAsync(hd, 0, sizeof(double) * 3 * n, stream_));
    sys_.h = h;
    sys_.hd = hd;
    sys_.anchored = anch_.upload(hs.anchored.data(), hs.anchored.size(), stream_);
    sys_.g = float(hs.gamma_eff);
    sys_.a = float(hs.anchor_weight);
    K_.assign(size_t(hs.num_components), 0.0);
    K_total_ = 0.0;
    upload_moment_chunks(hs);
    motions_.reserve(size_t(16) * std::max(hs.num_components, 1));

    // Smoothing weight (mg) / Chebyshev bounds: lambda_max of D^-1 A.
    if (opt_.solver != cuda::Solver::Pcg) {
      lam_max_ = cuda::jacobi_lambda_max(A, diag);
      lam_min_ = lam_max_ / opt_.cheby_ratio;
    }
    sys_.nc = 0;
    sys_.nc2 = 0;
    cuda::Multigrid mg;  // host arrays: live until the stream is synchronised below
    if (opt_.solver == cuda::Solver::Multigrid) {
      mg = cuda::build_multigrid(lat_, A, lam_max_, opt_.mg_coarse_max, opt_.mg_levels);
      upload_multigrid(mg);
    }
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    ready_ = true;
  }

  // The handle nodes (q_i > 0) by lattice component, in chunks of at most one block, for the
  // moments' reduction (handles.h).
  void upload_moment_chunks(const HandleSystem& hs) {
    const int nc = std::max(hs.num_components, 0);
    std::vector<int> count(size_t(nc) + 1, 0);
    for (int i = 0; i < n_; ++i)
      if (hs.q[size_t(i)] > 0.0) ++count[size_t(lat_.component[size_t(i)]) + 1];
    for (int c = 0; c < nc; ++c) count[size_t(c) + 1] += count[size_t(c)];
    mc_nodes_host_.assign(size_t(count[size_t(nc)]), 0);
    std::vector<int> fill(count.begin(), count.end() - 1);
    for (int i = 0; i < n_; ++i)
      if (hs.q[size_t(i)] > 0.0) mc_nodes_host_[size_t(fill[size_t(lat_.component[size_t(i)])]++)] = i;
    mc_chunk_off_host_.assign(1, 0);
    mc_comp_off_host_.assign(1, 0);
    for (int c = 0; c < nc; ++c) {
      for (int b = count[size_t(c)]; b < count[size_t(c) + 1]; b += cuda::kMomentBlock)
        mc_chunk_off_host_.push_back(std::min(b + cuda::kMomentBlock, count[size_t(c) + 1]));
      mc_comp_off_host_.push_back(int(mc_chunk_off_host_.size()) - 1);
    }
    moment_chunks_.chunks = int(mc_chunk_off_host_.size()) - 1;
    moment_chunks_.components = nc;
    moment_chunks_.nodes = mc_nodes_.upload(mc_nodes_host_.data(), mc_nodes_host_.size(), stream_);
    moment_chunks_.chunk_off = mc_chunk_off_.upload(mc_chunk_off_host_.data(), mc_chunk_off_host_.size(), stream_);
    moment_chunks_.comp_chunk_off = mc_comp_off_.upload(mc_comp_off_host_.data(), mc_comp_off_host_.size(), stream_);
    mom_partial_.reserve(size_t(cuda::kMomentValues) * std::max(moment_chunks_.chunks, 1));
    mom_out_.reserve(size_t(cuda::kMomentValues) * std::max(nc, 1));
    h_moments_.reserve(size_t(cuda::kMomentValues) * std::max(nc, 1));
  }

  void upload_multigrid(const cuda::Multigrid& mg) {
    // Default inner iterations: with 2x2x2 aggregates and a dense inverse of them (two levels)
    // one PCG step per flip-flop reaches quality sooner than two (more flip-flops, each cheaper);
    // coarser two-level and three-level: two (one needs 2-3x the flip-flops; docs/results-gpu.md).
    if (opt_.inner == 0 && !mg.three_levels && mg.shift == 1 && inner_ != 1) {
      inner_ = 1;
      sys_.inner = 1;
      graph_.reset();
    }
    sys_.nc = mg.nc;
    sys_.agg = agg_.upload(mg.agg.data(), mg.agg.size(), stream_);
    sys_.rc = rc_.reserve(size_t(inner_) * mg.nc);
    sys_.zc = zc_.reserve(size_t(mg.nc));
    sys_.z = sys_.x_tmp;
    sys_.aq = sys_.w[0];
    sys_.pb[0] = sys_.s[0];
    sys_.pb[1] = sys_.s[1];
    sys_.omega = mg.omega;
    sys_.ainv = ainv_.upload(mg.ainv.data(), mg.ainv.size(), stream_);
    sys_.nc2 = mg.nc2;
    if (!mg.three_levels) return;
    sys_.agg2 = agg2_.upload(mg.agg2.data(), mg.agg2.size(), stream_);
    sys_.c_off = c_off_.upload(mg.c_off.data(), mg.c_off.size(), stream_);
    sys_.c_col = c_col_.upload(mg.c_col.data(), mg.c_col.size(), stream_);
    sys_.c_val = c_val_.upload(mg.c_val.data(), mg.c_val.size(), stream_);
    sys_.c_minv = c_minv_.upload(mg.c_minv.data(), mg.c_minv.size(), stream_);
    sys_.omega1 = mg.omega1;
    sys_.rc2 = rc2_.reserve(size_t(inner_) * mg.nc2);
    sys_.zc2 = zc2_.reserve(size_t(mg.nc2));
  }

  // The real rows of `nodes` (#N by 3); the shell follows them (as the CPU's fill_shell).
  void set_pose(const RowMatrixX3d& nodes) override {
    if (nodes.rows() < n_) throw InvalidInput("set_pose: fewer rows than the lattice's real nodes");
    std::vector<float4> h(static_cast<size_t>(n_));
    for (int i = 0; i < n_; ++i) h[i] = to_f4(nodes.row(i).transpose());
    LARAP_CUDA_CHECK(
        cudaMemcpyAsync(sys_.x, h.data(), h.size() * sizeof(float4), cudaMemcpyHostToDevice, stream_));
    fill_shell();
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
  }

  void get_pose(RowMatrixX3d& nodes) const override {
    std::vector<float4> h(static_cast<size_t>(n_all_));
    LARAP_CUDA_CHECK(
        cudaMemcpyAsync(h.data(), sys_.x, h.size() * sizeof(float4), cudaMemcpyDeviceToHost, stream_));
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    nodes.resize(n_all_, 3);
    for (int i = 0; i < n_all_; ++i) nodes.row(i) = from_f4(h[i]).transpose();
  }

  // H and K of a pose. Group maps: G maps uploaded, H formed on the device from the per-node
  // entries, K from the group moments on the host (O(groups x components)). Row targets: H and
  // K on the host (O(m)), H uploaded.
  void set_targets(const HandleTargets& targets) override {
    if (!ready_) throw StateError("set_handles must come before set_targets");
    const int n = n_;
    if (targets.rows) {
      handle_rhs(hs_, targets, H_rows_, K_);
      std::vector<float4>& h = h_rows_;
      h.resize(size_t(n));
      for (int i = 0; i < n; ++i)
        h[size_t(i)] = make_float4(float(H_rows_(i, 0)), float(H_rows_(i, 1)), float(H_rows_(i, 2)), 0.f);
      LARAP_CUDA_CHECK(cudaMemcpyAsync(h_.get(), h.data(), sizeof(float4) * n, cudaMemcpyHostToDevice, stream_));
      // H_rows_ is #N by 3 row-major: its first n rows are the real nodes' (the shell has none).
      LARAP_CUDA_CHECK(cudaMemcpyAsync(hd_.get(), H_rows_.data(), sizeof(double) * 3 * n, cudaMemcpyHostToDevice,
                                       stream_));
    } else {
      if (!targets.groups) throw StateError("handle targets: neither rows nor group maps");
      const int64_t G = hs_.num_groups();
      std::vector<double>& maps = h_maps_;
      maps.resize(size_t(12) * G);
      const GroupMaps gm = group_maps(hs_, targets.groups);
      for (int64_t g = 0; g < G; ++g) {
        for (int k = 0; k < 9; ++k) maps[size_t(12 * g + k)] = gm.A[g](k / 3, k % 3);
        for (int k = 0; k < 3; ++k) maps[size_t(12 * g + 9 + k)] = gm.b[g][k];
      }
      if (G > 0)
        LARAP_CUDA_CHECK(cudaMemcpyAsync(maps_.get(), maps.data(), sizeof(double) * maps.size(),
                                         cudaMemcpyHostToDevice, stream_));
      cuda::launch_group_rhs(sys_, entries_, maps_.get(), h_.get(), hd_.get(), stream_);
      LARAP_CUDA_CHECK(cudaGetLastError());
      group_constants(hs_, gm, K_);
    }
    K_total_ = 0.0;
    for (double k : K_) K_total_ += k;
    targets_set_ = true;
  }

  // Per lattice component: a device reduction over the handle nodes, O(components) downloaded.
  void moments(bool rest, std::vector<ComponentMoments>& out) override {
    if (!ready_ || !targets_set_) throw StateError("set_handles and set_targets must come before moments");
    const int nc = moment_chunks_.components;
    cuda::launch_moments(sys_, rest ? sys_.rest : sys_.x, moment_chunks_, mom_partial_.get(), mom_out_.get(),
                         stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    const size_t nv = size_t(cuda::kMomentValues) * nc;
    double* h = h_moments_.get();
    if (nv)
      LARAP_CUDA_CHECK(cudaMemcpyAsync(h, mom_out_.get(), sizeof(double) * nv, cudaMemcpyDeviceToHost, stream_));
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    out.assign(size_t(nc), ComponentMoments{});
    for (int c = 0; c < nc; ++c) {
      const double* v = h + size_t(cuda::kMomentValues) * c;
      ComponentMoments& m = out[size_t(c)];
      m.w = v[0];
      m.p = Eigen::Vector3d(v[1], v[2], v[3]);
      m.t = Eigen::Vector3d(v[4], v[5], v[6]);
      for (int k = 0; k < 9; ++k) {
        m.pt(k / 3, k % 3) = v[7 + k];
        m.pp(k / 3, k % 3) = v[16 + k];
      }
      m.tt = K_[size_t(c)];
    }
  }

  // Per lattice component x -> R x + t (centred frame, as the moments), one kernel.
  void apply_rigid(const std::vector<ComponentMotion>& motions, bool from_rest) override {
    if (!ready_) throw StateError("set_handles must come before apply_rigid");
    const int nc = moment_chunks_.components;
    std::vector<float>& m = h_motions_;
    m.assign(size_t(16) * nc, 0.f);
    bool any = false;
    for (int c = 0; c < nc && size_t(c) < motions.size(); ++c) {
      const ComponentMotion& mo = motions[size_t(c)];
      if (!mo.active) continue;
      any = true;
      float* r = &m[size_t(16) * c];
      for (int k = 0; k < 9; ++k) r[k] = float(mo.R(k / 3, k % 3));
      for (int k = 0; k < 3; ++k) r[9 + k] = float(mo.t[k]);
      r[12] = 1.f;
    }
    if (!any) return;
    LARAP_CUDA_CHECK(
        cudaMemcpyAsync(motions_.get(), m.data(), sizeof(float) * m.size(), cudaMemcpyHostToDevice, stream_));
    cuda::launch_component_rigid(sys_, comp_.get(), motions_.get(), from_rest, stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    fill_shell();
  }

  void iterate(int iterations, SolveStats& stats) override {
    if (!ready_ || !targets_set_) throw StateError("set_handles and set_targets must come before iterate");
    if (iterations <= 0) return;
    set_energy_buffer(size_t(2) * iterations);
    h_energy_.reserve(size_t(2) * iterations);
    LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.iter, 0, sizeof(int), stream_));
    LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.energy, 0, sizeof(double) * 2 * iterations, stream_));
    const bool profile = !opt_.profile_path.empty();
    double ms_rot = 0, ms_rhs = 0, ms_sol = 0;
    LARAP_CUDA_CHECK(cudaEventRecord(ev_[0].get(), stream_));
    if (profile) {
      for (int it = 0; it < iterations; ++it) {
        LARAP_CUDA_CHECK(cudaEventRecord(ev_[0].get(), stream_));
        cuda::launch_rotations(sys_, true, -1, stream_);
        LARAP_CUDA_CHECK(cudaGetLastError());
        LARAP_CUDA_CHECK(cudaEventRecord(ev_[1].get(), stream_));
        cuda::launch_rhs(sys_, opt_.solver == cuda::Solver::Pcg || opt_.solver == cuda::Solver::Multigrid,
                         stream_);
        LARAP_CUDA_CHECK(cudaGetLastError());
        LARAP_CUDA_CHECK(cudaEventRecord(ev_[2].get(), stream_));
        launch_solver();
        LARAP_CUDA_CHECK(cudaEventRecord(ev_[3].get(), stream_));
        LARAP_CUDA_CHECK(cudaEventSynchronize(ev_[3].get()));
        ms_rot += cuda::elapsed_ms(ev_[0], ev_[1]);
        ms_rhs += cuda::elapsed_ms(ev_[1], ev_[2]);
        ms_sol += cuda::elapsed_ms(ev_[2], ev_[3]);
      }
      LARAP_CUDA_CHECK(cudaEventRecord(ev_[0].get(), stream_));
    } else if (opt_.solver == cuda::Solver::Multigrid && opt_.fused && fused_blocks() > 0) {
      // One cooperative launch for all flip-flops (energy of flip-flop it - 1 in its rotation
      // phase, as in the graph); at most kFusedChunk flip-flops a launch.
      constexpr int kFusedChunk = 64;
      for (int it0 = 0; it0 < iterations; it0 += kFusedChunk) {
        cuda::System sc = sys_;
        sc.energy = sys_.energy + 2 * it0;
        const int cnt = std::min(kFusedChunk, iterations - it0);
        if (it0 > 0) {  // the first rotation phase of this chunk adds flip-flop it0 - 1's energy
          cuda::launch_rotations(sys_, false, it0 - 1, stream_);
          LARAP_CUDA_CHECK(cudaGetLastError());
        }
        LARAP_CUDA_CHECK(cuda::launch_mg_fused(sc, cnt, fused_blocks(), stream_));
      }
    } else if (opt_.graph) {
      if (!graph_.get()) build_graph();
      for (int it = 0; it < iterations; ++it) LARAP_CUDA_CHECK(cudaGraphLaunch(graph_.get(), stream_));
    } else {
      for (int it = 0; it < iterations; ++it) flip_flop();
    }
    cuda::launch_rotations(sys_, false, iterations - 1, stream_);  // energy of the last pose
    LARAP_CUDA_CHECK(cudaGetLastError());
    fill_shell();
    LARAP_CUDA_CHECK(cudaEventRecord(ev_[1].get(), stream_));
    LARAP_CUDA_CHECK(cudaMemcpyAsync(h_energy_.get(), sys_.energy, sizeof(double) * 2 * iterations,
                                     cudaMemcpyDeviceToHost, stream_));
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    const double loop_ms = cuda::elapsed_ms(ev_[0], ev_[1]);
    for (int it = 0; it < iterations; ++it)
      stats.energy.push_back(total_energy(h_energy_.get()[2 * it], h_energy_.get()[2 * it + 1]));
    if (profile) {
      stats.ms_rotations += ms_rot + loop_ms;  // + the final energy pass
      stats.ms_rhs += ms_rhs;
      stats.ms_solve += ms_sol;
      write_profile(
          "iterate", iterations,
          {{"ms_rotations", ms_rot}, {"ms_rhs", ms_rhs}, {"ms_solve", ms_sol}, {"ms_final_energy", loop_ms}});
    } else {
      // One graph per flip-flop: the stages are not timed apart; the loop's device time is
      // reported as solve time (docs/cuda.md).
      stats.ms_solve += loop_ms;
    }
  }

  double energy() override {
    if (!ready_ || !targets_set_) throw StateError("set_handles and set_targets must come before energy");
    set_energy_buffer(2);
    LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.energy, 0, sizeof(double) * 2, stream_));
    cuda::launch_rotations(sys_, true, -2, stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    cuda::launch_rotations(sys_, false, 0, stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    double e[2] = {0.0, 0.0};
    LARAP_CUDA_CHECK(cudaMemcpyAsync(e, sys_.energy, sizeof(e), cudaMemcpyDeviceToHost, stream_));
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    return total_energy(e[0], e[1]);
  }

  void transfer(const Binding& b, double* out, SolveStats& stats) override { transfer_any(b, out, stats); }

  // The transfer into the device output buffer, left there (no copy to the host).
  const float* transfer_on_device(const Binding& b, SolveStats& stats) override {
    const auto t0 = Clock::now();
    const int64_t nv = b.num_vertices();
    DevBinding& d = device_binding(b);
    const float* V = device_vertices(static_cast<float*>(nullptr));
    float* dout = device_out(static_cast<float*>(nullptr), size_t(3 * nv));
    cuda::launch_displacement(sys_, disp_.get(), stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    launch_transfer(b, d, 0, nv, V, dout);
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));  // consumers on other streams may read it now
    stats.ms_transfer += ms_since(t0);
    return dout;
  }
  void transfer(const Binding& b, float* out, SolveStats& stats) override { transfer_any(b, out, stats); }

 private:
  // Slot of j among i's lattice neighbours (-x,+x,-y,+y,-z,+z), or -1 if not a unit step.
  static int nbr_slot(const Eigen::Vector3i& ci, const Eigen::Vector3i& cj) {
    const Eigen::Vector3i d = cj - ci;
    if (d.cwiseAbs().sum() != 1) return -1;
    for (int a = 0; a < 3; ++a)
      if (d[a] != 0) return 2 * a + (d[a] > 0 ? 1 : 0);
    return -1;
  }
  // The stencil shell's rows of x from the real rows (after every change of the real rows).
  void fill_shell() {
    if (n_all_ == n_) return;
    cuda::launch_fill_shell(sys_, shell_off_.get(), shell_ids_.get(), shell_w_.get(), stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
  }

  float4 to_f4(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d c = p - origin_;
    return make_float4(float(c.x()), float(c.y()), float(c.z()), 0.f);
  }
  Eigen::Vector3d from_f4(const float4& p) const { return Eigen::Vector3d(p.x, p.y, p.z) + origin_; }

  // The graph holds the buffer's address: a new buffer needs a new graph.
  void set_energy_buffer(size_t n) {
    double* e = energy_.reserve(std::max<size_t>(n, 256));
    if (e != sys_.energy) {
      sys_.energy = e;
      graph_.reset();
    }
  }

  // Scaled energy from the device's two sums of one flip-flop: ARAP + anchors, and the handle
  // term without K (c.(M c - 2 H)), as the CPU backend forms it.
  double total_energy(double arap, double handles) const {
    return (arap + std::max(handles + K_total_, 0.0)) * hs_.energy_scale;
  }

  // Moves the device frame to `o` (the handle system's origin), keeping the pose.
  void recentre(const Eigen::Vector3d& o) {
    if (o == origin_) return;
    RowMatrixX3d pose;
    get_pose(pose);
    origin_ = o;
    std::vector<float4> rest(static_cast<size_t>(n_all_));
    for (int i = 0; i < n_all_; ++i) rest[size_t(i)] = to_f4(lat_.rest.row(i).transpose());
    rest_.upload(rest.data(), rest.size(), stream_);
    set_pose(pose);  // synchronises: `rest` may go
  }

  void launch_solver() {
    if (opt_.solver == cuda::Solver::Multigrid) {
      for (int k = 0; k < inner_; ++k) {
        cuda::launch_mg_iteration(sys_, k, stream_);
        LARAP_CUDA_CHECK(cudaGetLastError());
      }
      cuda::launch_mg_final(sys_, stream_);
      LARAP_CUDA_CHECK(cudaGetLastError());
      return;
    }
#ifdef LARAP_CUDA_EXPERIMENTS
    cuda::launch_experimental_solver(sys_, opt_.solver, inner_, lam_min_, lam_max_, stream_);
#endif
  }

  // Blocks for the fused kernel (0: no cooperative launch possible).
  int fused_blocks() {
    if (coop_max_ < 0) coop_max_ = cuda::mg_fused_max_blocks();
    if (coop_max_ <= 0) return 0;
    int dev = 0, sms = 1;
    LARAP_CUDA_CHECK(cudaGetDevice(&dev));
    LARAP_CUDA_CHECK(cudaDeviceGetAttribute(&sms, cudaDevAttrMultiProcessorCount, dev));
    int b = opt_.coop_blocks > 0 ? opt_.coop_blocks : std::max((n_ + 255) / 256, sms);
    return std::clamp(b, 1, coop_max_);
  }

  void flip_flop() {
    cuda::launch_rotations(sys_, true, -1, stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    cuda::launch_rhs(sys_, opt_.solver == cuda::Solver::Pcg || opt_.solver == cuda::Solver::Multigrid,
                     stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    launch_solver();
  }

  void build_graph() {
    cudaGraph_t g = nullptr;
    LARAP_CUDA_CHECK(cudaStreamBeginCapture(stream_, cudaStreamCaptureModeThreadLocal));
    try {
      flip_flop();
    } catch (...) {
      cudaStreamEndCapture(stream_, &g);
      if (g) cudaGraphDestroy(g);
      cudaGetLastError();
      throw;
    }
    LARAP_CUDA_CHECK(cudaStreamEndCapture(stream_, &g));
    cudaGraphExec_t exec = nullptr;
    const cudaError_t e = cudaGraphInstantiate(&exec, g, 0);
    cudaGraphDestroy(g);
    if (e != cudaSuccess) cuda::fail(e, "cudaGraphInstantiate");
    graph_.set(exec);
  }

  struct DevBinding {
    const Binding* key = nullptr;
    int64_t nv = -1;
    cuda::DeviceBuffer<int> table;
    cuda::DeviceBuffer<float4> packed;  // (base id as int bits, 3 fractions)
  };

  DevBinding& device_binding(const Binding& b) {
    DevBinding& d = bind_[b.kind == WeightKind::Trilinear ? 0 : 1];
    if (d.key == &b && d.nv == b.num_vertices()) return d;
    d.key = nullptr;
    {
      const int64_t nv = b.num_vertices();
      std::vector<float4> pk(static_cast<size_t>(nv));
      for (int64_t v = 0; v < nv; ++v) {
        int32_t id = int32_t(b.base[size_t(v)]);
        float fb;
        std::memcpy(&fb, &id, sizeof(fb));
        pk[size_t(v)] = make_float4(fb, float(b.frac[size_t(3 * v)]), float(b.frac[size_t(3 * v + 1)]),
                                    float(b.frac[size_t(3 * v + 2)]));
      }
      d.packed.upload(pk.data(), pk.size(), stream_);
    }
    if (b.kind == WeightKind::Trilinear) {
      static_assert(sizeof(lat_.cell_nodes[0]) == 8 * sizeof(int32_t), "cell_nodes layout");
      d.table.upload(reinterpret_cast<const int*>(lat_.cell_nodes.data()), lat_.cell_nodes.size() * 8,
                     stream_);
    } else {
      d.table.upload(b.node27.data(), b.node27.size(), stream_);
    }
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    d.key = &b;
    d.nv = b.num_vertices();
    return d;
  }

  const float* device_vertices(float*) {
    if (!vf_.get() || vf_n_ != V_.rows()) {
      std::vector<float> h(size_t(V_.size()));
      for (Eigen::Index k = 0; k < V_.size(); ++k) h[k] = float(V_.data()[k]);
      vf_.upload(h.data(), h.size(), stream_);
      LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
      vf_n_ = V_.rows();
    }
    return vf_.get();
  }
  const double* device_vertices(double*) {
    if (!vd_.get() || vd_n_ != V_.rows()) {
      vd_.upload(V_.data(), size_t(V_.size()), stream_);
      LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
      vd_n_ = V_.rows();
    }
    return vd_.get();
  }
  float* device_out(float*, size_t n) { return outf_.reserve(n); }
  double* device_out(double*, size_t n) { return outd_.reserve(n); }

  template <typename T>
  void launch_transfer(const Binding& b, DevBinding& d, int64_t v0, int64_t v1, const T* V, T* out) {
    const bool trilinear = b.kind == WeightKind::Trilinear;
#ifdef LARAP_CUDA_EXPERIMENTS
    if (opt_.transfer.mode != cuda::TransferKernel::Scalar) {
      cuda::launch_experimental_transfer(opt_.transfer, trilinear, v0, v1, d.packed.get(), d.table.get(),
                                         disp_.get(), V, out, stream_);
      return;
    }
#endif
    if (trilinear)
      cuda::launch_transfer_trilinear(v0, v1, d.packed.get(), d.table.get(), disp_.get(), V, out, stream_);
    else
      cuda::launch_transfer_bspline(v0, v1, d.packed.get(), d.table.get(), disp_.get(), V, out, stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
  }

  template <typename T>
  void transfer_any(const Binding& b, T* out, SolveStats& stats) {
    const auto t0 = Clock::now();
    const int64_t nv = b.num_vertices();
    if (nv == 0) return;
    DevBinding& d = device_binding(b);
    const T* V = device_vertices(static_cast<T*>(nullptr));
    T* dout = device_out(static_cast<T*>(nullptr), size_t(3 * nv));
    cuda::launch_displacement(sys_, disp_.get(), stream_);
    LARAP_CUDA_CHECK(cudaGetLastError());
    double kernel_ms = -1.0, kernel_rep_ms = -1.0;
    if (!opt_.profile_path.empty()) {  // kernel alone, timed (then the pipeline below repeats it)
      LARAP_CUDA_CHECK(cudaEventRecord(ev_[0].get(), stream_));
      launch_transfer(b, d, 0, nv, V, dout);
      LARAP_CUDA_CHECK(cudaEventRecord(ev_[1].get(), stream_));
      LARAP_CUDA_CHECK(cudaEventSynchronize(ev_[1].get()));
      kernel_ms = cuda::elapsed_ms(ev_[0], ev_[1]);
      // and the mean of kRep back-to-back launches (no launch gap between events and kernel)
      constexpr int kRep = 10;
      LARAP_CUDA_CHECK(cudaEventRecord(ev_[0].get(), stream_));
      for (int r = 0; r < kRep; ++r) launch_transfer(b, d, 0, nv, V, dout);
      LARAP_CUDA_CHECK(cudaEventRecord(ev_[1].get(), stream_));
      LARAP_CUDA_CHECK(cudaEventSynchronize(ev_[1].get()));
      kernel_rep_ms = cuda::elapsed_ms(ev_[0], ev_[1]) / kRep;
    }
    const auto t1 = Clock::now();
    copy_back(b, d, nv, V, dout, out);
    const double ms = ms_since(t0);
    stats.ms_transfer += ms;
    if (!opt_.profile_path.empty())
      write_profile("transfer", 0,
                    {{"kernel_ms", kernel_ms},
                     {"kernel_rep_ms", kernel_rep_ms},
                     {"pipeline_ms", ms_since(t1)},
                     {"total_ms", ms},
                     {"vertices", double(nv)},
                     {"bytes_out", double(sizeof(T) * 3 * nv)},
                     {"stencil", double(b.stencil_size())},
                     {"elem_size", double(sizeof(T))}});
  }

  // The transfer of vertices [0, nv) into the caller's host array `out`, as opt_.copy says
  // (cuda_options.h; measured in docs/results-gpu.md).
  template <typename T>
  void copy_back(const Binding& b, DevBinding& d, int64_t nv, const T* V, T* dout, T* out) {
    if (opt_.copy == cuda::CopyBack::Direct) {
      launch_transfer(b, d, 0, nv, V, dout);
      LARAP_CUDA_CHECK(
          cudaMemcpyAsync(out, dout, sizeof(T) * 3 * size_t(nv), cudaMemcpyDeviceToHost, stream_));
      LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
      return;
    }
    // Chunk c: kernel, copy into pinned memory, event; the host copies it on into `out`.
    T* stage = reinterpret_cast<T*>(staging_.reserve(size_t(3 * nv) * sizeof(T)));
    const int64_t chunk = opt_.copy_chunk;
    const int64_t nchunks = (nv + chunk - 1) / chunk;
    while (int64_t(chunk_ev_.size()) < nchunks) chunk_ev_.emplace_back(std::make_unique<cuda::Event>());
    for (int64_t c = 0; c < nchunks; ++c) {
      const int64_t v0 = c * chunk, v1 = std::min(nv, v0 + chunk);
      launch_transfer(b, d, v0, v1, V, dout);
      LARAP_CUDA_CHECK(cudaMemcpyAsync(stage + 3 * v0, dout + 3 * v0, sizeof(T) * 3 * (v1 - v0),
                                       cudaMemcpyDeviceToHost, stream_));
      LARAP_CUDA_CHECK(cudaEventRecord(chunk_ev_[c]->get(), stream_));
    }
    if (opt_.copy == cuda::CopyBack::Staged) {
      for (int64_t c = 0; c < nchunks; ++c) {
        const int64_t v0 = c * chunk, v1 = std::min(nv, v0 + chunk);
        LARAP_CUDA_CHECK(cudaEventSynchronize(chunk_ev_[c]->get()));
        parallel_copy(out + 3 * v0, stage + 3 * v0, sizeof(T) * 3 * (v1 - v0));
      }
      return;
    }
    // Overlap: each chunk is a task that waits for its own event, so the host copies of early
    // chunks run while later chunks are still on their way (no exception may leave a task).
    std::atomic<int> error{int(cudaSuccess)};
    parallel_for(nchunks, [&](int64_t c) {
      const cudaError_t e = cudaEventSynchronize(chunk_ev_[size_t(c)]->get());
      if (e != cudaSuccess) {
        int expected = int(cudaSuccess);
        error.compare_exchange_strong(expected, int(e));
        return;
      }
      const int64_t v0 = c * chunk, v1 = std::min(nv, v0 + chunk);
      std::memcpy(out + 3 * v0, stage + 3 * v0, sizeof(T) * 3 * size_t(v1 - v0));
    }, 1);
    if (error.load() != int(cudaSuccess)) cuda::fail(cudaError_t(error.load()), "cudaEventSynchronize");
  }

  void write_profile(const char* what, int iterations,
                     std::initializer_list<std::pair<const char*, double>> kv) {
    FILE* f = std::fopen(opt_.profile_path.c_str(), "a");
    if (!f) return;
    std::fprintf(f, "{\"what\": \"%s\", \"nodes\": %d, \"handles\": %lld, \"iterations\": %d, \"inner\": %d",
                 what, n_, static_cast<long long>(hs_.m), iterations, inner_);
    for (const auto& p : kv) std::fprintf(f, ", \"%s\": %.6g", p.first, p.second);
    std::fprintf(f, "}\n");
    std::fclose(f);
  }

  const Lattice& lat_;
  const RowMatrixX3d& V_;
  Eigen::Vector3d origin_;
  int n_ = 0;      // real nodes: the unknowns
  int n_all_ = 0;  // real + stencil shell nodes
  std::vector<int> nbr_host_;  // 6 * n_: the neighbour slots (system.h)
  cuda::CudaOptions opt_;
  int inner_ = 8;      // inner solver iterations per flip-flop (opt_.inner, or automatic)
  int coop_max_ = -1;  // most co-resident blocks of the fused kernel (-1: not asked yet)
  double lam_min_ = 0.0, lam_max_ = 2.0;
  bool ready_ = false;
  bool targets_set_ = false;
  HandleSystem hs_;
  std::vector<double> K_;  // K of the current targets, per lattice component
  double K_total_ = 0.0;
  RowMatrixX3d H_rows_;    // row targets: H on the host
  std::vector<float4> h_rows_;
  std::vector<double> h_maps_;
  std::vector<float> h_motions_;
  std::vector<int> mc_nodes_host_, mc_chunk_off_host_, mc_comp_off_host_;
  cuda::GroupEntries entries_;
  cuda::MomentChunks moment_chunks_;

  cuda::Stream stream_;  // first: destroyed after every buffer's last use
  cuda::System sys_;
  cuda::DeviceBuffer<float4> rest_, x_, p_, r_[2], w_[2], s_[2], xtmp_, disp_, h_;
  cuda::DeviceBuffer<double> hd_, q_, m_val_, e_q_, e_P_, maps_, mom_partial_, mom_out_;
  cuda::DeviceBuffer<int> comp_, m_off_, m_col_, e_off_, e_group_, mc_nodes_, mc_chunk_off_, mc_comp_off_;
  cuda::DeviceBuffer<float> motions_;
  cuda::PinnedBuffer<double> h_moments_;
  cuda::DeviceBuffer<int> agg_, nbr_, rem_off_, rem_col_;
  cuda::DeviceBuffer<float> a_diag_, a_nb_, rem_val_;
  cuda::DeviceBuffer<float> ainv_;
  cuda::DeviceBuffer<float4> rc_, zc_, rc2_, zc2_;
  cuda::DeviceBuffer<int> agg2_, c_off_, c_col_;
  cuda::DeviceBuffer<float> c_val_, c_minv_;
  cuda::DeviceBuffer<int> nbx_off_, nbx_, shell_off_, shell_ids_, a_off_, a_col_, iter_;
  cuda::DeviceBuffer<float> shell_w_;
  cuda::DeviceBuffer<float> a_val_, minv_, rot_, coef_;
  cuda::DeviceBuffer<uint8_t> anch_;
  cuda::DeviceBuffer<double> dots_, energy_;
  cuda::DeviceBuffer<unsigned> counters_;
  cuda::PinnedBuffer<double> h_energy_;
  cuda::PinnedBuffer<char> staging_;
  DevBinding bind_[2];
  cuda::DeviceBuffer<float> vf_;
  cuda::DeviceBuffer<double> vd_;
  int64_t vf_n_ = -1, vd_n_ = -1;
  cuda::DeviceBuffer<float> outf_;
  cuda::DeviceBuffer<double> outd_;
  cuda::Event ev_[4];
  std::vector<std::unique_ptr<cuda::Event>> chunk_ev_;
  cuda::GraphExec graph_;  // last: destroyed first
};

}  // namespace

std::unique_ptr<Backend> make_cuda_backend(const Lattice& lattice, const RowMatrixX3d& vertices) {
  std::string why;
  if (!cuda_available(&why)) throw DeviceError("device 'cuda' is not available: " + why);
  return std::make_unique<CudaBackend>(lattice, vertices);
}

bool cuda_available(std::string* why) {
  static std::once_flag once;
  static bool ok = false;
  static std::string reason;
  std::call_once(once, [] {
    int count = 0;
    cudaError_t e = cudaGetDeviceCount(&count);
    if (e != cudaSuccess) {
      cudaGetLastError();
      reason = std::string("no usable CUDA device (") + cudaGetErrorString(e) + ")";
      return;
    }
    if (count == 0) {
      reason = "no CUDA device found";
      return;
    }
    e = cuda::probe_kernels();
    if (e != cudaSuccess) {
      cudaGetLastError();
      reason = std::string("this build's kernels cannot run on the GPU present (") + cudaGetErrorString(e) +
               "); rebuild with CMAKE_CUDA_ARCHITECTURES for it";
      return;
    }
    ok = true;
  });
  if (!ok && why) *why = reason;
  return ok;
}

}  // namespace larap
#endif  // LARAP_WITH_CUDA
