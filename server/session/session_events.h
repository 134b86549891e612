// What sessions and handlers report as they work, for the service's metrics (DESIGN.md §5.4).
// Sessions know nothing of Prometheus: they call these hooks, which ServerMetrics implements.
// Every hook may be called from any thread; the defaults do nothing.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "absl/status/status.h"
#include "rim/mapper.h"

namespace rim::server {

class SessionEvents {
 public:
  virtual ~SessionEvents() = default;
  virtual void ScanAccepted(const std::string& robot) {}
  virtual void ScanRejected(const std::string& robot, absl::StatusCode code) {}
  // A frame was trained (`timing` holds its per-stage times), or training it failed.
  virtual void FrameIntegrated(const std::string& robot, const StageTimings& timing) {}
  virtual void FrameFailed(const std::string& robot) {}
  // Iterations trained between frames, while a robot streaming in real time had not sent its
  // next scan (Mapper::TrainBetweenFrames); `timing` holds their stages, train_s their wall time.
  virtual void TrainedBetweenFrames(const std::string& robot, const StageTimings& timing) {}
  // The session's distance field was refreshed: after a frame (then also in that frame's
  // timing.distance_s), or between frames (a refresh made up after a budget skip, or at a
  // stream's end).
  virtual void DistanceRefreshed(const std::string& robot, double seconds) {}
  virtual void WalAppended(const std::string& robot, double seconds) {}
  virtual void CheckpointWritten(const std::string& robot, double seconds, uint64_t bytes) {}
  // A tile was meshed and Draco-encoded (cache misses only); `blocks_remeshed` of its mesh blocks
  // were meshed anew, the others came from the mesh block cache.
  virtual void TileEncoded(const std::string& robot, size_t bytes, double seconds,
                           int blocks_remeshed) {}
  // A watcher spent `cpu_seconds` of CPU meshing and encoding one tile (cache hits included), and
  // waited `budget_wait_seconds` for the meshing budget before it
  // (server/session/meshing_budget.h).
  virtual void WatchMeshed(const std::string& robot, double cpu_seconds,
                           double budget_wait_seconds) {}
  // A watcher pushed a tile `delay_seconds` after the frame that made its version was integrated.
  virtual void TilePushed(const std::string& robot, double delay_seconds) {}
  virtual void QueryAnswered(const std::string& robot, size_t points, double seconds) {}
};

}  // namespace rim::server
