// Scans as StreamScans receives them (service_stream.cc): bytes parsed as rim.v1.Scan messages,
// checked and converted by ConvertScan, then submitted to a fresh session (write-ahead log append,
// queue) and trained by its trainer thread, as the stream handler does. The input is up to four
// entries (fuzz_util.h), one message each, streamed to one session in order; an entry's op bit 0
// also saves a checkpoint after it, so that whatever the scans did to the map is written to disk
// and read back too.
#include <mutex>

#include "fuzz_session.h"
#include "server/service/scan_convert.h"

namespace {

using rim::fuzz::kRobot;

rim::fuzz::FuzzService& Service() {
  // A checkpoint every second frame, from the trainer thread, truncating the log, as the server
  // does every 100.
  static rim::fuzz::FuzzService service("rim_fuzz_ingest", /*checkpoint_every_frames=*/2);
  return service;
}

// What a stream does with one scan message (ScanStreamReactor::HandleScan and SubmitLocked), with
// the session lookup standing in for the token check.
void Ingest(rim::fuzz::FuzzService& service, rim::v1::Scan& scan) {
  if (scan.robot_id().empty()) scan.set_robot_id(kRobot);
  auto session = service.sessions.Get(scan.robot_id());
  if (!session.ok()) {
    RIM_FUZZ_CHECK(session.status().code() == absl::StatusCode::kInvalidArgument ||
                   session.status().code() == absl::StatusCode::kNotFound);
    return;
  }
  const absl::Status budget = service.sessions.CheckHostMemoryBudget();
  absl::StatusOr<rim::PosedScan> posed =
      budget.ok() ? rim::server::ConvertScan(scan, size_t(service.limits.max_points_per_scan))
                  : budget;
  if (!posed.ok()) {
    // scan_convert.h: a malformed field is INVALID_ARGUMENT naming it, a scan over the limit
    // RESOURCE_EXHAUSTED.
    RIM_FUZZ_CHECK(posed.status().code() == absl::StatusCode::kInvalidArgument ||
                   posed.status().code() == absl::StatusCode::kResourceExhausted);
    RIM_FUZZ_CHECK(!posed.status().message().empty());
    (*session)->CountRejected(posed.status().code());
    return;
  }
  std::mutex mu;
  absl::Status trained = absl::UnknownError("no INTEGRATED ack");
  const absl::Status submitted =
      (*session)->Submit(scan.sequence(), std::move(*posed), [&](const auto& ack) {
        std::lock_guard<std::mutex> lock(mu);
        trained = ack.status;
      });
  if (!submitted.ok()) return;
  (*session)->Drain();
  std::lock_guard<std::mutex> lock(mu);
  // An accepted scan is in the write-ahead log, and replaying the log after a crash must be able
  // to integrate it again: the validator has to refuse every scan that training would refuse.
  RIM_FUZZ_CHECK(trained.ok());
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  rim::fuzz::FuzzService& service = Service();
  auto session = service.sessions.Create(kRobot, "", rim::fuzz::TinyMapOverrides());
  RIM_FUZZ_CHECK(session.ok());
  for (const auto& entry : rim::fuzz::SplitEntries(rim::fuzz::Bytes(data, size), 4)) {
    rim::v1::Scan scan;
    if (!scan.ParseFromArray(entry.bytes.data(), int(entry.bytes.size()))) continue;
    Ingest(service, scan);
    if (entry.op & 1) RIM_FUZZ_CHECK(service.sessions.Save(kRobot).ok());
  }
  // Whatever was saved and logged must load again (the write-ahead log replayed on top).
  RIM_FUZZ_CHECK(service.sessions.Close(kRobot, /*save=*/true).ok());
  auto loaded = service.sessions.Load(kRobot);
  RIM_FUZZ_CHECK(loaded.ok());
  RIM_FUZZ_CHECK(service.sessions.Close(kRobot, /*save=*/false).ok());
  return 0;
}
