#include "server/session/meshing_budget.h"

#include <time.h>

#include <algorithm>

namespace rim::server {

MeshingBudget::MeshingBudget(double cores, double burst_s)
    : cores_(cores > 0 ? cores : 0.0),
      burst_(std::max(0.0, burst_s) * (cores > 0 ? cores : 0.0)),
      credit_(burst_),
      last_(Clock::now()) {}

void MeshingBudget::RefillLocked(Clock::time_point now) {
  if (now <= last_) return;
  credit_ = std::min(burst_, credit_ + cores_ * std::chrono::duration<double>(now - last_).count());
  last_ = now;
}

MeshingBudget::Clock::duration MeshingBudget::Delay(Clock::time_point now) {
  if (!limited()) return Clock::duration::zero();
  std::lock_guard<std::mutex> lock(mu_);
  RefillLocked(now);
  // A nanosecond of CPU is within rounding of the refill's arithmetic: no debt.
  if (credit_ >= -1e-9) return Clock::duration::zero();
  return std::chrono::duration_cast<Clock::duration>(
             std::chrono::duration<double>(-credit_ / cores_)) +
         Clock::duration(1);  // rounded up: waiting that long leaves the credit at zero or above
}

void MeshingBudget::Charge(double cpu_s, Clock::time_point now) {
  if (!limited() || !(cpu_s > 0)) return;
  std::lock_guard<std::mutex> lock(mu_);
  RefillLocked(now);
  credit_ -= cpu_s;
}

double DefaultMeshingCores(unsigned cores) { return std::max(1u, cores) / 10.0; }

double ThreadCpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

}  // namespace rim::server
