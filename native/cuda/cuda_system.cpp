// The CUDA backend's lattice system per handle set (CudaBackend::set_handles): A = ARAP + handle
// term, split into diagonal, the 6 neighbour slots and a CSR remainder (system.h), the handle
// term's per-node entries, the moment chunks of the rigid start (handles.h) and the multigrid
// set-up's upload (multigrid.h).
#ifdef LARAP_WITH_CUDA
#include <cuda_runtime.h>
#include <larap/errors.h>

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <algorithm>
#include <vector>

#include "cuda_backend.h"
#include "handles.h"
#include "multigrid.h"

namespace larap {

void CudaBackend::set_handles(const HandleSystem& hs) {
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
  SpR Mh = handle_matrix(hs, n);  // B^T diag(alpha) B: the warm start's moments
  Mh.makeCompressed();
  SpR M = Mh;
  if (hs.has_ties()) M += SpR(tie_matrix(hs, n));  // and the glue of carried parts, the braces
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
  if (!hs.has_ties()) {  // the warm start's moments read M without the glue and the braces
    moment_chunks_.m_off = sys_.m_off;
    moment_chunks_.m_col = sys_.m_col;
    moment_chunks_.m_val = sys_.m_val;
  } else {  // `Mh` lives until the stream is synchronised below
    moment_chunks_.m_off = mh_off_.upload(Mh.outerIndexPtr(), size_t(n) + 1, stream_);
    moment_chunks_.m_col = mh_col_.upload(Mh.innerIndexPtr(), size_t(Mh.nonZeros()), stream_);
    moment_chunks_.m_val = mh_val_.upload(Mh.valuePtr(), size_t(Mh.nonZeros()), stream_);
  }
  comp_.upload(hs.node_component.data(), size_t(n_all_), stream_);  // carried parts: the carrier's
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
    mg = cuda::build_multigrid(lat_, A, lam_max_, opt_.mg_coarse_max, opt_.mg_levels, cuda::kApSlots);
    upload_multigrid(mg);
  }
  LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
  ready_ = true;
}

void CudaBackend::upload_moment_chunks(const HandleSystem& hs) {
  const int nc = std::max(hs.num_components, 0);
  std::vector<int> count(size_t(nc) + 1, 0);
  for (int i = 0; i < n_; ++i)
    if (hs.q[size_t(i)] > 0.0) ++count[size_t(hs.node_component[size_t(i)]) + 1];
  for (int c = 0; c < nc; ++c) count[size_t(c) + 1] += count[size_t(c)];
  mc_nodes_host_.assign(size_t(count[size_t(nc)]), 0);
  std::vector<int> fill(count.begin(), count.end() - 1);
  for (int i = 0; i < n_; ++i)
    if (hs.q[size_t(i)] > 0.0) mc_nodes_host_[size_t(fill[size_t(hs.node_component[size_t(i)])]++)] = i;
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
  mom_partial_.reserve(size_t(2 * cuda::kMomentValues) * std::max(moment_chunks_.chunks, 1));  // pose, rest
  mom_out_.reserve(size_t(2 * cuda::kMomentValues) * std::max(nc, 1));
  h_moments_.reserve(size_t(2 * cuda::kMomentValues) * std::max(nc, 1));
}

void CudaBackend::upload_multigrid(const cuda::Multigrid& mg) {
  // Default inner iterations: two PCG steps per flip-flop on every hierarchy. One step with the
  // exact 2x2x2 coarse solve was the default until 2026-11-24 (it reached a small pose's quality
  // in fewer flip-flop costs), but a large move solved at once lagged: a hand bent 90 degrees at
  // the wrist left its fingers 4.7% of the hand off the rigid turn after 30 flip-flops (two steps
  // and the CPU: 0.07%; docs/cuda.md, "Options").
  sys_.nc = mg.nc;
  sys_.agg = agg_.upload(mg.agg.data(), mg.agg.size(), stream_);
  // A P: the coarse correction's gather (mg_c_node) reads zc through it, two loads deep.
  sys_.ap_col = ap_col_.upload(mg.ap.col.data(), mg.ap.col.size(), stream_);
  sys_.ap_val = ap_val_.upload(mg.ap.val.data(), mg.ap.val.size(), stream_);
  sys_.ap_off = ap_off_.upload(mg.ap.rem_off.data(), mg.ap.rem_off.size(), stream_);
  sys_.ap_rcol = ap_rcol_.upload(mg.ap.rem_col.data(), mg.ap.rem_col.size(), stream_);
  sys_.ap_rval = ap_rval_.upload(mg.ap.rem_val.data(), mg.ap.rem_val.size(), stream_);
  sys_.sm = sm_.reserve(size_t(n_));
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

}  // namespace larap
#endif  // LARAP_WITH_CUDA
