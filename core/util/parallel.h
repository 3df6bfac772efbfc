// One parallel loop over index ranges on short-lived threads, for bulk array work outside the
// render's thread pool (export helpers, scene commit). Deterministic: each range is fixed.
#pragma once
#include <algorithm>
#include <cstddef>
#include <thread>
#include <vector>

namespace pl {

// Runs fn(begin, end) over [0, count) split into one range per thread (this one included;
// threads <= 0: all cores); counts under min_per_thread per thread stay on this thread
// (starting threads costs more than the work).
template <class F>
void parallel_ranges(size_t count, int threads, F&& fn, size_t min_per_thread = 32768) {
  const size_t hw = threads > 0 ? size_t(threads) : std::max(1u, std::thread::hardware_concurrency());
  const size_t n = std::min(hw, std::max<size_t>(1, count / std::max<size_t>(1, min_per_thread)));
  if (n <= 1) {
    fn(size_t(0), count);
    return;
  }
  std::vector<std::thread> pool;
  pool.reserve(n - 1);
  for (size_t k = 1; k < n; ++k) pool.emplace_back([&fn, k, n, count] { fn(count * k / n, count * (k + 1) / n); });
  fn(size_t(0), count / n);
  for (std::thread& t : pool) t.join();
}

}  // namespace pl
