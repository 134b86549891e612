// WatchMeshTiles: pushes tiles as training changes them, until the client cancels or the session
// closes. A watcher thread (one per watch; dashboards are few) waits for integrated frames, lists
// the tiles newer than the last version it sent, encodes them through the session's tile cache and
// queues them; the reactor writes the queue one message at a time. The queue is bounded: a slow
// dashboard holds the watcher back instead of growing memory.
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>

#include "server/service.h"
#include "server/status_mapping.h"

namespace rim::server {
namespace {

constexpr size_t kMaxQueuedTiles = 16;
constexpr auto kPollInterval = std::chrono::milliseconds(500);

class WatchReactor : public grpc::ServerWriteReactor<rim::v1::MeshTile> {
 public:
  WatchReactor(std::shared_ptr<Session> session, uint64_t since_version)
      : session_(std::move(session)), since_version_(since_version) {
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
  void Watch() {
    uint64_t sent_version = since_version_;
    uint64_t seen_frames = 0;
    while (true) {
      {
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait(lock, [this] { return stop_ || queue_.size() < kMaxQueuedTiles; });
        if (stop_) return;
      }
      uint64_t newest = sent_version;
      for (const TileInfo& tile : session_->mapper().ListTiles(sent_version)) {
        auto encoded = session_->tiles().Get(session_->mapper(), tile);
        std::lock_guard<std::mutex> lock(mu_);
        if (stop_) return;
        if (!encoded.ok()) {
          stop_ = true;
          FinishLocked(ToGrpcStatus(encoded.status()));
          return;
        }
        queue_.push_back(ToMessage(tile, **encoded));
        newest = std::max(newest, (*encoded)->version);
        WriteNextLocked();
      }
      sent_version = newest;
      bool closed = false;
      seen_frames = session_->WaitForIntegrated(seen_frames, kPollInterval, &closed);
      if (closed) {
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait(lock, [this] { return stop_ || (queue_.empty() && !writing_); });
        stop_ = true;
        FinishLocked(grpc::Status::OK);  // the session closed: nothing more will change
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
    return m;
  }

  // Caller holds mu_.
  void WriteNextLocked() {
    if (writing_ || finished_ || queue_.empty()) return;
    current_ = std::move(queue_.front());
    queue_.pop_front();
    writing_ = true;
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
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<rim::v1::MeshTile> queue_;
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
    SessionManager* sessions, const rim::v1::WatchMeshTilesRequest& request) {
  auto session = sessions->Get(request.robot_id());
  if (!session.ok()) return new FailedWatch(ToGrpcStatus(session.status()));
  return new WatchReactor(*session, request.since_version());
}

}  // namespace rim::server
