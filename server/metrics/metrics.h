// The service's Prometheus metrics (DESIGN.md §5.4; every family is listed in docs/metrics.md).
//
// Three sources feed one registry:
// - events (SessionEvents hooks, called by sessions and handlers): counters and histograms;
// - a collector that reads the open sessions at scrape time: gauges such as queue depth, lag,
//   sub-maps by state and memory, so that they are never stale and cost nothing between scrapes;
// - a gRPC server interceptor: requests by method and status code, and their durations.
// Serve() exposes them over HTTP on --metrics.
#pragma once

#include <grpcpp/support/server_interceptor.h>

#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "server/session/session_events.h"

namespace prometheus {
class Exposer;
class Registry;
}  // namespace prometheus

namespace rim::server {

class SessionManager;

class ServerMetrics : public SessionEvents {
 public:
  // `host_memory_budget_bytes` is reported as a gauge (0: no budget).
  explicit ServerMetrics(uint64_t host_memory_budget_bytes);
  ~ServerMetrics() override;

  // Scrape-time gauges read these sessions; call once, before Serve().
  void WatchSessions(const SessionManager* sessions);
  // Starts the HTTP exposer on `address` (host:port; port 0 picks one) and returns the bound
  // port. INVALID_ARGUMENT for an address it cannot bind.
  absl::StatusOr<int> Serve(const std::string& address);
  // Stops the HTTP exposer and waits for a scrape in progress. Call it before the watched
  // SessionManager is destroyed: a scrape reads it.
  void StopServing();
  // Interceptor factories counting every RPC, for ServerBuilder::experimental().
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>>
  InterceptorFactories();
  // The exposition text of every family, as a scrape would see it (for tests and debugging).
  std::string Text() const;

  void ScanAccepted(const std::string& robot) override;
  void ScanRejected(const std::string& robot, absl::StatusCode code) override;
  void FrameIntegrated(const std::string& robot, const StageTimings& timing) override;
  void FrameFailed(const std::string& robot) override;
  void TrainedBetweenFrames(const std::string& robot, const StageTimings& timing) override;
  void DistanceRefreshed(const std::string& robot, double seconds) override;
  void WalAppended(const std::string& robot, double seconds) override;
  void CheckpointWritten(const std::string& robot, double seconds, uint64_t bytes) override;
  void TileEncoded(const std::string& robot, size_t bytes, double seconds,
                   int blocks_remeshed) override;
  void WatchMeshed(const std::string& robot, double cpu_seconds,
                   double budget_wait_seconds) override;
  void TilePushed(const std::string& robot, double delay_seconds) override;
  void QueryAnswered(const std::string& robot, size_t points, double seconds) override;

  // Called by the interceptor when an RPC ends; `method` is the full gRPC method path.
  void RpcFinished(const std::string& method, int code, double seconds);

 private:
  struct Families;
  class SessionCollector;
  std::shared_ptr<prometheus::Registry> registry_;
  std::unique_ptr<Families> families_;
  std::shared_ptr<SessionCollector> collector_;
  std::unique_ptr<prometheus::Exposer> exposer_;
};

// "rim.v1.Rim/CreateSession" -> "CreateSession"; other services keep "package.Service/Method".
std::string MetricMethodName(const std::string& grpc_method_path);
// The gRPC code name used as a label value ("OK", "INVALID_ARGUMENT", ...).
std::string GrpcCodeName(int code);

}  // namespace rim::server
