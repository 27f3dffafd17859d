#include "core/parallel.h"

#include <gtest/gtest.h>
#include <sched.h>

namespace s2r {
namespace {

// Threads by default follow the CPU affinity (a Slurm task with
// --cpus-per-task 2 on a 64-core node runs 2 workers, not 64).
TEST(Parallel, WorkersFollowTheAffinity) {
  cpu_set_t all;
  ASSERT_EQ(sched_getaffinity(0, sizeof(all), &all), 0);
  EXPECT_EQ(worker_count(0), CPU_COUNT(&all));
  EXPECT_EQ(worker_count(3), 3);
  int first = 0;
  while (!CPU_ISSET(first, &all)) ++first;
  cpu_set_t one;
  CPU_ZERO(&one);
  CPU_SET(first, &one);
  ASSERT_EQ(sched_setaffinity(0, sizeof(one), &one), 0);  // this thread only
  EXPECT_EQ(worker_count(0), 1);
  std::atomic<int> sum{0};
  parallel_for(100, 0, [&](int i) { sum += i; });
  EXPECT_EQ(sum, 4950);
  ASSERT_EQ(sched_setaffinity(0, sizeof(all), &all), 0);
  EXPECT_EQ(worker_count(0), CPU_COUNT(&all));
}

}  // namespace
}  // namespace s2r
