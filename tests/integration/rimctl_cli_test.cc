// The real rimctl binary against the real rim_server, the way scripts use it (DESIGN.md §5.5):
// sessions, streaming the synthetic city, query CSV / .npy, a slice picture, mesh files, watch,
// health, and the exit codes and messages of the failure cases.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "gmock/gmock.h"
#include "rim/io/mesh_io.h"
#include "support/server_process.h"
#include "support/subprocess.h"
#include "support/temp_dir.h"

namespace rim {
namespace {

using ::testing::HasSubstr;
using testing_support::ProcessResult;

constexpr char kRobot[] = "cli_city";
// Five frames of the city with a coarse LiDAR and 5 iterations: a few seconds on 2 cores.
constexpr char kCity[] = "sim:city?frames=5&columns=900";

std::unique_ptr<testing_support::ServerProcess> g_server;
std::string g_dir;

ProcessResult Rimctl(std::vector<std::string> args, const std::string& stdin_data = "") {
  args.insert(args.begin(), {RIMCTL_BIN, "--server", g_server->address()});
  return testing_support::RunProcess(args, stdin_data);
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string Describe(const ProcessResult& r) {
  return "exit " + std::to_string(r.exit_code) + "\nstdout:\n" + r.out + "\nstderr:\n" + r.err;
}

class RimctlCliTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto server = testing_support::ServerProcess::Start();
    ASSERT_TRUE(server.ok()) << server.status();
    g_server = std::move(*server);
    g_dir = testing_support::MakeTempDir("rimctl_cli");
  }
  static void TearDownTestSuite() { g_server.reset(); }
};

TEST_F(RimctlCliTest, HelpAndUsageErrors) {
  const ProcessResult help = testing_support::RunProcess({RIMCTL_BIN, "--help"});
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_THAT(help.out, HasSubstr("session create ROBOT_ID"));
  for (const char* command : {"info", "health", "session", "stream", "query", "mesh", "watch"}) {
    const ProcessResult r = testing_support::RunProcess({RIMCTL_BIN, command, "--help"});
    EXPECT_EQ(r.exit_code, 0) << command;
    EXPECT_THAT(r.out, HasSubstr("usage")) << command;
  }
  const ProcessResult none = testing_support::RunProcess({RIMCTL_BIN});
  EXPECT_EQ(none.exit_code, 2);
  EXPECT_THAT(none.err, HasSubstr("no command given"));
  const ProcessResult bad_flag = Rimctl({"query", kRobot, "--points", "p.csv", "--colour"});
  EXPECT_EQ(bad_flag.exit_code, 2);
  EXPECT_THAT(bad_flag.err, HasSubstr("unknown flag '--colour'"));
  const ProcessResult bad_command = Rimctl({"sessions", "list"});
  EXPECT_EQ(bad_command.exit_code, 2);
  EXPECT_THAT(bad_command.err, HasSubstr("unknown command 'sessions'"));
}

TEST_F(RimctlCliTest, InfoAndHealth) {
  const ProcessResult info = Rimctl({"info"});
  ASSERT_EQ(info.exit_code, 0) << Describe(info);
  EXPECT_THAT(info.out, HasSubstr("build: cpu"));
  EXPECT_THAT(info.out, HasSubstr("max query points: "));
  const ProcessResult health = Rimctl({"health"});
  EXPECT_EQ(health.exit_code, 0) << Describe(health);
  EXPECT_EQ(health.out, "SERVING\n");
  const ProcessResult unknown = Rimctl({"health", "--service", "no.such.Service"});
  EXPECT_EQ(unknown.exit_code, 5) << Describe(unknown);
  EXPECT_EQ(unknown.out, "SERVICE_UNKNOWN\n");
}

TEST_F(RimctlCliTest, SessionCreateListGet) {
  const ProcessResult created =
      Rimctl({"session", "create", kRobot, "--preset", "maicity", "--set", "train.iterations=5"});
  ASSERT_EQ(created.exit_code, 0) << Describe(created);
  EXPECT_THAT(created.out, HasSubstr("created session cli_city"));
  const ProcessResult again = Rimctl({"session", "create", kRobot});
  EXPECT_EQ(again.exit_code, 1);
  EXPECT_THAT(again.err, HasSubstr(kRobot));
  const ProcessResult bad_set = Rimctl({"session", "create", "other", "--set", "train.nope=1"});
  EXPECT_EQ(bad_set.exit_code, 1);
  EXPECT_THAT(bad_set.err, HasSubstr("train.nope"));
  const ProcessResult list = Rimctl({"session", "list"});
  ASSERT_EQ(list.exit_code, 0) << Describe(list);
  EXPECT_THAT(list.out, HasSubstr(kRobot));
  EXPECT_THAT(list.out, HasSubstr("1 session(s)"));
  const ProcessResult get = Rimctl({"session", "get", kRobot, "--config"});
  ASSERT_EQ(get.exit_code, 0) << Describe(get);
  EXPECT_THAT(get.out, HasSubstr("\nintegrated frames: 0\n"));
  EXPECT_THAT(get.out, HasSubstr("train.iterations = 5"));
}

TEST_F(RimctlCliTest, StreamTheSyntheticCity) {
  const ProcessResult r = Rimctl({"stream", kRobot, kCity});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_THAT(r.out, HasSubstr("accepted: 5, integrated: 5, rejected: 0"));
  EXPECT_THAT(r.err, HasSubstr("stream: 100%"));  // not a terminal: lines per tenth
  const ProcessResult get = Rimctl({"session", "get", kRobot});
  EXPECT_THAT(get.out, HasSubstr("\nintegrated frames: 5\n"));
}

TEST_F(RimctlCliTest, QueryCsvAndNpy) {
  // A 10 x 10 patch 1 m above the street around the start of the drive.
  std::string csv = "x,y,z\n";
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j)
      csv += std::to_string(95 + i) + "," + std::to_string(j - 5) + ",1\n";
  const std::string points = g_dir + "/points.csv";
  std::ofstream(points) << csv;

  const ProcessResult r = Rimctl({"query", kRobot, "--points", points});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  const std::vector<std::string> lines = absl::StrSplit(r.out, '\n', absl::SkipEmpty());
  ASSERT_EQ(lines.size(), 101u);
  EXPECT_EQ(lines[0], "x,y,z,sdf,observed");
  int observed = 0;
  for (size_t i = 1; i < lines.size(); ++i) {
    const std::vector<std::string> cells = absl::StrSplit(lines[i], ',');
    ASSERT_EQ(cells.size(), 5u) << lines[i];
    float sdf = 0;
    ASSERT_TRUE(absl::SimpleAtof(cells[3], &sdf)) << lines[i];
    EXPECT_TRUE(std::isfinite(sdf)) << lines[i];
    ASSERT_TRUE(cells[4] == "0" || cells[4] == "1") << lines[i];
    observed += cells[4] == "1";
  }
  EXPECT_GT(observed, 50);  // the street around the sensor was seen

  // From stdin, with gradients, as .npy.
  const std::string npy = g_dir + "/answer.npy";
  const ProcessResult n =
      Rimctl({"query", kRobot, "--points", "-", "--gradient", "--out", npy}, csv);
  ASSERT_EQ(n.exit_code, 0) << Describe(n);
  const std::string bytes = ReadFile(npy);
  ASSERT_GT(bytes.size(), 10u);
  EXPECT_EQ(bytes.substr(0, 6), "\x93NUMPY");
  EXPECT_THAT(bytes.substr(0, 128), HasSubstr("'shape': (100, 8)"));
  const size_t header = uint8_t(bytes[8]) | (uint8_t(bytes[9]) << 8);
  EXPECT_EQ(bytes.size(), 10 + header + 100 * 8 * 4);

  const ProcessResult bad = Rimctl({"query", kRobot, "--points", "-"}, "x,y,z\n1,2\n");
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_THAT(bad.err, HasSubstr("stdin:2: expected x,y,z"));
}

TEST_F(RimctlCliTest, SlicePicture) {
  const std::string png = g_dir + "/slice.png";
  const ProcessResult r = Rimctl({"query", kRobot, "--grid", "88,-12,1,112,8,1,0.1", "--out", png});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_THAT(r.out, HasSubstr("slice z = 1 m: 241 x 201 cells"));
  const std::string bytes = ReadFile(png);
  EXPECT_EQ(bytes.substr(0, 8), "\x89PNG\r\n\x1a\n");
  EXPECT_GT(bytes.size(), 2000u);
  const ProcessResult not_flat =
      Rimctl({"query", kRobot, "--grid", "0,0,0,1,1,1,0.1", "--out", png});
  EXPECT_EQ(not_flat.exit_code, 2);
  EXPECT_THAT(not_flat.err, HasSubstr("exactly one extent must be flat"));
}

TEST_F(RimctlCliTest, MeshFilesAndWatch) {
  const std::string dir = g_dir + "/mesh";
  const ProcessResult r = Rimctl({"mesh", kRobot, "--out", dir});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_THAT(r.out, HasSubstr("tiles: "));
  int drc = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("tile_", 0) == 0 && entry.path().extension() == ".drc") {
      ++drc;
      EXPECT_GT(entry.file_size(), 0u) << name;
    }
  }
  EXPECT_GE(drc, 1);
  auto mesh = ReadMeshPly(dir + "/mesh.ply");
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_GT(mesh->faces.size(), 1000u);

  // A coarser level of detail: the same surface in fewer faces; a level the session lacks is
  // refused by name.
  const ProcessResult session = Rimctl({"session", "get", kRobot});
  ASSERT_EQ(session.exit_code, 0) << Describe(session);
  EXPECT_THAT(session.out, HasSubstr("mesh levels: 0.05 0.1 0.2"));
  const std::string coarse_dir = g_dir + "/mesh_coarse";
  const ProcessResult coarse = Rimctl({"mesh", kRobot, "--out", coarse_dir, "--resolution", "0.2"});
  ASSERT_EQ(coarse.exit_code, 0) << Describe(coarse);
  auto coarse_mesh = ReadMeshPly(coarse_dir + "/mesh.ply");
  ASSERT_TRUE(coarse_mesh.ok()) << coarse_mesh.status();
  EXPECT_GT(coarse_mesh->faces.size(), 0u);
  EXPECT_LT(3 * coarse_mesh->faces.size(), mesh->faces.size());
  const ProcessResult bad = Rimctl({"mesh", kRobot, "--out", coarse_dir, "--resolution", "0.07"});
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_THAT(bad.err, HasSubstr("resolution_m"));

  const ProcessResult watch = Rimctl({"watch", kRobot, "--duration", "0.5", "--resolution", "0.2"});
  EXPECT_EQ(watch.exit_code, 0) << Describe(watch);
  EXPECT_THAT(watch.out, HasSubstr("watched 0 tile updates"));
}

TEST_F(RimctlCliTest, RejectedScansMakeStreamFail) {
  // A two-frame KITTI folder whose second scan is empty: the server rejects it, and stream says
  // so in its summary and exit code.
  const std::string dir = g_dir + "/kitti";
  std::filesystem::create_directories(dir + "/velodyne");
  std::string scan;
  for (int i = 0; i < 400; ++i) {
    const float p[4] = {float(i % 20) * 0.1f - 1.f, float(i / 20) * 0.1f - 1.f, -1.f, 0.5f};
    scan.append(reinterpret_cast<const char*>(p), sizeof(p));
  }
  std::ofstream(dir + "/velodyne/000000.bin", std::ios::binary) << scan;
  std::ofstream(dir + "/velodyne/000001.bin", std::ios::binary);
  std::ofstream(dir + "/poses.txt") << "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.1 0 1 0 0 0 0 1 0\n";
  std::ofstream(dir + "/calib.txt") << "Tr: 1 0 0 0 0 1 0 0 0 0 1 0\n";
  const ProcessResult created = Rimctl({"session", "create", "cli_kitti"});
  ASSERT_EQ(created.exit_code, 0) << Describe(created);
  const ProcessResult r = Rimctl({"stream", "cli_kitti", dir});
  EXPECT_EQ(r.exit_code, 4) << Describe(r);
  EXPECT_THAT(r.out, HasSubstr("accepted: 1, integrated: 1, rejected: 1"));
  EXPECT_THAT(r.err, HasSubstr("rejected scan 1"));
}

TEST_F(RimctlCliTest, ClearFailures) {
  const ProcessResult unknown = Rimctl({"session", "get", "nobody"});
  EXPECT_EQ(unknown.exit_code, 1);
  EXPECT_THAT(unknown.err, HasSubstr("nobody"));
  const ProcessResult stream_unknown = Rimctl({"stream", "nobody", "sim:city?frames=1"});
  EXPECT_EQ(stream_unknown.exit_code, 1);
  EXPECT_THAT(stream_unknown.err, HasSubstr("nobody"));
  const ProcessResult bad_path = Rimctl({"stream", kRobot, g_dir + "/no_such_dataset"});
  EXPECT_EQ(bad_path.exit_code, 1);
  EXPECT_THAT(bad_path.err, HasSubstr("no_such_dataset"));
  const ProcessResult bad_range = Rimctl({"stream", kRobot, kCity, "--frames", "3:9"});
  EXPECT_EQ(bad_range.exit_code, 1);
  EXPECT_THAT(bad_range.err, HasSubstr("has 5 frames"));
  const ProcessResult unreachable = testing_support::RunProcess(
      {RIMCTL_BIN, "--server", "127.0.0.1:1", "--connect-timeout", "0.5", "session", "list"});
  EXPECT_EQ(unreachable.exit_code, 3) << Describe(unreachable);
  EXPECT_THAT(unreachable.err, HasSubstr("cannot reach rim_server at 127.0.0.1:1"));
}

// Last: save, close and load through rimctl, then health once the server is gone.
TEST_F(RimctlCliTest, SaveCloseLoadThenServerGone) {
  EXPECT_EQ(Rimctl({"session", "save", kRobot}).exit_code, 0);
  const ProcessResult closed = Rimctl({"session", "close", kRobot, "--save"});
  EXPECT_EQ(closed.exit_code, 0) << Describe(closed);
  EXPECT_EQ(Rimctl({"session", "get", kRobot}).exit_code, 1);
  const ProcessResult loaded = Rimctl({"session", "load", kRobot});
  ASSERT_EQ(loaded.exit_code, 0) << Describe(loaded);
  EXPECT_THAT(loaded.out, HasSubstr("\nintegrated frames: 5\n"));

  const std::string address = g_server->address();
  ASSERT_EQ(g_server->Stop().value_or(-1), 0) << g_server->Log();
  const ProcessResult health = testing_support::RunProcess(
      {RIMCTL_BIN, "--server", address, "--connect-timeout", "0.5", "health"});
  EXPECT_EQ(health.exit_code, 3) << Describe(health);
}

}  // namespace
}  // namespace rim
