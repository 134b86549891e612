// Session folders never lead out of the data dir, end to end on the real rim_server: a symbolic
// link planted as a session's folder, inside a saved session, or in place of the sessions/
// folder is refused with FAILED_PRECONDITION naming the link, nothing outside the data dir is
// read or written, and the server goes on serving other sessions. Robot ids that could name
// another path (or are not even valid header values) are INVALID_ARGUMENT before anything
// touches the disk, and the client process survives sending them.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "client/client.h"
#include "gmock/gmock.h"
#include "support/server_process.h"
#include "support/small_session.h"
#include "support/temp_dir.h"

namespace rim {
namespace {

using ::testing::HasSubstr;
using testing_support::GroundScans;
using testing_support::ServerProcess;
namespace fs = std::filesystem;

const std::vector<std::pair<std::string, std::string>> kSmallMap =
    testing_support::SmallMapOverrides();

// Every file below `dir`, recursively (links not followed).
std::vector<std::string> FilesUnder(const std::string& dir) {
  std::vector<std::string> files;
  for (const auto& e : fs::recursive_directory_iterator(dir)) files.push_back(e.path().string());
  return files;
}

void ExpectRefusedLink(const absl::Status& s, const std::string& link) {
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("symbolic link")) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr(link)) << s;
}

TEST(ServerPathsTest, SymlinksInTheDataDirAreRefused) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string data_dir = (*server)->data_dir();
  {
    auto client = Client::Connect((*server)->address());
    ASSERT_TRUE(client.ok());
    ASSERT_TRUE(client->CreateSession("saved", "maicity", kSmallMap).ok());
    ASSERT_TRUE(client->Session("saved").Stream(GroundScans(2)).ok());
  }
  ASSERT_EQ((*server)->Stop().value_or(-1), 0);  // saves the session

  // Somewhere outside the data dir: a copy of the saved session, and an empty folder.
  const std::string outside = testing_support::MakeTempDir("rim_outside");
  fs::copy(data_dir + "/sessions/saved", outside + "/copy", fs::copy_options::recursive);
  fs::create_directories(outside + "/empty");
  const std::vector<std::string> outside_before = FilesUnder(outside);
  // A session folder that is a link to the copy, and one to the empty folder.
  fs::create_directory_symlink(outside + "/copy", data_dir + "/sessions/linked");
  fs::create_directory_symlink(outside + "/empty", data_dir + "/sessions/fresh");
  // Inside the saved session, its checkpoint's state file replaced by a link to the copy's.
  std::string state;
  for (const auto& e : fs::recursive_directory_iterator(data_dir + "/sessions/saved"))
    if (e.path().filename() == "state.rimf") state = e.path().string();
  ASSERT_FALSE(state.empty());
  fs::remove(state);
  std::string copied_state = state;
  copied_state.replace(0, (data_dir + "/sessions/saved").size(), outside + "/copy");
  fs::create_symlink(copied_state, state);

  auto restarted = ServerProcess::StartOn(data_dir);
  ASSERT_TRUE(restarted.ok()) << restarted.status();
  auto client = Client::Connect((*restarted)->address());
  ASSERT_TRUE(client.ok());
  ExpectRefusedLink(client->LoadSession("linked").status(), "sessions/linked");
  ExpectRefusedLink(client->CreateSession("fresh", "maicity", kSmallMap).status(),
                    "sessions/fresh");
  ExpectRefusedLink(client->LoadSession("saved").status(), "state.rimf");
  // None of them was opened, nothing was written outside, and other sessions work.
  for (const char* robot : {"linked", "fresh", "saved"})
    EXPECT_EQ(client->GetSession(robot).status().code(), absl::StatusCode::kNotFound) << robot;
  EXPECT_EQ(FilesUnder(outside), outside_before);
  ASSERT_TRUE(client->CreateSession("healthy", "maicity", kSmallMap).ok());
  EXPECT_TRUE(client->Session("healthy").Stream(GroundScans(1)).ok());
  EXPECT_TRUE(client->SaveSession("healthy").ok());
  EXPECT_EQ((*restarted)->Stop().value_or(-1), 0);
}

TEST(ServerPathsTest, LinkPlantedInAnOpenSessionStopsItsCheckpoint) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  const std::string data_dir = (*server)->data_dir();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  ASSERT_TRUE(client->CreateSession("open", "maicity", kSmallMap).ok());
  ASSERT_TRUE(client->Session("open").Stream(GroundScans(2)).ok());
  ASSERT_TRUE(client->SaveSession("open").ok());
  // The next checkpoint's folder name, planted as a link out of the data dir.
  const std::string outside = testing_support::MakeTempDir("rim_outside");
  std::string next;
  for (int i = 0; i < 100 && next.empty(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "/ckpt-%06d", i);
    if (!fs::exists(data_dir + "/sessions/open" + name)) next = data_dir + "/sessions/open" + name;
  }
  fs::create_directory_symlink(outside, next);
  ExpectRefusedLink(client->SaveSession("open").status(), "ckpt-");
  EXPECT_TRUE(fs::is_empty(outside));
  // The session itself is still open and serving.
  EXPECT_TRUE(client->GetSession("open").ok());
  fs::remove(next);
  EXPECT_TRUE(client->SaveSession("open").ok());
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

TEST(ServerPathsTest, RobotIdsThatNameOtherPathsAreRejected) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok());
  for (const std::string robot :
       {std::string(".."), std::string("."), std::string("a/b"), std::string("../escape"),
        std::string("/abs"), std::string("x\\y"), std::string(65, 'r'), std::string(""),
        std::string("nul\0byte", 8)}) {
    const absl::Status created = client->CreateSession(robot, "maicity", kSmallMap).status();
    EXPECT_EQ(created.code(), absl::StatusCode::kInvalidArgument) << robot << ": " << created;
    EXPECT_THAT(std::string(created.message()), HasSubstr("robot_id")) << created;
    EXPECT_EQ(client->LoadSession(robot).status().code(), absl::StatusCode::kInvalidArgument)
        << robot;
  }
  // Nothing was created in the sessions folder or next to the data dir.
  const std::string data_dir = (*server)->data_dir();
  EXPECT_FALSE(fs::exists(data_dir + "/escape"));
  EXPECT_FALSE(fs::exists(fs::path(data_dir).parent_path() / "escape"));
  EXPECT_TRUE(!fs::exists(data_dir + "/sessions") || fs::is_empty(data_dir + "/sessions"));
  EXPECT_TRUE(client->CreateSession(std::string(64, 'r'), "maicity", kSmallMap).ok());
  // A token that cannot be a header value (here with the newline of a file read carelessly) is
  // refused by the client library instead of aborting the process inside gRPC.
  ClientOptions options;
  options.token = "secret\n";
  const auto bad_token = Client::Connect((*server)->address(), options);
  EXPECT_EQ(bad_token.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(bad_token.status().message()), HasSubstr("token"));
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

}  // namespace
}  // namespace rim
