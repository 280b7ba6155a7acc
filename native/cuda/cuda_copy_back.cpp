// The CUDA backend's transfer, host side (the kernels: transfer.h): the binding and the rest
// vertices on the device (uploaded once per binding), the transfer kernel, and the copy back into
// the caller's array (direct, staged through pinned memory, or overlapped chunk by chunk:
// cuda_options.h), or the result left on the device (transfer_on_device).
#ifdef LARAP_WITH_CUDA
#include <cuda_runtime.h>
#include <larap/errors.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <memory>
#include <vector>

#include "cuda_backend.h"
#include "flip_flop.h"
#include "parallel.h"
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

}  // namespace

void CudaBackend::transfer(const Binding& b, double* out, SolveStats& stats) { transfer_any(b, out, stats); }

void CudaBackend::transfer(const Binding& b, float* out, SolveStats& stats) { transfer_any(b, out, stats); }

const float* CudaBackend::transfer_on_device(const Binding& b, SolveStats& stats) {
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

CudaBackend::DevBinding& CudaBackend::device_binding(const Binding& b) {
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

const float* CudaBackend::device_vertices(float*) {
  if (!vf_.get() || vf_n_ != V_.rows()) {
    std::vector<float> h(size_t(V_.size()));
    for (Eigen::Index k = 0; k < V_.size(); ++k) h[k] = float(V_.data()[k]);
    vf_.upload(h.data(), h.size(), stream_);
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    vf_n_ = V_.rows();
  }
  return vf_.get();
}

const double* CudaBackend::device_vertices(double*) {
  if (!vd_.get() || vd_n_ != V_.rows()) {
    vd_.upload(V_.data(), size_t(V_.size()), stream_);
    LARAP_CUDA_CHECK(cudaStreamSynchronize(stream_));
    vd_n_ = V_.rows();
  }
  return vd_.get();
}

template <typename T>
void CudaBackend::launch_transfer(const Binding& b, DevBinding& d, int64_t v0, int64_t v1, const T* V,
                                  T* out) {
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
void CudaBackend::transfer_any(const Binding& b, T* out, SolveStats& stats) {
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

template <typename T>
void CudaBackend::copy_back(const Binding& b, DevBinding& d, int64_t nv, const T* V, T* dout, T* out) {
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

}  // namespace larap
#endif  // LARAP_WITH_CUDA
