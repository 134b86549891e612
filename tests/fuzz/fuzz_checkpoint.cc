// A saved session as LoadSession finds it on disk (session_manager.cc, mapper_persistence.cc,
// submap_store.cc): CURRENT, the checkpoint's config, state and sub-map files, and the session's
// own config, restored through SessionManager::Load. Each entry of the input (fuzz_util.h) is one
// file; op % 5 picks which:
//   0 CURRENT   1 <session>/config.rimf   2 ckpt-000000/config.rimf   3 ckpt-000000/state.rimf
//   4 ckpt-000000/submaps/submap_<n>.subm (kind SUB8, 8-bit rows, with op bit 6 set; else SUBM,
//     the float32 files of older checkpoints)
// Entries are wrapped in the checksummed container (binary_io.h) with the right kind tag, so that
// the fuzzer reaches the parsers behind the checksum; with op bit 7 set the bytes are written as
// they are, for the container checks themselves. A session that loads is then used: queried,
// meshed, trained one frame, saved, and must load again.
#include <filesystem>

#include "fuzz_session.h"
#include "rim/base/binary_io.h"

namespace {

namespace fs = std::filesystem;
using rim::fuzz::kRobot;

rim::fuzz::FuzzService& Service() {
  static rim::fuzz::FuzzService service("rim_fuzz_checkpoint");
  return service;
}

// The container of binary_io.h, written directly: WriteFileAtomic would fsync every file.
std::string Container(std::string_view kind, std::string_view payload) {
  rim::ByteWriter w;
  w.Bytes("RIMF", 4);
  w.U32(rim::kFileFormatVersion);
  w.Bytes(kind.data(), 4);
  w.U64(payload.size());
  w.Bytes(payload.data(), payload.size());
  w.U32(rim::Crc32c(w.data().data(), w.data().size()));
  return w.Release();
}

void WriteSessionFiles(const std::string& dir, std::string_view input) {
  const std::string ckpt = dir + "/ckpt-000000";
  fs::create_directories(ckpt + "/submaps");
  int submaps = 0;
  for (const auto& e : rim::fuzz::SplitEntries(input, 16)) {
    std::string path;
    const char* kind = "";
    switch (e.op % 5) {
      case 0:
        path = dir + "/CURRENT", kind = "CURR";
        break;
      case 1:
        path = dir + "/config.rimf", kind = "CONF";
        break;
      case 2:
        path = ckpt + "/config.rimf", kind = "CONF";
        break;
      case 3:
        path = ckpt + "/state.rimf", kind = "STAT";
        break;
      default:
        // Both sub-map formats: 8-bit rows (what rim writes) and float32 (older files).
        path = ckpt + "/submaps/submap_" + std::to_string(submaps++) + ".subm",
        kind = (e.op & 0x40) ? "SUB8" : "SUBM";
        break;
    }
    rim::fuzz::WriteFileOrDie(path,
                              (e.op & 0x80) ? std::string(e.bytes) : Container(kind, e.bytes));
  }
}

// What clients may do with a loaded session; none of it may crash on whatever the files held.
void UseSession(rim::server::Session& session) {
  const float xyz[] = {0.f, 0.f, -1.f, 0.5f, -0.3f, 0.2f, 3.f, 40.f, -2.f};
  rim::QueryResult q;
  RIM_FUZZ_CHECK(session.mapper().QuerySdf(xyz, 3, /*want_gradient=*/true, &q).ok());
  RIM_FUZZ_CHECK(q.sdf.size() == 3 && q.gradient.size() == 9 && q.observed.size() == 3);
  // Every tile of the tiny map (a handful): a sub-map's key comes from its file.
  int meshed = 0;
  for (const rim::TileInfo& tile : session.mapper().ListTiles(0)) {
    if (meshed++ == 16) break;
    (void)session.mapper().ObservedVoxels(tile.key);
    (void)session.mapper().ExtractMeshTile(tile.key);
  }
  RIM_FUZZ_CHECK(session.Submit(0, rim::fuzz::TinyScan(0.1), {}).ok());
  session.Drain();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  rim::fuzz::FuzzService& service = Service();
  const std::string dir = service.SessionDir();
  std::error_code ec;
  fs::remove_all(dir, ec);
  fs::create_directories(dir);
  WriteSessionFiles(dir, rim::fuzz::Bytes(data, size));
  auto session = service.sessions.Load(kRobot);
  if (!session.ok()) {
    RIM_FUZZ_CHECK(!session.status().message().empty());
    return 0;
  }
  UseSession(**session);
  // Whatever loaded must save and load again.
  RIM_FUZZ_CHECK(service.sessions.Close(kRobot, /*save=*/true).ok());
  auto again = service.sessions.Load(kRobot);
  RIM_FUZZ_CHECK(again.ok());
  RIM_FUZZ_CHECK(service.sessions.Close(kRobot, /*save=*/false).ok());
  return 0;
}
