// WatchMeshTiles: pushes tiles as training changes them, until the client cancels or the session
// closes. A watcher thread (one per watch; dashboards are few) works in rounds: it lists the tiles
// newer than the last round's, meshes and encodes them through the session's tile cache (only
// their changed blocks are re-meshed) and queues them; the reactor writes the queue one message at
// a time. Rounds start at most once per watch.min_interval_s, when a frame was integrated since
// the last one, so a tile is pushed at most once per interval, at its newest version. The queue
// holds at most one message per tile: a slow dashboard gets the newest version of each tile when
// it catches up, and memory stays bounded by the tile count. Every tile a watcher meshes is charged
// to the server's meshing budget (server/session/meshing_budget.h), and the watcher waits while it
// is in debt, so all watches together take at most --meshing-cores of the machine.
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "rim/base/thread_priority.h"
#include "server/service/latest_queue.h"
#include "server/service/service.h"
#include "server/service/status_mapping.h"
#include "server/session/meshing_budget.h"

namespace rim::server {
namespace {

constexpr auto kPollInterval = std::chrono::milliseconds(500);
constexpr auto kBudgetSlice = std::chrono::milliseconds(50);

class WatchReactor : public grpc::ServerWriteReactor<rim::v1::MeshTile> {
 public:
  WatchReactor(std::shared_ptr<Session> session, uint64_t since_version, float resolution_m,
               StreamLimiter::Slot slot)
      : session_(std::move(session)),
        since_version_(since_version),
        resolution_m_(resolution_m),
        slot_(std::move(slot)) {
    watcher_ = std::thread([this] { Watch(); });
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard<std::mutex> lock(mu_);
    writing_ = false;
    if (!ok) {
      stop_ = true;
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "the client went away"));
    } else {
      WriteNextLocked();
    }
    cv_.notify_all();
  }

  void OnCancel() override {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
    FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "watch cancelled"));
    cv_.notify_all();
  }

  void OnDone() override {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
      cv_.notify_all();
    }
    watcher_.join();  // the watcher never outlives the reactor
    delete this;
  }

 private:
  // One round: every tile newer than `*listed_version`, at its newest version. Returns false when
  // the watch ended.
  bool PushRound(uint64_t* listed_version) {
    uint64_t newest = *listed_version;
    // Oldest change first: a tile the box has left keeps the version of its last change and its
    // wait counts from then, while a tile the box still covers is meshed at the newest version
    // whenever its turn comes. Key order made the tiles the box left wait behind the live ones.
    std::vector<TileInfo> tiles = session_->mapper().ListTiles(*listed_version);
    std::stable_sort(tiles.begin(), tiles.end(),
                     [](const TileInfo& a, const TileInfo& b) { return a.version < b.version; });
    for (TileInfo tile : tiles) {
      {
        std::lock_guard<std::mutex> lock(mu_);
        if (stop_) return false;
      }
      // Tiles that change after the listing get versions above every listed one, so the next
      // round lists them.
      newest = std::max(newest, tile.version);
      // Frames integrated since the listing (a round can take a while) may have moved the tile:
      // mesh it at its version now, so the push carries the newest state. The next round lists it
      // again; it is skipped unless it moved further.
      for (const TileInfo& now : session_->mapper().ListTiles(tile.version))
        if (now.key == tile.key) tile.version = now.version;
      uint64_t& pushed = pushed_[tile.key];
      if (tile.version <= pushed) continue;
      // Within the server's meshing budget: wait until it has paid for the tiles meshed before.
      const double waited = WaitForMeshingBudget();
      if (waited < 0) return false;
      const double cpu_start = ThreadCpuSeconds();
      auto encoded = session_->tiles().Get(session_->mapper(), tile, resolution_m_);
      const double cpu = ThreadCpuSeconds() - cpu_start;
      if (MeshingBudget* budget = session_->meshing_budget()) budget->Charge(cpu);
      if (SessionEvents* events = session_->events())
        events->WatchMeshed(session_->robot_id(), cpu, waited);
      std::lock_guard<std::mutex> lock(mu_);
      if (stop_) return false;
      if (!encoded.ok()) {
        stop_ = true;
        FinishLocked(ToGrpcStatus(encoded.status()));
        return false;
      }
      pushed = std::max(tile.version, (*encoded)->version);
      pending_.Put(tile.key, ToMessage(tile, **encoded));
      WriteNextLocked();
    }
    *listed_version = newest;
    return true;
  }

  // Waits while the meshing budget is in debt. Returns the seconds waited, or -1 when the watch
  // ended meanwhile.
  double WaitForMeshingBudget() {
    MeshingBudget* budget = session_->meshing_budget();
    if (!budget || !budget->limited()) return 0;
    const auto start = std::chrono::steady_clock::now();
    std::unique_lock<std::mutex> lock(mu_);
    for (auto delay = budget->Delay(); delay > std::chrono::steady_clock::duration::zero();
         delay = budget->Delay()) {
      // In slices, as other watches may take the credit first.
      if (cv_.wait_for(lock, std::min<std::chrono::steady_clock::duration>(delay, kBudgetSlice),
                       [this] { return stop_; }))
        return -1;
    }
    if (stop_) return -1;
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }

  void Watch() {
    NameThisThread("rim-watch");
    LowerThisThreadPriority(session_->background_nice());
    const auto interval = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(session_->mapper().config().watch.min_interval_s));
    uint64_t listed_version = since_version_;
    uint64_t seen_frames = 0;
    while (true) {
      const auto round_start = std::chrono::steady_clock::now();
      if (!PushRound(&listed_version)) return;
      // Coalescing: the next round no sooner than an interval after this one. Waited in slices,
      // so that a session that closes meanwhile gets its last round at once.
      bool closed = false;
      while (!closed && std::chrono::steady_clock::now() < round_start + interval) {
        {
          std::unique_lock<std::mutex> lock(mu_);
          cv_.wait_until(
              lock,
              std::min(round_start + interval, std::chrono::steady_clock::now() + kPollInterval),
              [this] { return stop_; });
          if (stop_) return;
        }
        session_->WaitForIntegrated(~uint64_t{0}, std::chrono::milliseconds(0), &closed);
      }
      seen_frames = session_->WaitForIntegrated(seen_frames, kPollInterval, &closed);
      if (closed) {
        // The session closed: push what its last frames changed, then end the stream.
        if (!PushRound(&listed_version)) return;
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait(lock, [this] { return stop_ || (pending_.empty() && !writing_); });
        stop_ = true;
        FinishLocked(grpc::Status::OK);  // nothing more will change
        return;
      }
    }
  }

  static rim::v1::MeshTile ToMessage(const TileInfo& tile, const EncodedTile& encoded) {
    rim::v1::MeshTile m;
    m.set_key_x(tile.key.x());
    m.set_key_y(tile.key.y());
    m.set_key_z(tile.key.z());
    m.set_version(encoded.version);
    auto* b = m.mutable_bounds();
    b->mutable_min()->set_x(tile.min_m.x());
    b->mutable_min()->set_y(tile.min_m.y());
    b->mutable_min()->set_z(tile.min_m.z());
    b->mutable_max()->set_x(tile.max_m.x());
    b->mutable_max()->set_y(tile.max_m.y());
    b->mutable_max()->set_z(tile.max_m.z());
    m.set_draco(encoded.draco);
    m.set_vertex_count(encoded.vertex_count);
    m.set_face_count(encoded.face_count);
    m.set_resolution_m(encoded.resolution_m);
    return m;
  }

  // Caller holds mu_.
  void WriteNextLocked() {
    if (writing_ || finished_ || pending_.empty()) return;
    current_ = std::move(*pending_.Pop());
    writing_ = true;
    session_->RecordTilePush(current_.version());
    StartWrite(&current_);
    cv_.notify_all();
  }

  void FinishLocked(const grpc::Status& status) {
    if (finished_) return;
    finished_ = true;
    Finish(status);
  }

  std::shared_ptr<Session> session_;
  const uint64_t since_version_;
  const float resolution_m_;        // the level of detail pushed
  const StreamLimiter::Slot slot_;  // released when the watch is done
  std::mutex mu_;
  std::condition_variable cv_;
  // At most one message per tile: a newer version replaces a queued older one.
  LatestPerKeyQueue<Int3, rim::v1::MeshTile, Int3Hash, Int3Equal> pending_;
  // Watcher thread only: the version each tile was last queued at.
  absl::flat_hash_map<Int3, uint64_t, Int3Hash, Int3Equal> pushed_;
  rim::v1::MeshTile current_;
  bool writing_ = false, stop_ = false, finished_ = false;
  std::thread watcher_;
};

class FailedWatch : public grpc::ServerWriteReactor<rim::v1::MeshTile> {
 public:
  explicit FailedWatch(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

}  // namespace

grpc::ServerWriteReactor<rim::v1::MeshTile>* NewWatchReactor(
    SessionManager* sessions, const rim::v1::WatchMeshTilesRequest& request,
    StreamLimiter::Slot slot) {
  auto session = sessions->Get(request.robot_id());
  if (!session.ok()) return new FailedWatch(ToGrpcStatus(session.status()));
  auto level = (*session)->mapper().MeshLevel(request.resolution_m());
  if (!level.ok()) return new FailedWatch(ToGrpcStatus(level.status()));
  return new WatchReactor(*session, request.since_version(), *level, std::move(slot));
}

}  // namespace rim::server
