#include "server/auth/security.h"

#include <arpa/inet.h>
#include <grpcpp/security/server_credentials.h>

#include <fstream>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"

namespace rim::server {

bool IsLoopbackListen(absl::string_view listen) {
  if (absl::StartsWith(listen, "unix:") || absl::StartsWith(listen, "unix-abstract:")) return true;
  if (absl::StartsWith(listen, "ipv4:") || absl::StartsWith(listen, "ipv6:"))
    listen.remove_prefix(5);
  std::string host;
  if (absl::StartsWith(listen, "[")) {
    const size_t close = listen.find(']');
    if (close == absl::string_view::npos) return false;
    host = std::string(listen.substr(1, close - 1));
  } else {
    const size_t colon = listen.rfind(':');
    host = std::string(colon == absl::string_view::npos ? listen : listen.substr(0, colon));
  }
  if (absl::AsciiStrToLower(host) == "localhost") return true;
  in_addr v4{};
  if (inet_pton(AF_INET, host.c_str(), &v4) == 1)
    return (ntohl(v4.s_addr) >> 24) == 127;  // 127.0.0.0/8
  in6_addr v6{};
  if (inet_pton(AF_INET6, host.c_str(), &v6) == 1) {
    if (IN6_IS_ADDR_LOOPBACK(&v6)) return true;
    return IN6_IS_ADDR_V4MAPPED(&v6) && v6.s6_addr[12] == 127;  // ::ffff:127.x.y.z
  }
  return false;
}

absl::Status CheckExposure(const ServerConfig& config) {
  if (!config.tokens_file.empty() || config.insecure) return absl::OkStatus();
  // The dashboard's API reads every map, so it follows the same rule as the gRPC port.
  const std::string& exposed = !IsLoopbackListen(config.listen) ? config.listen
                               : !config.http.empty() && !IsLoopbackListen(config.http)
                                   ? config.http
                                   : std::string();
  if (exposed.empty()) return absl::OkStatus();
  return absl::FailedPreconditionError(absl::StrCat(
      "refusing to listen on ", exposed,
      " without --tokens: anyone who can reach it could read, change and close every map. Give "
      "--tokens FILE (and --tls-cert/--tls-key; see docs/security.md), listen on loopback, or "
      "pass --insecure to serve it open on purpose"));
}

absl::StatusOr<std::string> ReadPemFile(const std::string& flag, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("--", flag, ": cannot read ", path));
  std::stringstream text;
  text << in.rdbuf();
  if (text.str().find("-----BEGIN ") == std::string::npos)
    return absl::InvalidArgumentError(
        absl::StrCat("--", flag, ": ", path, " holds no PEM block (-----BEGIN ...)"));
  return text.str();
}

absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> MakeServerCredentials(
    const ServerConfig& config) {
  if (config.tls_cert.empty()) return grpc::InsecureServerCredentials();
  absl::StatusOr<std::string> cert = ReadPemFile("tls-cert", config.tls_cert);
  if (!cert.ok()) return cert.status();
  absl::StatusOr<std::string> key = ReadPemFile("tls-key", config.tls_key);
  if (!key.ok()) return key.status();
  grpc::SslServerCredentialsOptions options(GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE);
  options.pem_key_cert_pairs.push_back({*key, *cert});
  if (!config.tls_client_ca.empty()) {
    absl::StatusOr<std::string> ca = ReadPemFile("tls-client-ca", config.tls_client_ca);
    if (!ca.ok()) return ca.status();
    options.pem_root_certs = *ca;
    options.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(options);
}

absl::StatusOr<Security> SetUpSecurity(const ServerConfig& config) {
  if (absl::Status exposure = CheckExposure(config); !exposure.ok()) return exposure;
  Security security;
  if (!config.tokens_file.empty()) {
    absl::StatusOr<std::vector<TokenEntry>> tokens = ReadTokensFile(config.tokens_file);
    if (!tokens.ok()) return tokens.status();
    security.authorizer = Authorizer(std::move(*tokens));
    const Authorizer& a = security.authorizer;
    security.log_lines.push_back(absl::StrCat("access control on: ", a.CountRole(Role::kAdmin),
                                              " admin, ", a.CountRole(Role::kViewer), " viewer, ",
                                              a.CountRole(Role::kRobot), " robot token(s)"));
  } else {
    security.log_lines.push_back("access control off (no --tokens): every caller is an admin");
  }
  absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> credentials =
      MakeServerCredentials(config);
  if (!credentials.ok()) return credentials.status();
  security.credentials = std::move(*credentials);
  if (!config.tls_cert.empty()) {
    security.log_lines.push_back(absl::StrCat(
        "transport: TLS", config.tls_client_ca.empty() ? "" : ", client certificates required"));
  } else {
    security.log_lines.push_back("transport: plaintext (no --tls-cert)");
    if (!IsLoopbackListen(config.listen))
      security.log_lines.push_back(
          "warning: tokens and maps cross the network in plaintext; give --tls-cert");
  }
  return security;
}

}  // namespace rim::server
