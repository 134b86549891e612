#include "rim/base/worker_pool.h"

#include <algorithm>
#include <string>

#include "rim/base/thread_priority.h"

namespace rim {

WorkerPool::WorkerPool(int threads, const char* name) {
  for (int i = 1; i < std::max(threads, 1); ++i)
    workers_.emplace_back([this, name = std::string(name != nullptr ? name : "")] {
      if (!name.empty()) NameThisThread(name);
      Work();
    });
}

WorkerPool::~WorkerPool() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  start_cv_.notify_all();
  for (std::thread& t : workers_) t.join();
}

bool WorkerPool::Drain(uint32_t generation, const std::function<void(int)>& fn, int tasks) {
  uint64_t claim = claim_.load(std::memory_order_acquire);
  for (;;) {
    // A claim is (generation, next task): a thread that woke for an earlier region finds another
    // generation here and takes nothing, so it never runs a task of a region it did not see.
    if (uint32_t(claim >> 32) != generation || int(uint32_t(claim)) >= tasks) return false;
    if (!claim_.compare_exchange_weak(claim, claim + 1, std::memory_order_acq_rel)) continue;
    fn(int(uint32_t(claim)));
    if (finished_.fetch_add(1, std::memory_order_acq_rel) + 1 == tasks) return true;
    claim = claim_.load(std::memory_order_acquire);
  }
}

void WorkerPool::Run(int tasks, const std::function<void(int)>& fn) {
  if (workers_.empty() || tasks <= 1) {
    for (int i = 0; i < tasks; ++i) fn(i);
    return;
  }
  const int nice = ThisThreadNice();
  uint32_t generation;
  {
    std::lock_guard<std::mutex> lock(mu_);
    caller_nice_ = nice;
    fn_ = &fn;
    tasks_ = tasks;
    generation = uint32_t(++generation_);
    finished_.store(0, std::memory_order_relaxed);
    claim_.store(uint64_t(generation) << 32, std::memory_order_release);
  }
  start_cv_.notify_all();
  if (Drain(generation, fn, tasks)) return;
  // Wait only for tasks that a worker took and is still running. A worker that has not woken yet
  // (on a busy machine it may sit behind other threads for milliseconds) is not waited for: it
  // will find every task taken. The last task's finisher notifies under the lock, so the wake-up
  // cannot fall between the check and the wait.
  std::unique_lock<std::mutex> lock(mu_);
  done_cv_.wait(lock, [&] { return finished_.load(std::memory_order_acquire) == tasks; });
}

void WorkerPool::Work() {
  uint64_t seen = 0;
  int my_nice = ThisThreadNice();
  for (;;) {
    int nice, tasks;
    const std::function<void(int)>* fn;
    {
      std::unique_lock<std::mutex> lock(mu_);
      start_cv_.wait(lock, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
      nice = caller_nice_;
      fn = fn_;
      tasks = tasks_;
    }
    if (nice > my_nice && LowerThisThreadPriority(nice)) my_nice = nice;
    // fn is only called for a task claimed under this generation, and Run does not return while
    // such a task runs, so fn is still alive whenever it is called.
    if (Drain(uint32_t(seen), *fn, tasks)) {
      std::lock_guard<std::mutex> lock(mu_);
      done_cv_.notify_one();
    }
  }
}

void ParallelFor(int64_t n, int64_t block, int threads,
                 const std::function<void(int64_t begin, int64_t end)>& fn) {
  if (n <= 0) return;
  block = std::max<int64_t>(block, 1);
  const int64_t blocks = (n + block - 1) / block;
  WorkerPool pool(int(std::min<int64_t>(std::max(threads, 1), blocks)), /*name=*/nullptr);
  // Run counts tasks in an int: more blocks than that go in rounds.
  constexpr int64_t kRound = int64_t(1) << 30;
  for (int64_t first = 0; first < blocks; first += kRound) {
    pool.Run(int(std::min(kRound, blocks - first)), [&](int task) {
      const int64_t begin = (first + task) * block;
      fn(begin, std::min(n, begin + block));
    });
  }
}

}  // namespace rim
