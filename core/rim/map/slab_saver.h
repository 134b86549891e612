// Background saving of slabs that left the local map (§3.3): the trainer hands batches over and
// goes on; a worker thread writes them into the thread-safe sub-map store. Readers that need the
// store to be current call Flush() first.
#pragma once

#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>

#include "rim/map/submap_store.h"

namespace rim {

class SlabSaver {
 public:
  // With `background` false, Submit writes synchronously.
  SlabSaver(SubmapStore* store, bool background);
  ~SlabSaver();
  SlabSaver(const SlabSaver&) = delete;
  SlabSaver& operator=(const SlabSaver&) = delete;

  void Submit(SlabBatch&& batch);
  // Returns once every batch submitted before the call is in the store.
  void Flush();
  size_t pending() const;

 private:
  void Run();

  SubmapStore* store_;
  bool background_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<SlabBatch> queue_;
  size_t in_flight_ = 0;
  bool stop_ = false;
  std::thread worker_;
};

}  // namespace rim
