// rim's C++ client library: a small typed wrapper over the rim.v1 gRPC stubs (DESIGN.md §5.1).
//
//   auto client = rim::Client::Connect("127.0.0.1:50051");
//   client->CreateSession("robot_1", "maicity", {{"train.iterations", "10"}});
//   rim::SessionHandle session = client->Session("robot_1");
//   auto summary = session.Stream(scans);           // waits for every INTEGRATED ack
//   auto sdf = session.Query(points, /*want_gradient=*/true);
//   auto tiles = session.MeshTiles(/*since_version=*/0);
//
// Every call returns absl::Status / absl::StatusOr with the server's gRPC code and message (the
// codes of rim.proto: INVALID_ARGUMENT names the field, NOT_FOUND an unknown session, ...). A
// server that cannot be reached gives UNAVAILABLE with "cannot reach rim_server at ADDR: ...".
//
// Every call carries `authorization: Bearer <token>` when a token is set, and every call about one
// session carries `x-robot-id: <robot id>`, the header a proxy in front of several servers routes
// by (DESIGN.md §6). A Client and its SessionHandles share one channel; they are cheap to copy and
// safe to use from several threads at once.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/tiles.h"
#include "rim/base/scan.h"
#include "rim/base/types.h"
#include "rim/v1/rim.pb.h"

namespace rim {

struct ClientOptions {
  // Sent as `authorization: Bearer <token>` on every call when not empty.
  std::string token;
  // Deadline of each unary call and of each query (a chunked query gets it per chunk).
  std::chrono::milliseconds deadline{30'000};
  // Deadline of GetMeshTiles, which meshes every changed sub-map before it answers.
  std::chrono::milliseconds mesh_deadline{300'000};
  // How long Connect waits for the channel to come up.
  std::chrono::milliseconds connect_timeout{10'000};
  // TLS (docs/security.md): on when any of these is set. tls_ca_file: PEM certificates that sign
  // the server's (empty: the system's roots). tls_cert_file and tls_key_file, together: this
  // client's certificate and key, for a server that requires client certificates (mTLS).
  std::string tls_ca_file;
  std::string tls_cert_file;
  std::string tls_key_file;
};

// Health of the server (or of one service) as the standard grpc.health.v1 check reports it.
enum class ServingStatus { kUnknown, kServing, kNotServing, kServiceUnknown };
const char* ServingStatusName(ServingStatus status);

namespace client_internal {
class Connection;
}

// One Scan stream's outcome.
struct StreamSummary {
  struct Rejection {
    uint64_t sequence = 0;
    int code = 0;  // gRPC status code of the rejection
    std::string reason;
  };
  uint64_t sent = 0;
  uint64_t accepted = 0;
  uint64_t integrated = 0;
  uint64_t rejected = 0;  // rejected on arrival, or accepted and then failed in training
  std::vector<Rejection> rejections;
  uint64_t map_version = 0;  // the newest map version an ack reported
  double seconds = 0;        // from the first write to the last ack
  int retries = 0;           // streams opened again after a break (StreamOptions::max_retries)
  uint64_t duplicates = 0;   // resent scans the server had accepted before
};

struct StreamOptions {
  // At most this many scans per second (a recorded sequence replayed in real time); 0: as fast as
  // the server reads them (its flow control paces the stream when training lags).
  double rate_hz = 0;
  // Whether the scans come at a sensor's rate, as the sensor makes them: the stream then sends the
  // `x-rim-real-time: 1` header, and the session trains what keeps up with that rate (while the
  // scans' timestamps keep to it) instead of training every frame fully and holding the stream
  // back when its queue is full (docs/service.md, "Replays keep the offline map"). Unset: true
  // when rate_hz > 0. Set it for a live source that paces itself (a sensor driver feeding
  // `source`), or to false to replay a recording at its rate and still train every frame fully.
  std::optional<bool> real_time;
  // Sequence number of the first scan; the stream numbers scans consecutively from it.
  uint64_t first_sequence = 0;
  // Called for every ack (ACCEPTED, INTEGRATED, REJECTED) on the stream's reader thread.
  std::function<void(const rim::v1::ScanAck&)> on_ack;
  // Called after each scan is written, with the number written so far (writer thread).
  std::function<void(uint64_t sent)> on_sent;
  // When the stream breaks (UNAVAILABLE, CANCELLED, INTERNAL, UNKNOWN or ABORTED: the server,
  // the proxy or the connection went away), open a new stream, up to this many times,
  // `retry_backoff` apart, and send again every scan without its final ack, marked Scan.resend: the
  // server acknowledges the ones it had accepted (durable) without taking them twice, so nothing is
  // lost or doubled. Behind a proxy the new stream may reach another replica, which takes the
  // session over. Needs scan sequences that increase across the robot's streams. 0: no retries.
  int max_retries = 0;
  std::chrono::milliseconds retry_backoff{1000};
  // With retries: a stream that is still being opened, or has scans without their final ack, and
  // has had no ack at all for this long, is taken for broken: it is cancelled and retried like one
  // that broke. A replica killed behind a proxy can leave the client's stream open with nothing
  // coming back (seen with HAProxy in tests/e2e/scale_e2e.py). 0: wait as long as the stream stays
  // open.
  std::chrono::milliseconds stall_timeout{30000};
  // Called before each retry with its number (1, 2, ...) and why the stream before it ended.
  std::function<void(int retry, const absl::Status& why)> on_retry;
  // Called (on a watchdog thread) when a stream cancelled for its stall has still not ended one
  // stall_timeout later. gRPC 1.51 can leave a call blocked for good, cancelled or not, when a
  // proxy answers it with a response of another protocol (an HTML error page; docs/clients.md),
  // and Stream cannot return while the call blocks it: a program that must not hang exits here
  // (rimctl does, with exit code 3). Unset: Stream waits.
  std::function<void()> on_stuck;
};

// Fills *scan with the next scan to send and returns true, or returns false at the end. The
// stream sets robot_id and sequence. An error ends the stream (scans already sent are still
// integrated and acknowledged) and becomes Stream's result.
using ScanSource = std::function<absl::StatusOr<bool>(rim::v1::Scan* scan)>;

struct QueryResult {
  // One per point, metres: the signed Euclidean distance to the nearest mapped surface, bounded
  // by the session's query.max_distance_m (see `saturated`).
  std::vector<float> sdf;
  std::vector<float> gradient;    // three per point when asked for (unit length), else empty
  std::vector<uint8_t> observed;  // one per point: 1 observed, 0 an extrapolation
  // One per point: 1 when no surface lies within query.max_distance_m (sdf is then that bound:
  // "at least this far"). Empty from a server that does not send it.
  std::vector<uint8_t> saturated;
  // The map version that answered; for a batch answered in chunks, the oldest of their versions
  // (training may move the map between chunks).
  uint64_t map_version = 0;
  double server_seconds = 0;  // summed over chunks
};

struct Box3d {
  std::array<double, 3> min = {0, 0, 0};
  std::array<double, 3> max = {0, 0, 0};
};

struct WatchOptions {
  uint64_t since_version = 0;
  // Stop after this long (returning OK); 0: until the callback returns false or the session ends.
  std::chrono::milliseconds duration{0};
  // Level of detail (mesh cell size, metres): one of SessionInfo.mesh_levels_m; 0 the finest.
  float resolution_m = 0;
};

// The calls about one session. Obtained from Client::Session; copies share the connection.
class SessionHandle {
 public:
  const std::string& robot_id() const { return robot_id_; }

  absl::StatusOr<rim::v1::SessionInfo> Info() const;

  // Streams scans over one StreamScans call and returns once every sent scan has its final ack
  // (INTEGRATED or REJECTED). A rejected scan does not end the stream; it is counted and listed
  // in the summary. Errors: the source's error, or the stream's gRPC status.
  absl::StatusOr<StreamSummary> Stream(const ScanSource& next,
                                       const StreamOptions& options = {}) const;
  absl::StatusOr<StreamSummary> Stream(const std::vector<PosedScan>& scans,
                                       const StreamOptions& options = {}) const;

  // Signed distances (and gradients) at world-frame points. Batches over the server's
  // max_query_points (from GetServerInfo, asked once per Client) go over StreamQuerySdf in chunks
  // of that size; the answer is the same as for one call.
  absl::StatusOr<QueryResult> Query(const std::vector<Vec3f>& points_W,
                                    bool want_gradient = false) const;

  // Every tile newer than since_version (only those meeting `region` when given), decoded, at
  // level of detail `resolution_m` (one of SessionInfo.mesh_levels_m; 0 the finest).
  absl::StatusOr<std::vector<DecodedTile>> MeshTiles(
      uint64_t since_version = 0, const std::optional<Box3d>& region = std::nullopt,
      float resolution_m = 0) const;

  // Calls on_tile for each tile as training changes it, until on_tile returns false, the
  // duration passes (both OK) or the stream fails (its status; NOT_FOUND for an unknown session,
  // DataLoss for a tile that does not decode).
  absl::Status Watch(const std::function<bool(const DecodedTile&)>& on_tile,
                     const WatchOptions& options = {}) const;

 private:
  friend class Client;
  SessionHandle(std::shared_ptr<client_internal::Connection> connection, std::string robot_id)
      : connection_(std::move(connection)), robot_id_(std::move(robot_id)) {}

  std::shared_ptr<client_internal::Connection> connection_;
  std::string robot_id_;
};

class Client {
 public:
  // Opens a channel to `address` (host:port) and waits up to options.connect_timeout for it.
  // UNAVAILABLE "cannot reach rim_server at ADDR: ..." when it does not come up (a failed TLS
  // handshake looks the same); NOT_FOUND or INVALID_ARGUMENT for unreadable or unpaired TLS files.
  static absl::StatusOr<Client> Connect(const std::string& address, ClientOptions options = {});

  const std::string& address() const;

  absl::StatusOr<rim::v1::ServerInfo> Info() const;
  // Sessions by robot id. `overrides` are dotted config keys and values ("train.iterations", "10").
  absl::StatusOr<rim::v1::SessionInfo> CreateSession(
      const std::string& robot_id, const std::string& preset = "",
      const std::vector<std::pair<std::string, std::string>>& overrides = {}) const;
  absl::StatusOr<rim::v1::SessionInfo> GetSession(const std::string& robot_id) const;
  absl::StatusOr<std::vector<rim::v1::SessionInfo>> ListSessions() const;
  absl::StatusOr<rim::v1::SaveSessionResponse> SaveSession(const std::string& robot_id) const;
  absl::StatusOr<rim::v1::SessionInfo> LoadSession(const std::string& robot_id) const;
  absl::Status CloseSession(const std::string& robot_id, bool save) const;

  // The standard health check (grpc.health.v1.Health/Check); "" asks about the whole server.
  // A service the server does not know is kServiceUnknown, not an error.
  absl::StatusOr<ServingStatus> Health(const std::string& service = "") const;

  SessionHandle Session(const std::string& robot_id) const {
    return SessionHandle(connection_, robot_id);
  }

 private:
  explicit Client(std::shared_ptr<client_internal::Connection> connection)
      : connection_(std::move(connection)) {}

  std::shared_ptr<client_internal::Connection> connection_;
};

}  // namespace rim
