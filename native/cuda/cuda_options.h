// Options of the CUDA backend, with their defaults (docs/cuda.md, "Options").
//
// The product runs on the defaults. Benchmarks and tests set options through environment
// variables LARAP_CUDA_<NAME>, parsed in exactly one place, cuda_options_from_environment()
// (cuda_options.cpp), which the backend calls when it is made and at every set_handles (so that
// a benchmark can switch options without rebuilding the lattice). A bad value is
// larap::InvalidInput naming the variable. The fault injection for the out-of-memory tests,
// LARAP_CUDA_FAIL_ALLOC_AFTER_BYTES, is not an option: it is read at every allocation
// (device_memory.h).
//
// Experiments: the solvers pcg, cheby and jacobi and the transfer kernels staged and ilp* were
// measured and rejected (docs/results-gpu.md); they are compiled only with the CMake option
// LARAP_CUDA_EXPERIMENTS=ON (native/cuda/experiments/); otherwise asking for one is
// InvalidInput.
#pragma once
#include <string>

namespace larap {
namespace cuda {

// Inner linear solver of each flip-flop.
enum class Solver {
  Multigrid,  // mg: CG preconditioned by a two- or three-level aggregation cycle (the product)
  Pcg,        // experiment: Jacobi-preconditioned CG, one fused kernel per iteration
  Chebyshev,  // experiment: Chebyshev-accelerated Jacobi
  Jacobi,     // experiment: weighted Jacobi
};

// Kernel of the vertex transfer.
struct TransferKernel {
  enum Mode { Scalar = 0, Staged = 1, Ilp = 2 };
  Mode mode = Scalar;           // scalar: one vertex per thread (the product); staged, ilp: experiments
  int vertices_per_thread = 1;  // ilp: 1, 2 or 4
  bool streaming = false;       // ilp: streaming cache hints on read-once data
};

// How the transfer's result reaches the caller's host array (docs/cuda.md, "The copy back").
enum class CopyBack {
  Overlap,  // chunks: kernel + copy into pinned memory per chunk; host threads each wait for
            // their chunk and copy it on into the caller's array while later chunks still move
  Staged,   // the same chunks, copied on one after another (each copy itself parallel)
  Direct,   // one kernel, then one copy from the device straight into the caller's (pageable) array
};

struct CudaOptions {
  Solver solver = Solver::Multigrid;  // LARAP_CUDA_SOLVER = mg | pcg | cheby | jacobi
  // Inner solver iterations per flip-flop, 1..1000; 0 = automatic: mg 2 (1 with two levels of
  // 2x2x2 aggregates until 2026-11-24: it lags on large moves); the experiments 8.  LARAP_CUDA_INNER
  int inner = 0;
  int mg_coarse_max = 1536;  // most nodes of mg's dense coarsest level, 1..8192  LARAP_CUDA_MG_COARSE
  // mg levels: 0 = automatic (2 when the 2x2x2 aggregates are at most mg_coarse_max nodes,
  // else 3), 2 or 3.                                                  LARAP_CUDA_MG_LEVELS
  int mg_levels = 0;
  bool fused = true;    // mg: all flip-flops of a solve in one cooperative kernel  LARAP_CUDA_FUSED
  bool graph = true;    // otherwise: one CUDA graph per flip-flop (false: plain launches)  LARAP_CUDA_GRAPH
  int coop_blocks = 0;  // blocks of the fused kernel; 0 = max(ceil(n / 256), #SMs)  LARAP_CUDA_COOP_BLOCKS
  // A file to which per-stage device times are appended as JSON lines (plain launches, a sync
  // per flip-flop); empty = off.                                      LARAP_CUDA_PROFILE
  std::string profile_path;
  // A file to which the fused kernel (the product's path, unlike LARAP_CUDA_PROFILE) appends, per
  // iterate, its mean clock cycles per phase of a flip-flop: one thread's clock64() after each
  // grid-wide barrier, so a phase counts its slowest block and the barrier (the final update's
  // phase is empty where it is left to the next flip-flop); empty = off.  LARAP_CUDA_PHASES
  std::string phases_path;
  TransferKernel transfer;    // LARAP_CUDA_TRANSFER = scalar | staged | ilp1 | ilp2 | ilp4 | ilp2s | ilp4s
  double cheby_ratio = 50.0;  // cheby: lambda_max / lambda_min assumed   LARAP_CUDA_CHEBY_RATIO
  CopyBack copy = CopyBack::Overlap;  // LARAP_CUDA_COPY = overlap | staged | direct
  int copy_chunk = 1 << 16;           // vertices per chunk of overlap / staged, 1024..2^24  LARAP_CUDA_COPY_CHUNK
  // The global step's starting residual: true = from edge differences with the handle term in
  // double (flip_flop.cuh, residual_at); false = b - A x in float as before 2026-11-22, kept only
  // to measure the difference (docs/cuda.md, "Precision").      LARAP_CUDA_EXACT_RESIDUAL
  bool exact_residual = true;
};

// The options from the LARAP_CUDA_* environment variables (unset or empty: the default).
CudaOptions cuda_options_from_environment();

// Was this build made with LARAP_CUDA_EXPERIMENTS?
constexpr bool kExperimentsBuilt =
#ifdef LARAP_CUDA_EXPERIMENTS
    true;
#else
    false;
#endif

}  // namespace cuda
}  // namespace larap
