// rim_server end to end: starts the real binary on a loopback port with a temporary data dir,
// creates a session, streams synthetic LiDAR scans of an analytic scene (one of them invalid),
// queries the SDF, fetches Draco mesh tiles, checks the documented error codes, and stops the
// server with SIGTERM.
#include <fcntl.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "proto/codec/mesh_codec.h"
#include "rim/v1/rim.grpc.pb.h"
#include "support/analytic_scene.h"
#include "support/temp_dir.h"

namespace rim::server {
namespace {

using testing_support::AnalyticScene;
using testing_support::LidarModel;

constexpr char kRobot[] = "robot_1";
constexpr int kScans = 10;

// The server process: started in SetUpTestSuite, stopped by the last test (SIGTERM).
pid_t g_pid = -1;
std::unique_ptr<rim::v1::Rim::Stub> g_stub;

AnalyticScene Scene() {
  AnalyticScene scene;
  scene.ground_z = 0.f;
  scene.boxes.push_back({Eigen::Vector3f(1.0f, -0.6f, -0.1f), Eigen::Vector3f(1.6f, 0.6f, 1.2f)});
  return scene;
}

std::vector<Eigen::Isometry3f> Poses() {
  return testing_support::StraightTrajectory(-0.5f, 0.4f, kScans, 1.0f);
}

std::string Pack(const std::vector<Eigen::Vector3f>& points) {
  std::string out(points.size() * 12, '\0');
  for (size_t i = 0; i < points.size(); ++i) std::memcpy(&out[12 * i], points[i].data(), 12);
  return out;
}

// A small-map session request (2 m box) with `iterations` training iterations per frame.
rim::v1::CreateSessionRequest SmallSessionRequest(const std::string& robot, int iterations,
                                                  int min_iterations = -1) {
  rim::v1::CreateSessionRequest request;
  request.set_robot_id(robot);
  std::vector<std::pair<std::string, std::string>> overrides = {
      {"grid.half_extent_x_m", "2"},
      {"grid.half_extent_y_m", "2"},
      {"grid.z_min_m", "-1.2"},
      {"grid.z_max_m", "1.2"},
      {"train.iterations", std::to_string(iterations)}};
  if (min_iterations >= 0)
    overrides.push_back({"train.min_iterations", std::to_string(min_iterations)});
  overrides.push_back({"sampler.rays_per_iteration", "512"});
  for (const auto& [k, v] : overrides) {
    auto* o = request.add_overrides();
    o->set_key(k);
    o->set_value(v);
  }
  return request;
}

// A 16-beam LiDAR looking down to -60 degrees: the ground near the sensor, inside the 2 m map.
LidarModel TestLidar() {
  LidarModel lidar;
  lidar.beams = 16;
  lidar.columns = 360;
  lidar.max_range_m = 6.f;
  lidar.elev_min_deg = -60.f;
  return lidar;
}

rim::v1::Scan MakeScan(uint64_t sequence, const Eigen::Isometry3f& pose,
                       const std::vector<Eigen::Vector3f>& points) {
  rim::v1::Scan scan;
  scan.set_robot_id(kRobot);
  scan.set_sequence(sequence);
  scan.set_timestamp_s(0.1 * double(sequence));
  const Eigen::Quaternionf q(pose.rotation());
  auto* p = scan.mutable_pose();
  p->mutable_translation()->set_x(pose.translation().x());
  p->mutable_translation()->set_y(pose.translation().y());
  p->mutable_translation()->set_z(pose.translation().z());
  p->mutable_rotation()->set_w(q.w());
  p->mutable_rotation()->set_x(q.x());
  p->mutable_rotation()->set_y(q.y());
  p->mutable_rotation()->set_z(q.z());
  scan.set_points_xyz(Pack(points));
  return scan;
}

// Starts rim_server on a free loopback port with `data_dir`; returns its address, or "" (with the
// server's output in *log) when it did not come up.
std::string StartServer(const std::string& data_dir, pid_t* pid, std::string* log) {
  int out[2];
  if (pipe(out) != 0) return "";
  *pid = fork();
  if (*pid < 0) return "";
  if (*pid == 0) {
    dup2(out[1], STDOUT_FILENO);
    close(out[0]);
    close(out[1]);
    execl(RIM_SERVER_BIN, RIM_SERVER_BIN, "--listen", "127.0.0.1:0", "--data-dir", data_dir.c_str(),
          "--max-sessions", "4", nullptr);
    _exit(127);
  }
  close(out[1]);
  // Wait for "rim_server listening on HOST:PORT".
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  std::string address;
  while (address.empty() && std::chrono::steady_clock::now() < deadline) {
    pollfd fd{out[0], POLLIN, 0};
    if (poll(&fd, 1, 500) <= 0) continue;
    char buf[256];
    const ssize_t n = read(out[0], buf, sizeof(buf));
    if (n <= 0) break;
    log->append(buf, size_t(n));
    const size_t at = log->find("listening on ");
    const size_t eol = at == std::string::npos ? at : log->find('\n', at);
    if (eol != std::string::npos) address = log->substr(at + 13, eol - at - 13);
  }
  close(out[0]);
  return address;
}

std::unique_ptr<rim::v1::Rim::Stub> Connect(const std::string& address) {
  auto channel = grpc::CreateChannel(address, grpc::InsecureChannelCredentials());
  if (!channel->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(10)))
    return nullptr;
  return rim::v1::Rim::NewStub(channel);
}

class ServerE2eTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const std::string data_dir = testing_support::MakeTempDir("rim_server_e2e");
    std::string log;
    const std::string address = StartServer(data_dir, &g_pid, &log);
    ASSERT_FALSE(address.empty()) << "rim_server did not start: " << log;
    g_stub = Connect(address);
    ASSERT_NE(g_stub, nullptr);
  }

  static void TearDownTestSuite() {
    g_stub.reset();
    if (g_pid > 0) {
      kill(g_pid, SIGKILL);
      waitpid(g_pid, nullptr, 0);
      g_pid = -1;
    }
  }
};

TEST_F(ServerE2eTest, ServerInfo) {
  grpc::ClientContext ctx;
  rim::v1::ServerInfo info;
  ASSERT_TRUE(g_stub->GetServerInfo(&ctx, rim::v1::GetServerInfoRequest(), &info).ok());
  EXPECT_EQ(info.build(), "cpu");
  EXPECT_EQ(info.device(), "cpu");  // no --device
  EXPECT_EQ(info.max_sessions(), 4u);
  EXPECT_GE(info.presets_size(), 5);
}

TEST_F(ServerE2eTest, CreateSessionAndErrors) {
  rim::v1::CreateSessionRequest request = SmallSessionRequest(kRobot, 15);
  {
    grpc::ClientContext ctx;
    rim::v1::SessionInfo info;
    const grpc::Status s = g_stub->CreateSession(&ctx, request, &info);
    ASSERT_TRUE(s.ok()) << s.error_message();
    EXPECT_EQ(info.robot_id(), kRobot);
    EXPECT_NE(info.config().find("train.iterations = 15"), std::string::npos) << info.config();
  }
  {
    grpc::ClientContext ctx;
    rim::v1::SessionInfo info;
    EXPECT_EQ(g_stub->CreateSession(&ctx, request, &info).error_code(),
              grpc::StatusCode::ALREADY_EXISTS);
  }
  {
    grpc::ClientContext ctx;
    rim::v1::CreateSessionRequest bad;
    bad.set_robot_id("bad id!");
    rim::v1::SessionInfo info;
    const grpc::Status s = g_stub->CreateSession(&ctx, bad, &info);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("robot_id"), std::string::npos);
  }
  {
    grpc::ClientContext ctx;
    rim::v1::CreateSessionRequest bad;
    bad.set_robot_id("other");
    auto* o = bad.add_overrides();
    o->set_key("train.no_such_key");
    o->set_value("1");
    rim::v1::SessionInfo info;
    const grpc::Status s = g_stub->CreateSession(&ctx, bad, &info);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("train.no_such_key"), std::string::npos) << s.error_message();
  }
  {
    grpc::ClientContext ctx;
    rim::v1::GetSessionRequest get;
    get.set_robot_id("nobody");
    rim::v1::SessionInfo info;
    EXPECT_EQ(g_stub->GetSession(&ctx, get, &info).error_code(), grpc::StatusCode::NOT_FOUND);
  }
}

TEST_F(ServerE2eTest, StreamScansAcksAndRejects) {
  const AnalyticScene scene = Scene();
  const LidarModel lidar = TestLidar();
  const auto poses = Poses();
  grpc::ClientContext ctx;
  auto stream = g_stub->StreamScans(&ctx);
  std::map<uint64_t, std::vector<int>> states;  // sequence -> ack states in order
  std::map<uint64_t, std::string> reasons;
  std::thread reader([&] {
    rim::v1::ScanAck ack;
    while (stream->Read(&ack)) {
      states[ack.sequence()].push_back(ack.state());
      if (ack.state() == rim::v1::ScanAck::REJECTED) reasons[ack.sequence()] = ack.reason();
    }
  });
  uint64_t sequence = 0;
  for (int i = 0; i < kScans; ++i) {
    const auto points = testing_support::SimulateScan(scene, lidar, poses[i], 100 + i);
    ASSERT_GT(points.size(), 1000u);
    ASSERT_TRUE(stream->Write(MakeScan(sequence++, poses[i], points)));
    if (i == 4) {  // a NaN point and a bad quaternion in the middle: rejected, the stream goes on
      auto bad_points = points;
      bad_points[7].x() = std::numeric_limits<float>::quiet_NaN();
      ASSERT_TRUE(stream->Write(MakeScan(1000, poses[i], bad_points)));
      rim::v1::Scan bad_pose = MakeScan(1001, poses[i], points);
      bad_pose.mutable_pose()->mutable_rotation()->set_w(2.0);
      ASSERT_TRUE(stream->Write(bad_pose));
    }
  }
  stream->WritesDone();
  reader.join();
  const grpc::Status status = stream->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  for (uint64_t s = 0; s < kScans; ++s) {
    EXPECT_EQ(states[s],
              (std::vector<int>{rim::v1::ScanAck::ACCEPTED, rim::v1::ScanAck::INTEGRATED}))
        << "scan " << s;
  }
  EXPECT_EQ(states[1000], std::vector<int>{rim::v1::ScanAck::REJECTED});
  EXPECT_NE(reasons[1000].find("scan.points_xyz"), std::string::npos) << reasons[1000];
  EXPECT_EQ(states[1001], std::vector<int>{rim::v1::ScanAck::REJECTED});
  EXPECT_NE(reasons[1001].find("scan.pose.rotation is not a unit quaternion"), std::string::npos)
      << reasons[1001];

  grpc::ClientContext get_ctx;
  rim::v1::GetSessionRequest get;
  get.set_robot_id(kRobot);
  rim::v1::SessionInfo info;
  ASSERT_TRUE(g_stub->GetSession(&get_ctx, get, &info).ok());
  EXPECT_EQ(info.integrated_frames(), uint64_t(kScans));
  EXPECT_EQ(info.accepted_frames(), uint64_t(kScans));
  EXPECT_EQ(info.rejected_frames(), 2u);
  EXPECT_GT(info.map_version(), 0u);
}

TEST_F(ServerE2eTest, QuerySdfAtSurface) {
  const AnalyticScene scene = Scene();
  const auto surface = scene.SampleSurface(Eigen::Vector3f(-1.2f, -1.2f, -0.2f),
                                           Eigen::Vector3f(1.2f, 1.2f, 1.f), 500, 7);
  ASSERT_GT(surface.size(), 100u);
  std::vector<Eigen::Vector3f> points;
  for (const auto& s : surface) points.push_back(s.p);
  rim::v1::QuerySdfRequest request;
  request.set_robot_id(kRobot);
  request.set_points_xyz(Pack(points));
  request.set_want_gradient(true);
  grpc::ClientContext ctx;
  rim::v1::QuerySdfResponse response;
  const grpc::Status s = g_stub->QuerySdf(&ctx, request, &response);
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(response.sdf().size(), points.size() * 4);
  ASSERT_EQ(response.gradient().size(), points.size() * 12);
  ASSERT_EQ(response.observed().size(), points.size());
  ASSERT_EQ(response.saturated().size(), points.size());
  int observed = 0, close = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    if (response.observed()[i] == 0) continue;
    ++observed;
    float sdf;
    std::memcpy(&sdf, response.sdf().data() + 4 * i, 4);
    if (std::abs(sdf) < 0.05f) ++close;
  }
  std::printf("observed %d of %zu surface points, %d within 5 cm\n", observed, points.size(),
              close);
  EXPECT_GT(observed, int(points.size()) / 2);
  EXPECT_GT(close, observed * 7 / 10);

  // Bad inputs: wrong length, NaN, unknown session.
  rim::v1::QuerySdfRequest bad = request;
  bad.set_points_xyz(request.points_xyz().substr(0, 13));
  grpc::ClientContext c1;
  EXPECT_EQ(g_stub->QuerySdf(&c1, bad, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  const float nan[3] = {0.f, std::numeric_limits<float>::quiet_NaN(), 0.f};
  bad.set_points_xyz(std::string(reinterpret_cast<const char*>(nan), 12));
  grpc::ClientContext c2;
  EXPECT_EQ(g_stub->QuerySdf(&c2, bad, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  bad.set_robot_id("nobody");
  grpc::ClientContext c3;
  EXPECT_EQ(g_stub->QuerySdf(&c3, bad, &response).error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(ServerE2eTest, StreamQuerySdfAnswersEachChunkLikeTheUnaryCall) {
  // Three chunks of a larger batch; each answer must equal the unary answer for that chunk.
  std::vector<rim::v1::QuerySdfRequest> chunks;
  for (int c = 0; c < 3; ++c) {
    std::vector<Eigen::Vector3f> points;
    for (int i = 0; i < 200; ++i)
      points.emplace_back(-1.f + 0.01f * float(i), 0.3f * float(c) - 0.3f, 0.05f + 0.1f * float(c));
    rim::v1::QuerySdfRequest r;
    r.set_robot_id(kRobot);
    r.set_points_xyz(Pack(points));
    r.set_want_gradient(c == 1);
    chunks.push_back(r);
  }
  grpc::ClientContext ctx;
  auto stream = g_stub->StreamQuerySdf(&ctx);
  for (const auto& r : chunks) ASSERT_TRUE(stream->Write(r));
  stream->WritesDone();
  std::vector<rim::v1::QuerySdfResponse> answers;
  rim::v1::QuerySdfResponse a;
  while (stream->Read(&a)) answers.push_back(a);
  const grpc::Status s = stream->Finish();
  ASSERT_TRUE(s.ok()) << s.error_message();
  ASSERT_EQ(answers.size(), chunks.size());
  for (size_t c = 0; c < chunks.size(); ++c) {
    grpc::ClientContext uctx;
    rim::v1::QuerySdfResponse unary;
    ASSERT_TRUE(g_stub->QuerySdf(&uctx, chunks[c], &unary).ok());
    EXPECT_EQ(answers[c].sdf(), unary.sdf()) << "chunk " << c;
    EXPECT_EQ(answers[c].gradient(), unary.gradient()) << "chunk " << c;
    EXPECT_EQ(answers[c].observed(), unary.observed()) << "chunk " << c;
  }
  // A bad chunk ends the stream with its error.
  grpc::ClientContext bctx;
  auto bad_stream = g_stub->StreamQuerySdf(&bctx);
  rim::v1::QuerySdfRequest bad = chunks[0];
  bad.set_robot_id("nobody");
  ASSERT_TRUE(bad_stream->Write(bad));
  bad_stream->WritesDone();
  while (bad_stream->Read(&a)) {
  }
  EXPECT_EQ(bad_stream->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(ServerE2eTest, MeshTilesDecode) {
  rim::v1::GetMeshTilesRequest request;
  request.set_robot_id(kRobot);
  grpc::ClientContext ctx;
  auto reader = g_stub->GetMeshTiles(&ctx, request);
  rim::v1::MeshTile tile;
  int tiles = 0;
  size_t faces = 0;
  while (reader->Read(&tile)) {
    ++tiles;
    auto mesh = codec::DecodeTileDraco(tile.draco());
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    faces += mesh->faces.size();
    EXPECT_GT(tile.version(), 0u);
  }
  ASSERT_TRUE(reader->Finish().ok());
  EXPECT_GE(tiles, 1);
  EXPECT_GT(faces, 0u);
}

// Levels of detail: the session lists its levels; each level's tiles decode, name their level,
// and cost fewer bytes the coarser they are; a level the session does not have is refused by name,
// by GetMeshTiles and WatchMeshTiles alike.
TEST_F(ServerE2eTest, MeshTilesComeInLevelsOfDetail) {
  rim::v1::SessionInfo info;
  {
    grpc::ClientContext ctx;
    rim::v1::GetSessionRequest get;
    get.set_robot_id(kRobot);
    ASSERT_TRUE(g_stub->GetSession(&ctx, get, &info).ok());
  }
  ASSERT_GE(info.mesh_levels_m_size(), 3);
  // Every tile of GetMeshTiles at `level`, read to the end: the stream's status.
  const auto get_tiles = [](float level, std::vector<rim::v1::MeshTile>* tiles) {
    rim::v1::GetMeshTilesRequest request;
    request.set_robot_id(kRobot);
    request.set_resolution_m(level);
    grpc::ClientContext ctx;
    auto reader = g_stub->GetMeshTiles(&ctx, request);
    rim::v1::MeshTile tile;
    while (reader->Read(&tile)) tiles->push_back(tile);
    return reader->Finish();
  };
  std::vector<size_t> bytes, faces;
  for (int i = 0; i < 3; ++i) {
    const float level = info.mesh_levels_m(i);
    std::vector<rim::v1::MeshTile> tiles;
    ASSERT_TRUE(get_tiles(level, &tiles).ok()) << level << " m";
    size_t b = 0, f = 0;
    for (const rim::v1::MeshTile& tile : tiles) {
      EXPECT_FLOAT_EQ(tile.resolution_m(), level);
      auto mesh = codec::DecodeTileDraco(tile.draco());
      ASSERT_TRUE(mesh.ok()) << mesh.status();
      b += tile.draco().size();
      f += mesh->faces.size();
    }
    std::printf("level %.3f m: %zu faces, %zu bytes\n", level, f, b);
    bytes.push_back(b);
    faces.push_back(f);
  }
  ASSERT_GT(faces[0], 0u);
  EXPECT_GT(faces[2], 0u);
  EXPECT_LT(faces[1], faces[0]);
  EXPECT_LT(faces[2], faces[1]);
  EXPECT_LE(3 * bytes[2], bytes[0]);  // a coarse tile costs at most a third of the fine one

  const auto refused = [](const grpc::Status& status) {
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("resolution_m"), std::string::npos)
        << status.error_message();
  };
  for (float bad : {0.07f, -1.f}) {
    std::vector<rim::v1::MeshTile> tiles;
    refused(get_tiles(bad, &tiles));
    EXPECT_TRUE(tiles.empty()) << bad;
  }
  rim::v1::WatchMeshTilesRequest watch;
  watch.set_robot_id(kRobot);
  watch.set_resolution_m(0.07f);
  grpc::ClientContext ctx;
  auto reader = g_stub->WatchMeshTiles(&ctx, watch);
  rim::v1::MeshTile tile;
  size_t pushed = 0;
  while (reader->Read(&tile)) ++pushed;
  refused(reader->Finish());
  EXPECT_EQ(pushed, 0u);
}

// Last (gtest runs tests in definition order): SIGTERM stops the server cleanly.
TEST_F(ServerE2eTest, WatchMeshTilesPushesTilesAsTrainingChangesThem) {
  uint64_t since = 0;
  {
    grpc::ClientContext ctx;
    rim::v1::GetSessionRequest get;
    get.set_robot_id(kRobot);
    rim::v1::SessionInfo info;
    ASSERT_TRUE(g_stub->GetSession(&ctx, get, &info).ok());
    since = info.map_version();
  }
  grpc::ClientContext watch_ctx;
  watch_ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  rim::v1::WatchMeshTilesRequest watch;
  watch.set_robot_id(kRobot);
  watch.set_since_version(since);
  auto reader = g_stub->WatchMeshTiles(&watch_ctx, watch);
  // Nothing has changed since `since`: new tiles can only come from the scans streamed now.
  std::thread streamer([&] {
    const AnalyticScene scene = Scene();
    const LidarModel lidar = TestLidar();
    const auto poses = Poses();
    grpc::ClientContext ctx;
    auto stream = g_stub->StreamScans(&ctx);
    for (int i = 0; i < 2; ++i)
      stream->Write(MakeScan(uint64_t(2000 + i), poses[i],
                             testing_support::SimulateScan(scene, lidar, poses[i], 300 + i)));
    stream->WritesDone();
    rim::v1::ScanAck ack;
    while (stream->Read(&ack)) {
    }
    stream->Finish();
  });
  rim::v1::MeshTile tile;
  ASSERT_TRUE(reader->Read(&tile));
  EXPECT_GT(tile.version(), since);
  auto mesh = codec::DecodeTileDraco(tile.draco());
  ASSERT_TRUE(mesh.ok()) << mesh.status();
  EXPECT_EQ(mesh->faces.size(), tile.face_count());
  streamer.join();
  watch_ctx.TryCancel();
  while (reader->Read(&tile)) {
  }
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  // Unknown session: NOT_FOUND.
  grpc::ClientContext bad_ctx;
  watch.set_robot_id("nobody");
  auto bad = g_stub->WatchMeshTiles(&bad_ctx, watch);
  while (bad->Read(&tile)) {
  }
  EXPECT_EQ(bad->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(ServerE2eTest, TwoRobotsStreamAtOnce) {
  // Two sessions trained side by side, each by its own trainer, from two concurrent streams.
  const std::vector<std::string> robots = {"robot_left", "robot_right"};
  for (const std::string& robot : robots) {
    rim::v1::CreateSessionRequest request = SmallSessionRequest(robot, 10);
    grpc::ClientContext ctx;
    rim::v1::SessionInfo info;
    ASSERT_TRUE(g_stub->CreateSession(&ctx, request, &info).ok());
  }
  constexpr int kEach = 5;
  std::vector<int> integrated(robots.size(), 0);
  std::vector<std::thread> streams;
  for (size_t r = 0; r < robots.size(); ++r) {
    streams.emplace_back([&, r] {
      const AnalyticScene scene = Scene();
      const LidarModel lidar = TestLidar();
      const auto poses = Poses();
      grpc::ClientContext ctx;
      auto stream = g_stub->StreamScans(&ctx);
      for (int i = 0; i < kEach; ++i) {
        rim::v1::Scan scan = MakeScan(
            uint64_t(i), poses[i], testing_support::SimulateScan(scene, lidar, poses[i], 50 + i));
        scan.set_robot_id(robots[r]);
        stream->Write(scan);
      }
      stream->WritesDone();
      rim::v1::ScanAck ack;
      while (stream->Read(&ack)) integrated[r] += ack.state() == rim::v1::ScanAck::INTEGRATED;
      EXPECT_TRUE(stream->Finish().ok());
    });
  }
  for (auto& t : streams) t.join();
  for (size_t r = 0; r < robots.size(); ++r) {
    EXPECT_EQ(integrated[r], kEach) << robots[r];
    grpc::ClientContext ctx;
    rim::v1::GetSessionRequest get;
    get.set_robot_id(robots[r]);
    rim::v1::SessionInfo info;
    ASSERT_TRUE(g_stub->GetSession(&ctx, get, &info).ok());
    EXPECT_EQ(info.integrated_frames(), uint64_t(kEach)) << robots[r];
    // Each map answers for the box face the scans saw.
    std::vector<Eigen::Vector3f> face;
    for (float y = -0.4f; y <= 0.4f; y += 0.2f)
      for (float z = 0.1f; z <= 0.9f; z += 0.2f) face.emplace_back(1.0f, y, z);
    rim::v1::QuerySdfRequest q;
    q.set_robot_id(robots[r]);
    q.set_points_xyz(Pack(face));
    rim::v1::QuerySdfResponse a;
    grpc::ClientContext qctx;
    ASSERT_TRUE(g_stub->QuerySdf(&qctx, q, &a).ok());
    int close = 0, observed = 0;
    for (size_t i = 0; i < face.size(); ++i) {
      float sdf;
      std::memcpy(&sdf, a.sdf().data() + 4 * i, 4);
      observed += a.observed()[i] != 0;
      close += a.observed()[i] != 0 && std::abs(sdf) < 0.05f;
    }
    EXPECT_GT(observed, int(face.size()) / 2) << robots[r];
    EXPECT_GT(close, observed * 7 / 10) << robots[r];
  }
}

// A dashboard watching a session: what it receives of each tile, in arrival order.
struct WatchLog {
  std::map<std::array<int, 3>, std::vector<uint64_t>> versions;
  grpc::Status status;
};

// Watches `robot` from version 0 until the stream ends; sleeps `stall` before its first read, as
// a dashboard that fell behind.
WatchLog WatchUntilEnd(const std::string& robot, std::chrono::milliseconds stall) {
  WatchLog log;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
  rim::v1::WatchMeshTilesRequest watch;
  watch.set_robot_id(robot);
  auto reader = g_stub->WatchMeshTiles(&ctx, watch);
  std::this_thread::sleep_for(stall);
  rim::v1::MeshTile tile;
  while (reader->Read(&tile))
    log.versions[{tile.key_x(), tile.key_y(), tile.key_z()}].push_back(tile.version());
  log.status = reader->Finish();
  return log;
}

TEST_F(ServerE2eTest, WatchersGetCoalescedPushesOfTheNewestVersions) {
  // A bad interval is refused by name.
  {
    rim::v1::CreateSessionRequest bad = SmallSessionRequest("robot_badwatch", 5);
    auto* o = bad.add_overrides();
    o->set_key("watch.min_interval_s");
    o->set_value("-1");
    grpc::ClientContext ctx;
    rim::v1::SessionInfo info;
    const grpc::Status s = g_stub->CreateSession(&ctx, bad, &info);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("watch.min_interval_s"), std::string::npos)
        << s.error_message();
  }
  // Two sessions streamed alike: one pushes at most every 3 s, the other after every frame.
  const std::vector<std::pair<std::string, const char*>> robots = {{"robot_coalesced", "3"},
                                                                   {"robot_every_frame", "0"}};
  std::vector<WatchLog> logs(robots.size());
  std::vector<std::map<std::array<int, 3>, uint64_t>> final_versions(robots.size());
  std::vector<double> watched_s(robots.size());
  for (size_t r = 0; r < robots.size(); ++r) {
    const std::string& robot = robots[r].first;
    rim::v1::CreateSessionRequest request = SmallSessionRequest(robot, 5);
    auto* o = request.add_overrides();
    o->set_key("watch.min_interval_s");
    o->set_value(robots[r].second);
    {
      grpc::ClientContext ctx;
      rim::v1::SessionInfo info;
      ASSERT_TRUE(g_stub->CreateSession(&ctx, request, &info).ok());
    }
    const auto start = std::chrono::steady_clock::now();
    // The every-frame watcher also stalls for a second: it must still end with each tile's
    // newest version, never an older one after a newer.
    std::thread watcher([&, r, robot] {
      logs[r] = WatchUntilEnd(robot, std::chrono::milliseconds(r == 1 ? 1000 : 0));
    });
    {
      const AnalyticScene scene = Scene();
      const LidarModel lidar = TestLidar();
      const auto poses = Poses();
      grpc::ClientContext ctx;
      auto stream = g_stub->StreamScans(&ctx);
      for (int i = 0; i < kScans; ++i) {
        rim::v1::Scan scan = MakeScan(
            uint64_t(i), poses[i], testing_support::SimulateScan(scene, lidar, poses[i], 70 + i));
        scan.set_robot_id(robot);
        stream->Write(scan);
      }
      stream->WritesDone();
      rim::v1::ScanAck ack;
      int integrated = 0;
      while (stream->Read(&ack)) integrated += ack.state() == rim::v1::ScanAck::INTEGRATED;
      ASSERT_TRUE(stream->Finish().ok());
      ASSERT_EQ(integrated, kScans);
    }
    {
      rim::v1::GetMeshTilesRequest get;
      get.set_robot_id(robot);
      grpc::ClientContext ctx;
      auto reader = g_stub->GetMeshTiles(&ctx, get);
      rim::v1::MeshTile tile;
      while (reader->Read(&tile))
        final_versions[r][{tile.key_x(), tile.key_y(), tile.key_z()}] = tile.version();
      ASSERT_TRUE(reader->Finish().ok());
    }
    // Closing the session ends the watch after a last round.
    {
      rim::v1::CloseSessionRequest close;
      close.set_robot_id(robot);
      rim::v1::CloseSessionResponse closed;
      grpc::ClientContext ctx;
      ASSERT_TRUE(g_stub->CloseSession(&ctx, close, &closed).ok());
    }
    watcher.join();
    watched_s[r] = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  int pushes[2] = {0, 0};
  for (size_t r = 0; r < robots.size(); ++r) {
    const WatchLog& log = logs[r];
    EXPECT_TRUE(log.status.ok()) << robots[r].first << ": " << log.status.error_message();
    ASSERT_FALSE(final_versions[r].empty());
    for (const auto& [key, final_version] : final_versions[r]) {
      auto it = log.versions.find(key);
      ASSERT_NE(it, log.versions.end()) << robots[r].first << ": a tile never pushed";
      const std::vector<uint64_t>& v = it->second;
      for (size_t i = 1; i < v.size(); ++i)
        EXPECT_LT(v[i - 1], v[i]) << robots[r].first << ": an older version after a newer";
      EXPECT_EQ(v.back(), final_version) << robots[r].first << ": not the newest version";
      pushes[r] = std::max(pushes[r], int(v.size()));
    }
  }
  std::printf("most pushes of one tile: %d in %.1f s at a 3 s interval, %d in %.1f s at 0 s\n",
              pushes[0], watched_s[0], pushes[1], watched_s[1]);
  // At most one push per tile per interval (plus the first round and the closing one).
  EXPECT_LE(pushes[0], 2 + int(watched_s[0] / 3.0));
  EXPECT_LT(pushes[0], kScans / 2);
}

TEST_F(ServerE2eTest, SigtermExitsZero) {
  ASSERT_GT(g_pid, 0);
  ASSERT_EQ(kill(g_pid, SIGTERM), 0);
  int status = 0;
  pid_t done = 0;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(15);
  while ((done = waitpid(g_pid, &status, WNOHANG)) == 0 &&
         std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_EQ(done, g_pid) << "rim_server did not exit within 15 s of SIGTERM";
  g_pid = -1;
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
}

// kill -9 in the middle of a stream, restart, LoadSession: every scan that was acked ACCEPTED is
// in the recovered map (DESIGN.md §5.3), replayed from the write-ahead log.
TEST(ServerCrashTest, KillNineLosesNoAcceptedScan) {
  const std::string data_dir = testing_support::MakeTempDir("rim_server_crash");
  std::string log;
  pid_t pid = -1;
  std::string address = StartServer(data_dir, &pid, &log);
  ASSERT_FALSE(address.empty()) << log;
  auto stub = Connect(address);
  ASSERT_NE(stub, nullptr);
  // Slow training, so that accepted scans are still queued when the server dies.
  rim::v1::CreateSessionRequest create = SmallSessionRequest("crashbot", 120, 120);
  {
    grpc::ClientContext ctx;
    rim::v1::SessionInfo info;
    ASSERT_TRUE(stub->CreateSession(&ctx, create, &info).ok());
  }
  constexpr int kSent = 6;
  const AnalyticScene scene = Scene();
  const LidarModel lidar = TestLidar();
  const auto poses = Poses();
  int accepted = 0, integrated = 0;
  {
    grpc::ClientContext ctx;
    auto stream = stub->StreamScans(&ctx);
    for (int i = 0; i < kSent; ++i) {
      rim::v1::Scan scan =
          MakeScan(uint64_t(i), poses[i], testing_support::SimulateScan(scene, lidar, poses[i], i));
      scan.set_robot_id("crashbot");
      ASSERT_TRUE(stream->Write(scan));
    }
    rim::v1::ScanAck ack;
    while (accepted < kSent && stream->Read(&ack)) {
      accepted += ack.state() == rim::v1::ScanAck::ACCEPTED;
      integrated += ack.state() == rim::v1::ScanAck::INTEGRATED;
    }
    ASSERT_EQ(accepted, kSent);
    ASSERT_EQ(kill(pid, SIGKILL), 0);
    waitpid(pid, nullptr, 0);
    ctx.TryCancel();
  }
  std::printf("killed with %d scans accepted, %d integrated\n", accepted, integrated);
  EXPECT_LT(integrated, kSent);  // the crash really lost queued work that the log must restore

  log.clear();
  address = StartServer(data_dir, &pid, &log);
  ASSERT_FALSE(address.empty()) << log;
  stub = Connect(address);
  ASSERT_NE(stub, nullptr);
  {
    grpc::ClientContext ctx;
    rim::v1::LoadSessionRequest load;
    load.set_robot_id("crashbot");
    rim::v1::SessionInfo info;
    const grpc::Status s = stub->LoadSession(&ctx, load, &info);
    ASSERT_TRUE(s.ok()) << s.error_message();
    EXPECT_EQ(info.integrated_frames(), uint64_t(kSent));
  }
  {
    // Creating it anew would hide the saved data: refused.
    grpc::ClientContext ctx;
    rim::v1::SessionInfo info;
    create.set_robot_id("crashbot");
    EXPECT_EQ(stub->CreateSession(&ctx, create, &info).error_code(),
              grpc::StatusCode::ALREADY_EXISTS);
  }
  {
    // The client resends what it had no INTEGRATED ack for, marked `resend`, plus one new scan:
    // the restored session knows the highest sequence it accepted (from the log), acknowledges
    // 4 and 5 as duplicates without integrating them again, and takes 6.
    grpc::ClientContext ctx;
    auto stream = stub->StreamScans(&ctx);
    for (int i = 4; i <= kSent; ++i) {
      rim::v1::Scan scan =
          MakeScan(uint64_t(i), poses[i], testing_support::SimulateScan(scene, lidar, poses[i], i));
      scan.set_robot_id("crashbot");
      scan.set_resend(true);
      ASSERT_TRUE(stream->Write(scan));
    }
    stream->WritesDone();
    std::map<uint64_t, std::vector<std::pair<int, bool>>> acks;
    rim::v1::ScanAck ack;
    while (stream->Read(&ack)) acks[ack.sequence()].push_back({ack.state(), ack.duplicate()});
    ASSERT_TRUE(stream->Finish().ok());
    const std::vector<std::pair<int, bool>> duplicate = {{rim::v1::ScanAck::ACCEPTED, true},
                                                         {rim::v1::ScanAck::INTEGRATED, true}};
    const std::vector<std::pair<int, bool>> fresh = {{rim::v1::ScanAck::ACCEPTED, false},
                                                     {rim::v1::ScanAck::INTEGRATED, false}};
    EXPECT_EQ(acks[4], duplicate);
    EXPECT_EQ(acks[5], duplicate);
    EXPECT_EQ(acks[uint64_t(kSent)], fresh);
    grpc::ClientContext get_ctx;
    rim::v1::GetSessionRequest get;
    get.set_robot_id("crashbot");
    rim::v1::SessionInfo info;
    ASSERT_TRUE(stub->GetSession(&get_ctx, get, &info).ok());
    EXPECT_EQ(info.map_frames(), uint64_t(kSent + 1));  // 6 replayed + 1: none twice
  }
  ASSERT_EQ(kill(pid, SIGTERM), 0);
  int wstatus = 0;
  waitpid(pid, &wstatus, 0);
  EXPECT_TRUE(WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0);
}

}  // namespace
}  // namespace rim::server
