// rim_server's access control pieces without a server (docs/security.md): token hashing, the
// tokens-file parser, authentication of the authorization header, the role table, robot
// ownership, the loopback rule and the security flags of the server config.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "gmock/gmock.h"
#include "server/auth/auth.h"
#include "server/auth/security.h"
#include "server/config/server_config.h"

namespace rim::server {
namespace {

using ::testing::HasSubstr;

// FIPS 180-2 test vectors.
TEST(AuthTest, HashTokenIsLowerHexSha256) {
  EXPECT_EQ(HashToken("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(HashToken(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
}

TEST(AuthTest, ParsesRolesSubjectsAndDigestsSkippingComments) {
  const std::string text =
      "# operators\n"
      "admin ops " +
      HashToken("a") +
      "\n"
      "\n"
      "  viewer dashboard\t" +
      HashToken("v") +
      "  # wall screen\n"
      "robot robot_1 " +
      absl::AsciiStrToUpper(HashToken("r")) + "\r\n";
  auto tokens = ParseTokens(text, "tokens.txt");
  ASSERT_TRUE(tokens.ok()) << tokens.status();
  ASSERT_EQ(tokens->size(), 3u);
  EXPECT_EQ((*tokens)[0].role, Role::kAdmin);
  EXPECT_EQ((*tokens)[0].subject, "ops");
  EXPECT_EQ((*tokens)[1].role, Role::kViewer);
  EXPECT_EQ((*tokens)[1].subject, "dashboard");
  EXPECT_EQ((*tokens)[2].role, Role::kRobot);
  EXPECT_EQ((*tokens)[2].subject, "robot_1");
  // Upper-case hex reads as the same digest: the robot's token authenticates.
  Authorizer auth(std::move(*tokens));
  const std::string header = "Bearer r";
  auto principal = auth.Authenticate(&header);
  ASSERT_TRUE(principal.ok()) << principal.status();
  EXPECT_EQ(principal->role, Role::kRobot);
  EXPECT_EQ(principal->subject, "robot_1");
}

TEST(AuthTest, RejectsBadLinesNamingFileAndLine) {
  const std::string digest = HashToken("x");
  struct Case {
    std::string text;
    std::string message;
  };
  const std::vector<Case> cases = {
      {"admin ops\n", "tokens.txt:1: expected 'ROLE SUBJECT SHA256HEX', got 2 fields"},
      {"\nadmin ops " + digest + " extra\n", "tokens.txt:2: expected"},
      {"root ops " + digest, "tokens.txt:1: unknown role 'root'"},
      {"robot bad/id " + digest, "tokens.txt:1: robot_id 'bad/id'"},
      {"viewer v " + digest.substr(1), "tokens.txt:1: the digest must be 64 hex digits"},
      {"viewer v " + digest.substr(1) + "g", "the digest must be 64 hex digits"},
      {"viewer v " + digest + "\nadmin a " + digest,
       "tokens.txt:2: this token's digest is already"},
      {"# nothing yet\n\n", "tokens.txt: holds no tokens"},
  };
  for (const Case& c : cases) {
    auto tokens = ParseTokens(c.text, "tokens.txt");
    ASSERT_FALSE(tokens.ok()) << c.text;
    EXPECT_EQ(tokens.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_THAT(std::string(tokens.status().message()), HasSubstr(c.message)) << c.text;
  }
  EXPECT_EQ(ReadTokensFile("/nonexistent/tokens").status().code(), absl::StatusCode::kNotFound);
}

TEST(AuthTest, AuthenticatesOnlyAKnownBearerToken) {
  auto tokens =
      ParseTokens("admin ops " + HashToken("s3cret") + "\nviewer v " + HashToken("look"), "t");
  ASSERT_TRUE(tokens.ok());
  Authorizer auth(std::move(*tokens));
  EXPECT_TRUE(auth.enabled());
  auto check = [&](const std::string* header) { return auth.Authenticate(header).status().code(); };
  EXPECT_EQ(check(nullptr), absl::StatusCode::kUnauthenticated);
  const std::vector<std::string> refused = {
      "", "Bearer ", "Basic s3cret", "s3cret", "Bearer s3cret ", "Bearer S3CRET", "Bearer s3cre"};
  for (const std::string& h : refused)
    EXPECT_EQ(check(&h), absl::StatusCode::kUnauthenticated) << "'" << h << "'";
  const std::string ok = "Bearer s3cret", lower = "bearer look";
  EXPECT_EQ(auth.Authenticate(&ok)->role, Role::kAdmin);
  EXPECT_EQ(auth.Authenticate(&lower)->role, Role::kViewer);
  EXPECT_EQ(auth.CountRole(Role::kAdmin), 1u);
  EXPECT_EQ(auth.CountRole(Role::kRobot), 0u);

  // Without a tokens file everyone is an admin.
  Authorizer open;
  EXPECT_FALSE(open.enabled());
  auto anyone = open.Authenticate(nullptr);
  ASSERT_TRUE(anyone.ok());
  EXPECT_EQ(anyone->role, Role::kAdmin);
}

TEST(AuthTest, RoleTable) {
  const std::vector<Rpc> all = {Rpc::kCreateSession, Rpc::kGetSession,     Rpc::kListSessions,
                                Rpc::kCloseSession,  Rpc::kSaveSession,    Rpc::kLoadSession,
                                Rpc::kStreamScans,   Rpc::kQuerySdf,       Rpc::kStreamQuerySdf,
                                Rpc::kGetMeshTiles,  Rpc::kWatchMeshTiles, Rpc::kGetServerInfo};
  const std::vector<Rpc> robot = {Rpc::kCreateSession,  Rpc::kGetSession,     Rpc::kStreamScans,
                                  Rpc::kQuerySdf,       Rpc::kStreamQuerySdf, Rpc::kGetMeshTiles,
                                  Rpc::kWatchMeshTiles, Rpc::kSaveSession,    Rpc::kGetServerInfo};
  const std::vector<Rpc> viewer = {Rpc::kQuerySdf,       Rpc::kStreamQuerySdf, Rpc::kGetMeshTiles,
                                   Rpc::kWatchMeshTiles, Rpc::kGetSession,     Rpc::kListSessions,
                                   Rpc::kGetServerInfo};
  auto in = [](const std::vector<Rpc>& list, Rpc rpc) {
    return std::find(list.begin(), list.end(), rpc) != list.end();
  };
  for (Rpc rpc : all) {
    EXPECT_TRUE(RoleAllows(Role::kAdmin, rpc)) << RpcName(rpc);
    EXPECT_EQ(RoleAllows(Role::kRobot, rpc), in(robot, rpc)) << RpcName(rpc);
    EXPECT_EQ(RoleAllows(Role::kViewer, rpc), in(viewer, rpc)) << RpcName(rpc);
  }
  EXPECT_FALSE(RoleAllows(Role::kRobot, Rpc::kLoadSession));
  EXPECT_FALSE(RoleAllows(Role::kRobot, Rpc::kCloseSession));
  EXPECT_FALSE(RoleAllows(Role::kRobot, Rpc::kListSessions));
  EXPECT_FALSE(RoleAllows(Role::kViewer, Rpc::kStreamScans));
}

TEST(AuthTest, RobotsActOnlyOnTheirOwnId) {
  const Principal robot{Role::kRobot, "robot_1"};
  EXPECT_TRUE(CheckRobot(robot, "robot_1").ok());
  const absl::Status other = CheckRobot(robot, "robot_2");
  EXPECT_EQ(other.code(), absl::StatusCode::kPermissionDenied);
  EXPECT_THAT(std::string(other.message()), HasSubstr("'robot_1' may not act on robot 'robot_2'"));
  EXPECT_EQ(CheckRobot(robot, "").code(), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(CheckRobot(robot, "robot_10").code(), absl::StatusCode::kPermissionDenied);
  EXPECT_TRUE(CheckRobot({Role::kViewer, "v"}, "robot_2").ok());
  EXPECT_TRUE(CheckRobot({Role::kAdmin, "ops"}, "robot_2").ok());
}

TEST(AuthTest, LoopbackAddresses) {
  for (const char* a :
       {"127.0.0.1:50051", "127.1.2.3:0", "localhost:50051", "LOCALHOST:1", "[::1]:50051",
        "[::ffff:127.0.0.1]:5", "unix:/tmp/rim.sock", "ipv4:127.0.0.1:9"})
    EXPECT_TRUE(IsLoopbackListen(a)) << a;
  for (const char* a :
       {"0.0.0.0:50051", "[::]:50051", ":50051", "10.0.0.5:50051", "128.0.0.1:1",
        "example.org:50051", "localhost.example.org:1", "[::ffff:10.0.0.1]:5", "[::1:50051"})
    EXPECT_FALSE(IsLoopbackListen(a)) << a;
}

absl::StatusOr<ServerConfig> Parse(std::vector<std::string> args) {
  args.insert(args.begin(), "rim_server");
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  return ParseServerConfig(int(argv.size()), argv.data());
}

TEST(ServerConfigDeviceTest, DeviceIsCpuCudaOrCudaN) {
  auto none = Parse({"--data-dir", "/d"});
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_EQ(none->device, "cpu");
  for (const char* good : {"cpu", "cuda", "cuda:1"}) {
    auto c = Parse({"--data-dir", "/d", "--device", good});
    ASSERT_TRUE(c.ok()) << good << ": " << c.status();
    EXPECT_EQ(c->device, good);
  }
  for (const char* bad : {"gpu", "cuda:", "cuda:-1", "CUDA"}) {
    auto c = Parse({"--data-dir", "/d", "--device", bad});
    ASSERT_FALSE(c.ok()) << bad;
    EXPECT_THAT(std::string(c.status().message()), HasSubstr("--device")) << bad;
  }
}

TEST(AuthTest, ExposureNeedsTokensOrInsecure) {
  auto open = Parse({"--data-dir", "/d", "--listen", "0.0.0.0:50051"});
  ASSERT_TRUE(open.ok()) << open.status();
  const absl::Status refused = CheckExposure(*open);
  EXPECT_EQ(refused.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(refused.message()),
              HasSubstr("refusing to listen on 0.0.0.0:50051 without --tokens"));
  // --insecure takes no value: the next word is a flag again.
  auto insecure = Parse({"--listen", "0.0.0.0:50051", "--insecure", "--data-dir", "/d"});
  ASSERT_TRUE(insecure.ok()) << insecure.status();
  EXPECT_TRUE(insecure->insecure);
  EXPECT_TRUE(CheckExposure(*insecure).ok());
  auto tokens = Parse({"--data-dir", "/d", "--listen", "0.0.0.0:1", "--tokens", "/t"});
  ASSERT_TRUE(tokens.ok());
  EXPECT_TRUE(CheckExposure(*tokens).ok());
  auto loopback = Parse({"--data-dir", "/d"});
  ASSERT_TRUE(loopback.ok());
  EXPECT_FALSE(loopback->insecure);
  EXPECT_TRUE(CheckExposure(*loopback).ok());
  EXPECT_FALSE(Parse({"--data-dir", "/d", "--insecure=maybe"}).ok());
  // The dashboard's API reads every map: --http follows the same rule.
  auto http = Parse({"--data-dir", "/d", "--http", "0.0.0.0:8080"});
  ASSERT_TRUE(http.ok()) << http.status();
  EXPECT_THAT(std::string(CheckExposure(*http).message()),
              HasSubstr("refusing to listen on 0.0.0.0:8080 without --tokens"));
  auto http_loopback = Parse({"--data-dir", "/d", "--http", "127.0.0.1:0"});
  ASSERT_TRUE(http_loopback.ok());
  EXPECT_TRUE(CheckExposure(*http_loopback).ok());
  auto http_tokens = Parse({"--data-dir", "/d", "--http", "0.0.0.0:8080", "--tokens", "/t"});
  ASSERT_TRUE(http_tokens.ok());
  EXPECT_TRUE(CheckExposure(*http_tokens).ok());
}

TEST(AuthTest, ReplicaFlags) {
  auto shared = Parse({"--data-dir", "/d", "--shared-sessions", "--replica-id", "rim-0"});
  ASSERT_TRUE(shared.ok()) << shared.status();
  EXPECT_TRUE(shared->shared_sessions);
  EXPECT_EQ(shared->replica_id, "rim-0");
  EXPECT_THAT(shared->ToString(), HasSubstr("shared_sessions = true\n"));
  // The id goes into lease files: no spaces, newlines or empty names.
  for (const char* bad : {"", "a b", "rim\nowner=x", "r\tx"})
    EXPECT_THAT(std::string(Parse({"--data-dir", "/d", "--replica-id", bad}).status().message()),
                HasSubstr("--replica-id: expected"))
        << bad;
  EXPECT_FALSE(Parse({"--data-dir", "/d", "--shared-sessions=maybe"}).ok());
}

TEST(AuthTest, TlsFlagsGoTogether) {
  auto both =
      Parse({"--data-dir", "/d", "--tls-cert", "c", "--tls-key", "k", "--tls-client-ca", "ca"});
  ASSERT_TRUE(both.ok()) << both.status();
  EXPECT_EQ(both->tls_client_ca, "ca");
  EXPECT_THAT(both->ToString(), HasSubstr("tls_client_ca = ca\n"));
  EXPECT_THAT(std::string(Parse({"--data-dir", "/d", "--tls-cert", "c"}).status().message()),
              HasSubstr("--tls-cert and --tls-key must be given together"));
  EXPECT_THAT(std::string(Parse({"--data-dir", "/d", "--tls-client-ca", "ca"}).status().message()),
              HasSubstr("--tls-client-ca needs --tls-cert"));
  ServerConfig missing = *both;
  missing.tls_cert = "/nonexistent/cert.pem";
  EXPECT_EQ(MakeServerCredentials(missing).status().code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace rim::server
