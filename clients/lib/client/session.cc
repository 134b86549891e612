// SessionHandle's queries and mesh tiles (the scan stream is in session_stream.cc).
#include <algorithm>
#include <thread>

#include "absl/strings/str_cat.h"
#include "client/client.h"
#include "client/connection.h"
#include "client/wire.h"

namespace rim {
namespace {

// Appends one answer for `count` points to *result, checking the array lengths first so that a
// malformed answer cannot leave *result half-filled.
absl::Status AppendAnswer(const rim::v1::QuerySdfResponse& answer, size_t count, bool want_gradient,
                          QueryResult* result) {
  auto sdf = UnpackFloats(answer.sdf(), count, "QuerySdfResponse.sdf");
  if (!sdf.ok()) return absl::DataLossError(sdf.status().message());
  if (answer.observed().size() != count) {
    return absl::DataLossError(absl::StrCat("QuerySdfResponse.observed has ",
                                            answer.observed().size(), " bytes for ", count,
                                            " points"));
  }
  if (!answer.saturated().empty() && answer.saturated().size() != count) {
    return absl::DataLossError(absl::StrCat("QuerySdfResponse.saturated has ",
                                            answer.saturated().size(), " bytes for ", count,
                                            " points"));
  }
  std::vector<float> gradient;
  if (want_gradient) {
    auto g = UnpackFloats(answer.gradient(), 3 * count, "QuerySdfResponse.gradient");
    if (!g.ok()) return absl::DataLossError(g.status().message());
    gradient = std::move(*g);
  }
  const bool first = result->sdf.empty();
  result->sdf.insert(result->sdf.end(), sdf->begin(), sdf->end());
  result->gradient.insert(result->gradient.end(), gradient.begin(), gradient.end());
  result->observed.insert(result->observed.end(), answer.observed().begin(),
                          answer.observed().end());
  if (answer.saturated().empty())
    result->saturated.insert(result->saturated.end(), count, 0);
  else
    result->saturated.insert(result->saturated.end(), answer.saturated().begin(),
                             answer.saturated().end());
  result->map_version =
      first ? answer.map_version() : std::min(result->map_version, answer.map_version());
  result->server_seconds += answer.server_seconds();
  return absl::OkStatus();
}

rim::v1::QuerySdfRequest MakeRequest(const std::string& robot_id, const std::vector<Vec3f>& points,
                                     size_t begin, size_t end, bool want_gradient) {
  rim::v1::QuerySdfRequest request;
  request.set_robot_id(robot_id);
  request.set_want_gradient(want_gradient);
  request.set_points_xyz(
      PackXyz(std::vector<Vec3f>(points.begin() + long(begin), points.begin() + long(end))));
  return request;
}

}  // namespace

absl::StatusOr<rim::v1::SessionInfo> SessionHandle::Info() const {
  client_internal::Connection& c = *connection_;
  grpc::ClientContext context;
  c.Prepare(&context, robot_id_, c.options().deadline);
  rim::v1::GetSessionRequest request;
  request.set_robot_id(robot_id_);
  rim::v1::SessionInfo info;
  const grpc::Status s = c.stub().GetSession(&context, request, &info);
  if (!s.ok()) return c.Error(s, absl::StrCat("GetSession ", robot_id_));
  return info;
}

absl::StatusOr<QueryResult> SessionHandle::Query(const std::vector<Vec3f>& points_W,
                                                 bool want_gradient) const {
  client_internal::Connection& c = *connection_;
  if (points_W.empty()) return absl::InvalidArgumentError("Query: no points to query");
  auto info = c.CachedInfo();
  if (!info.ok()) return info.status();
  const size_t limit = info->max_query_points() > 0 ? info->max_query_points() : points_W.size();
  const size_t chunks = (points_W.size() + limit - 1) / limit;
  const std::string what = absl::StrCat("QuerySdf ", robot_id_);
  QueryResult result;
  if (chunks == 1) {
    grpc::ClientContext context;
    c.Prepare(&context, robot_id_, c.options().deadline);
    rim::v1::QuerySdfResponse answer;
    const grpc::Status s = c.stub().QuerySdf(
        &context, MakeRequest(robot_id_, points_W, 0, points_W.size(), want_gradient), &answer);
    if (!s.ok()) return c.Error(s, what);
    const absl::Status appended = AppendAnswer(answer, points_W.size(), want_gradient, &result);
    if (!appended.ok()) return appended;
    return result;
  }

  // Larger than one call may carry: chunks of `limit` points over StreamQuerySdf, written from a
  // second thread so that sending the next chunk overlaps the server answering this one.
  grpc::ClientContext context;
  c.Prepare(&context, robot_id_, c.options().deadline * static_cast<int64_t>(chunks));
  auto stream = c.stub().StreamQuerySdf(&context);
  std::thread writer([&] {
    for (size_t k = 0; k < chunks; ++k) {
      const size_t begin = k * limit, end = std::min(points_W.size(), begin + limit);
      if (!stream->Write(MakeRequest(robot_id_, points_W, begin, end, want_gradient))) break;
    }
    stream->WritesDone();
  });
  absl::Status local;
  size_t answered = 0;
  rim::v1::QuerySdfResponse answer;
  while (local.ok() && answered < chunks && stream->Read(&answer)) {
    const size_t count = std::min(limit, points_W.size() - answered * limit);
    local = AppendAnswer(answer, count, want_gradient, &result);
    ++answered;
  }
  if (!local.ok()) context.TryCancel();
  writer.join();
  while (stream->Read(&answer)) {
  }
  const grpc::Status s = stream->Finish();
  if (!local.ok()) return local;
  if (!s.ok()) return c.Error(s, absl::StrCat("StreamQuerySdf ", robot_id_));
  if (answered != chunks) {
    return absl::DataLossError(absl::StrCat("StreamQuerySdf ", robot_id_, ": ", answered,
                                            " answers for ", chunks, " chunks"));
  }
  return result;
}

absl::StatusOr<std::vector<DecodedTile>> SessionHandle::MeshTiles(
    uint64_t since_version, const std::optional<Box3d>& region, float resolution_m) const {
  client_internal::Connection& c = *connection_;
  rim::v1::GetMeshTilesRequest request;
  request.set_robot_id(robot_id_);
  request.set_since_version(since_version);
  request.set_resolution_m(resolution_m);
  if (region) {
    auto* box = request.mutable_region();
    box->mutable_min()->set_x(region->min[0]);
    box->mutable_min()->set_y(region->min[1]);
    box->mutable_min()->set_z(region->min[2]);
    box->mutable_max()->set_x(region->max[0]);
    box->mutable_max()->set_y(region->max[1]);
    box->mutable_max()->set_z(region->max[2]);
  }
  grpc::ClientContext context;
  c.Prepare(&context, robot_id_, c.options().mesh_deadline);
  auto reader = c.stub().GetMeshTiles(&context, request);
  std::vector<DecodedTile> tiles;
  absl::Status local;
  rim::v1::MeshTile tile;
  while (reader->Read(&tile)) {
    if (!local.ok()) continue;
    auto decoded = DecodeTile(tile);
    if (decoded.ok()) {
      tiles.push_back(std::move(*decoded));
    } else {
      local = decoded.status();
      context.TryCancel();
    }
  }
  const grpc::Status s = reader->Finish();
  if (!local.ok()) return local;
  if (!s.ok()) return c.Error(s, absl::StrCat("GetMeshTiles ", robot_id_));
  return tiles;
}

absl::Status SessionHandle::Watch(const std::function<bool(const DecodedTile&)>& on_tile,
                                  const WatchOptions& options) const {
  client_internal::Connection& c = *connection_;
  rim::v1::WatchMeshTilesRequest request;
  request.set_robot_id(robot_id_);
  request.set_since_version(options.since_version);
  request.set_resolution_m(options.resolution_m);
  grpc::ClientContext context;
  c.Prepare(&context, robot_id_, options.duration);
  auto reader = c.stub().WatchMeshTiles(&context, request);
  absl::Status local;
  bool stopped = false;
  rim::v1::MeshTile tile;
  while (reader->Read(&tile)) {
    if (stopped) continue;
    auto decoded = DecodeTile(tile);
    if (!decoded.ok()) local = decoded.status();
    if (!decoded.ok() || !on_tile(*decoded)) {
      stopped = true;
      context.TryCancel();
    }
  }
  const grpc::Status s = reader->Finish();
  if (!local.ok()) return local;
  // Ending the watch on purpose (callback or duration) is the normal way out.
  if (s.ok() || (stopped && s.error_code() == grpc::StatusCode::CANCELLED)) return absl::OkStatus();
  if (options.duration.count() > 0 && s.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED)
    return absl::OkStatus();
  return c.Error(s, absl::StrCat("WatchMeshTiles ", robot_id_));
}

}  // namespace rim
