// WorkerPool: every task runs exactly once per Run, on several threads, over many back-to-back
// regions (the training loop's pattern), and a pool of one thread runs inline. ParallelFor: every
// item once, in whole blocks, nested calls, helpers named after the caller.
#include "rim/base/worker_pool.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "gtest/gtest.h"
#include "rim/base/thread_priority.h"

#if defined(__linux__)
#include <sys/prctl.h>
#endif

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

// The trainer's pattern: a task spins until a task with a smaller index has finished. Run
// returns without waiting for workers that have not woken; such a worker must never take a task
// of a region it did not see, nor miss one of the region it joins late.
TEST(WorkerPoolTest, BackToBackRegionsWithOrderedWaitsAndLateWorkers) {
  WorkerPool pool(3);
  std::vector<std::atomic<int>> done(8);
  for (int round = 0; round < 20000; ++round) {
    const int tasks = 2 + round % 7;
    for (auto& d : done) d.store(0);
    pool.Run(tasks, [&](int i) {
      if (i > 0)
        while (done[size_t(i - 1)].load(std::memory_order_acquire) == 0) std::this_thread::yield();
      ASSERT_EQ(done[size_t(i)].fetch_add(1, std::memory_order_release), 0);
    });
    for (int i = 0; i < 8; ++i) ASSERT_EQ(done[size_t(i)].load(), i < tasks ? 1 : 0) << round;
  }
}

// Regions that come a while apart, so that the workers have gone to sleep on the condition
// variable and must be woken for each, and tasks long enough that the caller sleeps for a
// worker's last task. Every task once, every time.
TEST(WorkerPoolTest, RegionsAfterPausesAndLongTasks) {
  WorkerPool pool(3);
  for (int round = 0; round < 60; ++round) {
    const int tasks = 2 + round % 5;
    std::vector<std::atomic<int>> runs(static_cast<size_t>(tasks));
    pool.Run(tasks, [&](int i) {
      if (round % 3 == 1) std::this_thread::sleep_for(std::chrono::microseconds(300));
      runs[size_t(i)].fetch_add(1);
    });
    for (int i = 0; i < tasks; ++i) ASSERT_EQ(runs[size_t(i)].load(), 1) << round << " " << i;
    if (round % 3 == 2) std::this_thread::sleep_for(std::chrono::microseconds(500));
  }
}

// Pools made and dropped around a region each, as ParallelFor does per query: the destructor
// stops workers that may not even have woken for the region yet.
TEST(WorkerPoolTest, PoolsDroppedRightAfterARegion) {
  for (int round = 0; round < 300; ++round) {
    std::atomic<int> sum{0};
    {
      WorkerPool pool(2 + round % 3);
      pool.Run(4, [&](int i) { sum.fetch_add(i + 1); });
    }
    ASSERT_EQ(sum.load(), 10) << round;
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

TEST(ParallelForTest, EveryItemOnceInWholeBlocks) {
  for (int64_t n : {0, 1, 5, 1000, 1001}) {
    for (int64_t block : {0, 1, 7, 64, 5000}) {
      for (int threads : {0, 1, 2, 4}) {
        std::vector<std::atomic<int>> runs(static_cast<size_t>(n));
        std::atomic<bool> whole{true};
        ParallelFor(n, block, threads, [&](int64_t begin, int64_t end) {
          const int64_t b = std::max<int64_t>(block, 1);
          if (begin % b != 0 || end != std::min(n, begin + b)) whole = false;
          for (int64_t i = begin; i < end; ++i) runs[size_t(i)].fetch_add(1);
        });
        EXPECT_TRUE(whole) << n << " " << block << " " << threads;
        for (int64_t i = 0; i < n; ++i)
          ASSERT_EQ(runs[size_t(i)].load(), 1) << n << " " << block << " " << threads << " " << i;
      }
    }
  }
}

TEST(ParallelForTest, BlocksSpreadOverThreadsAndCallsNest) {
  std::mutex mu;
  std::set<std::thread::id> ids;
  std::atomic<int> started{0};
  std::atomic<int64_t> sum{0};
  ParallelFor(2, 1, 2, [&](int64_t, int64_t) {
    started.fetch_add(1);
    while (started.load() < 2) std::this_thread::yield();  // both blocks at once: two threads
    {
      std::lock_guard<std::mutex> lock(mu);
      ids.insert(std::this_thread::get_id());
    }
    ParallelFor(100, 10, 2, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) sum.fetch_add(i);
    });
  });
  EXPECT_EQ(ids.size(), 2u);
  EXPECT_EQ(sum.load(), 2 * 4950);
}

}  // namespace
#if defined(__linux__)
// A query's or a refresh's helpers show as the thread they help (rim-train for a refresh), not as
// the trainer's pool.
TEST(ParallelForTest, HelpersCarryTheCallersName) {
  std::thread caller([] {
    NameThisThread("rim-test-pf");
    std::mutex mu;
    std::set<std::string> names;
    std::atomic<int> started{0};
    ParallelFor(3, 1, 3, [&](int64_t, int64_t) {
      started.fetch_add(1);
      while (started.load() < 3) std::this_thread::yield();
      char name[16] = {};
      prctl(PR_GET_NAME, name);
      std::lock_guard<std::mutex> lock(mu);
      names.insert(name);
    });
    EXPECT_EQ(names, std::set<std::string>{"rim-test-pf"});
  });
  caller.join();
}
#endif
#if defined(__linux__)
// The server lowers its trainer thread's priority (--background-nice); the pool that thread drives
// was made elsewhere, at the normal priority, and must follow it down, or training would keep
// half its work at the priority that queries are meant to have to themselves.
TEST(WorkerPoolTest, WorkersFollowTheCallersPriorityDown) {
  WorkerPool pool(3);  // made here, at this thread's priority
  const int base = ThisThreadNice();
  if (base > 12) GTEST_SKIP() << "the test process already runs at nice " << base;
  std::thread lowered([&] {
    NameThisThread("rim-test-low");
    ASSERT_TRUE(LowerThisThreadPriority(base + 6));
    EXPECT_EQ(ThisThreadNice(), base + 6);
    // Never raised again: that would need privileges, and the call says the thread stays put.
    LowerThisThreadPriority(base);
    EXPECT_EQ(ThisThreadNice(), base + 6);
    std::mutex mu;
    std::set<int> nices;
    std::set<std::thread::id> ids;
    for (int round = 0; round < 2000 && ids.size() < 3; ++round) {
      pool.Run(12, [&](int) {
        std::lock_guard<std::mutex> lock(mu);
        nices.insert(ThisThreadNice());
        ids.insert(std::this_thread::get_id());
        std::this_thread::sleep_for(std::chrono::microseconds(200));
      });
    }
    EXPECT_EQ(ids.size(), 3u) << "every pool thread should have taken a task";
    EXPECT_EQ(nices, std::set<int>{base + 6});
  });
  lowered.join();
  EXPECT_EQ(ThisThreadNice(), base);  // one thread's priority, not the process's
}
#endif

}  // namespace rim
