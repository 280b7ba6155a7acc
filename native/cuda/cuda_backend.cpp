// The CUDA backend (cuda_backend.h), construction and options: the lattice, the rest pose and the
// neighbour table uploaded once per backend; the options read at construction and at every
// set_handles; the profile lines of LARAP_CUDA_PROFILE; make_cuda_backend and cuda_available.
// The other methods, one file per concept: the system per handle set (cuda_system.cpp), the
// per-pose handle work (cuda_handles_host.cpp), the flip-flop loop and the pose (cuda_iterate.cpp),
// the transfer and its copy back (cuda_copy_back.cpp). Design and figures: docs/cuda.md,
// docs/results-gpu.md.
#ifdef LARAP_WITH_CUDA
#include "cuda_backend.h"

#include <cuda_runtime.h>
#include <larap/errors.h>

#include <algorithm>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "flip_flop.h"
#include "node_cells.h"

namespace larap {

CudaBackend::CudaBackend(const Lattice& lattice, const RowMatrixX3d& vertices) : lat_(lattice), V_(vertices) {
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
    // Edge weights (Lattice::adj_weight: half the sum of cell weights around each edge).
    const bool weighted = !lattice.adj_weight.empty();
    std::vector<float> slot_w(weighted ? size_t(6) * n_ : 0, 1.f), extra_w;
    std::vector<int> xoff(size_t(n_) + 1, 0), extra;
    for (int i = 0; i < n_; ++i) {
      for (int k = lattice.adj_offsets[i]; k < lattice.adj_offsets[i + 1]; ++k) {
        const int j = lattice.adj[k];
        if (j < 0 || j >= n_) throw DeviceError("lattice edge to a node that is not real");
        const int d = nbr_slot(lattice.node_coords[size_t(i)], lattice.node_coords[size_t(j)]);
        if (d < 0) throw DeviceError("lattice edge is not an axis-aligned unit step");
        int& slot = nbr_host_[size_t(d) * n_ + i];
        const float w = weighted ? float(lattice.adj_weight[size_t(k)]) : 1.f;
        if (slot == i) {
          slot = j;
          if (weighted) slot_w[size_t(d) * n_ + i] = w;
        } else {
          extra.push_back(j);
          if (weighted) extra_w.push_back(w);
        }
      }
      xoff[size_t(i) + 1] = int(extra.size());
    }
    sys_.nbr = nbr_.upload(nbr_host_.data(), nbr_host_.size(), stream_);
    sys_.nbx_off = nbx_off_.upload(xoff.data(), xoff.size(), stream_);
    sys_.nbx = nbx_.upload(extra.data(), extra.size(), stream_);
    if (weighted) {
      sys_.nbw = nbw_.upload(slot_w.data(), slot_w.size(), stream_);
      sys_.nbxw = nbxw_.upload(extra_w.data(), extra_w.size(), stream_);
    }
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));  // the host tables may go
  }
  {  // cell copies: corners, weights, and per node the copies it is a corner of (node_cells.h)
    const int ncell = int(lattice.num_cells());
    std::vector<int> corners(size_t(8) * ncell);
    for (int c = 0; c < ncell; ++c)
      for (int q = 0; q < 8; ++q) corners[size_t(q) * ncell + c] = lattice.cell_nodes[size_t(c)][size_t(q)];
    sys_.ncell = ncell;
    sys_.cell_nodes = cell_nodes_.upload(corners.data(), corners.size(), stream_);
    if (!lattice.cell_weight.empty()) {
      std::vector<float> w(lattice.cell_weight.begin(), lattice.cell_weight.end());
      sys_.cell_w = cell_w_.upload(w.data(), w.size(), stream_);
    }
    const NodeCells t = node_cells(lattice);
    std::vector<float4> s(t.s.size());
    for (size_t k = 0; k < s.size(); ++k)
      s[k] = make_float4(float(t.s[k][0]), float(t.s[k][1]), float(t.s[k][2]), 0.f);
    sys_.nc_off = nc_off_.upload(t.offsets.data(), t.offsets.size(), stream_);
    sys_.nc_cell = nc_cell_.upload(t.cell.data(), t.cell.size(), stream_);
    sys_.nc_s = nc_s_.upload(s.data(), s.size(), stream_);
    const BranchCouplings cp = couplings_by_branch(lattice);  // node_cells.h
    std::vector<float> cp_w(cp.weight.begin(), cp.weight.end());
    if (!cp.offsets.empty()) {
      sys_.cp_off = cp_off_.upload(cp.offsets.data(), cp.offsets.size(), stream_);
      sys_.cp_trunk = cp_trunk_.upload(cp.trunk.data(), cp.trunk.size(), stream_);
      sys_.cp_w = cp_w_.upload(cp_w.data(), cp_w.size(), stream_);
    }
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));  // the host tables may go
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
  sys_.rot = rot_.reserve(size_t(3) * std::max(1, sys_.ncell));
  disp_.reserve(n_all_);
  sys_.iter = iter_.reserve(1);
  configure();
  LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.p, 0, sizeof(float4) * n_, stream_));
  const size_t nc = size_t(std::max(1, sys_.ncell));
  std::vector<float4> eye(3 * nc, make_float4(0.f, 0.f, 0.f, 0.f));
  for (size_t c = 0; c < nc; ++c) eye[3 * c].x = eye[3 * c + 1].y = eye[3 * c + 2].z = 1.f;
  LARAP_CUDA_CHECK(
      cudaMemcpyAsync(sys_.rot, eye.data(), eye.size() * sizeof(float4), cudaMemcpyHostToDevice, stream_));
  LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
}

CudaBackend::~CudaBackend() {
  graph_.reset();
  cudaStreamSynchronize(stream_);
  cudaGetLastError();
}

void CudaBackend::configure() {
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

void CudaBackend::write_profile(const char* what, int iterations,
                                std::initializer_list<std::pair<const char*, double>> kv) {
  FILE* f = std::fopen(opt_.profile_path.c_str(), "a");
  if (!f) return;
  std::fprintf(f, "{\"what\": \"%s\", \"nodes\": %d, \"handles\": %lld, \"iterations\": %d, \"inner\": %d",
               what, n_, static_cast<long long>(hs_.m), iterations, inner_);
  for (const auto& p : kv) std::fprintf(f, ", \"%s\": %.6g", p.first, p.second);
  std::fprintf(f, "}\n");
  std::fclose(f);
}

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
