// A parallel loop on plain threads, for work interleaved with libraries that
// run their own thread pools (Ceres): OpenMP's spinning idle workers would
// compete with them for the cores.
#pragma once

#include <algorithm>
#include <atomic>
#include <functional>
#include <thread>
#include <vector>

namespace s2r {

// The cores this process may run on: its CPU affinity (what taskset, a
// container's cpuset or a Slurm task's --cpus-per-task leave it), not every
// core of the machine; hardware_concurrency where the affinity is unknown.
int usable_cores();

// `requested` threads, or with 0 one per usable core.
inline int worker_count(int requested) { return requested > 0 ? requested : usable_cores(); }

// Calls body(i) for i in [0, n), items handed out one at a time. `body` must
// not throw.
inline void parallel_for(int n, int threads, const std::function<void(int)>& body) {
  threads = std::min(worker_count(threads), n);
  if (threads <= 1) {
    for (int i = 0; i < n; ++i) body(i);
    return;
  }
  std::atomic<int> next{0};
  auto work = [&] {
    for (int i = next++; i < n; i = next++) body(i);
  };
  std::vector<std::thread> pool;
  for (int t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

}  // namespace s2r
