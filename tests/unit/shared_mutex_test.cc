// WriterFirstSharedMutex: readers share it, a writer excludes everyone, and a waiting writer gets
// in while readers keep taking the lock back to back with overlapping holds (with a
// reader-preferring lock such readers keep it forever).
#include "rim/base/shared_mutex.h"

#include <atomic>
#include <chrono>
#include <mutex>
#include <shared_mutex>
#include <thread>
#include <vector>

#include "gtest/gtest.h"

namespace rim {
namespace {

using Clock = std::chrono::steady_clock;

TEST(WriterFirstSharedMutexTest, ReadersShareAndAWriterExcludes) {
  WriterFirstSharedMutex mu;
  {
    std::shared_lock a(mu);
    // A second reader (another thread) gets in; a writer does not.
    bool reader_in = false, writer_in = true;
    std::thread([&] {
      reader_in = mu.try_lock_shared();
      if (reader_in) mu.unlock_shared();
      writer_in = mu.try_lock();
      if (writer_in) mu.unlock();
    }).join();
    EXPECT_TRUE(reader_in);
    EXPECT_FALSE(writer_in);
  }
  std::unique_lock w(mu);
  bool reader_in = true;
  std::thread([&] {
    reader_in = mu.try_lock_shared();
    if (reader_in) mu.unlock_shared();
  }).join();
  EXPECT_FALSE(reader_in);
}

TEST(WriterFirstSharedMutexTest, AWaitingWriterGetsInBetweenOverlappingReaders) {
  WriterFirstSharedMutex mu;
  std::atomic<bool> writer_done{false};
  // Two readers take turns so that one always holds the lock: a reader leaves only on its turn
  // and once the other is back in, then takes the lock again at once. A reader-preferring lock
  // lets the returning reader in and the writer never gets a moment without readers. Here the
  // returning reader waits behind the writer; the one still in gives up waiting for it after
  // 50 ms and leaves, and the writer gets in. The readers stop when the writer got in, or at
  // the deadline.
  const auto deadline = Clock::now() + std::chrono::seconds(5);
  std::atomic<int> turn{0};
  std::atomic<bool> in[2] = {false, false};
  std::atomic<int> reads{0};
  std::vector<std::thread> readers;
  for (int t = 0; t < 2; ++t) {
    readers.emplace_back([&, t] {
      while (!writer_done && Clock::now() < deadline) {
        std::shared_lock lock(mu);
        in[t] = true;
        ++reads;
        const auto give_up = Clock::now() + std::chrono::milliseconds(50);
        while (!(turn == t && in[1 - t]) && !writer_done && Clock::now() < give_up)
          std::this_thread::yield();
        in[t] = false;
        turn = 1 - t;
      }
    });
  }
  while (reads < 100) std::this_thread::yield();
  bool in_time = false;
  {
    std::unique_lock lock(mu);
    in_time = Clock::now() < deadline;
    writer_done = true;
  }
  for (auto& r : readers) r.join();
  EXPECT_TRUE(in_time) << "the writer waited until the readers gave up";
}

}  // namespace
}  // namespace rim
