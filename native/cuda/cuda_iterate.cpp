// The CUDA backend's flip-flop loop, host side (the kernels: flip_flop.h, solvers.h): iterate
// (one cooperative kernel, a CUDA graph, or plain launches; profiled stage by stage on request),
// the energy, and the pose on the device (set_pose / get_pose, the stencil shell, recentre).
#ifdef LARAP_WITH_CUDA
#include <cuda_runtime.h>
#include <larap/errors.h>

#include <algorithm>
#include <cstdio>
#include <vector>

#include "cuda_backend.h"
#include "flip_flop.h"
#include "solvers.h"
#ifdef LARAP_CUDA_EXPERIMENTS
#include "experiments/experiments.h"
#endif

namespace larap {

void CudaBackend::iterate(int iterations, SolveStats& stats) {
  if (!ready_ || !targets_set_) throw StateError("set_handles and set_targets must come before iterate");
  if (iterations <= 0) return;
  set_energy_buffer(size_t(2) * iterations);
  h_energy_.reserve(size_t(2) * iterations);
  LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.iter, 0, sizeof(int), stream_));
  LARAP_CUDA_CHECK(cudaMemsetAsync(sys_.energy, 0, sizeof(double) * 2 * iterations, stream_));
  const bool profile = !opt_.profile_path.empty();
  double ms_rot = 0, ms_rhs = 0, ms_sol = 0;
  bool last_energy_done = false;  // the fused kernel sums the last flip-flop's energy itself
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
    // phase, as in the graph; a launch's last flip-flop's at its end); at most kFusedChunk
    // flip-flops a launch.
    constexpr int kFusedChunk = 64;
    const int phases = cuda::fused_phases(sys_);
    std::vector<double> cycles;  // LARAP_CUDA_PHASES: per phase, summed over the flip-flops
    std::vector<long long> st;
    if (!opt_.phases_path.empty()) cycles.assign(phases, 0.0);
    for (int it0 = 0; it0 < iterations; it0 += kFusedChunk) {
      cuda::System sc = sys_;
      sc.energy = sys_.energy + 2 * it0;
      const int cnt = std::min(kFusedChunk, iterations - it0);
      if (!cycles.empty()) sc.stamps = stamps_.reserve(size_t(1) + size_t(cnt) * phases);
      LARAP_CUDA_CHECK(cuda::launch_mg_fused(sc, cnt, fused_blocks(), stream_));
      if (!cycles.empty()) {  // a synchronisation per chunk: measurement only
        st.resize(size_t(1) + size_t(cnt) * phases);
        LARAP_CUDA_CHECK(cudaMemcpyAsync(st.data(), sc.stamps, st.size() * sizeof(long long),
                                         cudaMemcpyDeviceToHost, stream_));
        LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
        for (size_t k = 1; k < st.size(); ++k) cycles[(k - 1) % phases] += double(st[k] - st[k - 1]);
      }
    }
    if (!cycles.empty()) write_phases(cycles, iterations);
    last_energy_done = true;
  } else if (opt_.graph) {
    if (!graph_.get()) build_graph();
    for (int it = 0; it < iterations; ++it) LARAP_CUDA_CHECK(cudaGraphLaunch(graph_.get(), stream_));
  } else {
    for (int it = 0; it < iterations; ++it) flip_flop();
  }
  if (!last_energy_done) {
    cuda::launch_rotations(sys_, false, iterations - 1, stream_);  // energy of the last pose
    LARAP_CUDA_CHECK(cudaGetLastError());
  }
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

double CudaBackend::energy() {
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

void CudaBackend::launch_solver() {
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

int CudaBackend::fused_blocks() {
  if (coop_max_ < 0) coop_max_ = cuda::mg_fused_max_blocks();
  if (coop_max_ <= 0) return 0;
  int dev = 0, sms = 1;
  LARAP_CUDA_CHECK(cudaGetDevice(&dev));
  LARAP_CUDA_CHECK(cudaDeviceGetAttribute(&sms, cudaDevAttrMultiProcessorCount, dev));
  int b = opt_.coop_blocks > 0 ? opt_.coop_blocks : std::max((n_ + 255) / 256, sms);
  return std::clamp(b, 1, coop_max_);
}

void CudaBackend::flip_flop() {
  cuda::launch_rotations(sys_, true, -1, stream_);
  LARAP_CUDA_CHECK(cudaGetLastError());
  cuda::launch_rhs(sys_, opt_.solver == cuda::Solver::Pcg || opt_.solver == cuda::Solver::Multigrid, stream_);
  LARAP_CUDA_CHECK(cudaGetLastError());
  launch_solver();
}

void CudaBackend::build_graph() {
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

void CudaBackend::write_phases(const std::vector<double>& cycles, int flip_flops) {
  int dev = 0, khz = 0;
  LARAP_CUDA_CHECK(cudaGetDevice(&dev));
  LARAP_CUDA_CHECK(cudaDeviceGetAttribute(&khz, cudaDevAttrClockRate, dev));  // the maximum clock
  FILE* f = std::fopen(opt_.phases_path.c_str(), "a");
  if (!f) return;
  // Phases in kernel order: rotations, rhs, per inner iteration a[, a1], coarse[, b1], c, d; final.
  std::fprintf(f,
               "{\"what\": \"phases\", \"nodes\": %d, \"inner\": %d, \"levels\": %d, \"flip_flops\": %d, "
               "\"blocks\": %d, \"clock_khz\": %d, \"cycles\": [",
               n_, inner_, sys_.nc2 > 0 ? 3 : 2, flip_flops, fused_blocks(), khz);
  for (size_t k = 0; k < cycles.size(); ++k) std::fprintf(f, "%s%.6g", k ? ", " : "", cycles[k] / flip_flops);
  std::fprintf(f, "]}\n");
  std::fclose(f);
}

void CudaBackend::set_energy_buffer(size_t n) {
  double* e = energy_.reserve(std::max<size_t>(n, 256));
  if (e != sys_.energy) {
    sys_.energy = e;
    graph_.reset();
  }
}

double CudaBackend::total_energy(double arap, double handles) const {
  return (arap + std::max(handles + K_total_, 0.0)) * hs_.energy_scale;
}

void CudaBackend::set_pose(const RowMatrixX3d& nodes) {
  if (nodes.rows() < n_) throw InvalidInput("set_pose: fewer rows than the lattice's real nodes");
  float4* h = h_pose_.reserve(size_t(n_all_));  // get_pose's size: one allocation for both
  for (int i = 0; i < n_; ++i) h[i] = to_f4(nodes.row(i).transpose());
  LARAP_CUDA_CHECK(cudaMemcpyAsync(sys_.x, h, sizeof(float4) * n_, cudaMemcpyHostToDevice, stream_));
  try {
    fill_shell();
  } catch (...) {
    cudaStreamSynchronize(stream_);  // the copy reads h_pose_: done before anything writes it again
    throw;
  }
  LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));  // h_pose_ may be written again
}

void CudaBackend::get_pose(RowMatrixX3d& nodes) const {
  float4* h = h_pose_.reserve(size_t(n_all_));
  LARAP_CUDA_CHECK(cudaMemcpyAsync(h, sys_.x, sizeof(float4) * n_all_, cudaMemcpyDeviceToHost, stream_));
  LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
  nodes.resize(n_all_, 3);
  for (int i = 0; i < n_all_; ++i) nodes.row(i) = from_f4(h[i]).transpose();
}

void CudaBackend::fill_shell() {
  if (n_all_ == n_) return;
  cuda::launch_fill_shell(sys_, shell_off_.get(), shell_ids_.get(), shell_w_.get(), stream_);
  LARAP_CUDA_CHECK(cudaGetLastError());
}

void CudaBackend::recentre(const Eigen::Vector3d& o) {
  if (o == origin_) return;
  RowMatrixX3d pose;
  get_pose(pose);
  origin_ = o;
  std::vector<float4> rest(static_cast<size_t>(n_all_));
  for (int i = 0; i < n_all_; ++i) rest[size_t(i)] = to_f4(lat_.rest.row(i).transpose());
  rest_.upload(rest.data(), rest.size(), stream_);
  set_pose(pose);  // synchronises: `rest` may go
}

}  // namespace larap
#endif  // LARAP_WITH_CUDA
