// Shares the compute between sessions (DESIGN.md §5.2): every session's trainer asks for a slot
// before training a frame and gives it back after. At most `slots` frames train at once, and
// waiting trainers get slots in the order they asked, so a session that streams fast cannot
// starve a slow one: with one slot, two busy sessions alternate frame by frame.
//
// Frames, not iterations, are the unit: a frame's iterations run back to back on the same
// session's state, and queries still interleave with them (a reader waits at most one iteration).
#pragma once

#include <condition_variable>
#include <cstdint>
#include <mutex>

namespace rim::server {

class ComputeScheduler {
 public:
  // `slots` >= 1 frames may train at once.
  explicit ComputeScheduler(int slots);

  // A held slot; released when destroyed.
  class Lease {
   public:
    Lease(Lease&& other) noexcept : owner_(other.owner_) { other.owner_ = nullptr; }
    Lease(const Lease&) = delete;
    Lease& operator=(const Lease&) = delete;
    Lease& operator=(Lease&&) = delete;
    ~Lease() {
      if (owner_) owner_->Release();
    }

   private:
    friend class ComputeScheduler;
    explicit Lease(ComputeScheduler* owner) : owner_(owner) {}
    ComputeScheduler* owner_;
  };

  // Blocks until a slot is free and every earlier caller has been served.
  Lease Acquire();

  int slots() const { return slots_; }
  // Frames training now, and trainers waiting for a slot.
  int active() const;
  int waiting() const;

 private:
  void Release();

  const int slots_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  uint64_t next_ticket_ = 0;  // handed to the next caller of Acquire
  uint64_t next_served_ = 0;  // the ticket that may take the next free slot
  int active_ = 0;
};

// Slots for a machine with `cores` hardware threads: one per two cores (each frame's tensor
// operations use two threads), at least one.
int DefaultTrainSlots(unsigned cores);

}  // namespace rim::server
