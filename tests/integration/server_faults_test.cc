// Faults, end to end on the real rim_server: a robot that disconnects mid-stream, queries past
// their deadline, kill -9 while a checkpoint is being written, a full disk, a corrupt checkpoint,
// and a restart with many sessions on disk. The server keeps working, loses no accepted scan and
// says clearly what went wrong.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "client/client.h"
#include "client/wire.h"
#include "gmock/gmock.h"
#include "rim/v1/rim.grpc.pb.h"
#include "support/server_process.h"
#include "support/small_session.h"
#include "support/temp_dir.h"

namespace rim {
namespace {

using ::testing::AnyOf;
using ::testing::HasSubstr;
using testing_support::GroundScan;
using testing_support::GroundScans;
using testing_support::ServerProcess;
using testing_support::ServerProcessOptions;
using namespace std::chrono_literals;
namespace fs = std::filesystem;

const std::vector<std::pair<std::string, std::string>> kSmallMap =
    testing_support::SmallMapOverrides();

// Waits until the session has integrated every accepted scan; returns its info.
rim::v1::SessionInfo WaitSettled(const Client& client, const std::string& robot) {
  rim::v1::SessionInfo info;
  for (int i = 0; i < 600; ++i) {
    auto got = client.GetSession(robot);
    EXPECT_TRUE(got.ok()) << got.status();
    if (!got.ok()) break;
    info = *got;
    if (info.queue_depth() == 0 && info.integrated_frames() == info.accepted_frames()) break;
    std::this_thread::sleep_for(50ms);
  }
  return info;
}

TEST(ServerFaultsTest, RobotDisconnectingMidStreamKeepsWhatWasAccepted) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("flaky", "maicity", kSmallMap).ok());

  auto stub = rim::v1::Rim::NewStub(
      grpc::CreateChannel((*server)->address(), grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  auto stream = stub->StreamScans(&ctx);
  int accepted = 0;
  for (int i = 0; i < 6; ++i)
    ASSERT_TRUE(stream->Write(ScanToProto(GroundScan(0.05 * i), "flaky", uint64_t(i))));
  rim::v1::ScanAck ack;
  while (accepted < 6 && stream->Read(&ack))
    if (ack.state() == rim::v1::ScanAck::ACCEPTED) ++accepted;
  ASSERT_EQ(accepted, 6);
  ctx.TryCancel();  // the robot drops off the network
  EXPECT_FALSE(stream->Finish().ok());

  // Everything accepted is trained, and the session takes a new stream.
  EXPECT_EQ(WaitSettled(*client, "flaky").integrated_frames(), 6u);
  auto more = client->Session("flaky").Stream(GroundScans(2));
  ASSERT_TRUE(more.ok()) << more.status();
  EXPECT_EQ(more->integrated, 2u);
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

// A server that stops answering without closing anything (here frozen with SIGSTOP; behind a
// proxy, a replica that died under it) leaves the stream open and silent. The client's stall
// timeout cancels it and opens new streams, each watched from its start, until the server answers
// again; then every scan is integrated exactly once.
TEST(ServerFaultsTest, SilentServerStreamIsCancelledAndRetried) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("frozen", "maicity", kSmallMap).ok());

  const std::vector<PosedScan> scans = GroundScans(8);
  StreamOptions options;
  options.max_retries = 20;
  options.retry_backoff = 100ms;
  options.stall_timeout = 1500ms;
  std::vector<std::string> reasons;
  std::mutex reasons_mu;
  options.on_retry = [&](int retry, const absl::Status& why) {
    std::lock_guard<std::mutex> lock(reasons_mu);
    EXPECT_EQ(retry, int(reasons.size()) + 1);
    reasons.push_back(why.ToString());
  };
  // A cancelled stream ends: the watchdog never reports one stuck here.
  std::atomic<bool> stuck{false};
  options.on_stuck = [&] { stuck = true; };
  size_t next = 0;
  const pid_t pid = (*server)->pid();
  std::thread thaw;
  auto summary = client->Session("frozen").Stream(
      [&](rim::v1::Scan* scan) -> absl::StatusOr<bool> {
        if (next == scans.size()) return false;
        if (next == 3) {
          // The first three are integrated; then the server freezes for 5 s, longer than three
          // stall timeouts, while the next scans go out.
          for (int i = 0; i < 400; ++i) {
            auto info = client->GetSession("frozen");
            if (info.ok() && info->integrated_frames() >= 3) break;
            std::this_thread::sleep_for(25ms);
          }
          EXPECT_EQ(kill(pid, SIGSTOP), 0);
          thaw = std::thread([pid] {
            std::this_thread::sleep_for(5s);
            kill(pid, SIGCONT);
          });
        }
        *scan = ScanToProto(scans[next], "frozen", 0);
        ++next;
        return true;
      },
      options);
  if (thaw.joinable()) thaw.join();
  ASSERT_TRUE(summary.ok()) << summary.status();
  EXPECT_EQ(summary->integrated, scans.size());
  EXPECT_EQ(summary->rejected, 0u);
  EXPECT_GE(summary->retries, 2);  // at least two silent streams were given up
  ASSERT_FALSE(reasons.empty());
  EXPECT_THAT(reasons[0], HasSubstr("no ack for 1.5 s"));
  EXPECT_FALSE(stuck);
  EXPECT_EQ(WaitSettled(*client, "frozen").integrated_frames(), scans.size());
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

TEST(ServerFaultsTest, QueriesPastTheirDeadlineFailCleanly) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("late", "maicity", kSmallMap).ok());
  ASSERT_TRUE(client->Session("late").Stream(GroundScans(2)).ok());
  auto stub = rim::v1::Rim::NewStub(
      grpc::CreateChannel((*server)->address(), grpc::InsecureChannelCredentials()));
  rim::v1::QuerySdfRequest request;
  request.set_robot_id("late");
  request.set_points_xyz(std::string(size_t(100000) * 12, '\0'));
  for (int i = 0; i < 5; ++i) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + 1ms);
    rim::v1::QuerySdfResponse response;
    const grpc::Status s = stub->QuerySdf(&ctx, request, &response);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << s.error_message();
  }
  // The server is unharmed: a query with time to spare is answered.
  auto q = client->Session("late").Query({Vec3f(0, 0, -1)});
  ASSERT_TRUE(q.ok()) << q.status();
  EXPECT_LT(std::abs(q->sdf[0]), 0.1f);
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

TEST(ServerFaultsTest, KillNineWhileSavingLosesNothing) {
  // Kill the server at different moments of a SaveSession: before, during or after the
  // checkpoint write. Whatever was on disk then, the restart loads every accepted scan.
  for (const auto delay : {0ms, 3ms, 10ms, 40ms}) {
    SCOPED_TRACE(testing::Message() << "kill after " << delay.count() << " ms");
    auto server = ServerProcess::Start();
    ASSERT_TRUE(server.ok()) << server.status();
    const std::string data_dir = (*server)->data_dir();
    {
      auto client = Client::Connect((*server)->address());
      ASSERT_TRUE(client.ok());
      ASSERT_TRUE(client->CreateSession("crashy", "maicity", kSmallMap).ok());
      auto streamed = client->Session("crashy").Stream(GroundScans(4));
      ASSERT_TRUE(streamed.ok());
      ASSERT_TRUE(client->SaveSession("crashy").ok());  // an older checkpoint exists
      streamed = client->Session("crashy").Stream(GroundScans(3));
      ASSERT_TRUE(streamed.ok());
      std::thread saver([&] { (void)client->SaveSession("crashy"); });
      std::this_thread::sleep_for(delay);
      (*server)->Kill();
      saver.join();
    }
    auto restarted = ServerProcess::StartOn(data_dir);
    ASSERT_TRUE(restarted.ok()) << restarted.status();
    auto client = Client::Connect((*restarted)->address());
    ASSERT_TRUE(client.ok());
    auto loaded = client->LoadSession("crashy");
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    EXPECT_EQ(loaded->integrated_frames(), 7u);
    EXPECT_EQ((*restarted)->Stop().value_or(-1), 0);
  }
}

TEST(ServerFaultsTest, CorruptCheckpointIsDetectedAndNamed) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string data_dir = (*server)->data_dir();
  {
    auto client = Client::Connect((*server)->address());
    ASSERT_TRUE(client.ok());
    ASSERT_TRUE(client->CreateSession("bitrot", "maicity", kSmallMap).ok());
    ASSERT_TRUE(client->Session("bitrot").Stream(GroundScans(3)).ok());
  }
  ASSERT_EQ((*server)->Stop().value_or(-1), 0);  // saves the session
  // Flip one byte in the middle of the largest checkpoint file.
  fs::path victim;
  uintmax_t largest = 0;
  for (const auto& e : fs::recursive_directory_iterator(data_dir + "/sessions/bitrot")) {
    if (!e.is_regular_file() || e.path().string().find("/wal") != std::string::npos) continue;
    if (e.file_size() > largest) {
      largest = e.file_size();
      victim = e.path();
    }
  }
  ASSERT_FALSE(victim.empty());
  {
    std::fstream f(victim, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(std::streamoff(largest / 2));
    char c = 0;
    f.read(&c, 1);
    c = char(c ^ 0x5a);
    f.seekp(std::streamoff(largest / 2));
    f.write(&c, 1);
  }
  auto restarted = ServerProcess::StartOn(data_dir);
  ASSERT_TRUE(restarted.ok()) << restarted.status();
  auto client = Client::Connect((*restarted)->address());
  ASSERT_TRUE(client.ok());
  auto loaded = client->LoadSession("bitrot");
  ASSERT_FALSE(loaded.ok());
  EXPECT_EQ(loaded.status().code(), absl::StatusCode::kDataLoss) << loaded.status();
  EXPECT_THAT(std::string(loaded.status().message()), HasSubstr(victim.filename().string()));
  // Nothing half-loaded stays open, and the server goes on serving others.
  EXPECT_EQ(client->GetSession("bitrot").status().code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(client->CreateSession("healthy", "maicity", kSmallMap).ok());
  EXPECT_EQ((*restarted)->Stop().value_or(-1), 0);
}

TEST(ServerFaultsTest, FullDiskRefusesScansInsteadOfCorrupting) {
  // The server under a file-size limit (ulimit -f): the write-ahead log hits it after a few
  // scans. Appends then fail, so scans are refused with the reason, and nothing accepted is lost.
  const std::string dir = testing_support::MakeTempDir("rim_full_disk");
  const std::string wrapper = dir + "/limited_server.sh";
  {
    std::ofstream w(wrapper);
    // 400 blocks of 512 bytes: room for about ten 19 kB scans in one log segment.
    w << "#!/bin/bash\nulimit -f 400\nexec \"" << RIM_SERVER_BIN << "\" \"$@\"\n";
  }
  ASSERT_EQ(chmod(wrapper.c_str(), 0755), 0);
  ServerProcessOptions options;
  options.binary = wrapper;
  auto server = ServerProcess::Start(options);
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("full", "maicity", kSmallMap).ok());
  std::vector<rim::v1::ScanAck> rejected;
  StreamOptions stream_options;
  stream_options.on_ack = [&](const rim::v1::ScanAck& ack) {
    if (ack.state() == rim::v1::ScanAck::REJECTED) rejected.push_back(ack);
  };
  auto summary = client->Session("full").Stream(GroundScans(30), stream_options);
  ASSERT_TRUE(summary.ok()) << summary.status();
  EXPECT_GT(summary->integrated, 3u);
  ASSERT_FALSE(rejected.empty()) << "30 scans fit under the file-size limit";
  EXPECT_THAT(rejected[0].reason(), AnyOf(HasSubstr("too large"), HasSubstr("write-ahead log")))
      << rejected[0].reason();
  // What was accepted is in the map, and the server still answers.
  const rim::v1::SessionInfo info = WaitSettled(*client, "full");
  EXPECT_EQ(info.integrated_frames(), summary->integrated);
  auto q = client->Session("full").Query({Vec3f(0, 0, -1)});
  EXPECT_TRUE(q.ok()) << q.status();
  auto health = client->Health();
  ASSERT_TRUE(health.ok());
  EXPECT_EQ(*health, ServingStatus::kServing);
  (*server)->Kill();  // saving would fail on the full disk; the log already holds every scan
}

TEST(ServerFaultsTest, RestartWithManySessionsOnDisk) {
  constexpr int kSessions = 6;
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string data_dir = (*server)->data_dir();
  {
    auto client = Client::Connect((*server)->address());
    ASSERT_TRUE(client.ok());
    for (int s = 0; s < kSessions; ++s) {
      const std::string robot = "fleet_" + std::to_string(s);
      ASSERT_TRUE(client->CreateSession(robot, "maicity", kSmallMap).ok());
      ASSERT_TRUE(client->Session(robot).Stream(GroundScans(1 + s % 3)).ok());
    }
  }
  ASSERT_EQ((*server)->Stop().value_or(-1), 0);
  auto restarted = ServerProcess::StartOn(data_dir);
  ASSERT_TRUE(restarted.ok()) << restarted.status();
  auto client = Client::Connect((*restarted)->address());
  ASSERT_TRUE(client.ok());
  for (int s = 0; s < kSessions; ++s) {
    const std::string robot = "fleet_" + std::to_string(s);
    auto loaded = client->LoadSession(robot);
    ASSERT_TRUE(loaded.ok()) << robot << ": " << loaded.status();
    EXPECT_EQ(loaded->integrated_frames(), uint64_t(1 + s % 3)) << robot;
  }
  EXPECT_EQ(client->ListSessions()->size(), size_t(kSessions));
  EXPECT_EQ((*restarted)->Stop().value_or(-1), 0);
}

}  // namespace
}  // namespace rim
