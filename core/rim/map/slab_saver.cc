#include "rim/map/slab_saver.h"

#include "rim/base/thread_priority.h"

namespace rim {

SlabSaver::SlabSaver(SubmapStore* store, bool background) : store_(store), background_(background) {
  if (background_)
    worker_ = std::thread([this] {
      NameThisThread("rim-saver");
      Run();
    });
}

SlabSaver::~SlabSaver() {
  if (!background_) return;
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  worker_.join();
}

void SlabSaver::Submit(SlabBatch&& batch) {
  if (!background_) {
    store_->Write(batch);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mu_);
    queue_.push_back(std::move(batch));
  }
  cv_.notify_all();
}

void SlabSaver::Flush() {
  if (!background_) return;
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [this] { return queue_.empty() && in_flight_ == 0; });
}

size_t SlabSaver::pending() const {
  std::lock_guard<std::mutex> lock(mu_);
  return queue_.size() + in_flight_;
}

void SlabSaver::Run() {
  std::unique_lock<std::mutex> lock(mu_);
  while (true) {
    cv_.wait(lock, [this] { return stop_ || !queue_.empty(); });
    if (queue_.empty()) return;  // stop requested and nothing left to write
    SlabBatch batch = std::move(queue_.front());
    queue_.pop_front();
    ++in_flight_;
    lock.unlock();
    store_->Write(batch);
    lock.lock();
    --in_flight_;
    cv_.notify_all();
  }
}

}  // namespace rim
