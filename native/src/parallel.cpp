#include "parallel.h"

#include <memory>
#include <mutex>
#include <thread>

#ifdef LARAP_WITH_TBB
#include <tbb/global_control.h>
#include <tbb/info.h>
#else
#include <omp.h>
#endif

namespace larap {
namespace {
std::mutex g_mutex;
int g_threads = 0;
#ifdef LARAP_WITH_TBB
std::unique_ptr<tbb::global_control> g_control;
#endif
}  // namespace

void set_num_threads(int n) {
  std::lock_guard<std::mutex> lock(g_mutex);
  g_threads = n > 0 ? n : 0;
#ifdef LARAP_WITH_TBB
  g_control.reset();
  if (g_threads > 0)
    g_control = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, size_t(g_threads));
#else
  omp_set_num_threads(g_threads > 0 ? g_threads : omp_get_num_procs());
#endif
}

int num_threads() {
#ifdef LARAP_WITH_TBB
  return int(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
#else
  return omp_get_max_threads();
#endif
}

}  // namespace larap
