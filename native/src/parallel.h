// Data-parallel loops of the CPU path. With oneTBB (the scheduler Blender itself runs on) the
// engine shares Blender's worker threads and degrades gracefully when the cores are busy;
// OpenMP is the fallback where TBB is not installed. Every loop body writes only its own
// outputs, so results do not depend on the schedule or the number of threads.
#pragma once
#include <cstdint>
#include <utility>

#ifdef LARAP_WITH_TBB
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#endif

namespace larap {

template <class F>
void parallel_for(int64_t n, F&& body, int64_t grain = 512) {
#ifdef LARAP_WITH_TBB
  tbb::parallel_for(tbb::blocked_range<int64_t>(0, n, grain),
                    [&](const tbb::blocked_range<int64_t>& r) {
                      for (int64_t i = r.begin(); i != r.end(); ++i) body(i);
                    });
#else
  (void)grain;
#pragma omp parallel for schedule(static)
  for (int64_t i = 0; i < n; ++i) body(i);
#endif
}

// Limit the engine's worker threads (0 = all cores). Process-wide.
void set_num_threads(int n);
int num_threads();

}  // namespace larap
