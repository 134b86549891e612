// rim_server with --tokens, end to end (docs/security.md): the real server and the real client.
// Missing and unknown tokens are UNAUTHENTICATED; a robot acts on its own session only (a scan
// for another robot in its stream is REJECTED with PERMISSION_DENIED, the stream goes on); a
// viewer reads but does not write; an admin loads and closes; health needs no token; a refused
// call changes nothing. Also rim_server --hash-token and rimctl --token.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "client/client.h"
#include "client/wire.h"
#include "gmock/gmock.h"
#include "rim/gpu/device_map.h"
#include "rim/v1/rim.grpc.pb.h"
#include "server/auth/auth.h"
#include "support/server_process.h"
#include "support/small_session.h"
#include "support/subprocess.h"
#include "support/temp_dir.h"

namespace rim {
namespace {

using ::testing::HasSubstr;
using testing_support::GroundScan;
using testing_support::ServerProcess;

constexpr char kAdmin[] = "admin-6d1f0c2e";
constexpr char kViewer[] = "viewer-93ab77d4";
constexpr char kRobot1[] = "robot1-0f5e2a9b";
constexpr char kRobot2[] = "robot2-c41d8e60";
constexpr char kRobot3[] = "robot3-7a2b19fe";  // its session is not made up front

const std::vector<std::pair<std::string, std::string>> kSmallMap =
    testing_support::SmallMapOverrides();

absl::StatusCode Code(const absl::Status& s) { return s.code(); }
template <typename T>
absl::StatusCode Code(const absl::StatusOr<T>& s) {
  return s.status().code();
}

class ServerAuthTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    const std::string tokens = testing_support::MakeTempDir("rim_auth") + "/tokens.txt";
    std::ofstream(tokens) << "# role subject sha256(token)\n"
                          << "admin ops " << server::HashToken(kAdmin) << "\n"
                          << "viewer wall " << server::HashToken(kViewer) << "\n"
                          << "robot r1 " << server::HashToken(kRobot1) << "\n"
                          << "robot r2 " << server::HashToken(kRobot2) << "\n"
                          << "robot r3 " << server::HashToken(kRobot3) << "\n";
    testing_support::ServerProcessOptions options;
    options.args = {"--tokens", tokens, "--warmup-frames", "0"};
    auto server = ServerProcess::Start(options);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = server->release();
    ASSERT_THAT(server_->Log(), HasSubstr("access control on: 1 admin, 1 viewer, 3 robot"));
    const Client admin = Connect(kAdmin);
    ASSERT_TRUE(admin.CreateSession("r1", "maicity", kSmallMap).ok());
    ASSERT_TRUE(admin.CreateSession("r2", "maicity", kSmallMap).ok());
    // r1's own token streams its first scans.
    auto summary = Connect(kRobot1).Session("r1").Stream({GroundScan(0), GroundScan(0.1)});
    ASSERT_TRUE(summary.ok()) << summary.status();
    ASSERT_EQ(summary->integrated, 2u);
  }
  static void TearDownTestSuite() {
    if (server_) {
      const auto stopped = server_->Stop();
      EXPECT_EQ(stopped.value_or(-1), 0) << stopped.status() << "\n" << server_->Log();
    }
    delete server_;
  }

  static Client Connect(const std::string& token) {
    ClientOptions options;
    options.token = token;
    auto client = Client::Connect(server_->address(), options);
    EXPECT_TRUE(client.ok()) << client.status();
    return std::move(*client);
  }

  static uint64_t Accepted(const std::string& robot) {
    auto info = Connect(kAdmin).GetSession(robot);
    EXPECT_TRUE(info.ok()) << info.status();
    return info.ok() ? info->accepted_frames() : 0;
  }

  static ServerProcess* server_;
};
ServerProcess* ServerAuthTest::server_ = nullptr;

TEST_F(ServerAuthTest, MissingOrUnknownTokenIsUnauthenticated) {
  for (const std::string token : {"", "not-a-token", "admin-6d1f0c2"}) {
    const Client c = Connect(token);
    EXPECT_EQ(Code(c.Info()), absl::StatusCode::kUnauthenticated) << token;
    EXPECT_EQ(Code(c.ListSessions()), absl::StatusCode::kUnauthenticated) << token;
    EXPECT_EQ(Code(c.GetSession("r1")), absl::StatusCode::kUnauthenticated) << token;
    EXPECT_EQ(Code(c.CreateSession("r9")), absl::StatusCode::kUnauthenticated) << token;
    EXPECT_EQ(Code(c.CloseSession("r1", false)), absl::StatusCode::kUnauthenticated) << token;
    EXPECT_EQ(Code(c.Session("r1").Query({Vec3f(0, 0, -1)})), absl::StatusCode::kUnauthenticated);
    EXPECT_EQ(Code(c.Session("r1").MeshTiles()), absl::StatusCode::kUnauthenticated);
    EXPECT_EQ(Code(c.Session("r1").Stream({GroundScan(0.2)})), absl::StatusCode::kUnauthenticated);
  }
  const absl::Status missing = Connect("").Info().status();
  EXPECT_THAT(std::string(missing.message()), HasSubstr("needs a token"));
  // Nothing happened: no session r9, r1 still there with only its own scans.
  EXPECT_EQ(Code(Connect(kAdmin).GetSession("r9")), absl::StatusCode::kNotFound);
  EXPECT_EQ(Accepted("r1"), 2u);
}

TEST_F(ServerAuthTest, HealthNeedsNoToken) {
  auto health = Connect("").Health();
  ASSERT_TRUE(health.ok()) << health.status();
  EXPECT_EQ(*health, ServingStatus::kServing);
}

TEST_F(ServerAuthTest, RobotActsOnItsOwnSessionOnly) {
  const Client r1 = Connect(kRobot1);
  EXPECT_TRUE(r1.Info().ok());
  EXPECT_TRUE(r1.GetSession("r1").ok());
  auto query = r1.Session("r1").Query({Vec3f(0, 0, -1), Vec3f(0, 0, 0)});
  ASSERT_TRUE(query.ok()) << query.status();
  EXPECT_EQ(query->sdf.size(), 2u);
  EXPECT_TRUE(r1.Session("r1").MeshTiles().ok());
  EXPECT_TRUE(r1.SaveSession("r1").ok());

  const absl::Status other = r1.GetSession("r2").status();
  EXPECT_EQ(other.code(), absl::StatusCode::kPermissionDenied);
  EXPECT_THAT(std::string(other.message()), HasSubstr("'r1' may not act on robot 'r2'"));
  EXPECT_EQ(Code(r1.CreateSession("r2")), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(r1.CreateSession("r7")), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(r1.SaveSession("r2")), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(r1.Session("r2").Query({Vec3f(0, 0, 0)})), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(r1.Session("r2").MeshTiles()), absl::StatusCode::kPermissionDenied);
  WatchOptions watch;
  watch.duration = std::chrono::milliseconds(2000);
  EXPECT_EQ(r1.Session("r2").Watch([](const DecodedTile&) { return true; }, watch).code(),
            absl::StatusCode::kPermissionDenied);
  // Operators' calls, even on its own session.
  EXPECT_EQ(Code(r1.ListSessions()), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(r1.LoadSession("r1")), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(r1.CloseSession("r1", false).code(), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(Connect(kAdmin).GetSession("r7")), absl::StatusCode::kNotFound);
  EXPECT_TRUE(Connect(kAdmin).GetSession("r1").ok());
}

TEST_F(ServerAuthTest, RobotCreatesAndSavesItsOwnNewSession) {
  const Client r3 = Connect(kRobot3);
  ASSERT_TRUE(r3.CreateSession("r3", "maicity", kSmallMap).ok());
  EXPECT_TRUE(r3.SaveSession("r3").ok());
  EXPECT_EQ(r3.CloseSession("r3", true).code(), absl::StatusCode::kPermissionDenied);
  EXPECT_TRUE(Connect(kAdmin).CloseSession("r3", false).ok());
}

// Every scan of a stream is checked: one for another robot is rejected, the others go in.
TEST_F(ServerAuthTest, ScanForAnotherRobotIsRejectedAndTheStreamGoesOn) {
  const uint64_t r1_before = Accepted("r1"), r2_before = Accepted("r2");
  auto stub = rim::v1::Rim::NewStub(
      grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials()));
  grpc::ClientContext context;
  context.AddMetadata("authorization", std::string("Bearer ") + kRobot1);
  auto stream = stub->StreamScans(&context);
  ASSERT_TRUE(stream->Write(ScanToProto(GroundScan(0.3), "r1", 10)));
  ASSERT_TRUE(stream->Write(ScanToProto(GroundScan(0.3), "r2", 11)));
  ASSERT_TRUE(stream->Write(ScanToProto(GroundScan(0.4), "r1", 12)));
  ASSERT_TRUE(stream->WritesDone());
  std::map<uint64_t, std::vector<rim::v1::ScanAck>> acks;
  rim::v1::ScanAck ack;
  while (stream->Read(&ack)) acks[ack.sequence()].push_back(ack);
  const grpc::Status status = stream->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_EQ(acks[11].size(), 1u);
  EXPECT_EQ(acks[11][0].state(), rim::v1::ScanAck::REJECTED);
  EXPECT_EQ(acks[11][0].code(), int(grpc::StatusCode::PERMISSION_DENIED));
  EXPECT_THAT(acks[11][0].reason(), HasSubstr("may not act on robot 'r2'"));
  for (uint64_t own : {10, 12}) {
    ASSERT_FALSE(acks[own].empty()) << own;
    EXPECT_EQ(acks[own].back().state(), rim::v1::ScanAck::INTEGRATED) << own;
  }
  EXPECT_EQ(Accepted("r1"), r1_before + 2);
  EXPECT_EQ(Accepted("r2"), r2_before);
}

// Every request of a query stream is checked: the stream ends at the first for another robot.
TEST_F(ServerAuthTest, QueryStreamEndsAtAnotherRobotsSession) {
  auto stub = rim::v1::Rim::NewStub(
      grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials()));
  grpc::ClientContext context;
  context.AddMetadata("authorization", std::string("Bearer ") + kRobot1);
  auto stream = stub->StreamQuerySdf(&context);
  rim::v1::QuerySdfRequest request;
  request.set_points_xyz(PackXyz(std::vector<Vec3f>{Vec3f(0, 0, -1)}));
  request.set_robot_id("r1");
  ASSERT_TRUE(stream->Write(request));
  rim::v1::QuerySdfResponse response;
  ASSERT_TRUE(stream->Read(&response));
  EXPECT_EQ(response.sdf().size(), 4u);
  request.set_robot_id("r2");
  stream->Write(request);
  EXPECT_FALSE(stream->Read(&response));
  const grpc::Status status = stream->Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_THAT(status.error_message(), HasSubstr("may not act on robot 'r2'"));
}

TEST_F(ServerAuthTest, ViewerReadsButDoesNotWrite) {
  const Client viewer = Connect(kViewer);
  auto sessions = viewer.ListSessions();
  ASSERT_TRUE(sessions.ok()) << sessions.status();
  EXPECT_GE(sessions->size(), 2u);
  EXPECT_TRUE(viewer.Info().ok());
  EXPECT_TRUE(viewer.GetSession("r1").ok());
  EXPECT_TRUE(viewer.Session("r2").Query({Vec3f(0, 0, 0)}).ok());
  EXPECT_TRUE(viewer.Session("r1").MeshTiles().ok());

  const uint64_t before = Accepted("r1");
  const absl::Status stream = viewer.Session("r1").Stream({GroundScan(0.5)}).status();
  EXPECT_EQ(stream.code(), absl::StatusCode::kPermissionDenied) << stream;
  EXPECT_THAT(std::string(stream.message()), HasSubstr("a viewer token may not call StreamScans"));
  EXPECT_EQ(Code(viewer.CreateSession("r8")), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(viewer.SaveSession("r1")), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Code(viewer.LoadSession("r1")), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(viewer.CloseSession("r1", false).code(), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(Accepted("r1"), before);
  EXPECT_EQ(Code(Connect(kAdmin).GetSession("r8")), absl::StatusCode::kNotFound);
}

TEST_F(ServerAuthTest, AdminClosesAndLoadsAnySession) {
  const Client admin = Connect(kAdmin);
  EXPECT_TRUE(admin.ListSessions().ok());
  ASSERT_TRUE(admin.CloseSession("r2", /*save=*/true).ok());
  EXPECT_EQ(Code(admin.GetSession("r2")), absl::StatusCode::kNotFound);
  auto loaded = admin.LoadSession("r2");
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->robot_id(), "r2");
  EXPECT_TRUE(admin.Session("r1").Query({Vec3f(0, 0, 0)}).ok());
}

TEST_F(ServerAuthTest, HashTokenPrintsTheDigestForTheTokensFile) {
  const auto direct = testing_support::RunProcess({RIM_SERVER_BIN, "--hash-token", "abc"});
  EXPECT_EQ(direct.exit_code, 0) << direct.err;
  EXPECT_EQ(direct.out, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad\n");
  const auto piped = testing_support::RunProcess({RIM_SERVER_BIN, "--hash-token", "-"}, "abc\n");
  EXPECT_EQ(piped.out, direct.out);
}

// --device names a GPU; where the build or the machine has none, the server refuses to start
// (exit 2) and says why, before it opens any port.
TEST_F(ServerAuthTest, DeviceWithoutAGpuIsRefusedAtStart) {
  if (gpu::BuiltWithCuda() && gpu::OpenDevice(0).ok()) GTEST_SKIP() << "a CUDA device is here";
  const std::string dir = ::testing::TempDir() + "/device_refused";
  const auto r = testing_support::RunProcess(
      {RIM_SERVER_BIN, "--data-dir", dir, "--listen", "127.0.0.1:0", "--device", "cuda"});
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_THAT(r.err, HasSubstr("--device cuda"));
  if (!gpu::BuiltWithCuda()) EXPECT_THAT(r.err, HasSubstr("-DRIM_CUDA=ON"));
  const auto bad = testing_support::RunProcess(
      {RIM_SERVER_BIN, "--data-dir", dir, "--listen", "127.0.0.1:0", "--device", "gpu0"});
  EXPECT_EQ(bad.exit_code, 2) << bad.err;
  EXPECT_THAT(bad.err, HasSubstr("--device: 'gpu0' is not cpu, cuda or cuda:N"));
}

TEST_F(ServerAuthTest, RimctlSendsItsToken) {
  const auto with = testing_support::RunProcess(
      {RIMCTL_BIN, "--server", server_->address(), "--token", kViewer, "session", "list"});
  EXPECT_EQ(with.exit_code, 0) << with.err;
  EXPECT_THAT(with.out, HasSubstr("r1"));
  const auto without =
      testing_support::RunProcess({RIMCTL_BIN, "--server", server_->address(), "session", "list"});
  EXPECT_EQ(without.exit_code, 1);
  EXPECT_THAT(without.err, HasSubstr("needs a token"));
}

}  // namespace
}  // namespace rim
