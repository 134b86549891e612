// rim_server's transport security, end to end (docs/security.md), with throwaway certificates
// that openssl makes at test time: TLS with the right CA connects, plaintext and untrusted CAs do
// not; with --tls-client-ca a client needs a certificate from that CA (C++ client and rimctl);
// tokens work over TLS; and a non-loopback --listen without --tokens is refused (exit 2) unless
// --insecure is given.
#include <gtest/gtest.h>

#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "client/client.h"
#include "gmock/gmock.h"
#include "server/auth/auth.h"
#include "support/server_process.h"
#include "support/subprocess.h"
#include "support/temp_dir.h"

namespace rim {
namespace {

using ::testing::HasSubstr;
using testing_support::RunProcess;
using testing_support::ServerProcess;

// A CA, a server certificate for localhost and 127.0.0.1, a client certificate from the CA, and a
// second ("rogue") CA with its own client certificate. P-256 keys: quick to make.
constexpr char kMakeCerts[] = R"(set -e
key='-newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes'
ca() {
  openssl req -x509 $key -keyout $1.key -out $1.crt -days 2 -subj /CN=$1 \
    -addext basicConstraints=critical,CA:TRUE -addext keyUsage=critical,keyCertSign,cRLSign
}
leaf() {
  openssl req -new $key -keyout $1.key -out $1.csr -subj /CN=$3
  openssl x509 -req -in $1.csr -CA $2.crt -CAkey $2.key -CAcreateserial -days 2 \
    -out $1.crt -extfile $4.ext
}
printf 'subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n' > server.ext
printf 'extendedKeyUsage=clientAuth\n' > client.ext
ca ca
ca rogue
leaf server ca localhost server
leaf client ca robot_1 client
leaf rogue_client rogue robot_1 client
)";

class ServerTlsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new std::string(testing_support::MakeTempDir("rim_tls"));
    const auto made = RunProcess({"/bin/sh", "-c", "cd '" + *dir_ + "' && " + kMakeCerts});
    ASSERT_EQ(made.exit_code, 0) << made.err;
  }
  static void TearDownTestSuite() { delete dir_; }

  static std::string Path(const std::string& name) { return *dir_ + "/" + name; }

  // rim_server with `args`, on 127.0.0.1 unless args say otherwise. Returns once it listens:
  // the harness's own health check speaks plaintext.
  static std::unique_ptr<ServerProcess> Start(std::vector<std::string> args) {
    testing_support::ServerProcessOptions options;
    options.args = std::move(args);
    options.args.insert(options.args.end(), {"--warmup-frames", "0"});
    options.wait_until_serving = false;
    auto server = ServerProcess::Start(options);
    EXPECT_TRUE(server.ok()) << server.status();
    return server.ok() ? std::move(*server) : nullptr;
  }
  static std::vector<std::string> TlsArgs() {
    return {"--tls-cert", Path("server.crt"), "--tls-key", Path("server.key")};
  }

  // The client's outcome: the error of Connect, else that of Info.
  static absl::Status InfoOver(const std::string& address, ClientOptions options) {
    options.connect_timeout = std::chrono::milliseconds(3000);
    auto client = Client::Connect(address, options);
    if (!client.ok()) return client.status();
    return client->Info().status();
  }
  static ClientOptions Tls(const std::string& ca, const std::string& cert = "") {
    ClientOptions o;
    o.tls_ca_file = ca.empty() ? "" : Path(ca + ".crt");
    if (!cert.empty()) {
      o.tls_cert_file = Path(cert + ".crt");
      o.tls_key_file = Path(cert + ".key");
    }
    return o;
  }

  static std::string* dir_;
};
std::string* ServerTlsTest::dir_ = nullptr;

TEST_F(ServerTlsTest, TlsConnectsWithTheCaAndNotOtherwise) {
  auto server = Start(TlsArgs());
  ASSERT_NE(server, nullptr);
  const std::string address = server->address();
  EXPECT_TRUE(InfoOver(address, Tls("ca")).ok()) << InfoOver(address, Tls("ca"));
  // Plaintext against TLS: the handshake never completes.
  const absl::Status plain = InfoOver(address, ClientOptions());
  EXPECT_EQ(plain.code(), absl::StatusCode::kUnavailable) << plain;
  EXPECT_THAT(std::string(plain.message()), HasSubstr("does it want TLS?"));
  // A CA that did not sign the server's certificate, or only the system's roots: not trusted.
  EXPECT_EQ(InfoOver(address, Tls("rogue")).code(), absl::StatusCode::kUnavailable);
  EXPECT_EQ(InfoOver(address, Tls("", "client")).code(), absl::StatusCode::kUnavailable);
  // Health works over TLS without a token.
  ClientOptions options = Tls("ca");
  auto client = Client::Connect(address, options);
  ASSERT_TRUE(client.ok()) << client.status();
  EXPECT_EQ(client->Health().value_or(ServingStatus::kUnknown), ServingStatus::kServing);
  EXPECT_EQ(server->Stop().value_or(-1), 0);
}

TEST_F(ServerTlsTest, MutualTlsNeedsAClientCertificateFromTheCa) {
  auto args = TlsArgs();
  args.insert(args.end(), {"--tls-client-ca", Path("ca.crt")});
  auto server = Start(args);
  ASSERT_NE(server, nullptr);
  const std::string address = server->address();
  EXPECT_FALSE(InfoOver(address, Tls("ca")).ok()) << "no client certificate";
  EXPECT_FALSE(InfoOver(address, Tls("ca", "rogue_client")).ok()) << "certificate of another CA";
  const absl::Status ok = InfoOver(address, Tls("ca", "client"));
  EXPECT_TRUE(ok.ok()) << ok;

  // rimctl's flags.
  const std::vector<std::string> rimctl = {
      RIMCTL_BIN, "--server", address, "--connect-timeout", "3", "--tls-ca", Path("ca.crt")};
  auto with_cert = rimctl;
  with_cert.insert(with_cert.end(),
                   {"--tls-cert", Path("client.crt"), "--tls-key", Path("client.key"), "info"});
  const auto info = RunProcess(with_cert);
  EXPECT_EQ(info.exit_code, 0) << info.err;
  EXPECT_THAT(info.out, HasSubstr("version: "));
  auto without_cert = rimctl;
  without_cert.push_back("info");
  EXPECT_NE(RunProcess(without_cert).exit_code, 0);
  auto half = rimctl;
  half.insert(half.end(), {"--tls-cert", Path("client.crt"), "info"});
  const auto unpaired = RunProcess(half);
  EXPECT_NE(unpaired.exit_code, 0);
  EXPECT_THAT(unpaired.err, HasSubstr("--tls-cert and --tls-key must be given together"));
  EXPECT_EQ(server->Stop().value_or(-1), 0);
}

TEST_F(ServerTlsTest, NonLoopbackWithoutTokensIsRefusedUnlessInsecure) {
  const std::string data = testing_support::MakeTempDir("rim_tls_data");
  for (const std::string listen : {"0.0.0.0:0", "[::]:0"}) {
    const auto refused = RunProcess({RIM_SERVER_BIN, "--listen", listen, "--data-dir", data}, "",
                                    std::chrono::seconds(60));
    EXPECT_EQ(refused.exit_code, 2) << listen << "\n" << refused.out << refused.err;
    EXPECT_THAT(refused.err, HasSubstr("refusing to listen on " + listen + " without --tokens"));
    EXPECT_THAT(refused.out, ::testing::Not(HasSubstr("listening on")));
  }
  auto server = Start({"--listen", "0.0.0.0:0", "--insecure"});
  ASSERT_NE(server, nullptr);
  ASSERT_THAT(server->address(), HasSubstr("0.0.0.0:"));
  const std::string port = server->address().substr(server->address().rfind(':'));
  EXPECT_TRUE(InfoOver("127.0.0.1" + port, ClientOptions()).ok());
  EXPECT_EQ(server->Stop().value_or(-1), 0);
}

TEST_F(ServerTlsTest, TokensOverTlsOnAnyAddress) {
  const std::string tokens = Path("tokens.txt");
  const auto hashed = RunProcess({RIM_SERVER_BIN, "--hash-token", "wall-screen-5"});
  ASSERT_EQ(hashed.exit_code, 0) << hashed.err;
  ASSERT_EQ(hashed.out, server::HashToken("wall-screen-5") + "\n");
  std::ofstream(tokens) << "viewer wall " << hashed.out;
  auto args = TlsArgs();
  args.insert(args.end(), {"--listen", "0.0.0.0:0", "--tokens", tokens});
  auto server = Start(args);
  ASSERT_NE(server, nullptr);
  const std::string address = "127.0.0.1" + server->address().substr(server->address().rfind(':'));
  ClientOptions viewer = Tls("ca");
  EXPECT_EQ(InfoOver(address, viewer).code(), absl::StatusCode::kUnauthenticated);
  viewer.token = "wall-screen-5";
  EXPECT_TRUE(InfoOver(address, viewer).ok());
  auto client = Client::Connect(address, viewer);
  ASSERT_TRUE(client.ok());
  EXPECT_EQ(client->CreateSession("robot_1").status().code(), absl::StatusCode::kPermissionDenied);
  EXPECT_EQ(server->Stop().value_or(-1), 0);
}

TEST_F(ServerTlsTest, BadSecurityFilesAreAStartupError) {
  const std::string data = testing_support::MakeTempDir("rim_tls_bad");
  const auto missing = RunProcess({RIM_SERVER_BIN, "--data-dir", data, "--tls-cert",
                                   Path("nonexistent.crt"), "--tls-key", Path("server.key")});
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_THAT(missing.err, HasSubstr("--tls-cert: cannot read"));
  const auto not_pem = RunProcess({RIM_SERVER_BIN, "--data-dir", data, "--tls-cert",
                                   Path("server.ext"), "--tls-key", Path("server.key")});
  EXPECT_EQ(not_pem.exit_code, 2);
  EXPECT_THAT(not_pem.err, HasSubstr("holds no PEM block"));
  const auto unpaired = RunProcess({RIM_SERVER_BIN, "--data-dir", data, "--tls-key", "k"});
  EXPECT_EQ(unpaired.exit_code, 2);
  EXPECT_THAT(unpaired.err, HasSubstr("--tls-cert and --tls-key must be given together"));
  const auto no_tokens = RunProcess({RIM_SERVER_BIN, "--data-dir", data, "--tokens", Path("none")});
  EXPECT_EQ(no_tokens.exit_code, 2);
  EXPECT_THAT(no_tokens.err, HasSubstr("--tokens: cannot read"));
  const auto bad_tokens =
      RunProcess({RIM_SERVER_BIN, "--data-dir", data, "--tokens", Path("client.ext")});
  EXPECT_EQ(bad_tokens.exit_code, 2);
  EXPECT_THAT(bad_tokens.err, HasSubstr("client.ext:1: expected 'ROLE SUBJECT SHA256HEX'"));
}

}  // namespace
}  // namespace rim
