#include "cuda_options.h"

#include <larap/errors.h>

#include <algorithm>
#include <cstdlib>

namespace larap {
namespace cuda {
namespace {

const char* env(const char* name) {
  const char* v = std::getenv(name);
  return v && *v ? v : nullptr;
}

int env_int(const char* name, int fallback) {
  const char* v = env(name);
  return v ? std::atoi(v) : fallback;
}

void require_experiments(const char* name, const std::string& value) {
  if (!kExperimentsBuilt)
    throw InvalidInput(std::string(name) + "=" + value +
                       " is a measured and rejected experiment: this build of larap has no "
                       "LARAP_CUDA_EXPERIMENTS (configure with -DLARAP_CUDA_EXPERIMENTS=ON)");
}

Solver parse_solver(const std::string& s) {
  if (s == "mg") return Solver::Multigrid;
  Solver v;
  if (s == "pcg")
    v = Solver::Pcg;
  else if (s == "cheby")
    v = Solver::Chebyshev;
  else if (s == "jacobi")
    v = Solver::Jacobi;
  else
    throw InvalidInput("LARAP_CUDA_SOLVER must be pcg, mg, cheby or jacobi, got '" + s + "'");
  require_experiments("LARAP_CUDA_SOLVER", s);
  return v;
}

TransferKernel parse_transfer(const std::string& s) {
  TransferKernel k;
  if (s == "scalar") return k;
  if (s == "staged") {
    k.mode = TransferKernel::Staged;
  } else if ((s.size() == 4 || (s.size() == 5 && s[4] == 's')) && s.compare(0, 3, "ilp") == 0 &&
             (s[3] == '1' || s[3] == '2' || s[3] == '4')) {
    k.mode = TransferKernel::Ilp;
    k.vertices_per_thread = s[3] - '0';
    k.streaming = s.size() == 5;
  } else {
    throw InvalidInput(
        "LARAP_CUDA_TRANSFER must be scalar, staged, ilp1, ilp2, ilp4, ilp1s, ilp2s or "
        "ilp4s, got '" +
        s + "'");
  }
  require_experiments("LARAP_CUDA_TRANSFER", s);
  return k;
}

}  // namespace

CudaOptions cuda_options_from_environment() {
  CudaOptions o;
  if (const char* v = env("LARAP_CUDA_SOLVER")) o.solver = parse_solver(v);
  if (env("LARAP_CUDA_INNER")) o.inner = std::clamp(env_int("LARAP_CUDA_INNER", 0), 1, 1000);
  o.mg_coarse_max = std::clamp(env_int("LARAP_CUDA_MG_COARSE", o.mg_coarse_max), 1, 8192);
  o.mg_levels = env_int("LARAP_CUDA_MG_LEVELS", 0);
  if (o.mg_levels != 0 && o.mg_levels != 2 && o.mg_levels != 3)
    throw InvalidInput("LARAP_CUDA_MG_LEVELS must be 2 or 3 (unset: automatic)");
  o.fused = env_int("LARAP_CUDA_FUSED", 1) != 0;
  o.graph = env_int("LARAP_CUDA_GRAPH", 1) != 0;
  o.exact_residual = env_int("LARAP_CUDA_EXACT_RESIDUAL", 1) != 0;
  o.coop_blocks = std::max(0, env_int("LARAP_CUDA_COOP_BLOCKS", 0));
  if (const char* v = env("LARAP_CUDA_PROFILE")) o.profile_path = v;
  if (const char* v = env("LARAP_CUDA_PHASES")) o.phases_path = v;
  if (const char* v = env("LARAP_CUDA_TRANSFER")) o.transfer = parse_transfer(v);
  o.cheby_ratio = std::max(1.0, double(env_int("LARAP_CUDA_CHEBY_RATIO", 50)));
  if (const char* v = env("LARAP_CUDA_COPY")) {
    const std::string c = v;
    if (c == "overlap")
      o.copy = CopyBack::Overlap;
    else if (c == "staged")
      o.copy = CopyBack::Staged;
    else if (c == "direct")
      o.copy = CopyBack::Direct;
    else
      throw InvalidInput("LARAP_CUDA_COPY must be overlap, staged or direct, got '" + c + "'");
  }
  o.copy_chunk = std::clamp(env_int("LARAP_CUDA_COPY_CHUNK", o.copy_chunk), 1024, 1 << 24);
  return o;
}

}  // namespace cuda
}  // namespace larap
