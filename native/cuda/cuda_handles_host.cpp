// The CUDA backend's per-pose handle work, host side (the kernels: handles.h): the targets' H and
// K (set_targets), the per-component moments of the rigid start (moments), and the per-component
// rigid motion of the nodes (apply_rigid). O(groups) on the host and in uploads.
#ifdef LARAP_WITH_CUDA
#include <cuda_runtime.h>
#include <larap/errors.h>

#include <Eigen/Dense>
#include <vector>

#include "cuda_backend.h"
#include "handles.h"

namespace larap {

void CudaBackend::set_targets(const HandleTargets& targets) {
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

void CudaBackend::moments(std::vector<ComponentMoments>& now, std::vector<ComponentMoments>& rest) {
  if (!ready_ || !targets_set_) throw StateError("set_handles and set_targets must come before moments");
  const int nc = moment_chunks_.components;
  cuda::launch_moments(sys_, moment_chunks_, mom_partial_.get(), mom_out_.get(), stream_);  // pose and rest
  LARAP_CUDA_CHECK(cudaGetLastError());
  const size_t nv = size_t(2 * cuda::kMomentValues) * nc;
  const double* h = h_moments_.get();
  if (nv)
    LARAP_CUDA_CHECK(cudaMemcpyAsync(h_moments_.get(), mom_out_.get(), sizeof(double) * nv,
                                     cudaMemcpyDeviceToHost, stream_));
  LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
  unpack_moments(h, now);
  unpack_moments(h + size_t(cuda::kMomentValues) * nc, rest);
}

void CudaBackend::unpack_moments(const double* h, std::vector<ComponentMoments>& out) const {
  const int nc = moment_chunks_.components;
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

void CudaBackend::apply_rigid(const std::vector<ComponentMotion>& motions, bool from_rest) {
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

}  // namespace larap
#endif  // LARAP_WITH_CUDA
