// rim_server's limits and bad input, end to end (DESIGN.md §5.2): every malformed scan is rejected
// with INVALID_ARGUMENT naming the field (or RESOURCE_EXHAUSTED for a limit), the stream goes on
// and the session stays usable with exactly the valid scans in it; depth images are ingested;
// queries and sessions have their limits; the host memory budget refuses sessions and scans; and
// health reports NOT_SERVING until warm-up is done.
#include <arpa/inet.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "client/client.h"
#include "client/wire.h"
#include "gmock/gmock.h"
#include "rim/v1/rim.grpc.pb.h"
#include "support/analytic_scene.h"
#include "support/server_process.h"
#include "support/small_session.h"

namespace rim {
namespace {

using ::testing::HasSubstr;
using namespace std::chrono_literals;
using testing_support::GroundScan;
using testing_support::ServerProcess;
using testing_support::ServerProcessOptions;

constexpr int kMaxPointsPerScan = 20000;
constexpr int kMaxQueryPoints = 1000;

const std::vector<std::pair<std::string, std::string>> kSmallMap =
    testing_support::SmallMapOverrides();

// A depth camera looking straight down at the same ground, 1 m below: every pixel reads 1 m.
rim::v1::Scan DepthScan(const std::string& robot, uint32_t width, uint32_t height) {
  rim::v1::Scan scan = ScanToProto(GroundScan(0.2), robot, 0);
  scan.clear_points_xyz();
  // Camera frame: z forward. Rotate 180 degrees about x so that +z points down (world -z).
  scan.mutable_pose()->mutable_rotation()->set_w(0);
  scan.mutable_pose()->mutable_rotation()->set_x(1);
  scan.mutable_pose()->mutable_rotation()->set_y(0);
  scan.mutable_pose()->mutable_rotation()->set_z(0);
  rim::v1::DepthImage* depth = scan.mutable_depth();
  depth->set_width(width);
  depth->set_height(height);
  depth->set_encoding(rim::v1::DepthImage::UINT16);
  depth->set_scale(1000.0);  // millimetres
  depth->set_fx(40);
  depth->set_fy(40);
  depth->set_cx(width / 2.0);
  depth->set_cy(height / 2.0);
  std::string data(size_t(width) * height * 2, '\0');
  for (size_t i = 0; i < size_t(width) * height; ++i) {
    const uint16_t mm = 1000;
    std::memcpy(&data[2 * i], &mm, 2);
  }
  depth->set_data(data);
  return scan;
}

class ServerLimitsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    ServerProcessOptions options;
    options.args = {"--max-points-per-scan", std::to_string(kMaxPointsPerScan),
                    "--max-query-points",    std::to_string(kMaxQueryPoints),
                    "--max-sessions",        "2"};
    auto server = ServerProcess::Start(options);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = server->release();
    auto client = Client::Connect(server_->address());
    ASSERT_TRUE(client.ok()) << client.status();
    client_ = new Client(std::move(*client));
  }
  static void TearDownTestSuite() {
    delete client_;
    if (server_) EXPECT_EQ(server_->Stop().value_or(-1), 0);
    delete server_;
  }
  static ServerProcess* server_;
  static Client* client_;
};
ServerProcess* ServerLimitsTest::server_ = nullptr;
Client* ServerLimitsTest::client_ = nullptr;

TEST_F(ServerLimitsTest, EveryBadScanIsRejectedByNameAndTheSessionStaysUsable) {
  const std::string robot = "limits_robot";
  ASSERT_TRUE(client_->CreateSession(robot, "maicity", kSmallMap).ok());
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();

  struct Case {
    const char* what;
    rim::v1::Scan scan;
    int code;  // expected gRPC code; 0: accepted and integrated
    const char* reason;
  };
  std::vector<Case> cases;
  auto good = [&](double x) { return ScanToProto(GroundScan(x), robot, 0); };
  cases.push_back({"valid", good(0.0), 0, ""});
  {
    rim::v1::Scan s = good(0.1);
    s.mutable_points_xyz()->push_back('x');
    cases.push_back({"13 bytes too many", s, 3, "not a multiple of 12"});
  }
  {
    rim::v1::Scan s = good(0.1);
    std::string p = s.points_xyz();
    std::memcpy(&p[12 * 5], &nan, 4);
    s.set_points_xyz(p);
    cases.push_back({"NaN point", s, 3, "scan.points_xyz has a non-finite value at point 5"});
  }
  {
    rim::v1::Scan s = good(0.1);
    s.mutable_pose()->mutable_translation()->set_y(inf);
    cases.push_back({"Inf in the pose", s, 3, "scan.pose.translation is not finite"});
  }
  {
    rim::v1::Scan s = good(0.1);
    s.mutable_pose()->mutable_rotation()->set_w(0.5);
    cases.push_back({"non-unit quaternion", s, 3, "not a unit quaternion"});
  }
  {
    rim::v1::Scan s = good(0.1);
    s.clear_points_xyz();
    s.set_points_xyz("");
    cases.push_back({"empty scan", s, 3, "scan.points_xyz is empty"});
  }
  {
    rim::v1::Scan s = good(0.1);
    s.set_origins_xyz(std::string(24, '\0'));
    cases.push_back({"origins of the wrong length", s, 3, "scan.origins_xyz has 24 bytes"});
  }
  {
    rim::v1::Scan s = DepthScan(robot, 64, 48);
    s.mutable_depth()->mutable_data()->resize(64 * 48 * 2 - 2);
    cases.push_back({"depth data vs size", s, 3, "scan.depth.data has"});
  }
  {
    rim::v1::Scan s = DepthScan(robot, 64, 48);
    s.mutable_depth()->set_fx(0);
    cases.push_back({"depth intrinsics", s, 3, "scan.depth.fx"});
  }
  {
    rim::v1::Scan s = good(0.1);
    s.set_points_xyz(std::string(size_t(kMaxPointsPerScan + 1) * 12, '\0'));
    cases.push_back({"too many points", s, 8, "--max-points-per-scan"});
  }
  cases.push_back({"valid depth image", DepthScan(robot, 64, 48), 0, ""});
  cases.push_back({"valid again", good(0.3), 0, ""});

  size_t next = 0;
  std::vector<rim::v1::ScanAck> acks;
  StreamOptions options;
  options.on_ack = [&](const rim::v1::ScanAck& ack) { acks.push_back(ack); };
  auto summary = client_->Session(robot).Stream(
      [&](rim::v1::Scan* scan) -> absl::StatusOr<bool> {
        if (next == cases.size()) return false;
        *scan = cases[next++].scan;  // the stream sets robot id and sequence (= index)
        return true;
      },
      options);
  ASSERT_TRUE(summary.ok()) << summary.status();
  for (size_t i = 0; i < cases.size(); ++i) {
    const Case& c = cases[i];
    std::vector<rim::v1::ScanAck> mine;
    for (const auto& a : acks)
      if (a.sequence() == i) mine.push_back(a);
    ASSERT_FALSE(mine.empty()) << c.what;
    if (c.code == 0) {
      EXPECT_EQ(mine.back().state(), rim::v1::ScanAck::INTEGRATED) << c.what;
    } else {
      ASSERT_EQ(mine.size(), 1u) << c.what;
      EXPECT_EQ(mine[0].state(), rim::v1::ScanAck::REJECTED) << c.what;
      EXPECT_EQ(mine[0].code(), c.code) << c.what << ": " << mine[0].reason();
      EXPECT_THAT(mine[0].reason(), HasSubstr(c.reason)) << c.what;
    }
  }
  EXPECT_EQ(summary->integrated, 3u);
  EXPECT_EQ(summary->rejected, cases.size() - 3);

  // Exactly the valid scans are in the map, and it answers: the ground 1 m below the sensors.
  auto info = client_->GetSession(robot);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->integrated_frames(), 3u);
  auto q = client_->Session(robot).Query({Vec3f(0.2f, 0.1f, -1.f), Vec3f(0.3f, -0.2f, -0.5f)});
  ASSERT_TRUE(q.ok()) << q.status();
  EXPECT_LT(std::abs(q->sdf[0]), 0.05f);
  EXPECT_EQ(q->observed[0], 1);
  EXPECT_GT(q->sdf[1], 0.2f);
  auto unknown = client_->Session("nobody").Query({Vec3f(0, 0, 0)});
  EXPECT_EQ(unknown.status().code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(unknown.status().message()), HasSubstr("nobody"));
}

TEST_F(ServerLimitsTest, QueriesAndSessionsHaveTheirLimits) {
  const std::string robot = "query_robot";
  ASSERT_TRUE(client_->CreateSession(robot, "maicity", kSmallMap).ok());
  auto stub = rim::v1::Rim::NewStub(
      grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials()));
  auto query = [&](const std::string& bytes) {
    grpc::ClientContext ctx;
    rim::v1::QuerySdfRequest request;
    request.set_robot_id(robot);
    request.set_points_xyz(bytes);
    rim::v1::QuerySdfResponse response;
    return stub->QuerySdf(&ctx, request, &response);
  };
  grpc::Status s = query(std::string(size_t(kMaxQueryPoints + 1) * 12, '\0'));
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(s.error_message(), HasSubstr("StreamQuerySdf"));
  s = query(std::string(25, '\0'));
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(s.error_message(), HasSubstr("points_xyz"));
  std::string nan_points(24, '\0');
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(&nan_points[16], &nan, 4);
  s = query(nan_points);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(s.error_message(), HasSubstr("non-finite"));
  EXPECT_TRUE(query(std::string(24, '\0')).ok());  // still usable

  // --max-sessions 2: the other test's session and this one fill it.
  auto third = client_->CreateSession("third_robot", "maicity", kSmallMap);
  if (client_->ListSessions()->size() >= 2) {
    EXPECT_EQ(third.status().code(), absl::StatusCode::kResourceExhausted);
    EXPECT_THAT(std::string(third.status().message()), HasSubstr("--max-sessions"));
  }
}

// A planner that opens stream after stream meets --max-streams: RESOURCE_EXHAUSTED naming it, the
// open streams keep working, and a slot freed by a closed stream can be taken again.
TEST(ServerStreamLimitTest, StreamsPastTheLimitAreRefusedByNameAndTheOpenOnesGoOn) {
  ServerProcessOptions options;
  options.args = {"--max-streams", "2"};
  auto server = ServerProcess::Start(options);
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("planned", "maicity", kSmallMap).ok());
  auto stub = rim::v1::Rim::NewStub(
      grpc::CreateChannel((*server)->address(), grpc::InsecureChannelCredentials()));
  rim::v1::QuerySdfRequest request;
  request.set_robot_id("planned");
  request.set_points_xyz(std::string(24, '\0'));  // two points at the origin
  struct Open {
    grpc::ClientContext ctx;
    std::unique_ptr<grpc::ClientReaderWriter<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse>>
        stream;
  };
  // Opens a query stream and asks once; false when the server refused it (status in *refused).
  auto open = [&](Open* o, grpc::Status* refused) {
    o->stream = stub->StreamQuerySdf(&o->ctx);
    rim::v1::QuerySdfResponse response;
    if (o->stream->Write(request) && o->stream->Read(&response)) return true;
    o->stream->WritesDone();
    *refused = o->stream->Finish();
    return false;
  };
  grpc::Status refused;
  Open a, b, c;
  ASSERT_TRUE(open(&a, &refused)) << refused.error_message();
  ASSERT_TRUE(open(&b, &refused)) << refused.error_message();
  ASSERT_FALSE(open(&c, &refused));
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(refused.error_message(), HasSubstr("--max-streams 2"));
  // A watch counts too.
  {
    grpc::ClientContext ctx;
    rim::v1::WatchMeshTilesRequest watch;
    watch.set_robot_id("planned");
    auto reader = stub->WatchMeshTiles(&ctx, watch);
    rim::v1::MeshTile tile;
    while (reader->Read(&tile)) {
    }
    const grpc::Status s = reader->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_THAT(s.error_message(), HasSubstr("WatchMeshTiles"));
  }
  // The open streams still answer, and unary queries are not streams.
  rim::v1::QuerySdfResponse response;
  ASSERT_TRUE(a.stream->Write(request) && a.stream->Read(&response));
  EXPECT_EQ(response.sdf().size(), 8u);
  EXPECT_TRUE(client->Session("planned").Query({Vec3f(0.f, 0.f, 0.f)}).ok());
  // Closing one frees its slot.
  a.stream->WritesDone();
  EXPECT_TRUE(a.stream->Finish().ok());
  std::unique_ptr<Open> d;
  for (int attempt = 0; attempt < 50 && !d; ++attempt) {  // the slot is freed as the stream ends
    auto o = std::make_unique<Open>();
    if (open(o.get(), &refused))
      d = std::move(o);
    else
      std::this_thread::sleep_for(20ms);
  }
  ASSERT_TRUE(d) << refused.error_message();
  d->stream->WritesDone();
  EXPECT_TRUE(d->stream->Finish().ok());
  b.stream->WritesDone();
  EXPECT_TRUE(b.stream->Finish().ok());
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

TEST(ServerMemoryBudgetTest, SessionsAndScansOverTheBudgetAreRefused) {
  // The small map's live grids and optimiser state take about 5 MB: an 8 MB budget holds one
  // session, not two.
  ServerProcessOptions options;
  options.args = {"--host-memory-budget-bytes", "8000000"};
  auto server = ServerProcess::Start(options);
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  auto first = client->CreateSession("first", "maicity", kSmallMap);
  ASSERT_TRUE(first.ok()) << first.status();
  ASSERT_LT(first->host_memory_bytes(), 8000000u);
  ASSERT_GT(2 * first->host_memory_bytes(), 8000000u);
  auto second = client->CreateSession("second", "maicity", kSmallMap);
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(second.status().message()), HasSubstr("host memory budget"));
  // Nothing of the refused session stays: it is not listed and can be created elsewhere later.
  EXPECT_EQ(client->ListSessions()->size(), 1u);
  EXPECT_EQ(client->GetSession("second").status().code(), absl::StatusCode::kNotFound);

  // A budget smaller than one session: scans are refused rather than growing the map.
  ServerProcessOptions tight;
  tight.args = {"--host-memory-budget-bytes", "1000"};
  auto small = ServerProcess::Start(tight);
  ASSERT_TRUE(small.ok());
  auto small_client = Client::Connect((*small)->address());
  ASSERT_TRUE(small_client.ok());
  auto none = small_client->CreateSession("any", "maicity", kSmallMap);
  EXPECT_EQ(none.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_EQ((*small)->Stop().value_or(-1), 0);

  // Room for one session and a hundred bytes more: the first scan is accepted (the budget is
  // checked on arrival) and its points fill the buffer past the budget; from then on ingest
  // refuses scans instead of growing.
  ServerProcessOptions scans;
  scans.args = {"--host-memory-budget-bytes", std::to_string(first->host_memory_bytes() + 100)};
  auto grow = ServerProcess::Start(scans);
  ASSERT_TRUE(grow.ok());
  auto grow_client = Client::Connect((*grow)->address());
  ASSERT_TRUE(grow_client.ok());
  ASSERT_TRUE(grow_client->CreateSession("grower", "maicity", kSmallMap).ok());
  auto one = grow_client->Session("grower").Stream({GroundScan(0)});
  ASSERT_TRUE(one.ok()) << one.status();
  ASSERT_EQ(one->integrated, 1u);
  std::vector<PosedScan> frames = {GroundScan(0.1), GroundScan(0.2)};
  std::vector<rim::v1::ScanAck> rejected;
  StreamOptions stream_options;
  stream_options.first_sequence = 1;
  stream_options.on_ack = [&](const rim::v1::ScanAck& ack) {
    if (ack.state() == rim::v1::ScanAck::REJECTED) rejected.push_back(ack);
  };
  auto summary = grow_client->Session("grower").Stream(frames, stream_options);
  ASSERT_TRUE(summary.ok()) << summary.status();
  EXPECT_EQ(summary->integrated, 0u);
  ASSERT_EQ(rejected.size(), 2u);
  EXPECT_EQ(rejected[0].code(), int(grpc::StatusCode::RESOURCE_EXHAUSTED));
  EXPECT_THAT(rejected[0].reason(), HasSubstr("host memory budget exceeded"));
  // What was accepted before is kept and answers queries.
  auto info = grow_client->GetSession("grower");
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->integrated_frames(), 1u);
  EXPECT_EQ(info->rejected_frames(), 2u);
  EXPECT_EQ((*grow)->Stop().value_or(-1), 0);
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

#if defined(__linux__)
// Nice values of the server's threads by name, read from /proc (field 19 of a task's stat).
std::vector<std::pair<std::string, int>> ThreadNices(pid_t pid) {
  std::vector<std::pair<std::string, int>> out;
  const std::string dir = "/proc/" + std::to_string(pid) + "/task";
  for (const auto& task : std::filesystem::directory_iterator(dir)) {
    std::ifstream comm(task.path() / "comm"), stat(task.path() / "stat");
    std::string name, line;
    std::getline(comm, name);
    std::getline(stat, line);
    // The name in stat is in parentheses and may hold spaces: count fields after the last ')'.
    std::istringstream rest(line.substr(line.rfind(')') + 2));
    std::string field;
    int nice = 0;
    for (int k = 3; k <= 19 && rest >> field; ++k)
      if (k == 19) nice = std::stoi(field);
    out.emplace_back(name, nice);
  }
  return out;
}

// docs/service.md, "Sharing the cores": training and the meshing for watchers run at
// --background-nice, and so do the dashboard's HTTP workers; the RPC threads that answer queries
// run at the process's own priority.
TEST(ServerPriorityTest, TrainingAndMeshingRunAtTheBackgroundNiceAndQueriesDoNot) {
  ServerProcessOptions options;
  options.args = {"--background-nice", "7", "--http", "127.0.0.1:0"};
  auto server = ServerProcess::Start(options);
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("nice", "maicity", kSmallMap).ok());
  auto streamed = client->Session("nice").Stream({GroundScan(0)});
  ASSERT_TRUE(streamed.ok()) << streamed.status();
  // A watcher meshes on its own thread; keep one open while the threads are read.
  grpc::ClientContext watch_context;
  rim::v1::WatchMeshTilesRequest watch_request;
  watch_request.set_robot_id("nice");
  auto channel = grpc::CreateChannel((*server)->address(), grpc::InsecureChannelCredentials());
  auto stub = rim::v1::Rim::NewStub(channel);
  auto watch = stub->WatchMeshTiles(&watch_context, watch_request);
  rim::v1::MeshTile first_tile;
  ASSERT_TRUE(watch->Read(&first_tile));  // the watcher thread is running
  ASSERT_TRUE(client->Session("nice").Query({Vec3f(0.f, 0.f, 0.5f)}).ok());
  int trainers = 0, watchers = 0, pools = 0, http_workers = 0, others_lowered = 0;
  for (const auto& [name, nice] : ThreadNices((*server)->pid())) {
    if (name == "rim-train") {
      ++trainers;
      EXPECT_EQ(nice, 7) << name;
    }
    if (name == "rim-watch") {
      ++watchers;
      EXPECT_EQ(nice, 7) << name;
    }
    if (name == "rim-http") {  // the dashboard's request workers
      ++http_workers;
      EXPECT_EQ(nice, 7) << name;
    }
    // Pool workers follow the trainer down when it first hands them work.
    if (name == "rim-pool" && nice == 7) ++pools;
    if (name.rfind("rim-", 0) != 0 && nice != 0) ++others_lowered;
  }
  EXPECT_GE(trainers, 1);  // a refresh's helper threads, if one runs, carry its name too
  EXPECT_GE(watchers, 1);
  EXPECT_GE(pools, 1);
  EXPECT_GE(http_workers, 1);
  EXPECT_EQ(others_lowered, 0) << "the RPC threads answer queries at the normal priority";
  watch_context.TryCancel();
  rim::v1::MeshTile ignored;
  while (watch->Read(&ignored)) {
  }
  watch->Finish();
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);

  // A value out of range is refused at start, by name.
  ServerProcessOptions bad;
  bad.args = {"--background-nice", "20"};
  auto refused = ServerProcess::Start(bad);
  ASSERT_FALSE(refused.ok());
  EXPECT_THAT(std::string(refused.status().message()), HasSubstr("--background-nice"));
}
#endif

// The body of GET http://host:port/path, over a plain socket ("" on any failure).
std::string HttpGet(const std::string& host_port, const std::string& path) {
  const size_t colon = host_port.rfind(':');
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(uint16_t(std::stoi(host_port.substr(colon + 1))));
  if (inet_pton(AF_INET, host_port.substr(0, colon).c_str(), &addr.sin_addr) != 1) return "";
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return "";
  std::string out;
  if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0) {
    const std::string request =
        "GET " + path + " HTTP/1.0\r\nHost: " + host_port + "\r\nConnection: close\r\n\r\n";
    if (send(fd, request.data(), request.size(), 0) == ssize_t(request.size())) {
      char buf[65536];
      for (ssize_t n; (n = recv(fd, buf, sizeof(buf), 0)) > 0;) out.append(buf, size_t(n));
    }
  }
  close(fd);
  const size_t body = out.find("\r\n\r\n");
  return body == std::string::npos ? "" : out.substr(body + 4);
}

// The value of one sample line `name{labels} value` of an exposition text; NaN when absent.
double MetricValue(const std::string& text, const std::string& series) {
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);)
    if (line.rfind(series + " ", 0) == 0) return std::stod(line.substr(series.size() + 1));
  return std::nan("");
}

// docs/service.md, "Sharing the cores": all watchers mesh within --meshing-cores CPU-seconds per
// second. A tiny budget makes a watcher wait between tiles, and it still gets the last version
// of every tile when the session closes; the CPU charged never runs ahead of the budget by more
// than its burst and the tile in hand.
TEST(ServerMeshingBudgetTest, WatchersWaitForTheBudgetAndStillGetEveryTileAtItsLastVersion) {
  // 5 ms of meshing per second, 5 ms of burst: well under what the frames' tiles cost (about
  // 10-40 ms of CPU here, less when the frames come faster than watch rounds), so the budget binds.
  constexpr double kCores = 0.005;
  ServerProcessOptions options;
  options.args = {"--meshing-cores", "0.005", "--metrics", "127.0.0.1:0"};
  auto server = ServerProcess::Start(options);
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string log = (*server)->Log();
  const std::string marker = "metrics on http://";
  const size_t at = log.find(marker);
  ASSERT_NE(at, std::string::npos) << log;
  const std::string metrics_addr =
      log.substr(at + marker.size(), log.find("/metrics", at) - at - marker.size());
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  auto overrides = kSmallMap;
  overrides.push_back({"watch.min_interval_s", "0"});  // a round after every frame
  ASSERT_TRUE(client->CreateSession("budget", "maicity", overrides).ok());
  const auto start = std::chrono::steady_clock::now();
  std::map<std::tuple<int, int, int>, uint64_t> pushed;  // newest version per tile
  std::thread watcher([&] {
    auto watched = client->Session("budget").Watch([&](const DecodedTile& tile) {
      auto& v = pushed[{tile.key[0], tile.key[1], tile.key[2]}];
      v = std::max(v, tile.version);
      return true;
    });
    EXPECT_TRUE(watched.ok()) << watched;  // OK when the session closes
  });
  std::vector<PosedScan> scans;
  for (int f = 0; f < 8; ++f) scans.push_back(GroundScan(0.3 * f));
  auto streamed = client->Session("budget").Stream(scans);
  ASSERT_TRUE(streamed.ok()) << streamed.status();
  auto tiles = client->Session("budget").MeshTiles();
  ASSERT_TRUE(tiles.ok()) << tiles.status();
  const std::string text = HttpGet(metrics_addr, "/metrics");
  const double elapsed_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_TRUE(client->CloseSession("budget", false).ok());
  watcher.join();
  // Every tile arrived, at the version the map has after the last frame.
  ASSERT_FALSE(tiles->empty());
  for (const DecodedTile& t : *tiles) {
    auto it = pushed.find({t.key[0], t.key[1], t.key[2]});
    ASSERT_NE(it, pushed.end()) << "tile " << t.key[0] << "," << t.key[1] << " never pushed";
    EXPECT_EQ(it->second, t.version) << "tile " << t.key[0] << "," << t.key[1];
  }
  const double cpu = MetricValue(text, "rim_meshing_cpu_seconds_total{session=\"budget\"}");
  const double waited =
      MetricValue(text, "rim_meshing_budget_wait_seconds_total{session=\"budget\"}");
  const double encode_wall = MetricValue(text, "rim_meshing_seconds_sum{session=\"budget\"}");
  ASSERT_FALSE(std::isnan(cpu) || std::isnan(waited)) << text;
  EXPECT_GT(cpu, kCores) << "the watcher meshed less than its burst: the budget never bound";
  EXPECT_GT(waited, 0.0);
  // Charged CPU ≤ budget × time + burst + the tile meshed after the last wait (its wall time,
  // at most all the encodings' wall time, bounds its CPU time).
  EXPECT_LE(cpu, kCores * elapsed_s + kCores + encode_wall);
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);

  // A budget that is not a number of cores is refused at start, by name.
  for (const char* bad : {"-1", "nan", "lots"}) {
    ServerProcessOptions refused_options;
    refused_options.args = {"--meshing-cores", bad};
    auto refused = ServerProcess::Start(refused_options);
    ASSERT_FALSE(refused.ok()) << bad;
    EXPECT_THAT(std::string(refused.status().message()), HasSubstr("--meshing-cores")) << bad;
  }
}

TEST(ServerWarmupTest, HealthIsNotServingUntilWarmedUp) {
  ServerProcessOptions options;
  options.wait_until_serving = false;
  options.args = {"--warmup-frames", "6"};
  auto server = ServerProcess::Start(options);
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  bool saw_not_serving = false;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  ServingStatus status = ServingStatus::kUnknown;
  while (std::chrono::steady_clock::now() < deadline) {
    auto h = client->Health();
    ASSERT_TRUE(h.ok()) << h.status();
    status = *h;
    if (status == ServingStatus::kNotServing) saw_not_serving = true;
    if (status == ServingStatus::kServing) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_TRUE(saw_not_serving) << "warm-up of 6 frames finished before the first health check";
  EXPECT_EQ(status, ServingStatus::kServing);
  EXPECT_THAT((*server)->Log(), HasSubstr("warmed up in"));
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

TEST(ServerShutdownTest, SigtermMidStreamEndsTheStreamSavesEveryAcceptedScanAndExitsZero) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string data_dir = (*server)->data_dir();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("leaving", "maicity", kSmallMap).ok());
  std::vector<PosedScan> frames;
  for (int i = 0; i < 200; ++i) frames.push_back(GroundScan(0.02 * i));
  std::atomic<int> accepted{0}, integrated{0};
  StreamOptions options;
  options.rate_hz = 20;  // a robot at 20 Hz: the stream is still going when SIGTERM comes
  options.on_ack = [&](const rim::v1::ScanAck& ack) {
    if (ack.state() == rim::v1::ScanAck::ACCEPTED) ++accepted;
    if (ack.state() == rim::v1::ScanAck::INTEGRATED) ++integrated;
  };
  absl::Status stream_status;
  std::thread robot([&] {
    auto summary = client->Session("leaving").Stream(frames, options);
    stream_status = summary.status();
  });
  for (int i = 0; i < 600 && integrated < 5; ++i) std::this_thread::sleep_for(50ms);
  ASSERT_GE(integrated.load(), 5);
  const auto start = std::chrono::steady_clock::now();
  auto code = (*server)->Stop(std::chrono::seconds(30));
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  robot.join();  // the stream ended: it does not hang on a server that went away
  ASSERT_TRUE(code.ok()) << code.status();
  EXPECT_EQ(*code, 0);
  EXPECT_LT(seconds, 10.0 + 5.0) << "past the 10 s shutdown deadline";
  EXPECT_LT(accepted.load(), 200);
  std::printf("SIGTERM after %d accepted scans: exit 0 in %.2f s; stream ended with: %s\n",
              accepted.load(), seconds, stream_status.ToString().c_str());
  // The server's own "shutting down" is not reported as an unreachable server.
  const std::string why(stream_status.message());
  if (why.find("shutting down") != std::string::npos)
    EXPECT_EQ(why.find("cannot reach"), std::string::npos) << why;

  // Restart on the same data dir: the saved session has every accepted scan.
  auto restarted = ServerProcess::StartOn(data_dir);
  ASSERT_TRUE(restarted.ok()) << restarted.status();
  auto client2 = Client::Connect((*restarted)->address());
  ASSERT_TRUE(client2.ok());
  auto loaded = client2->LoadSession("leaving");
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->integrated_frames(), uint64_t(accepted.load()));
  EXPECT_EQ((*restarted)->Stop().value_or(-1), 0);
}

}  // namespace
}  // namespace rim
