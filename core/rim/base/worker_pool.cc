#include "rim/base/worker_pool.h"

#include <algorithm>

#include "rim/base/thread_priority.h"

namespace rim {

WorkerPool::WorkerPool(int threads) {
  for (int i = 1; i < std::max(threads, 1); ++i)
    workers_.emplace_back([this] {
      NameThisThread("rim-pool");
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

void WorkerPool::Drain() {
  for (int i = next_.fetch_add(1); i < tasks_; i = next_.fetch_add(1)) (*fn_)(i);
}

void WorkerPool::Run(int tasks, const std::function<void(int)>& fn) {
  if (workers_.empty() || tasks <= 1) {
    for (int i = 0; i < tasks; ++i) fn(i);
    return;
  }
  const int nice = ThisThreadNice();
  {
    std::lock_guard<std::mutex> lock(mu_);
    caller_nice_ = nice;
    fn_ = &fn;
    tasks_ = tasks;
    next_.store(0);
    busy_ = int(workers_.size());
    ++generation_;
  }
  start_cv_.notify_all();
  Drain();
  // Every worker checks in for this generation before the next Run may reset the task counter.
  std::unique_lock<std::mutex> lock(mu_);
  done_cv_.wait(lock, [this] { return busy_ == 0; });
  fn_ = nullptr;
}

void WorkerPool::Work() {
  uint64_t seen = 0;
  int my_nice = ThisThreadNice();
  for (;;) {
    int nice;
    {
      std::unique_lock<std::mutex> lock(mu_);
      start_cv_.wait(lock, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
      nice = caller_nice_;
    }
    if (nice > my_nice && LowerThisThreadPriority(nice)) my_nice = nice;
    Drain();
    std::lock_guard<std::mutex> lock(mu_);
    if (--busy_ == 0) done_cv_.notify_one();
  }
}

}  // namespace rim
