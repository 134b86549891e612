// StreamScans: a bidirectional reactor. Per scan it validates, then Session::Submit()s; a full
// queue stops reading until Session::OnSpace fires (backpressure through gRPC flow control). Acks
// go out one write at a time from a queue: ACCEPTED (or REJECTED) from the reading side, and
// INTEGRATED from the trainer thread. The stream finishes once the client has half-closed, every
// accepted scan's INTEGRATED ack is written, and the distance field of each session it fed covers
// those scans. A scan for a robot the caller's token may not act on
// is REJECTED with PERMISSION_DENIED, like any bad scan, and the stream goes on.
//
// Threading: all state is guarded by Shared::mu. Callbacks from the trainer thread hold only a
// shared_ptr<Shared> and reach the reactor through Shared::reactor, which OnDone clears under the
// mutex before deleting the reactor, so a late callback finds nullptr and does nothing.
#include <algorithm>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "absl/strings/str_cat.h"
#include "server/service/scan_convert.h"
#include "server/service/service.h"
#include "server/service/status_mapping.h"

namespace rim::server {
namespace {

class ScanStreamReactor;

struct Shared {
  std::mutex mu;
  ScanStreamReactor* reactor = nullptr;
};

class ScanStreamReactor : public grpc::ServerBidiReactor<rim::v1::Scan, rim::v1::ScanAck> {
 public:
  ScanStreamReactor(SessionManager* sessions, const ServiceLimits& limits,
                    const Principal& principal, StreamLimiter::Slot slot, bool real_time)
      : sessions_(sessions),
        limits_(limits),
        principal_(principal),
        slot_(std::move(slot)),
        real_time_(real_time),
        shared_(std::make_shared<Shared>()) {
    shared_->reactor = this;
    std::lock_guard<std::mutex> lock(shared_->mu);
    StartRead(&in_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) {
      // The client is done sending. The stream ends once every session it fed has integrated
      // its scans and brought the distance field up to them (Session::Settle), so that a client
      // that saw the stream end can query every frame it sent.
      std::vector<std::shared_ptr<Session>> fed;
      {
        std::lock_guard<std::mutex> lock(shared_->mu);
        half_closed_ = true;
        fed.swap(fed_);
        settling_ += fed.size();
        MaybeFinishLocked();
      }
      std::weak_ptr<Shared> weak = shared_;
      for (const std::shared_ptr<Session>& session : fed) {
        session->Settle([weak] {
          std::shared_ptr<Shared> shared = weak.lock();
          if (!shared) return;
          std::lock_guard<std::mutex> lock(shared->mu);
          if (shared->reactor != nullptr) shared->reactor->OnSettledLocked();
        });
      }
      return;
    }
    HandleScan();
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard<std::mutex> lock(shared_->mu);
    writing_ = false;
    if (!ok) {
      cancelled_ = true;
      MaybeFinishLocked();
      return;
    }
    WriteNextLocked();
  }

  void OnCancel() override {
    std::lock_guard<std::mutex> lock(shared_->mu);
    cancelled_ = true;
    MaybeFinishLocked();
  }

  void OnDone() override {
    {
      std::lock_guard<std::mutex> lock(shared_->mu);
      shared_->reactor = nullptr;
    }
    delete this;
  }

  // Submits the pending scan (called with Shared::mu held). Returns the session to wait on when its
  // queue is full; nullptr when the scan was accepted, rejected or dropped.
  std::shared_ptr<Session> SubmitLocked() {
    if (!pending_) return nullptr;
    if (finished_) {
      pending_.reset();
      return nullptr;
    }
    Pending& p = *pending_;
    ++awaiting_integration_;
    std::weak_ptr<Shared> weak = shared_;
    const absl::Status s = p.session->Submit(
        p.sequence, p.scan,
        [weak](const IntegratedAck& ack) {
          std::shared_ptr<Shared> shared = weak.lock();
          if (!shared) return;
          std::lock_guard<std::mutex> lock(shared->mu);
          if (shared->reactor != nullptr) shared->reactor->OnIntegratedLocked(ack);
        },
        real_time_);
    if (s.ok()) {
      if (std::find(fed_.begin(), fed_.end(), p.session) == fed_.end()) fed_.push_back(p.session);
      rim::v1::ScanAck ack = MakeAck(*p.session, p.sequence, rim::v1::ScanAck::ACCEPTED);
      pending_.reset();
      EnqueueLocked(std::move(ack));
      ReadNextLocked();
      return nullptr;
    }
    --awaiting_integration_;
    if (s.code() == absl::StatusCode::kResourceExhausted) return p.session;
    p.session->CountRejected(s.code());
    RejectLocked(p.sequence, s);
    pending_.reset();
    ReadNextLocked();
    return nullptr;
  }

  std::shared_ptr<Shared> shared() const { return shared_; }

 private:
  struct Pending {
    std::shared_ptr<Session> session;
    uint64_t sequence;
    PosedScan scan;
  };

  void HandleScan() {
    const uint64_t sequence = in_.sequence();
    if (sessions_->stopping()) {
      // SIGTERM: this scan is not accepted, nothing more is read, and the stream ends once the
      // scans accepted before have their INTEGRATED acks, so the server can stop promptly.
      std::lock_guard<std::mutex> lock(shared_->mu);
      const absl::Status stopping = absl::UnavailableError(
          "rim_server is shutting down: scan not accepted; send it again once the server is back");
      RejectLocked(sequence, stopping);
      half_closed_ = true;
      end_status_ = ToGrpcStatus(stopping);
      MaybeFinishLocked();
      return;
    }
    // Before the lookup, so that the rejection does not tell whether the session exists.
    const absl::Status allowed = CheckRobot(principal_, in_.robot_id());
    if (!allowed.ok()) {
      std::lock_guard<std::mutex> lock(shared_->mu);
      RejectLocked(sequence, allowed);
      ReadNextLocked();
      return;
    }
    auto session = sessions_->Get(in_.robot_id());
    if (!session.ok()) {
      std::lock_guard<std::mutex> lock(shared_->mu);
      RejectLocked(sequence, session.status());
      ReadNextLocked();
      return;
    }
    // Sent again after a broken stream, and taken before: acknowledged, not integrated twice.
    if (in_.resend() && (*session)->Accepted(sequence)) {
      std::lock_guard<std::mutex> lock(shared_->mu);
      for (auto state : {rim::v1::ScanAck::ACCEPTED, rim::v1::ScanAck::INTEGRATED}) {
        rim::v1::ScanAck ack = MakeAck(**session, sequence, state);
        ack.set_duplicate(true);
        EnqueueLocked(std::move(ack));
      }
      ReadNextLocked();
      return;
    }
    // Over the memory budget, ingest refuses new scans rather than growing (§5.2 limits).
    const absl::Status budget = sessions_->CheckHostMemoryBudget();
    absl::StatusOr<PosedScan> scan =
        budget.ok() ? ConvertScan(in_, size_t(limits_.max_points_per_scan)) : budget;
    if (!scan.ok()) {
      (*session)->CountRejected(scan.status().code());
      std::lock_guard<std::mutex> lock(shared_->mu);
      RejectLocked(sequence, scan.status());
      ReadNextLocked();
      return;
    }
    {
      std::lock_guard<std::mutex> lock(shared_->mu);
      pending_ = Pending{*session, sequence, std::move(*scan)};
    }
    Retry(shared_);
  }

 public:
  // Tries the pending submit; while the queue is full, waits for space and tries again.
  static void Retry(const std::shared_ptr<Shared>& shared) {
    std::shared_ptr<Session> full;
    {
      std::lock_guard<std::mutex> lock(shared->mu);
      if (shared->reactor == nullptr) return;
      full = shared->reactor->SubmitLocked();
    }
    if (full) full->OnSpace([shared] { Retry(shared); });
  }

 private:
  rim::v1::ScanAck MakeAck(Session& session, uint64_t sequence, rim::v1::ScanAck::State state) {
    const SessionStats stats = session.Stats();
    rim::v1::ScanAck ack;
    ack.set_sequence(sequence);
    ack.set_state(state);
    ack.set_queue_depth(uint32_t(stats.queue_depth));
    ack.set_lag_frames(stats.accepted - stats.integrated - stats.failed);
    ack.set_iterations(uint32_t(stats.iterations_per_frame));
    ack.set_rays_per_iteration(uint32_t(stats.rays_per_iteration));
    ack.set_map_version(session.mapper().map_version());
    return ack;
  }

 public:
  void OnIntegratedLocked(const IntegratedAck& integrated) {
    --awaiting_integration_;
    rim::v1::ScanAck ack;
    ack.set_sequence(integrated.sequence);
    if (integrated.status.ok()) {
      ack.set_state(rim::v1::ScanAck::INTEGRATED);
    } else {
      ack.set_state(rim::v1::ScanAck::REJECTED);
      ack.set_reason(absl::StrCat("training failed: ", integrated.status.message()));
      ack.set_code(int32_t(ToGrpcStatus(integrated.status).error_code()));
    }
    ack.set_queue_depth(uint32_t(integrated.queue_depth));
    ack.set_lag_frames(integrated.lag_frames);
    ack.set_iterations(uint32_t(integrated.iterations));
    ack.set_rays_per_iteration(uint32_t(integrated.rays_per_iteration));
    ack.set_map_version(integrated.map_version);
    EnqueueLocked(std::move(ack));
    MaybeFinishLocked();
  }

  void OnSettledLocked() {
    --settling_;
    MaybeFinishLocked();
  }

 private:
  void RejectLocked(uint64_t sequence, const absl::Status& status) {
    rim::v1::ScanAck ack;
    ack.set_sequence(sequence);
    ack.set_state(rim::v1::ScanAck::REJECTED);
    ack.set_reason(std::string(status.message()));
    ack.set_code(int32_t(ToGrpcStatus(status).error_code()));
    EnqueueLocked(std::move(ack));
  }

  void EnqueueLocked(rim::v1::ScanAck ack) {
    if (finished_) return;
    queue_.push_back(std::move(ack));
    if (!writing_) WriteNextLocked();
  }

  void WriteNextLocked() {
    if (finished_ || queue_.empty()) {
      MaybeFinishLocked();
      return;
    }
    current_ = std::move(queue_.front());
    queue_.pop_front();
    writing_ = true;
    StartWrite(&current_);
  }

  void ReadNextLocked() {
    if (!finished_ && !half_closed_) StartRead(&in_);
  }

  void MaybeFinishLocked() {
    if (finished_) return;
    if (cancelled_) {
      finished_ = true;
      Finish(grpc::Status(grpc::StatusCode::CANCELLED, "scan stream cancelled"));
      return;
    }
    if (half_closed_ && !pending_ && awaiting_integration_ == 0 && settling_ == 0 &&
        queue_.empty() && !writing_) {
      finished_ = true;
      Finish(end_status_);
    }
  }

  SessionManager* const sessions_;
  const ServiceLimits limits_;
  const Principal principal_;
  const StreamLimiter::Slot slot_;  // released when the stream is done
  const bool real_time_;            // the client streams at a sensor's rate
  const std::shared_ptr<Shared> shared_;

  rim::v1::Scan in_;  // the read buffer; only the reading side touches it
  // Guarded by shared_->mu.
  std::optional<Pending> pending_;
  std::deque<rim::v1::ScanAck> queue_;
  rim::v1::ScanAck current_;
  bool writing_ = false;
  bool half_closed_ = false;
  bool cancelled_ = false;
  bool finished_ = false;
  grpc::Status end_status_;  // OK, or why the server ended the stream itself
  uint64_t awaiting_integration_ = 0;
  std::vector<std::shared_ptr<Session>> fed_;  // sessions that accepted a scan of this stream
  size_t settling_ = 0;                        // of those, the ones not settled yet
};

}  // namespace

grpc::ServerBidiReactor<rim::v1::Scan, rim::v1::ScanAck>* NewScanStreamReactor(
    SessionManager* sessions, const ServiceLimits& limits, const Principal& principal,
    StreamLimiter::Slot slot, bool real_time) {
  return new ScanStreamReactor(sessions, limits, principal, std::move(slot), real_time);
}

}  // namespace rim::server
