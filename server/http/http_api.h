// rim_server --http: the browser dashboard's static files and a small read-only JSON API over
// the sessions (docs/dashboard.md), served by civetweb on its own threads, so that a slow or
// oversized HTTP request never holds up gRPC serving.
//
//   GET /                                           the dashboard (files of --web-root)
//   GET /api/v1/sessions                            one entry per session
//   GET /api/v1/sessions/{robot}                    one session's entry
//   GET /api/v1/sessions/{robot}/tiles?since=V      tiles whose version is newer than V
//   GET /api/v1/sessions/{robot}/tiles/{x}_{y}_{z}.drc   the cached Draco bytes of one tile
//   GET /api/v1/sessions/{robot}/trajectory?since=N sensor positions of frames N, N+1, ...
//
// With --tokens every /api/ request needs `Authorization: Bearer TOKEN` of a role that may read
// (as GetSession, ListSessions and GetMeshTiles on gRPC); the static files are open, since they
// hold no map data. Errors are JSON `{"error": {"code": C, "message": "..."}}` with status C.
#pragma once

#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "server/auth/auth.h"
#include "server/session/session_manager.h"

struct mg_context;

namespace rim::server {

struct HttpRequest {
  std::string method;                          // GET, HEAD, ...
  std::string path;                            // percent-decoded, without the query
  std::string query;                           // raw, without '?'
  const std::string* authorization = nullptr;  // the header's value; null: absent
};

struct HttpResponse {
  int status = 200;
  std::string content_type;
  std::string body;
  std::vector<std::pair<std::string, std::string>> headers;  // extra headers
};

// The dashboard's files, read into memory once: only these paths are ever served, so no request
// path can reach another file. FAILED_PRECONDITION when `dir` has no index.html; RESOURCE_EXHAUSTED
// past 64 MiB in all.
class StaticFiles {
 public:
  static absl::StatusOr<StaticFiles> Load(const std::string& dir);
  // The file at a request path ("/" is "/index.html"); null when there is none.
  const std::pair<std::string, std::string>* Find(const std::string& path) const;
  size_t count() const { return files_.size(); }

 private:
  std::map<std::string, std::pair<std::string, std::string>> files_;  // path -> (type, bytes)
};

class HttpApi {
 public:
  HttpApi(SessionManager* sessions, const Authorizer* auth, StaticFiles files);
  // Answers one request (civetweb's threads call this; so do tests, without a socket).
  HttpResponse Handle(const HttpRequest& request) const;

 private:
  HttpResponse Sessions() const;
  HttpResponse SessionEntry(const std::string& robot) const;
  HttpResponse Tiles(const std::string& robot, const std::string& query) const;
  HttpResponse TileBytes(const std::string& robot, const std::string& name,
                         const std::string& query) const;
  HttpResponse Trajectory(const std::string& robot, const std::string& query) const;

  SessionManager* const sessions_;
  const Authorizer* const auth_;
  const StaticFiles files_;
};

class HttpServer {
 public:
  // Listens on `address` (host:port with a numeric host; port 0 picks a free one). The worker
  // threads (named rim-http) run at nice `worker_nice`: everything they do (tile listings that
  // mesh, tile bytes, session summaries) is dashboard work, background to queries
  // (docs/service.md, "Sharing the cores").
  static absl::StatusOr<std::unique_ptr<HttpServer>> Start(const std::string& address,
                                                           std::unique_ptr<HttpApi> api,
                                                           int worker_nice = 0);
  ~HttpServer();  // stops: waits for requests in progress
  int port() const { return port_; }
  const HttpApi* api() const { return api_.get(); }
  int worker_nice() const { return worker_nice_; }

 private:
  HttpServer() = default;
  std::unique_ptr<HttpApi> api_;
  int worker_nice_ = 0;
  mg_context* ctx_ = nullptr;
  int port_ = 0;
};

// The dashboard's folder when --web-root is not given: web/ beside the binary's folder (the build
// tree) or ../share/rim/web (an installed binary); empty when neither has an index.html.
std::string DefaultWebRoot();

}  // namespace rim::server
