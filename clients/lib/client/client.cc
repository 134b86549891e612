#include "client/client.h"

#include <grpcpp/grpcpp.h>

#include <fstream>
#include <sstream>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "client/connection.h"
#include "client/status.h"

namespace rim {
namespace client_internal {

Connection::Connection(std::string address, ClientOptions options,
                       std::shared_ptr<grpc::Channel> channel)
    : address_(std::move(address)),
      options_(std::move(options)),
      channel_(std::move(channel)),
      stub_(rim::v1::Rim::NewStub(channel_)),
      health_(grpc::health::v1::Health::NewStub(channel_)) {}

namespace {
// gRPC aborts the process on a header value outside printable ASCII, so such values are never
// handed to it: the token is checked in Connect, and a robot id that cannot be a header (the
// server rejects it as a robot id anyway, with a message naming it) is sent without one.
bool IsHeaderValue(absl::string_view value) {
  for (char c : value)
    if (c < 0x20 || c > 0x7e) return false;
  return true;
}
}  // namespace

void Connection::Prepare(grpc::ClientContext* context, absl::string_view robot_id,
                         std::chrono::milliseconds timeout) const {
  if (!options_.token.empty()) context->AddMetadata("authorization", "Bearer " + options_.token);
  if (!robot_id.empty() && IsHeaderValue(robot_id))
    context->AddMetadata("x-robot-id", std::string(robot_id));
  if (timeout.count() > 0) context->set_deadline(std::chrono::system_clock::now() + timeout);
}

absl::Status Connection::Error(const grpc::Status& status, absl::string_view what) const {
  // UNAVAILABLE is also what the server itself answers while it shuts down; its own messages
  // start with "rim_server", and saying "cannot reach" then would send the user looking for a
  // network problem.
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE &&
      !absl::StartsWith(status.error_message(), "rim_server ")) {
    return absl::UnavailableError(absl::StrCat("cannot reach rim_server at ", address_, ": ", what,
                                               ": ", status.error_message()));
  }
  return FromGrpc(status, what);
}

absl::StatusOr<rim::v1::ServerInfo> Connection::CachedInfo() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (info_) return *info_;
  }
  grpc::ClientContext context;
  Prepare(&context, "", options_.deadline);
  rim::v1::ServerInfo info;
  const grpc::Status s = stub_->GetServerInfo(&context, rim::v1::GetServerInfoRequest(), &info);
  if (!s.ok()) return Error(s, "GetServerInfo");
  std::lock_guard<std::mutex> lock(mu_);
  info_ = info;
  return info;
}

}  // namespace client_internal

namespace {

absl::StatusOr<std::string> ReadFile(const std::string& what, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(what, ": cannot read ", path));
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Plaintext unless a TLS option is set; then TLS, with a client certificate when one is given.
absl::StatusOr<std::shared_ptr<grpc::ChannelCredentials>> ChannelCredentials(
    const ClientOptions& options) {
  if (options.tls_ca_file.empty() && options.tls_cert_file.empty() && options.tls_key_file.empty())
    return grpc::InsecureChannelCredentials();
  if (options.tls_cert_file.empty() != options.tls_key_file.empty())
    return absl::InvalidArgumentError("tls_cert_file and tls_key_file must be given together");
  grpc::SslCredentialsOptions ssl;
  if (!options.tls_ca_file.empty()) {
    auto ca = ReadFile("tls_ca_file", options.tls_ca_file);
    if (!ca.ok()) return ca.status();
    ssl.pem_root_certs = *ca;
  }
  if (!options.tls_cert_file.empty()) {
    auto cert = ReadFile("tls_cert_file", options.tls_cert_file);
    if (!cert.ok()) return cert.status();
    auto key = ReadFile("tls_key_file", options.tls_key_file);
    if (!key.ok()) return key.status();
    ssl.pem_cert_chain = *cert;
    ssl.pem_private_key = *key;
  }
  return grpc::SslCredentials(ssl);
}

// Runs one unary call with the connection's metadata and deadline and converts its status.
template <typename Request, typename Response, typename Method>
absl::StatusOr<Response> Unary(client_internal::Connection& c, Method method,
                               const Request& request, absl::string_view robot_id,
                               absl::string_view what) {
  grpc::ClientContext context;
  c.Prepare(&context, robot_id, c.options().deadline);
  Response response;
  const grpc::Status s = (c.stub().*method)(&context, request, &response);
  if (!s.ok()) {
    return c.Error(s, robot_id.empty() ? std::string(what) : absl::StrCat(what, " ", robot_id));
  }
  return response;
}

}  // namespace

const char* ServingStatusName(ServingStatus status) {
  switch (status) {
    case ServingStatus::kServing:
      return "SERVING";
    case ServingStatus::kNotServing:
      return "NOT_SERVING";
    case ServingStatus::kServiceUnknown:
      return "SERVICE_UNKNOWN";
    case ServingStatus::kUnknown:
      break;
  }
  return "UNKNOWN";
}

absl::StatusOr<Client> Client::Connect(const std::string& address, ClientOptions options) {
  if (address.empty()) return absl::InvalidArgumentError("no server address given");
  if (!client_internal::IsHeaderValue(options.token))
    return absl::InvalidArgumentError(
        "the token contains characters other than printable ASCII (a newline at its end?)");
  grpc::ChannelArguments args;
  // Query answers with gradients are 17 bytes per point: a max-size batch is far over gRPC's 4 MB
  // default. The server enforces its own limits; this only has to not be the smaller one.
  args.SetMaxReceiveMessageSize(256 << 20);
  args.SetMaxSendMessageSize(256 << 20);
  auto credentials = ChannelCredentials(options);
  if (!credentials.ok()) return credentials.status();
  auto channel = grpc::CreateCustomChannel(address, *credentials, args);
  if (!channel->WaitForConnected(std::chrono::system_clock::now() + options.connect_timeout)) {
    const bool tls = !options.tls_ca_file.empty() || !options.tls_cert_file.empty();
    return absl::UnavailableError(absl::StrCat(
        "cannot reach rim_server at ", address, ": no connection within ",
        options.connect_timeout.count() / 1000.0, " s (is the server running and listening there? ",
        tls ? "TLS: is its certificate signed by the CA given, for this host name, and does it "
              "want a client certificate?)"
            : "does it want TLS?)"));
  }
  return Client(std::make_shared<client_internal::Connection>(address, std::move(options),
                                                              std::move(channel)));
}

const std::string& Client::address() const { return connection_->address(); }

absl::StatusOr<rim::v1::ServerInfo> Client::Info() const {
  return Unary<rim::v1::GetServerInfoRequest, rim::v1::ServerInfo>(
      *connection_, &rim::v1::Rim::Stub::GetServerInfo, {}, "", "GetServerInfo");
}

absl::StatusOr<rim::v1::SessionInfo> Client::CreateSession(
    const std::string& robot_id, const std::string& preset,
    const std::vector<std::pair<std::string, std::string>>& overrides) const {
  rim::v1::CreateSessionRequest request;
  request.set_robot_id(robot_id);
  request.set_preset(preset);
  for (const auto& [key, value] : overrides) {
    auto* o = request.add_overrides();
    o->set_key(key);
    o->set_value(value);
  }
  return Unary<rim::v1::CreateSessionRequest, rim::v1::SessionInfo>(
      *connection_, &rim::v1::Rim::Stub::CreateSession, request, robot_id, "CreateSession");
}

absl::StatusOr<rim::v1::SessionInfo> Client::GetSession(const std::string& robot_id) const {
  rim::v1::GetSessionRequest request;
  request.set_robot_id(robot_id);
  return Unary<rim::v1::GetSessionRequest, rim::v1::SessionInfo>(
      *connection_, &rim::v1::Rim::Stub::GetSession, request, robot_id, "GetSession");
}

absl::StatusOr<std::vector<rim::v1::SessionInfo>> Client::ListSessions() const {
  auto response = Unary<rim::v1::ListSessionsRequest, rim::v1::ListSessionsResponse>(
      *connection_, &rim::v1::Rim::Stub::ListSessions, {}, "", "ListSessions");
  if (!response.ok()) return response.status();
  return std::vector<rim::v1::SessionInfo>(response->sessions().begin(),
                                           response->sessions().end());
}

absl::StatusOr<rim::v1::SaveSessionResponse> Client::SaveSession(
    const std::string& robot_id) const {
  rim::v1::SaveSessionRequest request;
  request.set_robot_id(robot_id);
  return Unary<rim::v1::SaveSessionRequest, rim::v1::SaveSessionResponse>(
      *connection_, &rim::v1::Rim::Stub::SaveSession, request, robot_id, "SaveSession");
}

absl::StatusOr<rim::v1::SessionInfo> Client::LoadSession(const std::string& robot_id) const {
  rim::v1::LoadSessionRequest request;
  request.set_robot_id(robot_id);
  return Unary<rim::v1::LoadSessionRequest, rim::v1::SessionInfo>(
      *connection_, &rim::v1::Rim::Stub::LoadSession, request, robot_id, "LoadSession");
}

absl::Status Client::CloseSession(const std::string& robot_id, bool save) const {
  rim::v1::CloseSessionRequest request;
  request.set_robot_id(robot_id);
  request.set_save(save);
  return Unary<rim::v1::CloseSessionRequest, rim::v1::CloseSessionResponse>(
             *connection_, &rim::v1::Rim::Stub::CloseSession, request, robot_id, "CloseSession")
      .status();
}

absl::StatusOr<ServingStatus> Client::Health(const std::string& service) const {
  client_internal::Connection& c = *connection_;
  grpc::ClientContext context;
  c.Prepare(&context, "", c.options().deadline);
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  grpc::health::v1::HealthCheckResponse response;
  const grpc::Status s = c.health().Check(&context, request, &response);
  // The protocol answers NOT_FOUND for a service the server does not know.
  if (s.error_code() == grpc::StatusCode::NOT_FOUND) return ServingStatus::kServiceUnknown;
  if (!s.ok()) return c.Error(s, "Health/Check");
  switch (response.status()) {
    case grpc::health::v1::HealthCheckResponse::SERVING:
      return ServingStatus::kServing;
    case grpc::health::v1::HealthCheckResponse::NOT_SERVING:
      return ServingStatus::kNotServing;
    case grpc::health::v1::HealthCheckResponse::SERVICE_UNKNOWN:
      return ServingStatus::kServiceUnknown;
    default:
      return ServingStatus::kUnknown;
  }
}

}  // namespace rim
