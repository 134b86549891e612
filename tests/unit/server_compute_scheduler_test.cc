// ComputeScheduler (server/session/compute_scheduler.h): never more frames training than slots, and
// slots handed out in the order they were asked for.
#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>
#include <vector>

#include "gtest/gtest.h"
#include "server/session/compute_scheduler.h"

namespace rim::server {
namespace {

using namespace std::chrono_literals;

// Waits until `n` trainers are queued behind the held slots.
void WaitForWaiting(const ComputeScheduler& s, int n) {
  for (int i = 0; i < 2000 && s.waiting() < n; ++i) std::this_thread::sleep_for(1ms);
  ASSERT_EQ(s.waiting(), n);
}

TEST(ComputeSchedulerTest, SlotsGoInTheOrderTheyWereAskedFor) {
  ComputeScheduler scheduler(1);
  std::vector<int> order;
  std::mutex mu;
  std::vector<std::thread> threads;
  {
    auto held = scheduler.Acquire();
    for (int i = 0; i < 4; ++i) {
      threads.emplace_back([&, i] {
        auto lease = scheduler.Acquire();
        std::lock_guard<std::mutex> lock(mu);
        order.push_back(i);
      });
      WaitForWaiting(scheduler, i + 1);  // thread i is queued before thread i + 1 starts
    }
    EXPECT_TRUE(order.empty());  // nobody trains while the slot is held
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(order, (std::vector<int>{0, 1, 2, 3}));
  EXPECT_EQ(scheduler.active(), 0);
}

TEST(ComputeSchedulerTest, NeverMoreFramesThanSlotsAndTwoBusySessionsAlternate) {
  ComputeScheduler scheduler(2);
  std::atomic<int> now{0}, peak{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 6; ++t)
    threads.emplace_back([&] {
      for (int k = 0; k < 20; ++k) {
        auto lease = scheduler.Acquire();
        const int n = ++now;
        int p = peak.load();
        while (n > p && !peak.compare_exchange_weak(p, n)) {
        }
        std::this_thread::sleep_for(200us);
        --now;
      }
    });
  for (auto& t : threads) t.join();
  EXPECT_EQ(peak.load(), 2);

  // One slot, two sessions training back to back: neither gets two frames in a row while the
  // other waits.
  ComputeScheduler one(1);
  std::vector<int> frames;
  std::mutex mu;
  auto session = [&](int id) {
    for (int k = 0; k < 10; ++k) {
      auto lease = one.Acquire();
      {
        std::lock_guard<std::mutex> lock(mu);
        frames.push_back(id);
      }
      std::this_thread::sleep_for(2ms);
    }
  };
  std::thread a, b;
  {
    auto held = one.Acquire();  // both start queued
    a = std::thread(session, 0);
    WaitForWaiting(one, 1);
    b = std::thread(session, 1);
    WaitForWaiting(one, 2);
  }
  a.join();
  b.join();
  ASSERT_EQ(frames.size(), 20u);
  for (size_t i = 1; i < frames.size(); ++i) EXPECT_NE(frames[i], frames[i - 1]) << i;
}

TEST(ComputeSchedulerTest, DefaultSlotsFollowTheCores) {
  EXPECT_EQ(DefaultTrainSlots(0), 1);
  EXPECT_EQ(DefaultTrainSlots(2), 1);
  EXPECT_EQ(DefaultTrainSlots(16), 8);
  EXPECT_EQ(ComputeScheduler(0).slots(), 1);
}

}  // namespace
}  // namespace rim::server
