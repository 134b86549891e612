// SessionHandle::Stream: StreamScans calls. The calling thread writes scans (paced by rate_hz and
// by gRPC flow control, which is how the server's backpressure reaches the robot); a reader
// thread counts acks. The server ends a stream once the client has half-closed and every accepted
// scan has its INTEGRATED (or training-failure REJECTED) ack, so reading to the end is exactly
// "wait for all scans to be integrated".
//
// Retries (StreamOptions::max_retries): every scan is kept until its final ack. When a stream
// breaks, a new one sends the kept scans again, in order and marked `resend`, then goes on with
// the source. The summary counts each sequence once, however many times it was sent.
#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include "absl/strings/str_cat.h"
#include "client/client.h"
#include "client/connection.h"
#include "client/wire.h"

namespace rim {
namespace {

// Sent on StreamScans when the stream is paced at a sensor's rate (server/service/service.h).
constexpr char kRealTimeHeader[] = "x-rim-real-time";

// How a broken stream ends: the server or the connection gone (UNAVAILABLE), or a proxy that
// reset the stream when the replica behind it died (CANCELLED: HTTP/2 RST_STREAM CANCEL, INTERNAL,
// UNKNOWN). This client never cancels its own streams.
bool Retryable(grpc::StatusCode code) {
  return code == grpc::StatusCode::UNAVAILABLE || code == grpc::StatusCode::INTERNAL ||
         code == grpc::StatusCode::UNKNOWN || code == grpc::StatusCode::ABORTED ||
         code == grpc::StatusCode::CANCELLED;
}

// A rejection that a later stream may undo: the server was going away or the session was moving
// between replicas.
bool RetryableRejection(int code) {
  return code == int(grpc::StatusCode::UNAVAILABLE) ||
         code == int(grpc::StatusCode::FAILED_PRECONDITION);
}

}  // namespace

absl::StatusOr<StreamSummary> SessionHandle::Stream(const ScanSource& next,
                                                    const StreamOptions& options) const {
  client_internal::Connection& c = *connection_;
  const auto start = std::chrono::steady_clock::now();

  std::mutex mu;  // guards everything below that the reader thread touches
  StreamSummary summary;
  auto last_ack = start;
  auto last_progress = start;                    // the last ack, or the start of the current stream
  std::map<uint64_t, rim::v1::Scan> unfinished;  // sent, no final ack yet, by sequence
  std::set<uint64_t> accepted, integrated;
  std::map<uint64_t, StreamSummary::Rejection> rejected;

  absl::Status source_status;
  bool source_done = false;
  uint64_t from_source = 0;  // scans taken from the source so far
  for (int attempt = 0;; ++attempt) {
    grpc::ClientContext context;
    // No deadline: a stream lasts as long as the robot drives.
    c.Prepare(&context, robot_id_, std::chrono::milliseconds(0));
    // A stream paced at a sensor's rate says so: the session then trains what keeps up with it
    // (docs/service.md, "Sharing the cores"); an upload or a replay does not, and trains every
    // frame fully, held back by its queue (docs/service.md, "Replays keep the offline map").
    if (options.real_time.value_or(options.rate_hz > 0)) context.AddMetadata(kRealTimeHeader, "1");
    bool opening = true;  // until StreamScans returns: opening the call blocks
    {
      std::lock_guard<std::mutex> lock(mu);
      last_progress = std::chrono::steady_clock::now();
    }
    // Cancels a stream that went silent while being opened or with scans unacknowledged
    // (StreamOptions::stall_timeout); Finish then says CANCELLED, and the stream is retried. It
    // watches from before the call starts: a context cancelled before its call starts cancels the
    // call as it starts.
    std::mutex watch_mu;
    std::condition_variable watch_cv;
    bool stream_over = false, stalled = false;
    std::thread watchdog([&] {
      if (options.max_retries <= 0 || options.stall_timeout.count() <= 0) return;
      std::unique_lock<std::mutex> watch(watch_mu);
      while (
          !watch_cv.wait_for(watch, std::chrono::milliseconds(100), [&] { return stream_over; })) {
        std::lock_guard<std::mutex> lock(mu);
        if ((opening || !unfinished.empty()) &&
            std::chrono::steady_clock::now() - last_progress > options.stall_timeout) {
          stalled = true;
          context.TryCancel();
          break;
        }
      }
      // A cancelled call ends at once. gRPC 1.51 can leave a call that got a response of another
      // protocol (an HTML error page from a proxy) blocked for good, cancelled or not, and a
      // blocked call cannot be left behind: on_stuck says so.
      if (stalled &&
          !watch_cv.wait_for(watch, options.stall_timeout, [&] { return stream_over; }) &&
          options.on_stuck) {
        options.on_stuck();
      }
    });
    auto stream = c.stub().StreamScans(&context);
    {
      std::lock_guard<std::mutex> lock(mu);
      opening = false;
    }
    std::thread reader([&] {
      rim::v1::ScanAck ack;
      while (stream->Read(&ack)) {
        {
          std::lock_guard<std::mutex> lock(mu);
          last_ack = std::chrono::steady_clock::now();
          last_progress = last_ack;
          summary.map_version = std::max(summary.map_version, ack.map_version());
          const uint64_t seq = ack.sequence();
          switch (ack.state()) {
            case rim::v1::ScanAck::ACCEPTED:
              accepted.insert(seq);
              if (ack.duplicate()) ++summary.duplicates;
              break;
            case rim::v1::ScanAck::INTEGRATED:
              accepted.insert(seq);
              integrated.insert(seq);
              unfinished.erase(seq);
              break;
            case rim::v1::ScanAck::REJECTED:
              rejected[seq] = {seq, ack.code(), ack.reason()};
              // Kept for the next stream when one may undo it; final otherwise.
              if (!(options.max_retries > 0 && RetryableRejection(ack.code())))
                unfinished.erase(seq);
              break;
            default:
              break;
          }
        }
        if (options.on_ack) options.on_ack(ack);
      }
    });

    // First what an earlier stream left without a final ack, then the source.
    std::vector<rim::v1::Scan> resend;
    {
      std::lock_guard<std::mutex> lock(mu);
      for (auto& [seq, scan] : unfinished) {
        resend.push_back(scan);
        resend.back().set_resend(true);
        rejected.erase(seq);  // decided again by this stream
      }
    }
    bool write_failed = false;
    for (const rim::v1::Scan& scan : resend) {
      if (!stream->Write(scan)) {
        write_failed = true;
        break;
      }
    }
    while (!write_failed && !source_done) {
      rim::v1::Scan scan;
      absl::StatusOr<bool> more = next(&scan);
      if (!more.ok()) {
        source_status = more.status();
        source_done = true;
        break;
      }
      if (!*more) {
        source_done = true;
        break;
      }
      scan.set_robot_id(robot_id_);
      scan.set_sequence(options.first_sequence + from_source);
      if (options.rate_hz > 0) {
        std::this_thread::sleep_until(
            start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                        std::chrono::duration<double>(double(from_source) / options.rate_hz)));
      }
      {
        std::lock_guard<std::mutex> lock(mu);
        unfinished[scan.sequence()] = scan;
      }
      ++from_source;
      {
        std::lock_guard<std::mutex> lock(mu);
        summary.sent = from_source;
      }
      // A failed write means the server ended the call; Finish says why. The scan stays in
      // `unfinished` for a retry.
      if (!stream->Write(scan)) {
        write_failed = true;
        break;
      }
      if (options.on_sent) options.on_sent(from_source);
    }
    stream->WritesDone();
    reader.join();
    const grpc::Status status = stream->Finish();
    {
      std::lock_guard<std::mutex> watch(watch_mu);
      stream_over = true;
    }
    watch_cv.notify_all();
    watchdog.join();
    bool again = false;
    {
      std::lock_guard<std::mutex> lock(mu);
      again = attempt < options.max_retries && source_status.ok() &&
              (stalled || (!status.ok() ? Retryable(status.error_code())
                                        : !source_done || !unfinished.empty()));
    }
    if (!again) {
      std::lock_guard<std::mutex> lock(mu);
      summary.accepted = accepted.size();
      summary.integrated = integrated.size();
      summary.rejected = rejected.size();
      summary.rejections.clear();
      for (auto& [seq, r] : rejected) summary.rejections.push_back(r);
      summary.seconds = std::chrono::duration<double>(last_ack - start).count();
      if (!source_status.ok()) return source_status;
      if (!status.ok()) return c.Error(status, absl::StrCat("StreamScans ", robot_id_));
      return summary;
    }
    ++summary.retries;
    if (options.on_retry) {
      const absl::Status why =
          stalled ? absl::DeadlineExceededError(
                        absl::StrCat("no ack for ", options.stall_timeout.count() / 1000.0, " s"))
          : !status.ok() ? c.Error(status, "StreamScans")
                         : absl::UnavailableError("the stream ended with scans unacknowledged");
      options.on_retry(summary.retries, why);
    }
    std::this_thread::sleep_for(options.retry_backoff);
  }
}

absl::StatusOr<StreamSummary> SessionHandle::Stream(const std::vector<PosedScan>& scans,
                                                    const StreamOptions& options) const {
  size_t index = 0;
  return Stream(
      [&](rim::v1::Scan* scan) -> absl::StatusOr<bool> {
        if (index == scans.size()) return false;
        *scan = ScanToProto(scans[index++], robot_id_, 0);
        return true;
      },
      options);
}

}  // namespace rim
