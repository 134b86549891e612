#include "server/session/compute_scheduler.h"

#include <algorithm>

namespace rim::server {

ComputeScheduler::ComputeScheduler(int slots) : slots_(std::max(1, slots)) {}

ComputeScheduler::Lease ComputeScheduler::Acquire() {
  std::unique_lock<std::mutex> lock(mu_);
  const uint64_t ticket = next_ticket_++;
  cv_.wait(lock, [&] { return ticket == next_served_ && active_ < slots_; });
  ++next_served_;
  ++active_;
  // The next ticket may be able to take another free slot right away.
  cv_.notify_all();
  return Lease(this);
}

void ComputeScheduler::Release() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    --active_;
  }
  cv_.notify_all();
}

int ComputeScheduler::active() const {
  std::lock_guard<std::mutex> lock(mu_);
  return active_;
}

int ComputeScheduler::waiting() const {
  std::lock_guard<std::mutex> lock(mu_);
  return int(next_ticket_ - next_served_);
}

int DefaultTrainSlots(unsigned cores) { return std::max(1, int(cores / 2)); }

}  // namespace rim::server
