// The C++ client library against the real rim_server on loopback: sessions, a scan stream with a
// rejected scan, queries (one call and chunked over StreamQuerySdf), mesh tiles decoded and
// welded, watching, health, save/close/load, and the error codes a caller sees.
#include "client/client.h"

#include <grpcpp/support/status.h>
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "gmock/gmock.h"
#include "support/analytic_scene.h"
#include "support/server_process.h"

namespace rim {
namespace {

using ::testing::HasSubstr;
using testing_support::AnalyticScene;
using testing_support::ServerProcess;

constexpr char kRobot[] = "client_robot";
constexpr int kScans = 8;
constexpr int kMaxQueryPoints = 500;  // small, so that a batch of 1200 goes out in 3 chunks

std::unique_ptr<ServerProcess> g_server;
std::unique_ptr<Client> g_client;

AnalyticScene Scene() {
  AnalyticScene scene;
  scene.boxes.push_back({Eigen::Vector3f(1.0f, -0.6f, -0.1f), Eigen::Vector3f(1.6f, 0.6f, 1.2f)});
  return scene;
}

// Scans along a short straight drive, seen by a 16-beam LiDAR looking down to -60 degrees so that
// the returns fall inside the small test map.
std::vector<PosedScan> Scans(int count, uint32_t seed) {
  testing_support::LidarModel lidar;
  lidar.beams = 16;
  lidar.columns = 360;
  lidar.max_range_m = 6.f;
  lidar.elev_min_deg = -60.f;
  const auto poses = testing_support::StraightTrajectory(-0.5f, 0.4f, count, 1.0f);
  std::vector<PosedScan> scans;
  for (int i = 0; i < count; ++i) {
    PosedScan scan;
    scan.T_world_sensor = poses[i].cast<double>();
    scan.timestamp_s = 0.1 * i;
    for (const Eigen::Vector3f& p : SimulateScan(Scene(), lidar, poses[i], seed + i))
      scan.points_S.push_back(p);
    scans.push_back(std::move(scan));
  }
  return scans;
}

// A 4 m map (so the test trains fast) with 15 iterations per frame, never fewer: with the default
// train.min_iterations a session trains fewer while its queue is full, and the accuracy checks
// would depend on how fast the machine is.
const std::vector<std::pair<std::string, std::string>> kSmallMap = {
    {"grid.half_extent_x_m", "2"},
    {"grid.half_extent_y_m", "2"},
    {"grid.z_min_m", "-1.2"},
    {"grid.z_max_m", "1.2"},
    {"train.iterations", "15"},
    {"train.min_iterations", "15"},
    {"sampler.rays_per_iteration", "512"}};

class ClientTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    testing_support::ServerProcessOptions options;
    options.args = {"--max-sessions", "4", "--max-query-points", std::to_string(kMaxQueryPoints)};
    auto server = ServerProcess::Start(options);
    ASSERT_TRUE(server.ok()) << server.status();
    g_server = std::move(*server);
    ClientOptions client_options;
    client_options.token = "test-token";  // sent as metadata; this server does not check it
    auto client = Client::Connect(g_server->address(), client_options);
    ASSERT_TRUE(client.ok()) << client.status();
    g_client = std::make_unique<Client>(std::move(*client));
  }
  static void TearDownTestSuite() {
    g_client.reset();
    g_server.reset();
  }
};

TEST_F(ClientTest, InfoAndHealth) {
  auto info = g_client->Info();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->max_query_points(), uint32_t(kMaxQueryPoints));
  EXPECT_EQ(info->max_sessions(), 4u);
  auto health = g_client->Health();
  ASSERT_TRUE(health.ok()) << health.status();
  EXPECT_EQ(*health, ServingStatus::kServing);
  auto unknown = g_client->Health("no.such.Service");
  ASSERT_TRUE(unknown.ok()) << unknown.status();
  EXPECT_EQ(*unknown, ServingStatus::kServiceUnknown);
}

TEST_F(ClientTest, CreateSessionAndItsErrors) {
  auto info = g_client->CreateSession(kRobot, "maicity", kSmallMap);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->robot_id(), kRobot);
  EXPECT_THAT(info->config(), HasSubstr("train.iterations = 15"));

  auto again = g_client->CreateSession(kRobot, "maicity", kSmallMap);
  EXPECT_EQ(again.status().code(), absl::StatusCode::kAlreadyExists);
  auto bad_key = g_client->CreateSession("other", "", {{"train.no_such_key", "1"}});
  EXPECT_EQ(bad_key.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(bad_key.status().message(), HasSubstr("train.no_such_key"));
  auto bad_id = g_client->CreateSession("bad id!");
  EXPECT_EQ(bad_id.status().code(), absl::StatusCode::kInvalidArgument);

  auto list = g_client->ListSessions();
  ASSERT_TRUE(list.ok()) << list.status();
  ASSERT_EQ(list->size(), 1u);
  EXPECT_EQ((*list)[0].robot_id(), kRobot);
}

TEST_F(ClientTest, StreamCountsAcksAndRejections) {
  std::vector<PosedScan> scans = Scans(kScans, 100);
  // One bad scan in the middle: rejected with a reason, and the stream goes on.
  PosedScan bad = scans[3];
  bad.points_S[5].y() = std::numeric_limits<float>::quiet_NaN();
  scans.insert(scans.begin() + 4, bad);

  std::atomic<int> acks{0};
  StreamOptions options;
  options.first_sequence = 100;
  options.on_ack = [&](const rim::v1::ScanAck&) { ++acks; };
  auto summary = g_client->Session(kRobot).Stream(scans, options);
  ASSERT_TRUE(summary.ok()) << summary.status();
  EXPECT_EQ(summary->sent, uint64_t(kScans + 1));
  EXPECT_EQ(summary->accepted, uint64_t(kScans));
  EXPECT_EQ(summary->integrated, uint64_t(kScans));
  EXPECT_EQ(summary->rejected, 1u);
  ASSERT_EQ(summary->rejections.size(), 1u);
  EXPECT_EQ(summary->rejections[0].sequence, 104u);
  EXPECT_EQ(summary->rejections[0].code, int(grpc::StatusCode::INVALID_ARGUMENT));
  EXPECT_THAT(summary->rejections[0].reason, HasSubstr("scan.points_xyz"));
  EXPECT_EQ(acks.load(), 2 * kScans + 1);
  EXPECT_GT(summary->map_version, 0u);

  auto info = g_client->Session(kRobot).Info();
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->integrated_frames(), uint64_t(kScans));
  EXPECT_EQ(info->rejected_frames(), 1u);
}

TEST_F(ClientTest, ChunkedQueryEqualsSingleCallsAndFindsTheSurface) {
  const AnalyticScene scene = Scene();
  const auto surface = scene.SampleSurface(Eigen::Vector3f(-1.2f, -1.2f, -0.2f),
                                           Eigen::Vector3f(1.2f, 1.2f, 1.f), 1200, 7);
  ASSERT_GT(surface.size(), size_t(2 * kMaxQueryPoints));  // needs more than one chunk
  std::vector<Vec3f> points;
  for (const auto& s : surface) points.push_back(s.p);
  const SessionHandle session = g_client->Session(kRobot);
  auto all = session.Query(points, /*want_gradient=*/true);
  ASSERT_TRUE(all.ok()) << all.status();
  ASSERT_EQ(all->sdf.size(), points.size());
  ASSERT_EQ(all->gradient.size(), 3 * points.size());
  ASSERT_EQ(all->observed.size(), points.size());
  EXPECT_GT(all->map_version, 0u);

  // The last, partial chunk asked on its own gives the same values: chunking is invisible.
  const size_t tail_begin = 2 * kMaxQueryPoints;
  auto tail = session.Query(std::vector<Vec3f>(points.begin() + tail_begin, points.end()), true);
  ASSERT_TRUE(tail.ok()) << tail.status();
  for (size_t i = tail_begin; i < points.size(); ++i) {
    ASSERT_EQ(all->sdf[i], tail->sdf[i - tail_begin]) << i;
    ASSERT_EQ(all->observed[i], tail->observed[i - tail_begin]) << i;
    ASSERT_EQ(all->gradient[3 * i + 2], tail->gradient[3 * (i - tail_begin) + 2]) << i;
  }

  int observed = 0, close = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    ASSERT_TRUE(std::isfinite(all->sdf[i]));
    if (!all->observed[i]) continue;
    ++observed;
    close += std::abs(all->sdf[i]) < 0.05f;
  }
  EXPECT_GT(observed, int(points.size()) / 2);
  EXPECT_GT(close, observed * 7 / 10);

  auto no_gradient = session.Query({Vec3f(0.f, 0.f, 0.5f)});
  ASSERT_TRUE(no_gradient.ok()) << no_gradient.status();
  EXPECT_TRUE(no_gradient->gradient.empty());
  auto nan = session.Query({Vec3f(0.f, std::nanf(""), 0.f)});
  EXPECT_EQ(nan.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(session.Query({}).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_F(ClientTest, MeshTilesDecodeAndWeld) {
  const SessionHandle session = g_client->Session(kRobot);
  auto tiles = session.MeshTiles();
  ASSERT_TRUE(tiles.ok()) << tiles.status();
  ASSERT_GE(tiles->size(), 1u);
  size_t faces = 0;
  uint64_t newest = 0;
  for (const DecodedTile& t : *tiles) {
    EXPECT_GT(t.version, 0u);
    EXPECT_FALSE(t.draco.empty());
    faces += t.mesh.faces.size();
    newest = std::max(newest, t.version);
  }
  const Mesh merged = MergeTiles(*tiles);
  EXPECT_GT(merged.faces.size(), 0u);
  EXPECT_LE(merged.faces.size(), faces);

  // Nothing is newer than the newest tile; nothing lies in a box far from the map.
  auto none = session.MeshTiles(newest);
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_TRUE(none->empty());
  Box3d far;
  far.min = {500, 500, 0};
  far.max = {510, 510, 5};
  auto outside = session.MeshTiles(0, far);
  ASSERT_TRUE(outside.ok()) << outside.status();
  EXPECT_TRUE(outside->empty());
}

TEST_F(ClientTest, WatchSeesTilesFromNewScans) {
  const SessionHandle session = g_client->Session(kRobot);
  auto info = session.Info();
  ASSERT_TRUE(info.ok()) << info.status();
  std::thread streamer([&] {
    StreamOptions options;
    options.first_sequence = 500;
    EXPECT_TRUE(session.Stream(Scans(2, 300), options).ok());
  });
  int seen = 0;
  WatchOptions options;
  options.since_version = info->map_version();
  options.duration = std::chrono::seconds(60);
  const absl::Status s = session.Watch(
      [&](const DecodedTile& tile) {
        EXPECT_GT(tile.version, info->map_version());
        ++seen;
        return false;  // one is enough
      },
      options);
  streamer.join();
  EXPECT_TRUE(s.ok()) << s;
  EXPECT_EQ(seen, 1);
}

TEST_F(ClientTest, UnknownSessionIsNotFoundEverywhere) {
  const SessionHandle nobody = g_client->Session("nobody");
  EXPECT_EQ(nobody.Info().status().code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(nobody.Info().status().message(), HasSubstr("nobody"));
  EXPECT_EQ(nobody.Query({Vec3f(0.f, 0.f, 0.f)}).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(nobody.MeshTiles().status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(nobody.Watch([](const DecodedTile&) { return true; }).code(),
            absl::StatusCode::kNotFound);
  EXPECT_EQ(g_client->SaveSession("nobody").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(g_client->CloseSession("nobody", false).code(), absl::StatusCode::kNotFound);
  // A stream to an unknown session rejects each scan with NOT_FOUND and still ends cleanly.
  auto summary = nobody.Stream(Scans(1, 1));
  ASSERT_TRUE(summary.ok()) << summary.status();
  EXPECT_EQ(summary->rejected, 1u);
  ASSERT_EQ(summary->rejections.size(), 1u);
  EXPECT_EQ(summary->rejections[0].code, int(grpc::StatusCode::NOT_FOUND));
}

TEST_F(ClientTest, SaveCloseAndLoadKeepTheMap) {
  auto before = g_client->GetSession(kRobot);
  ASSERT_TRUE(before.ok()) << before.status();
  auto saved = g_client->SaveSession(kRobot);
  ASSERT_TRUE(saved.ok()) << saved.status();
  EXPECT_FALSE(saved->checkpoint().empty());
  ASSERT_TRUE(g_client->CloseSession(kRobot, /*save=*/true).ok());
  EXPECT_EQ(g_client->GetSession(kRobot).status().code(), absl::StatusCode::kNotFound);
  auto loaded = g_client->LoadSession(kRobot);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->integrated_frames(), before->integrated_frames());
  auto query = g_client->Session(kRobot).Query({Vec3f(1.0f, 0.f, 0.5f)});
  ASSERT_TRUE(query.ok()) << query.status();
}

TEST_F(ClientTest, UnreachableServerIsUnavailable) {
  ClientOptions options;
  options.connect_timeout = std::chrono::milliseconds(500);
  auto client = Client::Connect("127.0.0.1:1", options);
  EXPECT_EQ(client.status().code(), absl::StatusCode::kUnavailable);
  EXPECT_THAT(client.status().message(), HasSubstr("cannot reach rim_server at 127.0.0.1:1"));
}

// Last: the server stops cleanly on SIGTERM with a session open.
TEST_F(ClientTest, ServerStopsCleanly) {
  auto code = g_server->Stop();
  ASSERT_TRUE(code.ok()) << code.status() << "\n" << g_server->Log();
  EXPECT_EQ(*code, 0) << g_server->Log();
}

}  // namespace
}  // namespace rim
