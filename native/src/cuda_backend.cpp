// CUDA backend, host side: device memory (RAII), the linear system's set-up, the flip-flop loop
// (captured once into a CUDA graph), the transfer with its copy back through pinned memory, and
// the mapping of every CUDA error to a larap exception. Kernels: native/cuda/kernels.cu.
// Design and figures: docs/cuda.md, docs/results-gpu.md.
//
// Tuning knobs (environment, read when a backend is made; for benchmarks):
//   LARAP_CUDA_SOLVER   mg (default, two-level PCG) | pcg | cheby | jacobi
//   LARAP_CUDA_INNER    inner solver iterations per flip-flop (default for mg: 1 with two levels
//                       of which the coarse one is 2x2x2 aggregates, else 2; 8 for the others)
//   LARAP_CUDA_MG_COARSE  most nodes of mg's dense coarsest level (default 1536)
//   LARAP_CUDA_MG_LEVELS  2 | 3 (default: 2 when 2x2x2 aggregates are at most MG_COARSE nodes,
//                       else 3: 2x2x2 aggregates smoothed on the device, dense level below)
//   LARAP_CUDA_GRAPH    1 (default): one CUDA graph per flip-flop; 0: plain launches
//   LARAP_CUDA_PROFILE  a file path: per-stage device times (plain launches, a sync per
//                       flip-flop) are appended to it as JSON lines, and stats carry them
//   LARAP_CUDA_CHEBY_RATIO  lambda_max / lambda_min assumed by the Chebyshev solver (default 50)
//   LARAP_CUDA_FUSED    1 (default): mg runs all flip-flops of a solve in one cooperative kernel;
//                       0: one graph (or plain launches) per flip-flop
//   LARAP_CUDA_COOP_BLOCKS  blocks of the fused kernel (default: enough for one node per thread,
//                       at least one per SM, at most what can be co-resident)
//   LARAP_CUDA_TRANSFER transfer kernel: scalar (default) | staged (16-byte loads/stores through
//                       shared memory) | ilp1 | ilp2 | ilp4 (vertices per thread, loads issued
//                       together; suffix s: streaming cache hints); docs/cuda.md
//   LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES  tests: device allocations fail (MemoryError) once the
//                       process's live device bytes would exceed this
#ifdef LARAP_WITH_CUDA
#include <cuda_runtime.h>
#include <larap/errors.h>

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <unordered_map>
#include <vector>

#include "../cuda/kernels.h"
#include "backend.h"

namespace larap {
namespace {

// Transfer kernel when LARAP_CUDA_TRANSFER is unset (docs/results-gpu.md has the measurements).
constexpr const char* kDefaultTransfer = "scalar";

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

[[noreturn]] void fail(cudaError_t e, const char* what) {
  cudaGetLastError();  // clear a non-sticky error so that the process can go on
  const std::string msg = std::string("CUDA error in ") + what + ": " + cudaGetErrorName(e) + " (" +
                          cudaGetErrorString(e) + ")";
  if (e == cudaErrorMemoryAllocation) throw OutOfMemory("device out of memory: " + msg);
  throw DeviceError(msg);
}
#define LARAP_CK(call)                              \
  do {                                              \
    const cudaError_t larap_err_ = (call);                 \
    if (larap_err_ != cudaSuccess) fail(larap_err_, #call);        \
  } while (0)

// ------------------------------------------------------------------ device allocations
// Live device bytes of every DevBuf in the process, and the fault-injection knob
// LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES (read at every allocation, for tests): an allocation that
// would take the total over it fails as if cudaMalloc had returned cudaErrorMemoryAllocation.
std::atomic<size_t> g_device_bytes{0};

void* device_alloc(size_t bytes) {
  const char* lim = std::getenv("LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES");
  if (lim && *lim) {
    const unsigned long long limit = std::strtoull(lim, nullptr, 10);
    if (g_device_bytes.load() + bytes > limit)
      throw OutOfMemory("device out of memory: cannot allocate " + std::to_string(bytes) + " bytes (" +
                        std::to_string(g_device_bytes.load()) + " in use; simulated by "
                        "LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES=" + lim + ")");
  }
  void* q = nullptr;
  const cudaError_t e = cudaMalloc(&q, bytes);
  if (e != cudaSuccess) {
    cudaGetLastError();
    if (e == cudaErrorMemoryAllocation)
      throw OutOfMemory("device out of memory: cannot allocate " + std::to_string(bytes) + " bytes");
    fail(e, "cudaMalloc");
  }
  g_device_bytes += bytes;
  return q;
}

// ------------------------------------------------------------------ RAII wrappers
template <typename T>
class DevBuf {
 public:
  DevBuf() = default;
  DevBuf(const DevBuf&) = delete;
  DevBuf& operator=(const DevBuf&) = delete;
  ~DevBuf() { release(); }
  void release() {
    if (p_) {
      cudaFree(p_);
      g_device_bytes -= cap_ * sizeof(T);
    }
    p_ = nullptr;
    cap_ = 0;
  }
  // At least n elements (contents not kept when it grows).
  T* reserve(size_t n) {
    if (n <= cap_ && p_) return p_;
    release();
    const size_t bytes = std::max<size_t>(n, 1) * sizeof(T);
    p_ = static_cast<T*>(device_alloc(bytes));
    cap_ = std::max<size_t>(n, 1);
    return p_;
  }
  T* upload(const T* src, size_t n, cudaStream_t st) {
    reserve(n);
    if (n) LARAP_CK(cudaMemcpyAsync(p_, src, n * sizeof(T), cudaMemcpyHostToDevice, st));
    return p_;
  }
  T* get() const { return p_; }
  size_t size() const { return cap_; }

 private:
  T* p_ = nullptr;
  size_t cap_ = 0;
};

template <typename T>
class Pinned {
 public:
  Pinned() = default;
  Pinned(const Pinned&) = delete;
  Pinned& operator=(const Pinned&) = delete;
  ~Pinned() { release(); }
  void release() {
    if (p_) cudaFreeHost(p_);
    p_ = nullptr;
    cap_ = 0;
  }
  T* reserve(size_t n) {
    if (n <= cap_ && p_) return p_;
    release();
    void* q = nullptr;
    const size_t bytes = std::max<size_t>(n, 1) * sizeof(T);
    const cudaError_t e = cudaMallocHost(&q, bytes);
    if (e != cudaSuccess) {
      cudaGetLastError();
      if (e == cudaErrorMemoryAllocation)
        throw OutOfMemory("out of pinned host memory: cannot allocate " + std::to_string(bytes) + " bytes");
      fail(e, "cudaMallocHost");
    }
    p_ = static_cast<T*>(q);
    cap_ = std::max<size_t>(n, 1);
    return p_;
  }
  T* get() const { return p_; }

 private:
  T* p_ = nullptr;
  size_t cap_ = 0;
};

class Event {
 public:
  Event() { LARAP_CK(cudaEventCreate(&e_)); }
  Event(const Event&) = delete;
  Event& operator=(const Event&) = delete;
  ~Event() {
    if (e_) cudaEventDestroy(e_);
  }
  cudaEvent_t get() const { return e_; }

 private:
  cudaEvent_t e_ = nullptr;
};

float elapsed_ms(const Event& a, const Event& b) {
  float ms = 0.f;
  LARAP_CK(cudaEventElapsedTime(&ms, a.get(), b.get()));
  return ms;
}

class Stream {
 public:
  Stream() { LARAP_CK(cudaStreamCreateWithFlags(&s_, cudaStreamNonBlocking)); }
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;
  ~Stream() {
    if (s_) {
      cudaStreamSynchronize(s_);
      cudaStreamDestroy(s_);
    }
  }
  operator cudaStream_t() const { return s_; }

 private:
  cudaStream_t s_ = nullptr;
};

class GraphExec {
 public:
  GraphExec() = default;
  GraphExec(const GraphExec&) = delete;
  GraphExec& operator=(const GraphExec&) = delete;
  ~GraphExec() { reset(); }
  void reset() {
    if (exec_) cudaGraphExecDestroy(exec_);
    exec_ = nullptr;
  }
  void set(cudaGraphExec_t e) {
    reset();
    exec_ = e;
  }
  cudaGraphExec_t get() const { return exec_; }

 private:
  cudaGraphExec_t exec_ = nullptr;
};

void parallel_copy(void* dst, const void* src, size_t bytes) {
  constexpr size_t piece = size_t(1) << 20;
  if (bytes < 4 * piece) {
    std::memcpy(dst, src, bytes);
    return;
  }
  const int64_t pieces = int64_t((bytes + piece - 1) / piece);
#pragma omp parallel for schedule(static)
  for (int64_t k = 0; k < pieces; ++k) {
    const size_t off = size_t(k) * piece;
    std::memcpy(static_cast<char*>(dst) + off, static_cast<const char*>(src) + off,
                std::min(piece, bytes - off));
  }
}

int env_int(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v && *v ? std::atoi(v) : fallback;
}

enum class Solver { PCG, MG, Cheby, Jacobi };

// ------------------------------------------------------------------ the backend
class CudaBackend final : public Backend {
 public:
  CudaBackend(const Lattice& lattice, const RowMatrixX3d& vertices) : lat_(lattice), V_(vertices) {
    n_ = int(lattice.num_nodes());
    origin_ = 0.5 * (lattice.rest.colwise().minCoeff() + lattice.rest.colwise().maxCoeff()).transpose();
    std::vector<float4> rest(static_cast<size_t>(n_));
    for (int i = 0; i < n_; ++i) rest[i] = to_f4(lattice.rest.row(i).transpose());
    sys_.n = n_;
    sys_.rest = rest_.upload(rest.data(), rest.size(), stream_);
    sys_.x = x_.upload(rest.data(), rest.size(), stream_);
    sys_.adj_off = adj_off_.upload(lattice.adj_offsets.data(), lattice.adj_offsets.size(), stream_);
    sys_.adj = adj_.upload(lattice.adj.data(), lattice.adj.size(), stream_);
    {  // fixed-width neighbour table (lattice edges are axis-aligned unit steps)
      std::vector<int> nbr(size_t(6) * n_);
      for (int i = 0; i < n_; ++i)
        for (int d = 0; d < 6; ++d) nbr[size_t(d) * n_ + i] = i;
      for (int i = 0; i < n_; ++i)
        for (int k = lattice.adj_offsets[i]; k < lattice.adj_offsets[i + 1]; ++k) {
          const int j = lattice.adj[k];
          const int d = nbr_slot(lattice.node_coords[size_t(i)], lattice.node_coords[size_t(j)]);
          if (d < 0) throw DeviceError("lattice edge is not an axis-aligned unit step");
          nbr[size_t(d) * n_ + i] = j;
        }
      sys_.nbr = nbr_.upload(nbr.data(), nbr.size(), stream_);
    }
    sys_.p = p_.reserve(n_);
    sys_.r[0] = r_[0].reserve(n_);
    sys_.r[1] = r_[1].reserve(n_);
    sys_.w[0] = w_[0].reserve(n_);
    sys_.w[1] = w_[1].reserve(n_);
    sys_.s[0] = s_[0].reserve(n_);
    sys_.s[1] = s_[1].reserve(n_);
    sys_.x_tmp = xtmp_.reserve(n_);
    sys_.rot = rot_.reserve(size_t(9) * n_);
    disp_.reserve(n_);
    sys_.iter = iter_.reserve(1);
    configure();
    LARAP_CK(cudaMemsetAsync(sys_.p, 0, sizeof(float4) * n_, stream_));
    std::vector<float> eye(static_cast<size_t>(9 * n_), 0.f);
    for (int i = 0; i < n_; ++i) eye[0 * size_t(n_) + i] = eye[4 * size_t(n_) + i] = eye[8 * size_t(n_) + i] = 1.f;
    LARAP_CK(cudaMemcpyAsync(sys_.rot, eye.data(), eye.size() * sizeof(float), cudaMemcpyHostToDevice, stream_));
    LARAP_CK(cudaStreamSynchronize(stream_));
  }

  ~CudaBackend() override {
    graph_.reset();
    cudaStreamSynchronize(stream_);
    cudaGetLastError();
  }

  std::string name() const override { return "cuda"; }

  // Reads the tuning knobs (environment, see the top of this file); at construction and at
  // every set_handles, so that a benchmark can switch solvers without rebuilding the lattice.
  void configure() {
    const char* sv = std::getenv("LARAP_CUDA_SOLVER");
    const std::string sname = sv ? sv : "mg";
    if (sname == "pcg") solver_ = Solver::PCG;
    else if (sname == "mg" || sname.empty()) solver_ = Solver::MG;
    else if (sname == "cheby") solver_ = Solver::Cheby;
    else if (sname == "jacobi") solver_ = Solver::Jacobi;
    else throw InvalidInput("LARAP_CUDA_SOLVER must be pcg, mg, cheby or jacobi, got '" + sname + "'");
    inner_ = std::clamp(env_int("LARAP_CUDA_INNER", solver_ == Solver::MG ? 2 : 8), 1, 1000);
    use_graph_ = env_int("LARAP_CUDA_GRAPH", 1) != 0;
    use_fused_ = env_int("LARAP_CUDA_FUSED", 1) != 0;
    coop_blocks_env_ = env_int("LARAP_CUDA_COOP_BLOCKS", 0);
    {
      const char* tv = std::getenv("LARAP_CUDA_TRANSFER");
      const std::string tn = tv && *tv ? tv : kDefaultTransfer;
      cuda::TransferVariant v;
      if (tn == "scalar") {
        v.mode = cuda::kTransferScalar;
      } else if (tn == "staged") {
        v.mode = cuda::kTransferStaged;
      } else if ((tn.size() == 4 || (tn.size() == 5 && tn[4] == 's')) && tn.compare(0, 3, "ilp") == 0 &&
                 (tn[3] == '1' || tn[3] == '2' || tn[3] == '4')) {
        v.mode = cuda::kTransferIlp;
        v.vpt = tn[3] - '0';
        v.stream = tn.size() == 5;
      } else {
        throw InvalidInput("LARAP_CUDA_TRANSFER must be scalar, staged, ilp1, ilp2, ilp4, ilp1s, ilp2s or "
                           "ilp4s, got '" + tn + "'");
      }
      transfer_ = v;
    }
    inner_env_ = std::getenv("LARAP_CUDA_INNER") && *std::getenv("LARAP_CUDA_INNER");
    const char* p = std::getenv("LARAP_CUDA_PROFILE");
    profile_path_ = p ? p : "";
    cheb_ratio_ = std::max(1.0, double(env_int("LARAP_CUDA_CHEBY_RATIO", 50)));
    mg_coarse_max_ = std::clamp(env_int("LARAP_CUDA_MG_COARSE", 1536), 1, 8192);
    mg_levels_env_ = env_int("LARAP_CUDA_MG_LEVELS", 0);
    if (mg_levels_env_ != 0 && mg_levels_env_ != 2 && mg_levels_env_ != 3)
      throw InvalidInput("LARAP_CUDA_MG_LEVELS must be 2 or 3 (unset: automatic)");
    graph_.reset();
    sys_.inner = inner_;
    sys_.dots = dots_.reserve(size_t(inner_ + 1) * 6);
    sys_.coef = coef_.reserve(size_t(inner_ + 2) * 8);
    sys_.counters = counters_.reserve(size_t(inner_ + 1));
    LARAP_CK(cudaMemsetAsync(sys_.counters, 0, sizeof(unsigned) * (inner_ + 1), stream_));
    LARAP_CK(cudaMemsetAsync(sys_.coef, 0, sizeof(float) * (inner_ + 2) * 8, stream_));
  }

  void set_handles(const HandleSystem& hs) override {
    configure();
    hs_ = hs;
    const int n = n_;
    const int64_t m = hs.m;
    using SpR = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;
    const auto trip = arap_triplets(lat_, hs);
    SpR A(n, n);
    A.setFromTriplets(trip.begin(), trip.end());
    SpR B(m, n);
    const auto bt = handle_triplets(hs);
    B.setFromTriplets(bt.begin(), bt.end());
    const SpR Bt = B.transpose();
    A = SpR(A + SpR(Bt * B));
    A.makeCompressed();
    SpR BtC = Bt;
    BtC.makeCompressed();

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
    {  // A split: diagonal, 6 lattice slots, remainder CSR (see kernels.h)
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
          const int d = nbr_slot(lat_.node_coords[size_t(i)], lat_.node_coords[size_t(j)]);
          if (d >= 0 && is_edge(i, j)) {
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
    std::vector<float> btw(BtC.nonZeros()), bw(hs.weights.size());
    for (int64_t q = 0; q < BtC.nonZeros(); ++q) btw[q] = float(BtC.valuePtr()[q]);
    for (size_t q = 0; q < bw.size(); ++q) bw[q] = float(hs.weights[q]);

    graph_.reset();
    sys_.a_off = a_off_.upload(A.outerIndexPtr(), size_t(n) + 1, stream_);
    sys_.a_col = a_col_.upload(A.innerIndexPtr(), A.nonZeros(), stream_);
    sys_.a_val = a_val_.upload(aval.data(), aval.size(), stream_);
    sys_.minv = minv_.upload(minv.data(), minv.size(), stream_);
    sys_.bt_off = bt_off_.upload(BtC.outerIndexPtr(), size_t(n) + 1, stream_);
    sys_.bt_handle = bt_h_.upload(BtC.innerIndexPtr(), BtC.nonZeros(), stream_);
    sys_.bt_w = bt_w_.upload(btw.data(), btw.size(), stream_);
    sys_.m = int(m);
    sys_.stencil = hs.stencil;
    sys_.b_ids = b_ids_.upload(hs.ids.data(), hs.ids.size(), stream_);
    sys_.b_w = b_w_.upload(bw.data(), bw.size(), stream_);
    sys_.anchored = anch_.upload(hs.anchored.data(), hs.anchored.size(), stream_);
    sys_.g = float(hs.gamma_eff);
    sys_.a = float(hs.anchor_weight);
    sys_.targets = targets_.reserve(size_t(std::max<int64_t>(m, 1)));
    hpos_.reserve(size_t(std::max<int64_t>(m, 1)));
    h_targets_.reserve(size_t(std::max<int64_t>(m, 1)));

    // Chebyshev bounds / smoothing weight: lambda_max of D^-1 A by power iteration (host, double).
    if (solver_ != Solver::PCG) {
      Eigen::VectorXd v = Eigen::VectorXd::Random(n).cwiseAbs() + Eigen::VectorXd::Constant(n, 0.1);
      double lam = 2.0;
      for (int it = 0; it < 40; ++it) {
        Eigen::VectorXd w = (A * v).cwiseQuotient(diag);
        lam = w.norm() / std::max(v.norm(), 1e-300);
        v = w / std::max(w.norm(), 1e-300);
      }
      lam_max_ = 1.05 * lam;
      lam_min_ = lam_max_ / cheb_ratio_;
    }
    sys_.nc = 0;
    sys_.nc2 = 0;
    if (solver_ == Solver::MG) build_two_level(A);
    LARAP_CK(cudaStreamSynchronize(stream_));
    ready_ = true;
  }

  // Aggregation of the fine nodes by (coord >> shift): coarse id of every fine node, count.
  int aggregate(int shift, std::vector<int>& agg) const {
    std::unordered_map<int64_t, int> ids;
    ids.reserve(size_t(n_) / 4 + 16);
    agg.assign(size_t(n_), 0);
    for (int i = 0; i < n_; ++i) {
      const Eigen::Vector3i& c = lat_.node_coords[size_t(i)];
      const int64_t key = (int64_t(c.x() >> shift) << 42) | (int64_t(c.y() >> shift) << 21) | int64_t(c.z() >> shift);
      agg[size_t(i)] = ids.emplace(key, int(ids.size())).first->second;
    }
    return int(ids.size());
  }

  // Dense inverse of a small SPD matrix, symmetrised, as float: one Cholesky factorisation, then
  // the two triangular solves for blocks of 64 identity columns in parallel (OpenMP; Eigen's own
  // parallelism is off in this project). 0.7-1.1 s serial at nc ~ 1500 before.
  static std::vector<float> dense_inverse(const Eigen::MatrixXd& Ac) {
    const int nc = int(Ac.rows());
    Eigen::LLT<Eigen::MatrixXd> llt(Ac);
    if (llt.info() != Eigen::Success) throw DeviceError("the coarse lattice system is not positive definite");
    Eigen::MatrixXd inv(nc, nc);
    constexpr int kCols = 64;
    const int nb = (nc + kCols - 1) / kCols;
#pragma omp parallel for schedule(dynamic)
    for (int b = 0; b < nb; ++b) {
      const int c0 = b * kCols, w = std::min(kCols, nc - c0);
      Eigen::MatrixXd X = Eigen::MatrixXd::Zero(nc, w);
      for (int k = 0; k < w; ++k) X(c0 + k, k) = 1.0;
      llt.matrixL().solveInPlace(X);
      llt.matrixU().solveInPlace(X);
      inv.middleCols(c0, w) = X;
    }
    std::vector<float> out(size_t(nc) * nc);
    for (int r = 0; r < nc; ++r)
      for (int c = 0; c < nc; ++c) out[size_t(r) * nc + c] = float(0.5 * (inv(r, c) + inv(c, r)));
    return out;
  }

  // Multilevel preconditioner. Level 1: aggregates = fine nodes with equal (coord >> shift), P
  // piecewise constant, Ac = P^T A P. Two levels (LARAP_CUDA_MG_LEVELS=2, or auto when the 2x2x2
  // aggregation gives at most LARAP_CUDA_MG_COARSE nodes): the smallest shift >= 1 within that
  // bound, Ac inverted densely. Three levels (=3, or auto when 2x2x2 gives more): level 1 = 2x2x2
  // aggregates with Ac1 kept sparse on the device and smoothed by damped Jacobi; level 2 = the
  // smallest shift >= 2 within the bound, Ac2 = P2^T Ac1 P2 inverted densely.
  template <class SpR>
  void build_two_level(const SpR& A) {
    const int n = n_;
    std::vector<int> agg;
    int nc = aggregate(1, agg);
    mg_shift_ = 1;
    const bool three = mg_levels_env_ == 3 || (mg_levels_env_ != 2 && nc > mg_coarse_max_);
    if (!three) {
      for (int shift = 2; nc > mg_coarse_max_ && shift < 31; ++shift) {
        nc = aggregate(shift, agg);
        mg_shift_ = shift;
      }
    }
    // Default inner iterations: with 2x2x2 aggregates and a dense inverse of them (two levels)
    // one PCG step per flip-flop reaches quality sooner than two (more flip-flops, each cheaper);
    // coarser two-level and three-level: two (one needs 2-3x the flip-flops; docs/results-gpu.md).
    if (!inner_env_ && !three && mg_shift_ == 1 && inner_ != 1) {
      inner_ = 1;
      sys_.inner = 1;
      graph_.reset();
    }
    // Ac = P^T A P (sparse, double)
    using SpC = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;
    SpC Ac(nc, nc);
    {
      std::vector<Eigen::Triplet<double>> tr;
      tr.reserve(size_t(A.nonZeros()));
      for (int i = 0; i < n; ++i)
        for (typename SpR::InnerIterator it(A, i); it; ++it)
          tr.emplace_back(agg[size_t(i)], agg[size_t(it.col())], it.value());
      Ac.setFromTriplets(tr.begin(), tr.end());
      Ac.makeCompressed();
    }
    sys_.nc = nc;
    sys_.agg = agg_.upload(agg.data(), agg.size(), stream_);
    sys_.rc = rc_.reserve(size_t(inner_) * nc);
    sys_.zc = zc_.reserve(size_t(nc));
    sys_.z = sys_.x_tmp;
    sys_.q = sys_.w[0];
    sys_.pb[0] = sys_.s[0];
    sys_.pb[1] = sys_.s[1];
    sys_.omega = float(4.0 / (3.0 * lam_max_));
    sys_.nc2 = 0;
    mg_nc2_ = 0;
    if (!three) {
      const std::vector<float> ainv = dense_inverse(Eigen::MatrixXd(Ac));
      sys_.ainv = ainv_.upload(ainv.data(), ainv.size(), stream_);
      return;
    }
    // Level 2: coarse nodes of level 1 grouped by fine coord >> shift2 (nested in level 1).
    std::vector<int> aggf2;
    int nc2 = 0;
    for (int shift = 2; shift < 31; ++shift) {
      nc2 = aggregate(shift, aggf2);
      if (nc2 <= mg_coarse_max_) break;
    }
    std::vector<int> agg2(size_t(nc), 0);
    for (int i = 0; i < n; ++i) agg2[size_t(agg[size_t(i)])] = aggf2[size_t(i)];
    Eigen::MatrixXd Ac2 = Eigen::MatrixXd::Zero(nc2, nc2);
    std::vector<float> cval(size_t(Ac.nonZeros())), cminv(size_t(nc), 1.f);
    Eigen::VectorXd cd = Eigen::VectorXd::Ones(nc);
    for (int c = 0; c < nc; ++c)
      for (int q = Ac.outerIndexPtr()[c]; q < Ac.outerIndexPtr()[c + 1]; ++q) {
        const int j = Ac.innerIndexPtr()[q];
        const double v = Ac.valuePtr()[q];
        cval[size_t(q)] = float(v);
        if (j == c) cd[c] = v;
        Ac2(agg2[size_t(c)], agg2[size_t(j)]) += v;
      }
    for (int c = 0; c < nc; ++c) {
      if (!(cd[c] > 0.0)) throw DeviceError("the coarse lattice system is not positive definite");
      cminv[size_t(c)] = float(1.0 / cd[c]);
    }
    double lam = 2.0;  // lambda_max of Dc^-1 Ac1 (power iteration)
    {
      Eigen::VectorXd v = Eigen::VectorXd::Random(nc).cwiseAbs() + Eigen::VectorXd::Constant(nc, 0.1);
      for (int it = 0; it < 40; ++it) {
        Eigen::VectorXd w = (Ac * v).cwiseQuotient(cd);
        lam = w.norm() / std::max(v.norm(), 1e-300);
        v = w / std::max(w.norm(), 1e-300);
      }
    }
    const std::vector<float> ainv = dense_inverse(Ac2);
    sys_.ainv = ainv_.upload(ainv.data(), ainv.size(), stream_);
    sys_.nc2 = nc2;
    mg_nc2_ = nc2;
    sys_.agg2 = agg2_.upload(agg2.data(), agg2.size(), stream_);
    sys_.c_off = c_off_.upload(Ac.outerIndexPtr(), size_t(nc) + 1, stream_);
    sys_.c_col = c_col_.upload(Ac.innerIndexPtr(), size_t(Ac.nonZeros()), stream_);
    sys_.c_val = c_val_.upload(cval.data(), cval.size(), stream_);
    sys_.c_minv = c_minv_.upload(cminv.data(), cminv.size(), stream_);
    sys_.omega1 = float(4.0 / (3.0 * 1.05 * lam));
    sys_.rc2 = rc2_.reserve(size_t(inner_) * nc2);
    sys_.zc2 = zc2_.reserve(size_t(nc2));
    // the upload above reads host vectors: wait before they go out of scope
    LARAP_CK(cudaStreamSynchronize(stream_));
  }

  void set_pose(const RowMatrixX3d& nodes) override {
    std::vector<float4> h(static_cast<size_t>(n_));
    for (int i = 0; i < n_; ++i) h[i] = to_f4(nodes.row(i).transpose());
    LARAP_CK(cudaMemcpyAsync(sys_.x, h.data(), h.size() * sizeof(float4), cudaMemcpyHostToDevice, stream_));
    LARAP_CK(cudaStreamSynchronize(stream_));
  }

  void get_pose(RowMatrixX3d& nodes) const override {
    std::vector<float4> h(static_cast<size_t>(n_));
    LARAP_CK(cudaMemcpyAsync(h.data(), sys_.x, h.size() * sizeof(float4), cudaMemcpyDeviceToHost, stream_));
    LARAP_CK(cudaStreamSynchronize(stream_));
    nodes.resize(n_, 3);
    for (int i = 0; i < n_; ++i) nodes.row(i) = from_f4(h[i]).transpose();
  }

  void handle_positions(RowMatrixX3d& out) const override {
    const int m = sys_.m;
    out.resize(m, 3);
    if (!ready_ || m == 0) {
      out.setZero();
      return;
    }
    std::vector<float4> h(static_cast<size_t>(m));
    cuda::launch_handle_positions(sys_, hpos_.get(), stream_);
    LARAP_CK(cudaGetLastError());
    LARAP_CK(cudaMemcpyAsync(h.data(), hpos_.get(), h.size() * sizeof(float4), cudaMemcpyDeviceToHost, stream_));
    LARAP_CK(cudaStreamSynchronize(stream_));
    for (int j = 0; j < m; ++j) out.row(j) = from_f4(h[j]).transpose();
  }

  void apply_rigid(const Eigen::Matrix3d& R, const Eigen::Vector3d& t) override {
    // Centred frame: x_c -> R x_c + (R o + t - o).
    const Eigen::Vector3d tc = R * origin_ + t - origin_;
    float r9[9];
    for (int k = 0; k < 9; ++k) r9[k] = float(R(k / 3, k % 3));
    if (!ready_) {  // anchored flags not known yet: every node moves
      RowMatrixX3d p;
      get_pose(p);
      for (int i = 0; i < n_; ++i) p.row(i) = (R * p.row(i).transpose() + t).transpose();
      set_pose(p);
      return;
    }
    cuda::launch_rigid(sys_, r9, float(tc.x()), float(tc.y()), float(tc.z()), stream_);
    LARAP_CK(cudaGetLastError());
    LARAP_CK(cudaStreamSynchronize(stream_));
  }

  void iterate(const RowMatrixX3d& targets, int iterations, SolveStats& stats) override {
    if (!ready_) throw StateError("set_handles must come before iterate");
    if (iterations <= 0) return;
    upload_targets(targets);
    set_energy_buffer(size_t(iterations));
    h_energy_.reserve(size_t(iterations));
    LARAP_CK(cudaMemsetAsync(sys_.iter, 0, sizeof(int), stream_));
    LARAP_CK(cudaMemsetAsync(sys_.energy, 0, sizeof(double) * iterations, stream_));
    const bool profile = !profile_path_.empty();
    double ms_rot = 0, ms_rhs = 0, ms_sol = 0;
    LARAP_CK(cudaEventRecord(ev_[0].get(), stream_));
    if (profile) {
      for (int it = 0; it < iterations; ++it) {
        LARAP_CK(cudaEventRecord(ev_[0].get(), stream_));
        cuda::launch_rotations(sys_, true, -1, stream_);
        LARAP_CK(cudaGetLastError());
        LARAP_CK(cudaEventRecord(ev_[1].get(), stream_));
        cuda::launch_rhs(sys_, solver_ == Solver::PCG || solver_ == Solver::MG, stream_);
        LARAP_CK(cudaGetLastError());
        LARAP_CK(cudaEventRecord(ev_[2].get(), stream_));
        launch_solver();
        LARAP_CK(cudaEventRecord(ev_[3].get(), stream_));
        LARAP_CK(cudaEventSynchronize(ev_[3].get()));
        ms_rot += elapsed_ms(ev_[0], ev_[1]);
        ms_rhs += elapsed_ms(ev_[1], ev_[2]);
        ms_sol += elapsed_ms(ev_[2], ev_[3]);
      }
      LARAP_CK(cudaEventRecord(ev_[0].get(), stream_));
    } else if (solver_ == Solver::MG && use_fused_ && fused_blocks() > 0) {
      // One cooperative launch for all flip-flops (energy of flip-flop it - 1 in its rotation
      // phase, as in the graph); at most kFusedChunk flip-flops a launch.
      constexpr int kFusedChunk = 64;
      for (int it0 = 0; it0 < iterations; it0 += kFusedChunk) {
        cuda::System sc = sys_;
        sc.energy = sys_.energy + it0;
        const int cnt = std::min(kFusedChunk, iterations - it0);
        if (it0 > 0) {  // the first rotation phase of this chunk adds flip-flop it0 - 1's energy
          cuda::launch_rotations(sys_, false, it0 - 1, stream_);
          LARAP_CK(cudaGetLastError());
        }
        LARAP_CK(cuda::launch_mg_fused(sc, cnt, fused_blocks(), stream_));
      }
    } else if (use_graph_) {
      if (!graph_.get()) build_graph();
      for (int it = 0; it < iterations; ++it) LARAP_CK(cudaGraphLaunch(graph_.get(), stream_));
    } else {
      for (int it = 0; it < iterations; ++it) flip_flop();
    }
    cuda::launch_rotations(sys_, false, iterations - 1, stream_);  // energy of the last pose
    LARAP_CK(cudaGetLastError());
    LARAP_CK(cudaEventRecord(ev_[1].get(), stream_));
    LARAP_CK(cudaMemcpyAsync(h_energy_.get(), sys_.energy, sizeof(double) * iterations,
                             cudaMemcpyDeviceToHost, stream_));
    LARAP_CK(cudaStreamSynchronize(stream_));
    const double loop_ms = elapsed_ms(ev_[0], ev_[1]);
    for (int it = 0; it < iterations; ++it) stats.energy.push_back(h_energy_.get()[it] * hs_.energy_scale);
    if (profile) {
      stats.ms_rotations += ms_rot + loop_ms;  // + the final energy pass
      stats.ms_rhs += ms_rhs;
      stats.ms_solve += ms_sol;
      write_profile("iterate", iterations, {{"ms_rotations", ms_rot}, {"ms_rhs", ms_rhs},
                                            {"ms_solve", ms_sol}, {"ms_final_energy", loop_ms}});
    } else {
      // One graph per flip-flop: the stages are not timed apart; the loop's device time is
      // reported as solve time (docs/cuda.md).
      stats.ms_solve += loop_ms;
    }
  }

  double energy(const RowMatrixX3d& targets) override {
    if (!ready_) throw StateError("set_handles must come before energy");
    upload_targets(targets);
    set_energy_buffer(1);
    LARAP_CK(cudaMemsetAsync(sys_.energy, 0, sizeof(double), stream_));
    cuda::launch_rotations(sys_, true, -2, stream_);
    LARAP_CK(cudaGetLastError());
    cuda::launch_rotations(sys_, false, 0, stream_);
    LARAP_CK(cudaGetLastError());
    double e = 0.0;
    LARAP_CK(cudaMemcpyAsync(&e, sys_.energy, sizeof(double), cudaMemcpyDeviceToHost, stream_));
    LARAP_CK(cudaStreamSynchronize(stream_));
    return e * hs_.energy_scale;
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
    LARAP_CK(cudaGetLastError());
    launch_transfer(b, d, 0, nv, V, dout);
    LARAP_CK(cudaStreamSynchronize(stream_));  // consumers on other streams may read it now
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
  // Is (i, j) a lattice edge? (a unit step between nodes need not be one: its cells may be gone)
  bool is_edge(int i, int j) const {
    const auto b = lat_.adj.begin() + lat_.adj_offsets[i], e = lat_.adj.begin() + lat_.adj_offsets[i + 1];
    return std::binary_search(b, e, j);
  }

  float4 to_f4(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d c = p - origin_;
    return make_float4(float(c.x()), float(c.y()), float(c.z()), 0.f);
  }
  Eigen::Vector3d from_f4(const float4& p) const {
    return Eigen::Vector3d(p.x, p.y, p.z) + origin_;
  }

  // The graph holds the buffer's address: a new buffer needs a new graph.
  void set_energy_buffer(size_t n) {
    double* e = energy_.reserve(std::max<size_t>(n, 256));
    if (e != sys_.energy) {
      sys_.energy = e;
      graph_.reset();
    }
  }

  void upload_targets(const RowMatrixX3d& targets) {
    const int m = sys_.m;
    float4* h = h_targets_.reserve(size_t(std::max(m, 1)));
    for (int j = 0; j < m; ++j) h[j] = to_f4(targets.row(j).transpose());
    if (m)
      LARAP_CK(cudaMemcpyAsync(const_cast<float4*>(sys_.targets), h, sizeof(float4) * m,
                               cudaMemcpyHostToDevice, stream_));
  }

  void launch_solver() {
    if (solver_ == Solver::PCG) {
      for (int k = 0; k <= inner_; ++k) {
        cuda::launch_cg(sys_, k, stream_);
        LARAP_CK(cudaGetLastError());
      }
      return;
    }
    if (solver_ == Solver::MG) {
      for (int k = 0; k < inner_; ++k) {
        cuda::launch_mg_iteration(sys_, k, stream_);
        LARAP_CK(cudaGetLastError());
      }
      cuda::launch_mg_final(sys_, stream_);
      LARAP_CK(cudaGetLastError());
      return;
    }
    // Chebyshev semi-iteration on D^-1 A with eigenvalues in [lo, hi]; Jacobi: fixed weight.
    const double lo = lam_min_, hi = lam_max_;
    const double theta = 0.5 * (hi + lo), delta = 0.5 * (hi - lo);
    const double sigma = theta / delta;
    double rho = 1.0 / sigma;
    for (int k = 0; k < inner_; ++k) {
      float c1 = 0.f, c2 = float(1.0 / theta);
      if (solver_ == Solver::Cheby && k > 0) {
        const double rn = 1.0 / (2.0 * sigma - rho);
        c1 = float(rn * rho);
        c2 = float(2.0 * rn / delta);
        rho = rn;
      }
      cuda::launch_cheby(sys_, k, c1, c2, stream_);
      LARAP_CK(cudaGetLastError());
    }
    if (inner_ & 1)
      LARAP_CK(cudaMemcpyAsync(sys_.x, sys_.x_tmp, sizeof(float4) * n_, cudaMemcpyDeviceToDevice, stream_));
  }

  // Blocks for the fused kernel (0: no cooperative launch possible).
  int fused_blocks() {
    if (coop_max_ < 0) coop_max_ = cuda::mg_fused_max_blocks();
    if (coop_max_ <= 0) return 0;
    int dev = 0, sms = 1;
    LARAP_CK(cudaGetDevice(&dev));
    LARAP_CK(cudaDeviceGetAttribute(&sms, cudaDevAttrMultiProcessorCount, dev));
    int b = coop_blocks_env_ > 0 ? coop_blocks_env_ : std::max((n_ + 255) / 256, sms);
    return std::clamp(b, 1, coop_max_);
  }

  void flip_flop() {
    cuda::launch_rotations(sys_, true, -1, stream_);
    LARAP_CK(cudaGetLastError());
    cuda::launch_rhs(sys_, solver_ == Solver::PCG || solver_ == Solver::MG, stream_);
    LARAP_CK(cudaGetLastError());
    launch_solver();
  }

  void build_graph() {
    cudaGraph_t g = nullptr;
    LARAP_CK(cudaStreamBeginCapture(stream_, cudaStreamCaptureModeThreadLocal));
    try {
      flip_flop();
    } catch (...) {
      cudaStreamEndCapture(stream_, &g);
      if (g) cudaGraphDestroy(g);
      cudaGetLastError();
      throw;
    }
    LARAP_CK(cudaStreamEndCapture(stream_, &g));
    cudaGraphExec_t exec = nullptr;
    const cudaError_t e = cudaGraphInstantiate(&exec, g, 0);
    cudaGraphDestroy(g);
    if (e != cudaSuccess) fail(e, "cudaGraphInstantiate");
    graph_.set(exec);
  }

  struct DevBinding {
    const Binding* key = nullptr;
    int64_t nv = -1;
    DevBuf<int> table;
    DevBuf<float4> packed;  // (base id as int bits, 3 fractions)
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
      d.table.upload(reinterpret_cast<const int*>(lat_.cell_nodes.data()), lat_.cell_nodes.size() * 8, stream_);
    } else {
      d.table.upload(b.node27.data(), b.node27.size(), stream_);
    }
    LARAP_CK(cudaStreamSynchronize(stream_));
    d.key = &b;
    d.nv = b.num_vertices();
    return d;
  }

  const float* device_vertices(float*) {
    if (!vf_.get() || vf_n_ != V_.rows()) {
      std::vector<float> h(size_t(V_.size()));
      for (Eigen::Index k = 0; k < V_.size(); ++k) h[k] = float(V_.data()[k]);
      vf_.upload(h.data(), h.size(), stream_);
      LARAP_CK(cudaStreamSynchronize(stream_));
      vf_n_ = V_.rows();
    }
    return vf_.get();
  }
  const double* device_vertices(double*) {
    if (!vd_.get() || vd_n_ != V_.rows()) {
      vd_.upload(V_.data(), size_t(V_.size()), stream_);
      LARAP_CK(cudaStreamSynchronize(stream_));
      vd_n_ = V_.rows();
    }
    return vd_.get();
  }
  float* device_out(float*, size_t n) { return outf_.reserve(n); }
  double* device_out(double*, size_t n) { return outd_.reserve(n); }

  template <typename T>
  void launch_transfer(const Binding& b, DevBinding& d, int64_t v0, int64_t v1, const T* V, T* out) {
    if (b.kind == WeightKind::Trilinear)
      cuda::launch_transfer_trilinear(v0, v1, d.packed.get(), d.table.get(), disp_.get(), V, out, transfer_, stream_);
    else
      cuda::launch_transfer_bspline(v0, v1, d.packed.get(), d.table.get(), disp_.get(), V, out, transfer_, stream_);
    LARAP_CK(cudaGetLastError());
  }

  template <typename T>
  void transfer_any(const Binding& b, T* out, SolveStats& stats) {
    const auto t0 = Clock::now();
    const int64_t nv = b.num_vertices();
    if (nv == 0) return;
    DevBinding& d = device_binding(b);
    const T* V = device_vertices(static_cast<T*>(nullptr));
    T* dout = device_out(static_cast<T*>(nullptr), size_t(3 * nv));
    T* stage = reinterpret_cast<T*>(staging_.reserve(size_t(3 * nv) * sizeof(T)));
    cuda::launch_displacement(sys_, disp_.get(), stream_);
    LARAP_CK(cudaGetLastError());
    double kernel_ms = -1.0, kernel_rep_ms = -1.0;
    if (!profile_path_.empty()) {  // kernel alone, timed (then the pipeline below repeats it)
      LARAP_CK(cudaEventRecord(ev_[0].get(), stream_));
      launch_transfer(b, d, 0, nv, V, dout);
      LARAP_CK(cudaEventRecord(ev_[1].get(), stream_));
      LARAP_CK(cudaEventSynchronize(ev_[1].get()));
      kernel_ms = elapsed_ms(ev_[0], ev_[1]);
      // and the mean of kRep back-to-back launches (no launch gap between events and kernel)
      constexpr int kRep = 10;
      LARAP_CK(cudaEventRecord(ev_[0].get(), stream_));
      for (int r = 0; r < kRep; ++r) launch_transfer(b, d, 0, nv, V, dout);
      LARAP_CK(cudaEventRecord(ev_[1].get(), stream_));
      LARAP_CK(cudaEventSynchronize(ev_[1].get()));
      kernel_rep_ms = elapsed_ms(ev_[0], ev_[1]) / kRep;
    }
    // Pipeline: chunk c is computed, copied to pinned memory, and copied on to `out` by the host
    // while the device works on chunk c + 1.
    const auto t1 = Clock::now();
    constexpr int64_t chunk = int64_t(1) << 18;
    const int64_t nchunks = (nv + chunk - 1) / chunk;
    while (int64_t(chunk_ev_.size()) < nchunks) chunk_ev_.emplace_back(std::make_unique<Event>());
    for (int64_t c = 0; c < nchunks; ++c) {
      const int64_t v0 = c * chunk, v1 = std::min(nv, v0 + chunk);
      launch_transfer(b, d, v0, v1, V, dout);
      LARAP_CK(cudaMemcpyAsync(stage + 3 * v0, dout + 3 * v0, sizeof(T) * 3 * (v1 - v0),
                               cudaMemcpyDeviceToHost, stream_));
      LARAP_CK(cudaEventRecord(chunk_ev_[c]->get(), stream_));
    }
    for (int64_t c = 0; c < nchunks; ++c) {
      const int64_t v0 = c * chunk, v1 = std::min(nv, v0 + chunk);
      LARAP_CK(cudaEventSynchronize(chunk_ev_[c]->get()));
      parallel_copy(out + 3 * v0, stage + 3 * v0, sizeof(T) * 3 * (v1 - v0));
    }
    const double ms = ms_since(t0);
    stats.ms_transfer += ms;
    if (!profile_path_.empty())
      write_profile("transfer", 0, {{"kernel_ms", kernel_ms},
                                    {"kernel_rep_ms", kernel_rep_ms},
                                    {"pipeline_ms", ms_since(t1)},
                                    {"total_ms", ms},
                                    {"vertices", double(nv)},
                                    {"bytes_out", double(sizeof(T) * 3 * nv)},
                                    {"stencil", double(b.stencil_size())},
                                    {"elem_size", double(sizeof(T))}});
  }

  void write_profile(const char* what, int iterations,
                     std::initializer_list<std::pair<const char*, double>> kv) {
    FILE* f = std::fopen(profile_path_.c_str(), "a");
    if (!f) return;
    std::fprintf(f, "{\"what\": \"%s\", \"nodes\": %d, \"handles\": %d, \"iterations\": %d, \"inner\": %d",
                 what, n_, sys_.m, iterations, inner_);
    for (const auto& p : kv) std::fprintf(f, ", \"%s\": %.6g", p.first, p.second);
    std::fprintf(f, "}\n");
    std::fclose(f);
  }

  const Lattice& lat_;
  const RowMatrixX3d& V_;
  Eigen::Vector3d origin_;
  int n_ = 0;
  Solver solver_ = Solver::PCG;
  int inner_ = 8;
  bool use_graph_ = true;
  bool use_fused_ = true;
  int coop_blocks_env_ = 0;
  cuda::TransferVariant transfer_;
  bool inner_env_ = false;
  int coop_max_ = -1;  // most co-resident blocks of the fused kernel (-1: not asked yet)
  std::string profile_path_;
  int mg_coarse_max_ = 1536;
  int mg_shift_ = 0;
  int mg_levels_env_ = 0;  // LARAP_CUDA_MG_LEVELS: 0 = automatic
  int mg_nc2_ = 0;
  double cheb_ratio_ = 50.0, lam_min_ = 0.0, lam_max_ = 2.0;
  bool ready_ = false;
  HandleSystem hs_;

  Stream stream_;  // first: destroyed after every buffer's last use
  cuda::System sys_;
  DevBuf<float4> rest_, x_, p_, r_[2], w_[2], s_[2], xtmp_, targets_, disp_;
  mutable DevBuf<float4> hpos_;
  DevBuf<int> agg_, nbr_, rem_off_, rem_col_;
  DevBuf<float> a_diag_, a_nb_, rem_val_;
  DevBuf<float> ainv_;
  DevBuf<float4> rc_, zc_, rc2_, zc2_;
  DevBuf<int> agg2_, c_off_, c_col_;
  DevBuf<float> c_val_, c_minv_;
  DevBuf<int> adj_off_, adj_, a_off_, a_col_, bt_off_, bt_h_, b_ids_, iter_;
  DevBuf<float> a_val_, minv_, bt_w_, b_w_, rot_, coef_;
  DevBuf<uint8_t> anch_;
  DevBuf<double> dots_, energy_;
  DevBuf<unsigned> counters_;
  Pinned<float4> h_targets_;
  Pinned<double> h_energy_;
  Pinned<char> staging_;
  DevBinding bind_[2];
  DevBuf<float> vf_;
  DevBuf<double> vd_;
  int64_t vf_n_ = -1, vd_n_ = -1;
  DevBuf<float> outf_;
  DevBuf<double> outd_;
  Event ev_[4];
  std::vector<std::unique_ptr<Event>> chunk_ev_;
  GraphExec graph_;  // last: destroyed first
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
      reason = std::string("this build's kernels cannot run on the GPU present (") +
               cudaGetErrorString(e) + "); rebuild with CMAKE_CUDA_ARCHITECTURES for it";
      return;
    }
    ok = true;
  });
  if (!ok && why) *why = reason;
  return ok;
}

}  // namespace larap
#endif  // LARAP_WITH_CUDA
