// Data-parallel loops of the CPU path. With oneTBB (the scheduler Blender itself runs on) the
// engine shares Blender's worker threads and degrades gracefully when the cores are busy;
// OpenMP is the fallback where TBB is not installed. Every loop body writes only its own
// outputs, so results do not depend on the schedule or the number of threads.
#pragma once
#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

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

// The indices i in [0, n) for which keep(i) holds, ascending (chunks of `chunk` scanned in
// parallel, then joined in order).
template <class F>
std::vector<int64_t> parallel_select(int64_t n, F&& keep, int64_t chunk = 65536) {
  const int64_t nchunks = (n + chunk - 1) / chunk;
  std::vector<std::vector<int64_t>> parts(static_cast<size_t>(nchunks));
  parallel_for(nchunks, [&](int64_t c) {
    const int64_t end = std::min(n, (c + 1) * chunk);
    for (int64_t i = c * chunk; i < end; ++i)
      if (keep(i)) parts[size_t(c)].push_back(i);
  }, 1);
  size_t total = 0;
  for (const auto& p : parts) total += p.size();
  std::vector<int64_t> out;
  out.reserve(total);
  for (const auto& p : parts) out.insert(out.end(), p.begin(), p.end());
  return out;
}

// Limit the engine's worker threads (0 = all cores). Process-wide.
void set_num_threads(int n);
int num_threads();

}  // namespace larap
