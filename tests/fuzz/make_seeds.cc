// Writes the seed corpora of the fuzz targets (tests/fuzz/corpus/<name>/seed-*) with rim's own
// writers, so that every seed is a valid input the fuzzer mutates from. Run it after changing a
// format: `cmake --build BUILD --target rim_fuzz_seeds && BUILD/tests/fuzz/rim_fuzz_seeds
// tests/fuzz/corpus`. Seeds are kept small (a few KB): the fuzzer explores from them, it does not
// need realistic sizes. Crash inputs kept as regression tests live beside the seeds as crash-*.
#include <filesystem>
#include <fstream>
#include <iterator>

#include "fuzz_session.h"
#include "rim/base/binary_io.h"
#include "rim/io/kitti.h"
#include "rim/io/lzf.h"
#include "rim/io/pcd.h"
#include "rim/io/ply_points.h"
#include "rim/io/png_io.h"
#include "server/wal/wal_record.h"

namespace {

namespace fs = std::filesystem;
using rim::fuzz::AppendEntry;

std::string g_out;

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void Seed(const std::string& target, const std::string& name, std::string_view bytes) {
  fs::create_directories(g_out + "/" + target);
  rim::fuzz::WriteFileOrDie(g_out + "/" + target + "/seed-" + name, bytes);
}

void Check(const absl::Status& s) {
  if (!s.ok()) {
    fprintf(stderr, "rim_fuzz_seeds: %s\n", std::string(s.message()).c_str());
    exit(1);
  }
}

rim::io::PointCloud SmallCloud() {
  rim::io::PointCloud cloud;
  for (int i = 0; i < 12; ++i) {
    cloud.points.emplace_back(0.37f * i, -1.5f * i, 100.0f / (i + 1));
    cloud.intensity.push_back(float(i % 3));
  }
  return cloud;
}

void ParserSeeds(const std::string& tmp) {
  using namespace rim::io;
  const PointCloud cloud = SmallCloud();
  const char* pcd_modes[] = {"ascii", "binary", "binary_compressed"};
  for (PcdDataMode mode :
       {PcdDataMode::kAscii, PcdDataMode::kBinary, PcdDataMode::kBinaryCompressed}) {
    Check(WritePcd(tmp + "/a.pcd", cloud, mode));
    Seed("pcd", pcd_modes[int(mode)], ReadAll(tmp + "/a.pcd"));
  }
  Check(WritePlyPoints(tmp + "/a.ply", cloud, PlyFormat::kAscii));
  Seed("ply_points", "ascii", ReadAll(tmp + "/a.ply"));
  Check(WritePlyPoints(tmp + "/a.ply", cloud, PlyFormat::kBinary));
  Seed("ply_points", "binary", ReadAll(tmp + "/a.ply"));
  // Big-endian, a list property, and an element before the vertices.
  std::string ply =
      "ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty list uchar float p\n"
      "element vertex 2\nproperty double x\nproperty float y\nproperty int z\n"
      "property list int uchar extra\nend_header\n";
  ply += std::string("\x01\x3f\x80\x00\x00", 5);
  for (int i = 0; i < 2; ++i) {
    ply += std::string("\x3f\xe0\x00\x00\x00\x00\x00\x00", 8) + std::string("\x3f\xc0\x00\x00", 4);
    ply += std::string("\x00\x00\x00", 3) + char(i) + std::string("\x00\x00\x00\x01\x07", 5);
  }
  Seed("ply_points", "big_endian_lists", ply);

  Check(WriteKittiBin(tmp + "/a.bin", cloud));
  Seed("kitti_bin", "scan", ReadAll(tmp + "/a.bin"));

  std::vector<uint16_t> pixels(9 * 7);
  for (size_t i = 0; i < pixels.size(); ++i) pixels[i] = uint16_t(i * 977);
  pixels[5] = 0, pixels[6] = 65535;
  auto png = EncodePng16(9, 7, pixels.data());
  Check(png.status());
  Seed("png_depth", "gray16", *png);
  std::vector<uint8_t> rgb(5 * 4 * 3, 200);
  Check(WritePngRgb8(tmp + "/c.png", 5, 4, rgb.data()));
  Seed("png_depth", "rgb8", ReadAll(tmp + "/c.png"));

  Seed("json", "cam_params",
       "{\"camera\": {\"w\": 1200, \"h\": 680, \"fx\": 600.0, \"fy\": 600.0, \"cx\": 599.5,"
       " \"cy\": 339.5, \"scale\": 6553.5}}");
  Seed(
      "json", "values",
      "{\"x\": [1, -2e3, true, false, null, \"a\\n\\u00e9\\ud83d\\ude00\"], \"o\": {\"k\": [[]]}}");

  std::string text;
  for (int i = 0; i < 600; ++i) text += char("abcabd\0\0\0xy"[i % 12] + i / 100);
  std::string lzf(4, '\0');
  const uint32_t n = uint32_t(text.size());
  std::memcpy(lzf.data(), &n, 4);
  Seed("lzf", "text", lzf + LzfCompress(text));

  Seed("pose_file", "poses_3x4",
       std::string(1, '\0') + "1 0 0 0 0 1 0 0 0 0 1 0\n0 -1 0 1 1 0 0 2 0 0 1 3\n");
  Seed("pose_file", "traj_4x4", std::string(1, '\1') + "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n");
  Seed("pose_file", "pose_4x4",
       std::string(1, '\2') + "0.6 0 0.8 1\n0 1 0 2\n-0.8 0 0.6 3\n0 0 0 1\n");
  Seed("pose_file", "calib",
       std::string(1, '\3') + "P0: 1 0 0 0 0 1 0 0 0 0 1 0\nTr: 0 -1 0 0 0 0 -1 0 1 0 0 0\n");
  Seed("pose_file", "intrinsics", std::string(1, '\4') + "585 0 320\n0 585 240\n0 0 1\n");
  Seed("pose_file", "times", std::string(1, '\5') + "1630577758.569490\n1630577759.068947\n");
}

std::string ScanMessage(const rim::PosedScan& posed, bool origins) {
  rim::v1::Scan scan;
  scan.set_robot_id(rim::fuzz::kRobot);
  scan.set_sequence(7);
  scan.set_timestamp_s(1.5);
  const Eigen::Vector3d t = posed.T_world_sensor.translation();
  scan.mutable_pose()->mutable_translation()->set_x(t.x());
  scan.mutable_pose()->mutable_rotation()->set_w(1);
  std::string xyz(reinterpret_cast<const char*>(posed.points_S.data()), 12 * posed.points_S.size());
  scan.set_points_xyz(xyz);
  if (origins) scan.set_origins_xyz(std::string(xyz.size(), '\0'));
  return scan.SerializeAsString();
}

std::string DepthMessage(bool float32) {
  rim::v1::Scan scan;
  scan.set_robot_id(rim::fuzz::kRobot);
  scan.mutable_pose()->mutable_rotation()->set_w(1);
  rim::v1::DepthImage* d = scan.mutable_depth();
  d->set_width(6), d->set_height(4), d->set_fx(5), d->set_fy(5), d->set_cx(2.5), d->set_cy(1.5);
  std::string data;
  for (int i = 0; i < 24; ++i) {
    if (float32) {
      const float v = 0.5f + 0.01f * i;
      data.append(reinterpret_cast<const char*>(&v), 4);
    } else {
      const uint16_t v = uint16_t(i == 3 ? 0 : 500 + 10 * i);
      data.append(reinterpret_cast<const char*>(&v), 2);
    }
  }
  d->set_data(data);
  d->set_encoding(float32 ? rim::v1::DepthImage::FLOAT32 : rim::v1::DepthImage::UINT16);
  d->set_scale(float32 ? 1.0 : 1000.0);
  return scan.SerializeAsString();
}

void WireSeeds() {
  std::string in;
  AppendEntry(0, ScanMessage(rim::fuzz::TinyScan(0), false), &in);
  AppendEntry(1, ScanMessage(rim::fuzz::TinyScan(0.5), true), &in);
  Seed("scan_ingest", "points", in);
  in.clear();
  AppendEntry(0, DepthMessage(false), &in);
  AppendEntry(1, DepthMessage(true), &in);
  Seed("scan_ingest", "depth", in);
  // Regression: a pose beyond 1e6 m passed ConvertScan, was logged as accepted, then refused by
  // training, and made every replay of the log fail.
  rim::PosedScan far = rim::fuzz::TinyScan(0);
  far.T_world_sensor.translation().x() = 2e6;
  in.clear();
  AppendEntry(0, ScanMessage(far, false), &in);
  AppendEntry(0, ScanMessage(rim::fuzz::TinyScan(0), false), &in);
  Seed("scan_ingest", "regress_far_pose", in);

  rim::v1::QuerySdfRequest q;
  q.set_robot_id(rim::fuzz::kRobot);
  const float xyz[] = {0.f, 0.f, -1.f, 1.f, 0.5f, -0.9f, 3.f, 0.f, 0.f, -40.f, 7.f, 2.f};
  q.set_points_xyz(std::string(reinterpret_cast<const char*>(xyz), sizeof(xyz)));
  Seed("query", "points", q.SerializeAsString());
  q.set_want_gradient(true);
  Seed("query", "gradient", q.SerializeAsString());
}

// A tiny session that integrated a few scans, then saved (checkpoint seeds) or not (log seeds).
void SessionSeeds() {
  rim::fuzz::FuzzService service("rim_fuzz_seeds");
  const std::string dir = service.SessionDir();
  auto session = service.sessions.Create(rim::fuzz::kRobot, "", rim::fuzz::TinyMapOverrides());
  Check(session.status());
  for (int i = 0; i < 2; ++i) Check((*session)->Submit(i, rim::fuzz::TinyScan(0.8 * i), {}));
  (*session)->Drain();

  // The log: every record framed by the harness (op 0), then a torn copy of the last one (op 1),
  // and a variant with a gap between two segments (op 2).
  std::vector<std::string> payloads;
  for (const auto& e : fs::directory_iterator(dir + "/wal")) {
    const std::string data = ReadAll(e.path());
    Check(rim::server::WalkWalSegment(e.path(), data, 0, false,
                                      [&](const rim::server::WalRecordView& r) {
                                        payloads.emplace_back(r.payload);
                                        return absl::OkStatus();
                                      })
              .status());
  }
  std::string log, gap;
  for (size_t i = 0; i < payloads.size(); ++i) {
    AppendEntry(0, payloads[i], &log);
    if (i == 1) AppendEntry(2 + 4 * 3, "", &gap);
    AppendEntry(0, payloads[i], &gap);
  }
  Seed("wal", "records", log);
  std::string torn;
  rim::server::FrameWalRecord(payloads.size(), payloads.back(), &torn);
  AppendEntry(1, std::string_view(torn).substr(0, torn.size() / 2), &log);
  Seed("wal", "torn_tail", log);
  Seed("wal", "gap", gap);

  Check(service.sessions.Save(rim::fuzz::kRobot).status());
  std::string ckpt;
  auto add = [&](uint8_t op, const std::string& path, const char* kind) {
    auto payload = rim::ReadFileChecked(path, kind);
    Check(payload.status());
    AppendEntry(op, *payload, &ckpt);
  };
  add(0, dir + "/CURRENT", "CURR");
  add(1, dir + "/config.rimf", "CONF");
  const std::string current = dir + "/" + *rim::ReadFileChecked(dir + "/CURRENT", "CURR");
  add(2, current + "/config.rimf", "CONF");
  add(3, current + "/state.rimf", "STAT");
  for (const auto& e : fs::directory_iterator(current + "/submaps"))
    add(0x40, e.path(), "SUB8");  // 64 % 5 = 4: a sub-map, 8-bit
  Seed("checkpoint", "saved", ckpt);
  // Only the session's config and log: a session that crashed before its first checkpoint.
  std::string fresh;
  AppendEntry(1, *rim::ReadFileChecked(dir + "/config.rimf", "CONF"), &fresh);
  Seed("checkpoint", "config_only", fresh);
  // Regression: a config asking for a 13 GB local map was allocated before any budget check.
  std::string huge_config = *rim::ReadFileChecked(dir + "/config.rimf", "CONF");
  huge_config += "grid.half_extent_x_m = 1900\ngrid.half_extent_y_m = 1900\n";
  std::string huge;
  AppendEntry(1, huge_config, &huge);
  Seed("checkpoint", "regress_huge_map", huge);
  AppendEntry(0, *rim::ReadFileChecked(dir + "/CURRENT", "CURR"), &huge);
  AppendEntry(2, huge_config, &huge);
  Seed("checkpoint", "regress_huge_map_ckpt", huge);
  Check(service.sessions.Close(rim::fuzz::kRobot, false));
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: %s tests/fuzz/corpus\n", argv[0]);
    return 2;
  }
  g_out = argv[1];
  rim::fuzz::ScratchDir tmp("rim_fuzz_seeds_files");
  ParserSeeds(tmp.path());
  WireSeeds();
  SessionSeeds();
  fprintf(stderr, "seeds written under %s\n", g_out.c_str());
  return 0;
}
