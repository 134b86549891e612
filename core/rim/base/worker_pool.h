// The project's one thread pool. A fixed set of threads that run the parallel parts of a training
// iteration (encode, gradient scatter, Adam) on the cores a session is given (train.threads). The
// caller's thread works too, so a pool of n threads starts n − 1. Regions are a few milliseconds
// long and come ~100 times a second, so the workers stay alive and wait on a condition variable
// instead of being started per region. The workers run at the priority of the thread that calls
// Run (a pool made on one thread and used from a lower-priority trainer thread follows it down;
// rim/base/thread_priority.h).
//
// ParallelFor below is the blocking loop on a pool of its own, for the large one-off loops of the
// evaluation (rim/eval), the mapper's queries and distance-field refreshes, and the simulator's
// sensors.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace rim {

class WorkerPool {
 public:
  // `name` names the workers (top -H, perf); nullptr or "" leaves them the name of the thread that
  // made the pool.
  explicit WorkerPool(int threads, const char* name = "rim-pool");
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  int threads() const { return int(workers_.size()) + 1; }

  // Runs fn(0) … fn(tasks − 1), each exactly once, spread over the threads in the order of their
  // index (a thread takes the next task when it finishes one); returns when all have finished.
  // Tasks are handed out in increasing index order, so a task may wait (spin) for one with a
  // smaller index: that one has been taken by a running thread. fn must not throw. Not
  // reentrant: one Run at a time per pool. Run waits for the tasks, not for the workers: when
  // the caller has run every task itself, it returns without waiting for a worker to wake.
  void Run(int tasks, const std::function<void(int)>& fn);

 private:
  void Work();
  // Runs tasks of the given region while any is left to take; true when this thread finished the
  // region's last task.
  bool Drain(uint32_t generation, const std::function<void(int)>& fn, int tasks);

  std::mutex mu_;
  std::condition_variable start_cv_, done_cv_;
  // The region being run, under mu_: what a worker reads when it wakes.
  const std::function<void(int)>* fn_ = nullptr;
  int tasks_ = 0;
  uint64_t generation_ = 0;
  // The region's generation (low 32 bits) in the high half, its next task in the low half.
  std::atomic<uint64_t> claim_{0};
  std::atomic<int> finished_{0};  // tasks of the region that have returned
  int caller_nice_ = 0;           // the nice value of the thread in Run
  bool stop_ = false;
  std::vector<std::thread> workers_;
};

// Calls fn(begin, end) on consecutive blocks of `block` items that cover [0, n), on `threads`
// threads (the caller's included, never more than there are blocks). Blocks are handed out in
// order on demand, so uneven blocks balance. The threads are a WorkerPool made for the call: its
// workers carry the caller's name and priority, and a call may nest inside another's fn. Each
// item's work must not depend on which block or thread runs it; then the result is the same for
// any `threads` and `block`. fn must not throw.
void ParallelFor(int64_t n, int64_t block, int threads,
                 const std::function<void(int64_t begin, int64_t end)>& fn);

}  // namespace rim
