// WorkerPool: every task runs exactly once per Run, on several threads, over many back-to-back
// regions (the training loop's pattern), and a pool of one thread runs inline.
#include "rim/base/worker_pool.h"

#include <atomic>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "gtest/gtest.h"

namespace rim {
namespace {

TEST(WorkerPoolTest, EveryTaskRunsExactlyOnce) {
  WorkerPool pool(3);
  EXPECT_EQ(pool.threads(), 3);
  for (int round = 0; round < 2000; ++round) {
    const int tasks = round % 7;  // including 0 and 1 (inline) and more tasks than threads
    std::vector<std::atomic<int>> runs(size_t(tasks) + 1);
    pool.Run(tasks, [&](int i) { runs[size_t(i)].fetch_add(1); });
    for (int i = 0; i < tasks; ++i) ASSERT_EQ(runs[size_t(i)].load(), 1) << round << " " << i;
    ASSERT_EQ(runs[size_t(tasks)].load(), 0);
  }
}

TEST(WorkerPoolTest, TasksRunOnSeveralThreads) {
  WorkerPool pool(2);
  std::mutex mu;
  std::set<std::thread::id> ids;
  std::atomic<int> started{0};
  // Each task waits until both have started, which only two threads running at once allow.
  pool.Run(2, [&](int) {
    started.fetch_add(1);
    while (started.load() < 2) std::this_thread::yield();
    std::lock_guard<std::mutex> lock(mu);
    ids.insert(std::this_thread::get_id());
  });
  EXPECT_EQ(ids.size(), 2u);
}

TEST(WorkerPoolTest, OneThreadRunsInline) {
  WorkerPool pool(1);
  EXPECT_EQ(pool.threads(), 1);
  std::vector<std::thread::id> ids;
  pool.Run(4, [&](int) { ids.push_back(std::this_thread::get_id()); });
  ASSERT_EQ(ids.size(), 4u);
  for (const auto& id : ids) EXPECT_EQ(id, std::this_thread::get_id());
}

}  // namespace
}  // namespace rim
