// How rim_server is exposed on the network (docs/security.md): the rule that a server without
// --tokens listens only on loopback unless told --insecure, the tokens' Authorizer, and TLS server
// credentials from --tls-cert/--tls-key (verifying client certificates with --tls-client-ca).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "server/auth/auth.h"
#include "server/config/server_config.h"

namespace grpc {
class ServerCredentials;
}

namespace rim::server {

// True when `listen` (a --listen address: host:port, [v6]:port or unix:PATH) can only be reached
// from this machine: 127.0.0.0/8, ::1, localhost or a Unix socket. An empty host, 0.0.0.0, [::]
// and any other name or address are not loopback.
bool IsLoopbackListen(absl::string_view listen);

// OK, or FAILED_PRECONDITION explaining why a server without --tokens must not listen on
// `config.listen` or `config.http` (not loopback and no --insecure).
absl::Status CheckExposure(const ServerConfig& config);

// Plaintext credentials without --tls-cert; TLS with the certificate chain and key, requiring and
// verifying client certificates signed by --tls-client-ca when it is given. NOT_FOUND naming the
// flag for a file that cannot be read, INVALID_ARGUMENT for one that holds no PEM block.
absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> MakeServerCredentials(
    const ServerConfig& config);

// The PEM file at `path`, for the flag `flag` (named in the error).
absl::StatusOr<std::string> ReadPemFile(const std::string& flag, const std::string& path);

// Everything above, set up once at start.
struct Security {
  Authorizer authorizer;  // open without --tokens
  std::shared_ptr<grpc::ServerCredentials> credentials;
  std::vector<std::string> log_lines;  // access control and transport, with warnings
};
// CheckExposure, then the tokens file and the credentials; the first error.
absl::StatusOr<Security> SetUpSecurity(const ServerConfig& config);

}  // namespace rim::server
