// Row-parallel loop shared by the inpainting stages: rows split into contiguous blocks over a
// fixed number of threads, so the work split (and any per-row result) is deterministic.
#pragma once

#include <algorithm>
#include <thread>
#include <vector>

namespace exo::inpainting {

// Runs fn(y) for every y in [0, h), rows split into contiguous blocks over `threads` threads.
template <typename Fn>
void ParallelRows(int h, int threads, const Fn& fn) {
  const int t_count = std::max(1, std::min(threads, h));
  auto worker = [&](int t) {
    for (int y = t * h / t_count; y < (t + 1) * h / t_count; ++y) fn(y);
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < t_count; ++t) pool.emplace_back(worker, t);
  worker(0);
  for (auto& th : pool) th.join();
}

}  // namespace exo::inpainting
