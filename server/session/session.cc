#include "server/session/session.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <optional>

#include "absl/strings/str_cat.h"
#include "rim/base/binary_io.h"
#include "rim/base/thread_priority.h"

namespace rim::server {
namespace {

double SteadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Bytes of the files under a checkpoint directory, the write-ahead log excluded.
uint64_t CheckpointBytes(const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  uint64_t total = 0;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_directory(ec) && it->path().filename() == "wal") {
      it.disable_recursion_pending();
      continue;
    }
    if (it->is_regular_file(ec)) total += it->file_size(ec);
  }
  return total;
}

}  // namespace

absl::StatusOr<std::unique_ptr<Session>> Session::Create(const std::string& robot_id,
                                                         const MapperConfig& config,
                                                         const SessionOptions& options,
                                                         std::unique_ptr<WriteAheadLog> wal) {
  auto mapper = Mapper::Create(config);
  if (!mapper.ok()) return mapper.status();
  return Adopt(robot_id, std::move(*mapper), options, std::move(wal));
}

std::unique_ptr<Session> Session::Adopt(const std::string& robot_id, std::unique_ptr<Mapper> mapper,
                                        const SessionOptions& options,
                                        std::unique_ptr<WriteAheadLog> wal) {
  return std::unique_ptr<Session>(
      new Session(robot_id, std::move(mapper), options, std::move(wal)));
}

Session::Session(const std::string& robot_id, std::unique_ptr<Mapper> mapper,
                 const SessionOptions& options, std::unique_ptr<WriteAheadLog> wal)
    : robot_id_(robot_id),
      mapper_(std::move(mapper)),
      options_(options),
      wal_(std::move(wal)),
      tiles_([events = options.events, robot_id](size_t bytes, double seconds, int blocks) {
        if (events) events->TileEncoded(robot_id, bytes, seconds, blocks);
      }) {
  next_index_ = uint64_t(mapper_->frames());
  if (wal_) next_index_ = std::max(next_index_, wal_->next_index());
  stats_.integrated = uint64_t(mapper_->frames());
  stats_.accepted = stats_.integrated;
  stats_.iterations_per_frame = mapper_->config().train.iterations;
  stats_.rays_per_iteration = mapper_->config().sampler.rays_per_iteration;
  // The trainer below decides when the distance field is refreshed (Run).
  mapper_->set_refresh_in_frame(false);
  trainer_ = std::thread([this] { Run(); });
}

Session::~Session() { Close(); }

int Session::AdaptiveIterations(size_t queue_depth, int fewest, int most) const {
  const TrainConfig& t = mapper_->config().train;
  if (most < 0) most = t.iterations;
  if (fewest < 0) fewest = std::min(t.min_iterations, most);
  if (queue_depth <= 1 || options_.queue_length <= 1) return most;
  // Linear from the full count with one scan waiting down to the minimum with a full queue.
  const double fill = double(queue_depth - 1) / double(options_.queue_length - 1);
  const int n = int(std::lround(most - fill * (most - fewest)));
  return std::clamp(n, fewest, most);
}

int PacedIterationCount(double period_s, double iteration_s, double overhead_s, size_t queue_depth,
                        int min_iterations, int max_iterations) {
  if (!(period_s >= kMinPacedPeriodS) || !(iteration_s > 0) || !(overhead_s >= 0))
    return max_iterations;
  const double waiting = double(std::max<size_t>(queue_depth, 1) - 1);
  const double budget = period_s * (0.95 - 0.25 * waiting) - overhead_s;
  const double n = std::floor(budget / iteration_s);
  if (!(n >= double(min_iterations))) return min_iterations;
  return int(std::min(n, double(max_iterations)));
}

double Session::IterationSeconds(int rays) const {
  const int full = mapper_->config().sampler.rays_per_iteration;
  const bool small = rays != full;
  const double measured = small ? small_iteration_s_ : iteration_s_;
  if (measured > 0) return measured;
  // Not measured on this batch yet: the other one's, in proportion.
  const double other = small ? iteration_s_ : small_iteration_s_;
  const int other_rays = small ? full : mapper_->config().sampler.paced_rays_per_iteration;
  return other > 0 && other_rays > 0 ? other * double(rays) / double(other_rays) : 0;
}

int Session::PacedIterations(size_t queue_depth, double period_s, int fewest, int most,
                             int rays) const {
  const TrainConfig& t = mapper_->config().train;
  if (most < 0) most = t.iterations;
  if (fewest < 0) fewest = std::min(t.min_iterations, most);
  if (rays <= 0) rays = mapper_->config().sampler.rays_per_iteration;
  if (paced_frames_ < 3) return most;  // the costs are not known yet
  return PacedIterationCount(period_s, IterationSeconds(rays), overhead_s_, queue_depth, fewest,
                             most);
}

int Session::FrameBatch(size_t queue_depth, double period_s) {
  const SamplerConfig& s = mapper_->config().sampler;
  const int small = s.paced_rays_per_iteration;
  if (!(period_s >= kMinPacedPeriodS) || small <= 0 || small == s.rays_per_iteration)
    return s.rays_per_iteration;
  if (paced_frames_ < 3) return small;
  // Every 20th frame that kept the configured batch tries the small one, so that its cost is
  // measured again once the load has changed.
  if (++frames_on_full_batch_ >= 20) {
    frames_on_full_batch_ = 0;
    return small;
  }
  // The small batch when the period fits its floor (the configured floor's rays); otherwise the
  // configured batch, whose floor costs less than the same rays in small batches.
  const int fewest = mapper_->IterationBounds(small).first;
  if (PacedIterationCount(period_s, IterationSeconds(small), overhead_s_, queue_depth, 0,
                          1 << 20) >= fewest) {
    frames_on_full_batch_ = 0;
    return small;
  }
  return s.rays_per_iteration;
}

absl::Status Session::Submit(uint64_t sequence, PosedScan scan, IntegratedFn on_integrated,
                             bool real_time) {
  std::lock_guard<std::mutex> lock(mu_);
  if (closing_)
    return absl::FailedPreconditionError(absl::StrCat("session ", robot_id_, " is closing"));
  if (queue_.size() >= size_t(options_.queue_length)) {
    pushed_back_ = true;
    return absl::ResourceExhaustedError(absl::StrCat(
        "ingest queue of session ", robot_id_, " is full (", options_.queue_length, " scans)"));
  }
  if (options_.lease) {
    if (absl::Status owned = options_.lease->Check(); !owned.ok()) {
      fenced_ = true;
      return owned;
    }
  }
  if (wal_) {
    // Durable before it counts as accepted: a crash after this point loses nothing (§5.3).
    const auto start = std::chrono::steady_clock::now();
    absl::Status logged = wal_->Append(next_index_, sequence, scan);
    if (!logged.ok()) return logged;
    stats_.wal_bytes = wal_->bytes();
    if (options_.events) options_.events->WalAppended(robot_id_, SecondsSince(start));
  }
  ++next_index_;
  // The robot's pace, for PacedIterations: a gap of two seconds or more is a pause, not a pace,
  // and a scan that comes after the session pushed back came at the session's pace, not the
  // robot's (an upload throttled by a full queue would otherwise look like a slow sensor).
  // An upload (a sender that did not say it streams in real time) clears the pace: its scans come
  // as fast as the sender makes or reads them, which on a shared machine tracks our own load.
  // A real-time stream whose timestamps run ahead of their arrival is a replay, paced like an
  // upload (SensorClock).
  const double now = SteadySeconds();
  if (real_time) {
    clock_.Arrive(now, scan.timestamp_s, pushed_back_);
  } else {
    clock_.Reset();
  }
  const bool paced = real_time && !clock_.ahead();
  if (!paced) {
    arrival_period_s_ = 0;
  } else if (!pushed_back_ && last_arrival_s_ >= 0 && now - last_arrival_s_ < 2.0) {
    const double dt = now - last_arrival_s_;
    arrival_period_s_ = arrival_period_s_ > 0 ? 0.8 * arrival_period_s_ + 0.2 * dt : dt;
  }
  last_arrival_s_ = paced ? now : -1;
  stats_.real_time = paced;
  pushed_back_ = false;
  last_sequence_ = has_sequence_ ? std::max(last_sequence_, sequence) : sequence;
  has_sequence_ = true;
  queue_.push_back(Item{sequence, std::move(scan), std::move(on_integrated), real_time});
  ++stats_.accepted;
  if (options_.events) options_.events->ScanAccepted(robot_id_);
  stats_.queue_depth = queue_.size();
  cv_.notify_all();
  return absl::OkStatus();
}

void Session::OnSpace(std::function<void()> fn) {
  std::unique_lock<std::mutex> lock(mu_);
  if (queue_.size() < size_t(options_.queue_length) || closing_) {
    lock.unlock();
    fn();
    return;
  }
  pushed_back_ = true;
  space_waiters_.push_back(std::move(fn));
}

absl::Status Session::Checkpoint(const std::string& dir) {
  const auto start = std::chrono::steady_clock::now();
  int64_t frames = 0;
  // A link planted in the session's folder since it was opened would redirect the save.
  if (absl::Status s = RefuseSymlinksUnder(dir); !s.ok()) return s;
  if (options_.lease) {
    if (absl::Status owned = options_.lease->Check(); !owned.ok()) {
      fenced_ = true;
      return owned;
    }
  }
  absl::Status saved = mapper_->Save(dir, &frames);
  if (!saved.ok()) return saved;
  const uint64_t bytes = CheckpointBytes(dir);
  std::lock_guard<std::mutex> lock(mu_);
  // The highest sequence accepted so far, before the log records that held it are dropped: a
  // client that sends scans again after a broken stream must find them taken (Scan.resend).
  if (has_sequence_) {
    saved = WriteFileAtomic(dir + "/" + kSequenceFile, "SEQN", std::to_string(last_sequence_));
    if (!saved.ok()) return saved;
  }
  absl::Status truncated = wal_ ? wal_->TruncateBefore(uint64_t(frames)) : absl::OkStatus();
  stats_.last_checkpoint_bytes = bytes;
  if (wal_) stats_.wal_bytes = wal_->bytes();
  if (options_.events) options_.events->CheckpointWritten(robot_id_, SecondsSince(start), bytes);
  return truncated;
}

uint64_t Session::WaitForIntegrated(uint64_t seen, std::chrono::milliseconds timeout,
                                    bool* closed) {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait_for(lock, timeout, [&] { return closing_ || stats_.integrated > seen; });
  *closed = closing_;
  return stats_.integrated;
}

void Session::Drain() {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [this] { return queue_.empty() && !busy_; });
}

void Session::Settle(std::function<void()> done) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (!closing_) {
      settle_waiters_.push_back(std::move(done));
      cv_.notify_all();
      return;
    }
  }
  done();
}

bool Session::TrainBetweenFrames(std::unique_lock<std::mutex>& lock) {
  // Not before a refresh that its budget now allows: that one goes first.
  if (refresh_owed_ && SteadySeconds() >= last_refresh_end_s_ + 4 * last_refresh_s_) return false;
  // Never while another session waits for a training slot: its frame comes first.
  if (options_.scheduler && (options_.scheduler->waiting() > 0 ||
                             options_.scheduler->active() >= options_.scheduler->slots()))
    return false;
  busy_ = true;
  lock.unlock();
  absl::StatusOr<int> trained;
  StageTimings timing;
  {
    std::optional<ComputeScheduler::Lease> slot;
    if (options_.scheduler) slot.emplace(options_.scheduler->Acquire());
    // A few iterations per slot, each only while no scan waits, nothing else wants the trainer
    // and no other session waits for the slot: a scan that arrives waits at most one iteration.
    trained = mapper_->TrainBetweenFrames(
        std::min(between_left_, kBetweenFramesIterations), between_rays_,
        [this] {
          if (options_.scheduler && options_.scheduler->waiting() > 0) return false;
          std::lock_guard<std::mutex> relock(mu_);
          return !closing_ && queue_.empty() && settle_waiters_.empty();
        },
        &timing);
  }
  lock.lock();
  busy_ = false;
  cv_.notify_all();
  // A failure here is the next frame's to report; stop training between frames until then.
  if (!trained.ok() || *trained == 0) {
    between_left_ = 0;
    return true;
  }
  between_left_ -= *trained;
  if (options_.events) options_.events->TrainedBetweenFrames(robot_id_, timing);
  return true;
}

double Session::RefreshDistanceFieldNow() {
  last_refresh_s_ = mapper_->RefreshDistanceField();
  last_refresh_end_s_ = SteadySeconds();
  if (options_.events) options_.events->DistanceRefreshed(robot_id_, last_refresh_s_);
  return last_refresh_s_;
}

double Session::RefreshDistanceFieldIfBehind() {
  if (!mapper_->DistanceFieldBehind()) return 0;
  std::optional<ComputeScheduler::Lease> slot;
  if (options_.scheduler) slot.emplace(options_.scheduler->Acquire());
  return RefreshDistanceFieldNow();
}

void Session::Close() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    closing_ = true;
  }
  cv_.notify_all();
  // Every caller returns only once the trainer has stopped; the first one joins it.
  std::lock_guard<std::mutex> lock(join_mu_);
  if (trainer_.joinable()) trainer_.join();
}

SessionStats Session::Stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  return stats_;
}

absl::Status Session::last_checkpoint_status() const {
  std::lock_guard<std::mutex> lock(mu_);
  return last_checkpoint_;
}

void Session::CountRejected(absl::StatusCode code) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.rejected;
  }
  if (options_.events) options_.events->ScanRejected(robot_id_, code);
}

void Session::RecordQuery(size_t points, double seconds) {
  if (options_.events) options_.events->QueryAnswered(robot_id_, points, seconds);
}

double Session::IntegratedAt(uint64_t map_version) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = std::lower_bound(
      integrated_at_.begin(), integrated_at_.end(), map_version,
      [](const std::pair<uint64_t, double>& e, uint64_t v) { return e.first < v; });
  if (it == integrated_at_.end()) return -1;
  return it->second;
}

void Session::RecordTilePush(uint64_t tile_version) {
  if (!options_.events) return;
  const double at = IntegratedAt(tile_version);
  if (at >= 0) options_.events->TilePushed(robot_id_, std::max(0.0, SteadySeconds() - at));
}

bool Session::Accepted(uint64_t sequence) const {
  std::lock_guard<std::mutex> lock(mu_);
  return has_sequence_ && sequence <= last_sequence_;
}

void Session::RestoreLastSequence(uint64_t sequence) {
  std::lock_guard<std::mutex> lock(mu_);
  last_sequence_ = has_sequence_ ? std::max(last_sequence_, sequence) : sequence;
  has_sequence_ = true;
}

std::vector<TrajectoryPoint> Session::Trajectory(uint64_t since, uint64_t* next) const {
  std::lock_guard<std::mutex> lock(mu_);
  *next = trajectory_next_;
  std::vector<TrajectoryPoint> out;
  if (trajectory_.empty() || since >= trajectory_next_) return out;
  const uint64_t first = trajectory_.front().index;
  out.assign(trajectory_.begin() + std::ptrdiff_t(since > first ? since - first : 0),
             trajectory_.end());
  return out;
}

bool Session::LatestPose(TrajectoryPoint* pose) const {
  std::lock_guard<std::mutex> lock(mu_);
  if (trajectory_.empty()) return false;
  *pose = trajectory_.back();
  return true;
}

void Session::Run() {
  NameThisThread("rim-train");
  LowerThisThreadPriority(options_.background_nice);
  std::unique_lock<std::mutex> lock(mu_);
  while (true) {
    // Drain everything accepted before stopping: an accepted scan is never dropped.
    const auto ready = [this] { return closing_ || !queue_.empty() || !settle_waiters_.empty(); };
    if (!ready() && between_left_ > 0 && TrainBetweenFrames(lock)) continue;
    if (refresh_owed_) {
      // The last frame's refresh was skipped for the budget: make it up when the budget allows,
      // unless a frame (which refreshes in its turn) comes first.
      const double wait_s =
          std::max(0.0, last_refresh_end_s_ + 4 * last_refresh_s_ - SteadySeconds());
      const auto deadline = std::chrono::steady_clock::now() +
                            std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                std::chrono::duration<double>(wait_s));
      if (!cv_.wait_until(lock, deadline, ready)) {
        refresh_owed_ = false;
        busy_ = true;
        lock.unlock();
        RefreshDistanceFieldIfBehind();
        lock.lock();
        busy_ = false;
        cv_.notify_all();
        continue;
      }
    } else {
      cv_.wait(lock, ready);
    }
    if (queue_.empty() && !settle_waiters_.empty()) {
      // Everything queued is integrated: bring the field up to it, then answer.
      std::vector<std::function<void()>> settled;
      settled.swap(settle_waiters_);
      busy_ = true;
      lock.unlock();
      refresh_owed_ = false;
      RefreshDistanceFieldIfBehind();
      for (auto& fn : settled) fn();
      lock.lock();
      busy_ = false;
      cv_.notify_all();
      continue;
    }
    if (queue_.empty()) break;
    Item item = std::move(queue_.front());
    queue_.pop_front();
    busy_ = true;
    const size_t depth_at_start = queue_.size() + 1;
    // The stream's regime now: a real-time stream found ahead of its sensor's clock since this
    // scan came (a replay's first scans) is a replay from here on.
    const bool paced = item.real_time && !clock_.ahead();
    const double period_s = paced ? arrival_period_s_ : 0;
    std::vector<std::function<void()>> waiters;
    waiters.swap(space_waiters_);
    lock.unlock();
    for (auto& fn : waiters) fn();

    // A robot streaming in real time gets what keeps its queue short, and a queue that fills
    // anyway (a burst) takes iterations away. A paced frame whose period fits enough of them
    // trains on smaller batches (sampler.paced_rays_per_iteration), more of them in its time.
    // A replay or an upload trains the configured iterations whatever its queue: nothing waits
    // for it but its sender, whom a full queue pushes back (docs/service.md).
    const int rays = FrameBatch(depth_at_start, period_s);
    const auto [fewest, most] = mapper_->IterationBounds(rays);
    const int iterations =
        paced ? std::min(AdaptiveIterations(depth_at_start, fewest, most),
                         PacedIterations(depth_at_start, period_s, fewest, most, rays))
              : most;
    const double frame_start_s = SteadySeconds();
    StageTimings timing;
    absl::Status status;
    {
      std::optional<ComputeScheduler::Lease> slot;
      if (options_.scheduler) slot.emplace(options_.scheduler->Acquire());
      status = mapper_->IntegrateScan(item.scan, iterations, &timing, rays);
      // The field's schedule (Mapper::DistanceRefreshDue: every query.refresh_frames frames, more
      // often while the map is young), held to a fifth of the session's time like the refreshes
      // below: a due refresh waits while the last one ended less than four of its durations ago,
      // so that under load (a refresh then takes longer, and frames come back to back) training
      // keeps its share; but never past twice query.refresh_frames.
      bool overdue = false;
      if (status.ok() && mapper_->DistanceRefreshDue(&overdue) &&
          (overdue || SteadySeconds() - last_refresh_end_s_ >= 4 * last_refresh_s_)) {
        const double seconds = RefreshDistanceFieldNow();
        timing.distance_s += seconds;
        timing.total_s += seconds;
      }
      const double now = SteadySeconds();
      // Nothing waiting: bring the distance field up to this frame before it is acknowledged,
      // so that a planner that waited for the ack reads distances from it; but at most a fifth
      // of the session's time goes to refreshing, or a robot streaming at the rate the map can
      // integrate would lose its training to them.
      bool idle;
      {
        std::lock_guard<std::mutex> relock(mu_);
        idle = queue_.empty();
      }
      refresh_owed_ = false;
      if (status.ok() && idle && mapper_->DistanceFieldBehind()) {
        if (now - last_refresh_end_s_ >= 4 * last_refresh_s_) {
          // Part of the frame (its ack waits for it), under the frame's training slot.
          const double seconds = RefreshDistanceFieldNow();
          timing.distance_s += seconds;
          timing.total_s += seconds;
        } else {
          refresh_owed_ = true;
        }
      }
    }

    // A paced frame trained what its period fits by the measured costs; until the next scan
    // comes, the session trains on (TrainBetweenFrames), up to the frame's bound.
    between_left_ =
        status.ok() && period_s >= kMinPacedPeriodS ? std::max(0, most - iterations) : 0;
    between_rays_ = rays;
    if (status.ok() && timing.iterations > 0) {
      // The costs PacedIterations plans with: wall times, so that they include what the other
      // threads (meshing, queries, other sessions) take from this one, and what an iteration
      // waits for between its stages (the map's lock while a planner's batch reads it).
      const double training_s = timing.train_s;
      const double per_iteration = training_s / timing.iterations;
      const double rest = std::max(0.0, SteadySeconds() - frame_start_s - training_s);
      double& cost =
          rays == mapper_->config().sampler.rays_per_iteration ? iteration_s_ : small_iteration_s_;
      cost = cost > 0 ? 0.8 * cost + 0.2 * per_iteration : per_iteration;
      overhead_s_ = paced_frames_ > 0 ? 0.8 * overhead_s_ + 0.2 * rest : rest;
      ++paced_frames_;
    }
    if (options_.events) {
      if (status.ok()) {
        options_.events->FrameIntegrated(robot_id_, timing);
      } else {
        options_.events->FrameFailed(robot_id_);
      }
    }
    lock.lock();
    if (!status.ok()) ++stats_.failed;
    if (status.ok()) {
      ++stats_.integrated;
      integrated_at_.emplace_back(mapper_->map_version(), SteadySeconds());
      if (integrated_at_.size() > 1024) integrated_at_.pop_front();
      TrajectoryPoint pose;
      pose.index = trajectory_next_++;
      pose.position = item.scan.T_world_sensor.translation().cast<float>();
      pose.orientation = Eigen::Quaternionf(item.scan.T_world_sensor.rotation().cast<float>());
      trajectory_.push_back(pose);
      if (trajectory_.size() > kTrajectoryLimit) trajectory_.pop_front();
      stats_.last_loss = timing.loss;
      stats_.last_timing = timing;
    }
    stats_.iterations_per_frame = iterations;
    stats_.rays_per_iteration = rays;
    stats_.queue_depth = queue_.size();
    IntegratedAck ack;
    ack.sequence = item.sequence;
    ack.status = status;
    ack.iterations = iterations;
    ack.rays_per_iteration = rays;
    ack.map_version = mapper_->map_version();
    ack.queue_depth = queue_.size();
    ack.lag_frames = stats_.accepted - stats_.integrated - stats_.failed;
    const bool checkpoint = options_.checkpoint_every_frames > 0 &&
                            !options_.checkpoint_dir.empty() && status.ok() &&
                            mapper_->frames() % options_.checkpoint_every_frames == 0;
    lock.unlock();
    if (checkpoint) {
      // On the trainer thread, between frames: nothing trains while the checkpoint is written.
      const absl::Status saved = Checkpoint(options_.checkpoint_dir);
      std::lock_guard<std::mutex> relock(mu_);
      last_checkpoint_ = saved;
    }
    // The ack goes out before the item counts as done, so Drain() returns only after it.
    if (item.on_integrated) item.on_integrated(ack);
    lock.lock();
    busy_ = false;
    cv_.notify_all();
  }
  std::vector<std::function<void()>> waiters;
  waiters.swap(space_waiters_);
  std::vector<std::function<void()>> settled;
  settled.swap(settle_waiters_);
  lock.unlock();
  for (auto& fn : waiters) fn();  // closing: let waiting handlers find out
  for (auto& fn : settled) fn();
}

}  // namespace rim::server
