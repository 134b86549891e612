// Internal to the client library: the channel, stubs and options shared by a Client and its
// SessionHandles, and the per-call setup (metadata, deadlines, error wording) every call uses.
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "client/client.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "rim/v1/rim.grpc.pb.h"

namespace rim::client_internal {

class Connection {
 public:
  Connection(std::string address, ClientOptions options, std::shared_ptr<grpc::Channel> channel);

  const std::string& address() const { return address_; }
  const ClientOptions& options() const { return options_; }
  rim::v1::Rim::Stub& stub() { return *stub_; }
  grpc::health::v1::Health::Stub& health() { return *health_; }

  // Adds the bearer token, `x-robot-id` (when robot_id is not empty) and, when timeout is
  // positive, a deadline that far from now.
  void Prepare(grpc::ClientContext* context, absl::string_view robot_id,
               std::chrono::milliseconds timeout) const;

  // The absl::Status of a failed call, its message prefixed with `what`; UNAVAILABLE says that the
  // server cannot be reached at this address.
  absl::Status Error(const grpc::Status& status, absl::string_view what) const;

  // The server's GetServerInfo answer, asked once and then remembered (its limits do not change
  // while it runs).
  absl::StatusOr<rim::v1::ServerInfo> CachedInfo();

 private:
  const std::string address_;
  const ClientOptions options_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<rim::v1::Rim::Stub> stub_;
  std::unique_ptr<grpc::health::v1::Health::Stub> health_;
  std::mutex mu_;
  std::optional<rim::v1::ServerInfo> info_;
};

}  // namespace rim::client_internal
