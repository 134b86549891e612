// A CPU budget for the meshing that watchers do in the background (docs/service.md, "Sharing the
// cores"): all of a server's watches together mesh at most `cores` CPU-seconds per second, so that
// dashboards never take the training's share of a small machine, however many tiles change.
//
// A token bucket in CPU-seconds: credit grows at `cores` per second of wall time up to `burst_s`
// seconds' worth, and each tile meshed is charged the CPU time its thread spent on it (a tile
// served from the cache costs next to nothing). A watcher meshes only while the credit is not
// negative; after a dear tile it waits until the refill has paid for it. Tile requests
// (GetMeshTiles, the dashboard's listings) answer a caller who waits, and are not budgeted.
#pragma once

#include <chrono>
#include <mutex>

namespace rim::server {

class MeshingBudget {
 public:
  using Clock = std::chrono::steady_clock;

  // `cores` <= 0: no budget (Delay is always zero). `burst_s`: how many seconds of credit build
  // up while meshing idles.
  explicit MeshingBudget(double cores, double burst_s = 1.0);

  double cores() const { return cores_; }
  bool limited() const { return cores_ > 0; }

  // How long a watcher must wait, from `now`, before it may mesh: zero while the credit is not
  // negative.
  Clock::duration Delay(Clock::time_point now = Clock::now());
  // Charges `cpu_s` CPU-seconds of meshing done by `now`.
  void Charge(double cpu_s, Clock::time_point now = Clock::now());

 private:
  void RefillLocked(Clock::time_point now);

  const double cores_;
  const double burst_;  // CPU-seconds
  std::mutex mu_;
  double credit_;  // CPU-seconds; negative while in debt
  Clock::time_point last_;
};

// The default budget for a machine with `cores` hardware threads: a tenth of them (0.2 on a
// 2-core box), at least a tenth of one. A dashboard at its default level (0.2 m) takes about 0.06
// cores there and is never held back; one at the finest level (5 cm) wants about 0.4, and a
// quarter of the cores let it starve the robot's training to its floor (docs/service.md, "Sharing
// the cores"; BENCHMARK.md, "Load").
double DefaultMeshingCores(unsigned cores);

// CPU time the calling thread has used, in seconds.
double ThreadCpuSeconds();

}  // namespace rim::server
