#include "server/service/service.h"

#include <algorithm>
#include <chrono>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "rim/base/version.h"
#include "rim/config/config.h"
#include "rim/gpu/device_map.h"
#include "server/service/scan_convert.h"
#include "server/service/status_mapping.h"

namespace rim::server {
namespace {

grpc::ServerUnaryReactor* Done(grpc::CallbackServerContext* ctx, const absl::Status& status) {
  grpc::ServerUnaryReactor* reactor = ctx->DefaultReactor();
  reactor->Finish(ToGrpcStatus(status));
  return reactor;
}

// Streams refused before they start (unauthenticated, or not allowed for the caller's role).
template <typename Request, typename Response>
class RefusedBidi : public grpc::ServerBidiReactor<Request, Response> {
 public:
  explicit RefusedBidi(const absl::Status& status) { this->Finish(ToGrpcStatus(status)); }
  void OnDone() override { delete this; }
};

class RefusedTiles : public grpc::ServerWriteReactor<rim::v1::MeshTile> {
 public:
  explicit RefusedTiles(const absl::Status& status) { Finish(ToGrpcStatus(status)); }
  void OnDone() override { delete this; }
};

const Authorizer& OpenAuthorizer() {
  static const Authorizer open;
  return open;
}

}  // namespace

RimService::RimService(SessionManager* sessions, const ServiceLimits& limits,
                       const Authorizer* auth)
    : sessions_(sessions),
      limits_(limits),
      auth_(auth != nullptr ? auth : &OpenAuthorizer()),
      streams_(limits.max_streams) {}

StreamLimiter::StreamLimiter(int max_streams)
    : max_(max_streams), open_(std::make_shared<std::atomic<int>>(0)) {}

absl::StatusOr<StreamLimiter::Slot> StreamLimiter::Acquire(const char* rpc) {
  if (open_->fetch_add(1) >= max_) {
    open_->fetch_sub(1);
    return absl::ResourceExhaustedError(
        absl::StrCat(rpc, ": ", max_, " streams are open on this server, its limit (--max-streams ",
                     max_, "); close one first"));
  }
  // The counter outlives the limiter if a stream does: the slot keeps it.
  std::shared_ptr<std::atomic<int>> open = open_;
  return Slot(open.get(), [open](void*) { open->fetch_sub(1); });
}

void FillSessionInfo(Session& session, rim::v1::SessionInfo* info) {
  const SessionStats stats = session.Stats();
  const MapperStats mapper = session.mapper().Stats();
  info->set_robot_id(session.robot_id());
  info->set_preset(session.mapper().config().preset);
  info->set_config(session.mapper().config().ToString());
  info->set_accepted_frames(stats.accepted);
  info->set_rejected_frames(stats.rejected);
  info->set_integrated_frames(stats.integrated);
  info->set_queue_depth(uint32_t(stats.queue_depth));
  info->set_iterations_per_frame(uint32_t(stats.iterations_per_frame));
  info->set_rays_per_iteration(uint32_t(stats.rays_per_iteration));
  for (float level : session.mapper().MeshLevels()) info->add_mesh_levels_m(level);
  info->set_map_version(mapper.map_version);
  info->set_buffer_points(uint64_t(mapper.buffer_points));
  info->set_submaps_active(uint32_t(mapper.submaps_active));
  info->set_submaps_frozen(uint32_t(mapper.submaps_frozen));
  info->set_submaps_on_disk(uint32_t(mapper.submaps_on_disk));
  info->set_host_memory_bytes(uint64_t(mapper.local_map_bytes + mapper.submap_bytes));
  info->set_decoder_frozen(mapper.decoder_frozen);
  info->set_last_loss(stats.last_loss);
  info->set_map_frames(uint64_t(std::max<int64_t>(0, mapper.frames)));
}

grpc::ServerUnaryReactor* RimService::CreateSession(grpc::CallbackServerContext* ctx,
                                                    const rim::v1::CreateSessionRequest* request,
                                                    rim::v1::SessionInfo* response) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kCreateSession, request->robot_id()); !s.ok())
    return Done(ctx, s);
  std::vector<std::pair<std::string, std::string>> overrides;
  for (const auto& o : request->overrides()) overrides.emplace_back(o.key(), o.value());
  auto session = sessions_->Create(request->robot_id(), request->preset(), overrides);
  if (!session.ok()) return Done(ctx, session.status());
  FillSessionInfo(**session, response);
  return Done(ctx, absl::OkStatus());
}

grpc::ServerUnaryReactor* RimService::GetSession(grpc::CallbackServerContext* ctx,
                                                 const rim::v1::GetSessionRequest* request,
                                                 rim::v1::SessionInfo* response) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kGetSession, request->robot_id()); !s.ok())
    return Done(ctx, s);
  auto session = sessions_->Get(request->robot_id());
  if (!session.ok()) return Done(ctx, session.status());
  FillSessionInfo(**session, response);
  return Done(ctx, absl::OkStatus());
}

grpc::ServerUnaryReactor* RimService::ListSessions(grpc::CallbackServerContext* ctx,
                                                   const rim::v1::ListSessionsRequest* request,
                                                   rim::v1::ListSessionsResponse* response) {
  if (auto principal = auth_->Authorize(*ctx, Rpc::kListSessions); !principal.ok())
    return Done(ctx, principal.status());
  for (const auto& session : sessions_->List()) FillSessionInfo(*session, response->add_sessions());
  return Done(ctx, absl::OkStatus());
}

grpc::ServerUnaryReactor* RimService::CloseSession(grpc::CallbackServerContext* ctx,
                                                   const rim::v1::CloseSessionRequest* request,
                                                   rim::v1::CloseSessionResponse* response) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kCloseSession, request->robot_id()); !s.ok())
    return Done(ctx, s);
  // Drains the session's queue on this handler thread; training itself stays on the trainer.
  return Done(ctx, sessions_->Close(request->robot_id(), request->save()));
}

grpc::ServerUnaryReactor* RimService::SaveSession(grpc::CallbackServerContext* ctx,
                                                  const rim::v1::SaveSessionRequest* request,
                                                  rim::v1::SaveSessionResponse* response) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kSaveSession, request->robot_id()); !s.ok())
    return Done(ctx, s);
  auto session = sessions_->Get(request->robot_id());
  if (!session.ok()) return Done(ctx, session.status());
  const uint64_t version = (*session)->mapper().map_version();
  auto checkpoint = sessions_->Save(request->robot_id());
  if (!checkpoint.ok()) return Done(ctx, checkpoint.status());
  response->set_checkpoint(*checkpoint);
  response->set_map_version(version);
  return Done(ctx, absl::OkStatus());
}

grpc::ServerUnaryReactor* RimService::LoadSession(grpc::CallbackServerContext* ctx,
                                                  const rim::v1::LoadSessionRequest* request,
                                                  rim::v1::SessionInfo* response) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kLoadSession, request->robot_id()); !s.ok())
    return Done(ctx, s);
  auto session = sessions_->Load(request->robot_id());
  if (!session.ok()) return Done(ctx, session.status());
  FillSessionInfo(**session, response);
  return Done(ctx, absl::OkStatus());
}

grpc::ServerBidiReactor<rim::v1::Scan, rim::v1::ScanAck>* RimService::StreamScans(
    grpc::CallbackServerContext* ctx) {
  auto principal = auth_->Authorize(*ctx, Rpc::kStreamScans);
  if (!principal.ok()) return new RefusedBidi<rim::v1::Scan, rim::v1::ScanAck>(principal.status());
  auto slot = streams_.Acquire("StreamScans");
  if (!slot.ok()) return new RefusedBidi<rim::v1::Scan, rim::v1::ScanAck>(slot.status());
  const auto header = ctx->client_metadata().find(kRealTimeHeader);
  const bool real_time = header != ctx->client_metadata().end() && header->second == "1";
  return NewScanStreamReactor(sessions_, limits_, *principal, *std::move(slot), real_time);
}

absl::Status AnswerQuery(SessionManager& sessions, const ServiceLimits& limits,
                         const rim::v1::QuerySdfRequest& request,
                         rim::v1::QuerySdfResponse* response) {
  const auto start = std::chrono::steady_clock::now();
  auto session = sessions.Get(request.robot_id());
  if (!session.ok()) return session.status();
  auto xyz = UnpackXyz(request.points_xyz(), "points_xyz", size_t(limits.max_query_points),
                       "--max-query-points; use StreamQuerySdf for larger batches");
  if (!xyz.ok()) return xyz.status();
  const size_t n = xyz->size() / 3;
  QueryResult result;
  absl::Status s = (*session)->mapper().QuerySdf(xyz->data(), n, request.want_gradient(), &result);
  if (!s.ok()) return s;
  response->set_sdf(reinterpret_cast<const char*>(result.sdf.data()), result.sdf.size() * 4);
  if (request.want_gradient())
    response->set_gradient(reinterpret_cast<const char*>(result.gradient.data()),
                           result.gradient.size() * 4);
  // The wire carries a plain 0/1 flag per point (rim.proto), whatever kind of observation it was.
  std::string* observed = response->mutable_observed();
  observed->resize(result.observed.size());
  for (size_t i = 0; i < result.observed.size(); ++i) (*observed)[i] = result.observed[i] ? 1 : 0;
  std::string* saturated = response->mutable_saturated();
  saturated->resize(result.saturated.size());
  for (size_t i = 0; i < result.saturated.size(); ++i)
    (*saturated)[i] = result.saturated[i] ? 1 : 0;
  response->set_map_version(result.map_version);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  response->set_server_seconds(seconds);
  (*session)->RecordQuery(n, seconds);
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* RimService::QuerySdf(grpc::CallbackServerContext* ctx,
                                               const rim::v1::QuerySdfRequest* request,
                                               rim::v1::QuerySdfResponse* response) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kQuerySdf, request->robot_id()); !s.ok())
    return Done(ctx, s);
  return Done(ctx, AnswerQuery(*sessions_, limits_, *request, response));
}

grpc::ServerBidiReactor<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse>*
RimService::StreamQuerySdf(grpc::CallbackServerContext* ctx) {
  auto principal = auth_->Authorize(*ctx, Rpc::kStreamQuerySdf);
  if (!principal.ok())
    return new RefusedBidi<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse>(principal.status());
  auto slot = streams_.Acquire("StreamQuerySdf");
  if (!slot.ok())
    return new RefusedBidi<rim::v1::QuerySdfRequest, rim::v1::QuerySdfResponse>(slot.status());
  return NewQueryStreamReactor(sessions_, limits_, *principal, *std::move(slot));
}

grpc::ServerWriteReactor<rim::v1::MeshTile>* RimService::GetMeshTiles(
    grpc::CallbackServerContext* ctx, const rim::v1::GetMeshTilesRequest* request) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kGetMeshTiles, request->robot_id()); !s.ok())
    return new RefusedTiles(s);
  return NewMeshTilesReactor(sessions_, *request);
}

grpc::ServerWriteReactor<rim::v1::MeshTile>* RimService::WatchMeshTiles(
    grpc::CallbackServerContext* ctx, const rim::v1::WatchMeshTilesRequest* request) {
  if (absl::Status s = auth_->Authorize(*ctx, Rpc::kWatchMeshTiles, request->robot_id()); !s.ok())
    return new RefusedTiles(s);
  auto slot = streams_.Acquire("WatchMeshTiles");
  if (!slot.ok()) return new RefusedTiles(slot.status());
  return NewWatchReactor(sessions_, *request, *std::move(slot));
}

grpc::ServerUnaryReactor* RimService::GetServerInfo(grpc::CallbackServerContext* ctx,
                                                    const rim::v1::GetServerInfoRequest* request,
                                                    rim::v1::ServerInfo* response) {
  if (auto principal = auth_->Authorize(*ctx, Rpc::kGetServerInfo); !principal.ok())
    return Done(ctx, principal.status());
  response->set_version(kRimVersion);
  response->set_build(gpu::BuiltWithCuda() ? "cuda" : "cpu");
  response->set_device(limits_.device);
  response->set_libtorch_version(TorchVersion());
  response->set_max_sessions(uint32_t(limits_.max_sessions));
  response->set_max_points_per_scan(uint32_t(limits_.max_points_per_scan));
  response->set_max_query_points(uint32_t(limits_.max_query_points));
  response->set_queue_length(uint32_t(limits_.queue_length));
  response->set_host_memory_budget_bytes(limits_.host_memory_budget_bytes);
  for (const std::string& name : PresetNames()) response->add_presets(name);
  return Done(ctx, absl::OkStatus());
}

}  // namespace rim::server
