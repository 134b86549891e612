// A crashed session's write-ahead log as LoadSession recovers it (wal.cc, wal_record.cc,
// scan_record.cc, SessionManager::Restore): segment files with torn tails, damaged, missing,
// out-of-order or gapped records, and record payloads that are not scans, replayed into the map
// of the session's config.rimf (the tiny map of fuzz_session.h, written once). Each input entry
// (fuzz_util.h) is an operation; op % 4 picks it:
//   0  append a framed record (correct header and CRC) whose payload is the entry's bytes
//   1  append the entry's bytes to the segment as they are (torn or damaged records)
//   2  start a new segment, its first index op / 4 past the next index (gaps)
//   3  skip op / 4 indices in the current segment (index mismatches)
// A session that recovers must take a new scan and then load again from its log.
#include <cinttypes>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "fuzz_session.h"
#include "rim/base/binary_io.h"
#include "server/wal/wal_record.h"

namespace {

namespace fs = std::filesystem;
using rim::fuzz::kRobot;

struct Fixture {
  rim::fuzz::FuzzService service{"rim_fuzz_wal"};
  std::string config;  // the config.rimf a newly created tiny session writes
};

Fixture& Get() {
  static Fixture f;
  static const bool ready = [] {
    auto session = f.service.sessions.Create(kRobot, "", rim::fuzz::TinyMapOverrides());
    RIM_FUZZ_CHECK(session.ok());
    std::ifstream in(f.service.SessionDir() + "/config.rimf", std::ios::binary);
    f.config.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    RIM_FUZZ_CHECK(f.service.sessions.Close(kRobot, /*save=*/false).ok());
    return !f.config.empty();
  }();
  RIM_FUZZ_CHECK(ready);
  return f;
}

std::string SegmentPath(const std::string& wal, uint64_t first_index) {
  char name[64];
  std::snprintf(name, sizeof(name), "wal-%020" PRIu64 ".log", first_index);
  return wal + "/" + name;
}

void WriteLog(const std::string& wal, std::string_view input) {
  fs::create_directories(wal);
  uint64_t first = 0, next = 0;
  std::string segment;
  auto flush = [&] { rim::fuzz::WriteFileOrDie(SegmentPath(wal, first), segment); };
  for (const auto& e : rim::fuzz::SplitEntries(input, 64)) {
    switch (e.op % 4) {
      case 0:
        rim::server::FrameWalRecord(next++, e.bytes, &segment);
        break;
      case 1:
        segment.append(e.bytes);
        break;
      case 2:
        flush();
        segment.clear();
        first = next += e.op / 4;
        break;
      default:
        next += e.op / 4;
        break;
    }
  }
  flush();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Fixture& f = Get();
  const std::string dir = f.service.SessionDir();
  std::error_code ec;
  fs::remove_all(dir, ec);
  fs::create_directories(dir);
  rim::fuzz::WriteFileOrDie(dir + "/config.rimf", f.config);
  WriteLog(dir + "/wal", rim::fuzz::Bytes(data, size));
  auto session = f.service.sessions.Load(kRobot);
  if (!session.ok()) {
    RIM_FUZZ_CHECK(!session.status().message().empty());
    return 0;
  }
  // Recovery cut any torn tail off, so a new record follows the intact ones, and the whole log
  // replays again after a shutdown without a save, to the same map.
  RIM_FUZZ_CHECK((*session)->Submit(0, rim::fuzz::TinyScan(0.1), {}).ok());
  (*session)->Drain();
  const int64_t frames = (*session)->mapper().frames();
  RIM_FUZZ_CHECK(f.service.sessions.CloseAll(/*save=*/false).ok());
  auto again = f.service.sessions.Load(kRobot);
  RIM_FUZZ_CHECK(again.ok());
  RIM_FUZZ_CHECK((*again)->mapper().frames() == frames);
  RIM_FUZZ_CHECK(f.service.sessions.Close(kRobot, /*save=*/false).ok());
  return 0;
}
