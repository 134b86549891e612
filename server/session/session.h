// One robot's mapping session in the service: the mapper, its bounded ingest queue and the
// trainer thread that owns training (DESIGN.md §5.2). gRPC handlers only validate and call
// Submit(); they never train. Knows nothing of gRPC: acks go out through callbacks.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "rim/base/scan.h"
#include "rim/config/config.h"
#include "rim/mapper.h"
#include "server/session/compute_scheduler.h"
#include "server/session/meshing_budget.h"
#include "server/session/sensor_clock.h"
#include "server/session/session_events.h"
#include "server/session/session_lease.h"
#include "server/session/tile_cache.h"
#include "server/wal/wal.h"

namespace rim::server {

struct SessionOptions {
  // Accepted scans waiting for training. When full, Submit() says so and the stream handler stops
  // reading until OnSpace fires: backpressure reaches the robot through gRPC flow control.
  int queue_length = 8;
  // The trainer writes a checkpoint into checkpoint_dir every this many integrated frames and
  // truncates the write-ahead log, so that the log (and replay after a crash) stays short.
  int checkpoint_every_frames = 0;  // 0: never on its own
  std::string checkpoint_dir;
  // The session folder's lease (server/session/session_lease.h): checked before every write to the
  // folder (log appends, checkpoints), so that a replica that lost the session writes nothing
  // more. Null: no check.
  std::shared_ptr<const SessionLease> lease;
  // Receives what the session does, for metrics; not owned, outlives the session; may be null.
  SessionEvents* events = nullptr;
  // Shares the compute with other sessions: a slot is held while a frame trains. Not owned,
  // outlives the session; null: train whenever a scan is queued.
  ComputeScheduler* scheduler = nullptr;
  // The nice value of the session's background threads (training with its refreshes, and the
  // meshing of its watchers): above 0, queries and ingest on the normal-priority RPC threads
  // take the cores first (docs/service.md, "Sharing the cores").
  int background_nice = 0;
  // The CPU budget of its watchers' meshing, shared with other sessions' watchers
  // (server/session/meshing_budget.h). Not owned, outlives the session; null: no budget.
  MeshingBudget* meshing_budget = nullptr;
};

struct IntegratedAck {
  uint64_t sequence = 0;
  absl::Status status;  // not OK if training this scan failed
  int iterations = 0;
  int rays_per_iteration = 0;  // the batch of each iteration
  uint64_t map_version = 0;
  size_t queue_depth = 0;
  uint64_t lag_frames = 0;
};

// The sensor pose of one integrated frame.
struct TrajectoryPoint {
  uint64_t index = 0;  // counts the frames this process integrated in the session, from 0
  Vec3f position = Vec3f::Zero();
  Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
};

struct SessionStats {
  uint64_t accepted = 0, integrated = 0, rejected = 0;
  uint64_t failed = 0;  // accepted, but training it returned an error
  uint64_t last_checkpoint_bytes = 0;
  int64_t wal_bytes = 0;
  size_t queue_depth = 0;
  int iterations_per_frame = 0;
  int rays_per_iteration = 0;  // the batch of those iterations
  float last_loss = 0;
  StageTimings last_timing;
  // The regime of the last accepted scan (docs/service.md, "Replays keep the offline map"): true
  // while a real-time stream keeps to its sensor's clock and iterations keep up with it; false
  // for a replay or an upload, which trains the configured iterations and is pushed back instead.
  bool real_time = false;
};

// Scans that arrive less than this far apart on average come from an upload, not from a sensor:
// the queue paces their training (Session::AdaptiveIterations), not their rate.
inline constexpr double kMinPacedPeriodS = 0.02;

// Iterations trained between frames per hold of a training slot (Session::TrainBetweenFrames):
// the scheduler and the queue are checked before each one.
inline constexpr int kBetweenFramesIterations = 4;

// Iterations that keep a session up with a robot that sends a scan every `period_s` seconds,
// when an iteration takes `iteration_s` and the rest of a frame (slide, preprocessing, its share
// of distance refreshes) `overhead_s`, wall time: what fits in 95 % of the period, less a quarter
// period for each scan waiting behind this one (`queue_depth` counts this one), so that the queue
// stays short; within [min_iterations, max_iterations]. max_iterations when the period is below
// kMinPacedPeriodS or a cost is unknown (not positive, or NaN).
int PacedIterationCount(double period_s, double iteration_s, double overhead_s, size_t queue_depth,
                        int min_iterations, int max_iterations);

class Session {
 public:
  using IntegratedFn = std::function<void(const IntegratedAck&)>;

  // With a write-ahead log, Submit() makes every scan durable before accepting it; record indices
  // count accepted scans, so a checkpoint holding F frames covers the records below F.
  static absl::StatusOr<std::unique_ptr<Session>> Create(
      const std::string& robot_id, const MapperConfig& config, const SessionOptions& options,
      std::unique_ptr<WriteAheadLog> wal = nullptr);
  // Takes over an existing mapper (a loaded session, its log already replayed).
  static std::unique_ptr<Session> Adopt(const std::string& robot_id, std::unique_ptr<Mapper> mapper,
                                        const SessionOptions& options,
                                        std::unique_ptr<WriteAheadLog> wal = nullptr);
  ~Session();  // drains the queue, then stops the trainer

  // Queues a validated scan. RESOURCE_EXHAUSTED when the queue is full (nothing changed; call
  // again after OnSpace); FAILED_PRECONDITION once the session is closing. `on_integrated` runs on
  // the trainer thread after the scan is trained. `real_time`: the scan comes from a stream at a
  // sensor's rate (its sender said so). Iterations are cut only for such scans, and only while
  // their timestamps keep to the sensor's clock (SensorClock): they set the pace that
  // PacedIterations trains to, and a queue that fills anyway takes iterations away
  // (AdaptiveIterations). Any other scan (an upload, a replay, a stream ahead of its sensor's
  // clock) clears the pace and trains the configured iterations; its sender waits for space.
  absl::Status Submit(uint64_t sequence, PosedScan scan, IntegratedFn on_integrated,
                      bool real_time = false);
  // Registers a one-shot callback run (on the trainer thread) when the queue has room again.
  void OnSpace(std::function<void()> fn);
  // Saves a checkpoint of the map into `dir`, then drops log records the checkpoint covers.
  absl::Status Checkpoint(const std::string& dir);
  // Waits until more than `seen` frames are integrated, the session closes, or the timeout passes;
  // returns the integrated count and sets *closed when the session is closing.
  uint64_t WaitForIntegrated(uint64_t seen, std::chrono::milliseconds timeout, bool* closed);
  // Waits until every queued scan is integrated.
  void Drain();
  // Runs `done` on the trainer thread once every scan queued so far is integrated and the
  // distance field covers them all (refreshed then if it is behind, whatever the refresh budget);
  // at once (on the caller's thread) when the session is closing. StreamScans calls it when a
  // client half-closes, so that a stream's end means every one of its frames can be queried.
  void Settle(std::function<void()> done);
  // Stops accepting, drains, stops the trainer. Idempotent; callable from several threads at once,
  // each returning once the trainer has stopped.
  void Close();

  // Iterations the trainer will use for the next frame, given the queue depth: the configured
  // number while the queue is short, fewer as it fills, never below train.min_iterations (§5.1).
  // `fewest`, `most`: the bounds, when not train.min_iterations and train.iterations (a paced
  // frame's smaller batches, Mapper::IterationBounds).
  int AdaptiveIterations(size_t queue_depth, int fewest = -1, int most = -1) const;
  // The most iterations that keep up with a robot streaming in real time (PacedIterationCount
  // with the robot's mean interval between scans, `period_s`, and the trainer's measured costs);
  // train.iterations until three frames have measured them.
  // `rays`: the frame's batch (0: sampler.rays_per_iteration), whose measured cost it plans with.
  int PacedIterations(size_t queue_depth, double period_s, int fewest = -1, int most = -1,
                      int rays = 0) const;
  // The batch of the next frame: sampler.rays_per_iteration, or for a paced frame
  // sampler.paced_rays_per_iteration when the period fits at least its floor of iterations
  // (Mapper::IterationBounds), by the costs measured so far. Trainer thread only.
  int FrameBatch(size_t queue_depth, double period_s);

  const std::string& robot_id() const { return robot_id_; }
  int background_nice() const { return options_.background_nice; }
  MeshingBudget* meshing_budget() const { return options_.meshing_budget; }
  SessionEvents* events() const { return options_.events; }
  TileCache& tiles() { return tiles_; }
  Mapper& mapper() { return *mapper_; }
  const Mapper& mapper() const { return *mapper_; }
  SessionStats Stats() const;
  // The outcome of the last periodic checkpoint (OK if none failed).
  absl::Status last_checkpoint_status() const;
  // Counts a scan of this session refused by a handler (bad input, full queue, closing).
  void CountRejected(absl::StatusCode code);
  // Reports an answered query batch to the metrics.
  void RecordQuery(size_t points, double seconds);
  // When (steady clock seconds) the first frame that brought the map to `map_version` or beyond
  // was integrated: a tile's version is the map version of the frame that last changed it. The
  // session remembers its last 1024 frames; older versions give the oldest it remembers, and a
  // version no frame of this process made (a loaded session's) gives -1.
  double IntegratedAt(uint64_t map_version) const;
  // Reports a tile pushed to a watcher (metrics: delay since its frame was integrated).
  void RecordTilePush(uint64_t tile_version);
  // The sensor poses of integrated frames with index >= `since`, oldest first, and in *next the
  // index the next frame will get. The session keeps the last kTrajectoryLimit frames it
  // integrated in this process (a loaded session starts empty); `since` older than those gives
  // the oldest kept.
  static constexpr size_t kTrajectoryLimit = 20000;
  std::vector<TrajectoryPoint> Trajectory(uint64_t since, uint64_t* next) const;
  // The last integrated frame's pose; false before the first.
  bool LatestPose(TrajectoryPoint* pose) const;

  // Whether a scan with this sequence number was accepted already: at or below the highest one
  // accepted (in this process, or before it: RestoreLastSequence). Clients number a robot's scans
  // increasingly; a client resending after a broken stream relies on this (Scan.resend).
  bool Accepted(uint64_t sequence) const;
  // Another replica holds the session folder's lease now (a write found its token gone): this
  // session writes nothing more, and the manager drops it (SessionManager::Get).
  bool fenced() const { return fenced_; }
  void RestoreLastSequence(uint64_t sequence);
  // In a session folder: the highest accepted sequence at the last checkpoint.
  static constexpr const char* kSequenceFile = "sequence.rimf";

 private:
  Session(const std::string& robot_id, std::unique_ptr<Mapper> mapper,
          const SessionOptions& options, std::unique_ptr<WriteAheadLog> wal);
  void Run();
  // Trainer thread: refreshes the distance field if it is behind the map; returns the seconds
  // taken (0 when it was current).
  double RefreshDistanceFieldIfBehind();
  // Trainer thread, holding a training slot: refreshes it now, records when and how long.
  double RefreshDistanceFieldNow();
  // Trainer thread, `lock` (on mu_) held and nothing ready: trains a few iterations between
  // frames while no scan comes (Mapper::TrainBetweenFrames); false when it should not now (a
  // refresh owed is due, or another session wants the training slot), so the caller waits.
  bool TrainBetweenFrames(std::unique_lock<std::mutex>& lock);

  struct Item {
    uint64_t sequence;
    PosedScan scan;
    IntegratedFn on_integrated;
    bool real_time;  // Submit's
  };

  const std::string robot_id_;
  std::unique_ptr<Mapper> mapper_;
  const SessionOptions options_;
  std::unique_ptr<WriteAheadLog> wal_;  // guarded by mu_
  uint64_t next_index_ = 0;             // index of the next accepted scan

  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Item> queue_;
  bool busy_ = false;  // the trainer is integrating a popped item
  bool closing_ = false;
  std::vector<std::function<void()>> space_waiters_;
  std::vector<std::function<void()>> settle_waiters_;
  SessionStats stats_;
  // (map version after the frame, steady seconds when it was integrated), oldest first.
  std::deque<std::pair<uint64_t, double>> integrated_at_;
  std::atomic<bool> fenced_{false};
  uint64_t last_sequence_ = 0;  // the highest accepted sequence, when has_sequence_
  bool has_sequence_ = false;
  std::deque<TrajectoryPoint> trajectory_;  // the last kTrajectoryLimit frames, oldest first
  uint64_t trajectory_next_ = 0;
  absl::Status last_checkpoint_;
  // Trainer thread only: when the distance field's last refresh ended and how long it took
  // (steady clock seconds), to keep refreshes between frames to a share of the session's time.
  double last_refresh_end_s_ = -1e9, last_refresh_s_ = 0;
  // The robot's pace (under mu_): when the last scan was accepted, and the mean interval between
  // accepted scans (exponential average; 0 until two arrived less than 2 s apart).
  double last_arrival_s_ = -1, arrival_period_s_ = 0;
  // Under mu_: the queue refused a scan or made a stream wait for space since the last scan was
  // accepted.
  bool pushed_back_ = false;
  // Under mu_: the sensor's clock of the real-time scans, to tell a live sensor from a replay.
  SensorClock clock_;
  // Trainer thread only: exponential averages of a training iteration's wall time and of the rest
  // of a frame's (slide, preprocessing, distance refreshes), and the frames they have seen.
  // iteration_s_ on the configured batch, small_iteration_s_ on the paced one.
  double iteration_s_ = 0, small_iteration_s_ = 0, overhead_s_ = 0;
  int paced_frames_ = 0;
  int frames_on_full_batch_ = 0;  // paced frames in a row that kept the configured batch
  // An iteration's cost on a batch of `rays`: measured, or the other batch's in proportion; 0
  // while neither is known.
  double IterationSeconds(int rays) const;
  // Trainer thread only: a refresh was skipped for the budget after the last frame; the trainer
  // makes it up once the budget allows, if no frame comes first.
  bool refresh_owed_ = false;
  // Trainer thread only: iterations the last frame may still train between frames (its bound,
  // IterationBounds' most, less what it trained; 0 unless the frame was paced), and their batch.
  int between_left_ = 0;
  int between_rays_ = 0;
  TileCache tiles_;
  // Held while joining trainer_, so that concurrent Close() calls neither race on the thread
  // object nor join it twice.
  std::mutex join_mu_;
  std::thread trainer_;
};

}  // namespace rim::server
