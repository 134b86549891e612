#include "server/http/http_api.h"

#include <civetweb.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <climits>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "nlohmann/json.hpp"
#include "rim/base/thread_priority.h"
#include "rim/base/version.h"

namespace rim::server {
namespace {

using nlohmann::json;

constexpr size_t kMaxStaticBytes = size_t(64) << 20;
constexpr const char* kApiPrefix = "/api/v1/sessions";
// How long one tile listing may spend meshing before it answers with what it has.
constexpr double kListBudgetSeconds = 2.0;

std::string ContentType(const std::string& path) {
  static const std::pair<const char*, const char*> kTypes[] = {
      {".html", "text/html; charset=utf-8"},
      {".js", "text/javascript; charset=utf-8"},
      {".mjs", "text/javascript; charset=utf-8"},
      {".css", "text/css; charset=utf-8"},
      {".json", "application/json"},
      {".wasm", "application/wasm"},
      {".png", "image/png"},
      {".svg", "image/svg+xml"},
      {".ico", "image/x-icon"},
      {".txt", "text/plain; charset=utf-8"},
  };
  for (const auto& [ext, type] : kTypes)
    if (absl::EndsWith(path, ext)) return type;
  return "application/octet-stream";
}

HttpResponse Json(int status, const json& value) {
  HttpResponse r;
  r.status = status;
  r.content_type = "application/json";
  r.body = value.dump();
  r.headers.emplace_back("Cache-Control", "no-store");
  return r;
}

HttpResponse Error(int status, const std::string& message) {
  return Json(status, json{{"error", {{"code", status}, {"message", message}}}});
}

// An absl status of a session lookup or a meshing call, as HTTP.
HttpResponse FromStatus(const absl::Status& status) {
  switch (status.code()) {
    case absl::StatusCode::kNotFound:
      return Error(404, std::string(status.message()));
    case absl::StatusCode::kInvalidArgument:
      return Error(400, std::string(status.message()));
    case absl::StatusCode::kUnauthenticated:
      return Error(401, std::string(status.message()));
    case absl::StatusCode::kPermissionDenied:
      return Error(403, std::string(status.message()));
    case absl::StatusCode::kResourceExhausted:
      return Error(503, std::string(status.message()));
    default:
      return Error(500, std::string(status.message()));
  }
}

// The value of `name` in a query string ("a=1&since=7"); false when absent.
bool QueryValue(const std::string& query, const std::string& name, std::string* value) {
  for (absl::string_view part : absl::StrSplit(query, '&')) {
    const size_t eq = part.find('=');
    if (part.substr(0, eq) != name) continue;
    *value = eq == absl::string_view::npos ? "" : std::string(part.substr(eq + 1));
    return true;
  }
  return false;
}

// `since` as a non-negative integer: 0 when absent; 400 for anything else.
absl::StatusOr<uint64_t> SinceParam(const std::string& query, const char* what) {
  std::string text;
  if (!QueryValue(query, "since", &text)) return uint64_t(0);
  uint64_t since = 0;
  const bool digits = !text.empty() && text.size() <= 20 &&
                      std::all_of(text.begin(), text.end(), absl::ascii_isdigit);
  if (!digits || !absl::SimpleAtoi(text, &since))
    return absl::InvalidArgumentError(absl::StrCat("since must be a non-negative integer ", what,
                                                   ", got '", text.substr(0, 40), "'"));
  return since;
}

// The level of detail of a tile request (`resolution_m`, metres): one of the session's levels, or
// the finest when absent or 0 (Mapper::MeshLevel).
absl::StatusOr<float> ResolutionParam(const std::string& query, const Mapper& mapper) {
  std::string text;
  if (!QueryValue(query, "resolution_m", &text)) return mapper.MeshLevel(0);
  float value = 0;
  if (text.empty() || text.size() > 20 || !absl::SimpleAtof(text, &value))
    return absl::InvalidArgumentError(
        absl::StrCat("resolution_m must be a number of metres, got '", text.substr(0, 40), "'"));
  return mapper.MeshLevel(value);
}

json Vec(const Vec3d& v) { return json::array({v.x(), v.y(), v.z()}); }

json SessionJson(Session& session) {
  const SessionStats stats = session.Stats();
  const MapperStats mapper = session.mapper().Stats();
  json entry = {
      {"robot_id", session.robot_id()},
      {"preset", session.mapper().config().preset},
      {"accepted_frames", stats.accepted},
      {"integrated_frames", stats.integrated},
      {"rejected_frames", stats.rejected},
      {"lag_frames", stats.accepted - std::min(stats.accepted, stats.integrated + stats.failed)},
      {"queue_depth", stats.queue_depth},
      {"iterations_per_frame", stats.iterations_per_frame},
      {"rays_per_iteration", stats.rays_per_iteration},
      {"mesh_levels_m", session.mapper().MeshLevels()},
      {"map_version", mapper.map_version},
      {"host_memory_bytes", uint64_t(mapper.local_map_bytes + mapper.submap_bytes)},
      {"submaps_active", mapper.submaps_active},
      {"decoder_frozen", mapper.decoder_frozen},
      {"last_loss", stats.last_loss},
  };
  uint64_t next = 0;
  session.Trajectory(UINT64_MAX, &next);
  entry["trajectory_length"] = next;
  TrajectoryPoint pose;
  if (session.LatestPose(&pose)) {
    const Eigen::Quaternionf& q = pose.orientation;
    entry["pose"] = {
        {"position", json::array({pose.position.x(), pose.position.y(), pose.position.z()})},
        {"orientation_wxyz", json::array({q.w(), q.x(), q.y(), q.z()})},
        {"frame", pose.index}};
  } else {
    entry["pose"] = nullptr;
  }
  return entry;
}

std::string TileName(const Int3& key) { return absl::StrCat(key.x(), "_", key.y(), "_", key.z()); }

// "3_-1_0.drc" -> (3, -1, 0).
bool ParseTileName(const std::string& name, Int3* key) {
  if (!absl::EndsWith(name, ".drc")) return false;
  const std::vector<std::string> parts =
      absl::StrSplit(absl::string_view(name).substr(0, name.size() - 4), '_');
  if (parts.size() != 3) return false;
  for (int i = 0; i < 3; ++i) {
    int v = 0;
    if (parts[i].empty() || parts[i].size() > 11 || !absl::SimpleAtoi(parts[i], &v)) return false;
    (*key)[i] = v;
  }
  return true;
}

}  // namespace

absl::StatusOr<StaticFiles> StaticFiles::Load(const std::string& dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_regular_file(fs::path(dir) / "index.html", ec))
    return absl::FailedPreconditionError(
        absl::StrCat("no dashboard in '", dir,
                     "' (index.html missing): build the `web` target, or pass --web-root DIR"));
  StaticFiles out;
  size_t total = 0;
  for (auto it = fs::recursive_directory_iterator(dir, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    if (!it->is_regular_file(ec)) continue;
    std::ifstream in(it->path(), std::ios::binary);
    std::ostringstream bytes;
    bytes << in.rdbuf();
    if (!in) return absl::UnavailableError(absl::StrCat("cannot read ", it->path().string()));
    total += bytes.str().size();
    if (total > kMaxStaticBytes)
      return absl::ResourceExhaustedError(
          absl::StrCat("the dashboard's files in '", dir, "' exceed 64 MiB"));
    const std::string rel = fs::relative(it->path(), dir, ec).generic_string();
    out.files_["/" + rel] = {ContentType(rel), bytes.str()};
  }
  if (ec) return absl::UnavailableError(absl::StrCat("reading '", dir, "': ", ec.message()));
  return out;
}

const std::pair<std::string, std::string>* StaticFiles::Find(const std::string& path) const {
  auto it = files_.find(path == "/" ? "/index.html" : path);
  return it == files_.end() ? nullptr : &it->second;
}

HttpApi::HttpApi(SessionManager* sessions, const Authorizer* auth, StaticFiles files)
    : sessions_(sessions), auth_(auth), files_(std::move(files)) {}

HttpResponse HttpApi::Handle(const HttpRequest& request) const {
  if (request.method != "GET" && request.method != "HEAD") {
    HttpResponse r = Error(405, absl::StrCat(request.method.substr(0, 16),
                                             " is not allowed: the dashboard's API is read-only"));
    r.headers.emplace_back("Allow", "GET, HEAD");
    return r;
  }
  const std::string& path = request.path;
  if (!absl::StartsWith(path, "/api/")) {
    const auto* file = files_.Find(path);
    if (file == nullptr) return Error(404, absl::StrCat("no file ", path.substr(0, 200)));
    HttpResponse r;
    r.content_type = file->first;
    r.body = file->second;
    r.headers.emplace_back("Cache-Control", "no-cache");
    return r;
  }

  // The API: authenticate first, so a refused request learns nothing about the sessions.
  Principal principal;
  if (auth_->enabled()) {
    auto who = auth_->Authenticate(request.authorization);
    if (!who.ok()) {
      HttpResponse r = Error(401, std::string(who.status().message()));
      r.headers.emplace_back("WWW-Authenticate", "Bearer");
      return r;
    }
    principal = *who;
  }
  const auto allow = [&](Rpc rpc) -> absl::Status {
    if (!RoleAllows(principal.role, rpc))
      return absl::PermissionDeniedError(
          absl::StrCat("role ", RoleName(principal.role), " may not call ", RpcName(rpc)));
    return absl::OkStatus();
  };

  if (path == kApiPrefix || path == std::string(kApiPrefix) + "/") {
    if (absl::Status s = allow(Rpc::kListSessions); !s.ok()) return FromStatus(s);
    return Sessions();
  }
  if (!absl::StartsWith(path, std::string(kApiPrefix) + "/"))
    return Error(404, absl::StrCat("no API path ", path.substr(0, 200)));
  const std::vector<std::string> parts =
      absl::StrSplit(path.substr(std::string(kApiPrefix).size() + 1), '/');
  const std::string& robot = parts[0];
  const Rpc rpc = parts.size() == 1                          ? Rpc::kGetSession
                  : parts.size() >= 2 && parts[1] == "tiles" ? Rpc::kGetMeshTiles
                                                             : Rpc::kGetSession;
  if (absl::Status s = allow(rpc); !s.ok()) return FromStatus(s);
  if (absl::Status s = CheckRobot(principal, robot); !s.ok()) return FromStatus(s);
  if (parts.size() == 1) return SessionEntry(robot);
  if (parts.size() == 2 && parts[1] == "tiles") return Tiles(robot, request.query);
  if (parts.size() == 3 && parts[1] == "tiles") return TileBytes(robot, parts[2], request.query);
  if (parts.size() == 2 && parts[1] == "trajectory") return Trajectory(robot, request.query);
  return Error(404, absl::StrCat("no API path ", path.substr(0, 200)));
}

HttpResponse HttpApi::Sessions() const {
  json list = json::array();
  for (const auto& session : sessions_->List()) list.push_back(SessionJson(*session));
  return Json(200, json{{"server_version", kRimVersion}, {"sessions", std::move(list)}});
}

// The dashboard reads the sessions open on this replica (Find): a look at a saved session never
// opens it here, even with --shared-sessions.
HttpResponse HttpApi::SessionEntry(const std::string& robot) const {
  auto session = sessions_->Find(robot);
  if (!session.ok()) return FromStatus(session.status());
  return Json(200, SessionJson(**session));
}

HttpResponse HttpApi::Tiles(const std::string& robot, const std::string& query) const {
  auto since = SinceParam(query, "map version");
  if (!since.ok()) return FromStatus(since.status());
  auto session = sessions_->Find(robot);
  if (!session.ok()) return FromStatus(session.status());
  Session& s = **session;
  auto level = ResolutionParam(query, s.mapper());
  if (!level.ok()) return FromStatus(level.status());
  // A coarser level's URLs name it; the finest's stay as they were.
  const std::string level_param =
      *level == s.mapper().MeshLevels().front() ? "" : absl::StrCat("&resolution_m=", *level);
  const uint64_t map_version = s.mapper().map_version();
  // Oldest versions first, a whole version at a time, until the budget is spent: a listing of a
  // large map that changed everywhere answers in about kListBudgetSeconds, and `next_since`
  // tells the caller where to go on (every tile at or below it has been listed).
  std::vector<TileInfo> listed = s.mapper().ListTiles(*since);
  std::stable_sort(listed.begin(), listed.end(),
                   [](const TileInfo& a, const TileInfo& b) { return a.version < b.version; });
  const auto start = std::chrono::steady_clock::now();
  uint64_t next_since = *since;
  bool complete = true;
  json tiles = json::array();
  for (size_t i = 0; i < listed.size();) {
    if (i > 0 && std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >
                     kListBudgetSeconds) {
      complete = false;
      break;
    }
    const uint64_t group = listed[i].version;
    for (; i < listed.size() && listed[i].version == group; ++i) {
      const TileInfo& tile = listed[i];
      // Meshed and encoded now unless cached at this version: the counts are those of the bytes
      // that the tile's URL serves.
      auto encoded = s.tiles().Get(s.mapper(), tile, *level);
      if (!encoded.ok()) return FromStatus(encoded.status());
      const uint64_t version = (*encoded)->version;
      tiles.push_back({{"key", json::array({tile.key.x(), tile.key.y(), tile.key.z()})},
                       {"version", version},
                       {"bounds", {{"min", Vec(tile.min_m)}, {"max", Vec(tile.max_m)}}},
                       {"vertex_count", (*encoded)->vertex_count},
                       {"face_count", (*encoded)->face_count},
                       {"bytes", (*encoded)->draco.size()},
                       {"url", absl::StrCat(kApiPrefix, "/", robot, "/tiles/", TileName(tile.key),
                                            ".drc?v=", version, level_param)}});
    }
    next_since = group;
  }
  return Json(200, json{{"robot_id", robot},
                        {"map_version", map_version},
                        {"resolution_m", *level},
                        {"tiles", tiles},
                        {"complete", complete},
                        {"next_since", next_since}});
}

HttpResponse HttpApi::TileBytes(const std::string& robot, const std::string& name,
                                const std::string& query) const {
  Int3 key;
  if (!ParseTileName(name, &key))
    return Error(404, absl::StrCat("no tile '", name.substr(0, 80),
                                   "': a tile is named KX_KY_KZ.drc by its sub-map key"));
  auto session = sessions_->Find(robot);
  if (!session.ok()) return FromStatus(session.status());
  Session& s = **session;
  auto level = ResolutionParam(query, s.mapper());
  if (!level.ok()) return FromStatus(level.status());
  for (const TileInfo& tile : s.mapper().ListTiles(0)) {
    if (tile.key != key) continue;
    auto encoded = s.tiles().Get(s.mapper(), tile, *level);
    if (!encoded.ok()) return FromStatus(encoded.status());
    HttpResponse r;
    r.content_type = "application/octet-stream";
    r.body = (*encoded)->draco;
    r.headers.emplace_back("Cache-Control", "no-store");
    r.headers.emplace_back("X-Rim-Tile-Version", std::to_string((*encoded)->version));
    return r;
  }
  return Error(404, absl::StrCat("session '", robot, "' has no tile ", TileName(key)));
}

HttpResponse HttpApi::Trajectory(const std::string& robot, const std::string& query) const {
  auto since = SinceParam(query, "frame index");
  if (!since.ok()) return FromStatus(since.status());
  auto session = sessions_->Find(robot);
  if (!session.ok()) return FromStatus(session.status());
  uint64_t next = 0;
  json positions = json::array();
  for (const TrajectoryPoint& p : (*session)->Trajectory(*since, &next))
    positions.push_back(json::array({p.position.x(), p.position.y(), p.position.z()}));
  return Json(200, json{{"robot_id", robot}, {"positions", positions}, {"next", next}});
}

namespace {

// civetweb's begin_request callback: every request is answered here (no document_root is set, so
// civetweb itself serves nothing).
int OnRequest(mg_connection* conn) {
  const auto* api = static_cast<const HttpServer*>(mg_get_user_data(mg_get_context(conn)))->api();
  const mg_request_info* info = mg_get_request_info(conn);
  HttpRequest request;
  request.method = info->request_method ? info->request_method : "";
  request.path = info->local_uri ? info->local_uri : "/";
  request.query = info->query_string ? info->query_string : "";
  const char* authorization = mg_get_header(conn, "Authorization");
  std::string auth_value;
  if (authorization != nullptr) {
    auth_value = authorization;
    request.authorization = &auth_value;
  }
  HttpResponse r = api->Handle(request);
  std::string head =
      absl::StrCat("HTTP/1.1 ", r.status, " ", mg_get_response_code_text(conn, r.status),
                   "\r\nContent-Type: ", r.content_type, "\r\nContent-Length: ", r.body.size(),
                   "\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n");
  for (const auto& [name, value] : r.headers) absl::StrAppend(&head, name, ": ", value, "\r\n");
  head += "\r\n";
  mg_write(conn, head.data(), head.size());
  if (request.method != "HEAD" && !r.body.empty()) mg_write(conn, r.body.data(), r.body.size());
  return r.status;
}

// civetweb's init_thread callback: names its request workers and moves them to the background.
void* OnThreadStart(const mg_context* ctx, int thread_type) {
  if (thread_type == 1) {  // a request worker
    NameThisThread("rim-http");
    LowerThisThreadPriority(static_cast<const HttpServer*>(mg_get_user_data(ctx))->worker_nice());
  }
  return nullptr;
}

}  // namespace

absl::StatusOr<std::unique_ptr<HttpServer>> HttpServer::Start(const std::string& address,
                                                              std::unique_ptr<HttpApi> api,
                                                              int worker_nice) {
  mg_init_library(0);
  std::unique_ptr<HttpServer> server(new HttpServer());
  server->api_ = std::move(api);
  server->worker_nice_ = worker_nice;
  // Own worker threads (a slow client holds one for at most request_timeout_ms); one request per
  // connection, so an idle browser connection never keeps a worker.
  const char* options[] = {"listening_ports",
                           address.c_str(),
                           "num_threads",
                           "16",
                           "request_timeout_ms",
                           "10000",
                           "enable_keep_alive",
                           "no",
                           "max_request_size",
                           "16384",
                           nullptr};
  mg_callbacks callbacks = {};
  callbacks.begin_request = OnRequest;
  callbacks.init_thread = OnThreadStart;
  server->ctx_ = mg_start(&callbacks, server.get(), options);
  if (server->ctx_ == nullptr) {
    mg_exit_library();
    return absl::UnavailableError(
        absl::StrCat("--http: cannot listen on '", address, "' (host:port, numeric host)"));
  }
  mg_server_port ports[4] = {};
  const int n = mg_get_server_ports(server->ctx_, 4, ports);
  if (n >= 1) server->port_ = ports[0].port;
  return server;
}

HttpServer::~HttpServer() {
  if (ctx_ != nullptr) {
    mg_stop(ctx_);
    mg_exit_library();
  }
}

std::string DefaultWebRoot() {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return "";
  const fs::path dir = exe.parent_path();
  for (const fs::path& candidate :
       {dir.parent_path() / "web", dir.parent_path() / "share/rim/web"}) {
    if (fs::is_regular_file(candidate / "index.html", ec)) return candidate.string();
  }
  return "";
}

}  // namespace rim::server
