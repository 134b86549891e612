// The rim.v1.Rim gRPC service (DESIGN.md §5.1), on the callback API. Handlers validate, hand work
// to sessions and return; training runs only on each session's trainer thread. Core errors are
// absl::Status, converted once at the edge by ToGrpcStatus.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "rim/v1/rim.grpc.pb.h"
#include "server/auth/auth.h"
#include "server/session/session_manager.h"

namespace rim::server {

struct ServiceLimits {
  int max_points_per_scan = 1 << 21;
  int max_query_points = 1 << 20;
  int queue_length = 8;
  int max_sessions = 16;
  uint64_t host_memory_budget_bytes = 0;
  // Where sessions train by default (--device): "cpu", or "cuda:N (the GPU's name)".
  std::string device = "cpu";
  // Long-lived streams open at once, all clients together (StreamScans, StreamQuerySdf,
  // WatchMeshTiles): each holds reactor state and a watch a thread of its own.
  int max_streams = 128;
};

// Counts the open long-lived streams against ServiceLimits::max_streams. A stream holds its slot
// for its whole life (the reactor owns it); past the limit a new stream ends at once with
// RESOURCE_EXHAUSTED naming --max-streams, and the open ones are untouched.
class StreamLimiter {
 public:
  using Slot = std::shared_ptr<void>;
  explicit StreamLimiter(int max_streams);
  absl::StatusOr<Slot> Acquire(const char* rpc);
  int open() const { return open_->load(); }

 private:
  const int max_;
  std::shared_ptr<std::atomic<int>> open_;
};

class RimService final : public rim::v1::Rim::CallbackService {
 public:
  // `auth` (not owned) authorizes every call first; nullptr: open, every call allowed.
  RimService(SessionManager* sessions, const ServiceLimits& limits,
             const Authorizer* auth = nullptr);

  grpc::ServerUnaryReactor* CreateSession(grpc::CallbackServerContext* ctx,
                                          const rim::v1::CreateSessionRequest* request,
                                          rim::v1::SessionInfo* response) override;
  grpc::ServerUnaryReactor* GetSession(grpc::CallbackServerContext* ctx,
                                       const rim::v1::GetSessionRequest* request,
                                       rim::v1::SessionInfo* response) override;
  grpc::ServerUnaryReactor* ListSessions(grpc::CallbackServerContext* ctx,
                                         const rim::v1::ListSessionsRequest* request,
                                         rim::v1::ListSessionsResponse* response) override;
  grpc::ServerUnaryReactor* CloseSession(grpc::CallbackServerContext* ctx,
                                         const rim::v1::CloseSessionRequest* request,
                                         rim::v1::CloseSessionResponse* response) override;
  grpc::ServerUnaryReactor* SaveSession(grpc::CallbackServerContext* ctx,
                                        const rim::v1::SaveSessionRequest* request,
                                        rim::v1::SaveSessionResponse* response) override;
  grpc::ServerUnaryReactor* LoadSession(grpc::CallbackServerContext* ctx,
                                        const rim::v1::LoadSessionRequest* request,
                                        rim::v1::SessionInfo* response) override;
  grpc::ServerBidiReactor<rim::v1::Scan, rim::v1::ScanAck>* StreamScans(
      grpc::CallbackServerContext* ctx) override;
  grpc::ServerUnaryReactor* QuerySdf(grpc::CallbackServerContext* ctx,
                                     const rim::v1::QuerySdfRequest* request,
                                     rim::v1::QuerySdfResponse* response) override;
  grpc::ServerBidiReactor<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse>* StreamQuerySdf(
      grpc::CallbackServerContext* ctx) override;
  grpc::ServerWriteReactor<rim::v1::MeshTile>* GetMeshTiles(
      grpc::CallbackServerContext* ctx, const rim::v1::GetMeshTilesRequest* request) override;
  grpc::ServerWriteReactor<rim::v1::MeshTile>* WatchMeshTiles(
      grpc::CallbackServerContext* ctx, const rim::v1::WatchMeshTilesRequest* request) override;
  grpc::ServerUnaryReactor* GetServerInfo(grpc::CallbackServerContext* ctx,
                                          const rim::v1::GetServerInfoRequest* request,
                                          rim::v1::ServerInfo* response) override;

 private:
  SessionManager* sessions_;
  const ServiceLimits limits_;
  const Authorizer* auth_;
  StreamLimiter streams_;
};

// Fills `info` from the session's counters and its mapper's statistics.
void FillSessionInfo(Session& session, rim::v1::SessionInfo* info);

// The StreamScans reactor (service_stream.cc) and the GetMeshTiles reactor (service_mesh.cc).
// Stream reactors check each message's robot id against `principal` (CheckRobot): a scan for
// another robot is REJECTED with PERMISSION_DENIED and the stream goes on; a query for another
// robot ends the query stream with PERMISSION_DENIED.
// The header a client sends on StreamScans when it streams at a sensor's rate (the C++ client
// does when StreamOptions::rate_hz > 0; clients/lib/client/session_stream.cc spells it too).
inline constexpr char kRealTimeHeader[] = "x-rim-real-time";
// `real_time`: the client sent kRealTimeHeader (a stream at a sensor's rate): its
// scans count toward the session's pace (Session::Submit).
grpc::ServerBidiReactor<rim::v1::Scan, rim::v1::ScanAck>* NewScanStreamReactor(
    SessionManager* sessions, const ServiceLimits& limits, const Principal& principal,
    StreamLimiter::Slot slot, bool real_time);
// One query (unary, or one message of a query stream): points limited to max_query_points.
absl::Status AnswerQuery(SessionManager& sessions, const ServiceLimits& limits,
                         const rim::v1::QuerySdfRequest& request,
                         rim::v1::QuerySdfResponse* response);
grpc::ServerBidiReactor<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse>* NewQueryStreamReactor(
    SessionManager* sessions, const ServiceLimits& limits, const Principal& principal,
    StreamLimiter::Slot slot);
grpc::ServerWriteReactor<rim::v1::MeshTile>* NewWatchReactor(
    SessionManager* sessions, const rim::v1::WatchMeshTilesRequest& request,
    StreamLimiter::Slot slot);
grpc::ServerWriteReactor<rim::v1::MeshTile>* NewMeshTilesReactor(
    SessionManager* sessions, const rim::v1::GetMeshTilesRequest& request);

}  // namespace rim::server
