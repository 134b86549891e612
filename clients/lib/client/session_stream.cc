// SessionHandle::Stream: one StreamScans call. The calling thread writes scans (paced by rate_hz
// and by gRPC flow control, which is how the server's backpressure reaches the robot); a reader
// thread counts acks. The server ends the stream once the client has half-closed and every
// accepted scan has its INTEGRATED (or training-failure REJECTED) ack, so reading to the end is
// exactly "wait for all scans to be integrated".
#include <algorithm>
#include <mutex>
#include <thread>

#include "absl/strings/str_cat.h"
#include "client/client.h"
#include "client/connection.h"
#include "client/wire.h"

namespace rim {

absl::StatusOr<StreamSummary> SessionHandle::Stream(const ScanSource& next,
                                                    const StreamOptions& options) const {
  client_internal::Connection& c = *connection_;
  grpc::ClientContext context;
  // No deadline: a stream lasts as long as the robot drives.
  c.Prepare(&context, robot_id_, std::chrono::milliseconds(0));
  auto stream = c.stub().StreamScans(&context);
  const auto start = std::chrono::steady_clock::now();

  std::mutex mu;
  StreamSummary summary;
  auto last_ack = start;
  std::thread reader([&] {
    rim::v1::ScanAck ack;
    while (stream->Read(&ack)) {
      {
        std::lock_guard<std::mutex> lock(mu);
        last_ack = std::chrono::steady_clock::now();
        summary.map_version = std::max(summary.map_version, ack.map_version());
        switch (ack.state()) {
          case rim::v1::ScanAck::ACCEPTED:
            ++summary.accepted;
            break;
          case rim::v1::ScanAck::INTEGRATED:
            ++summary.integrated;
            break;
          case rim::v1::ScanAck::REJECTED:
            ++summary.rejected;
            summary.rejections.push_back({ack.sequence(), ack.code(), ack.reason()});
            break;
          default:
            break;
        }
      }
      if (options.on_ack) options.on_ack(ack);
    }
  });

  absl::Status source_status;
  uint64_t sent = 0;
  for (;;) {
    rim::v1::Scan scan;
    absl::StatusOr<bool> more = next(&scan);
    if (!more.ok()) {
      source_status = more.status();
      break;
    }
    if (!*more) break;
    scan.set_robot_id(robot_id_);
    scan.set_sequence(options.first_sequence + sent);
    if (options.rate_hz > 0) {
      std::this_thread::sleep_until(
          start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                      std::chrono::duration<double>(double(sent) / options.rate_hz)));
    }
    // A failed write means the server ended the call; Finish says why.
    if (!stream->Write(scan)) break;
    ++sent;
    {
      std::lock_guard<std::mutex> lock(mu);
      summary.sent = sent;
    }
    if (options.on_sent) options.on_sent(sent);
  }
  stream->WritesDone();
  reader.join();
  const grpc::Status status = stream->Finish();
  summary.seconds = std::chrono::duration<double>(last_ack - start).count();
  if (!source_status.ok()) return source_status;
  if (!status.ok()) return c.Error(status, absl::StrCat("StreamScans ", robot_id_));
  return summary;
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
