#include "server/metrics/metrics.h"

#include <grpcpp/grpcpp.h>
#include <prometheus/collectable.h>
#include <prometheus/counter.h>
#include <prometheus/exposer.h>
#include <prometheus/family.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <exception>

#include "absl/strings/str_cat.h"
#include "rim/base/version.h"
#include "rim/gpu/device_map.h"
#include "rim/mesh/mesher.h"
#include "server/session/session_manager.h"

namespace rim::server {
namespace {

using prometheus::Histogram;

// Bucket bounds in seconds, each spanning the range its quantity takes on CPU and GPU builds.
const Histogram::BucketBoundaries kFrameBuckets{0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 30};
const Histogram::BucketBoundaries kStageBuckets{0.0005, 0.001, 0.003, 0.01, 0.03,
                                                0.1,    0.3,   1,     3,    10};
const Histogram::BucketBoundaries kQueryBuckets{0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025,
                                                0.05,   0.1,   0.25,   0.5,   1,    2.5};
const Histogram::BucketBoundaries kRefreshBuckets{0.01, 0.03, 0.1, 0.2, 0.3, 0.5, 1, 3, 10};
const Histogram::BucketBoundaries kMeshBuckets{0.005, 0.01, 0.03, 0.1, 0.3, 1, 3, 10};
const Histogram::BucketBoundaries kPushDelayBuckets{0.1, 0.25, 0.5, 1, 1.5, 2, 3, 5, 10, 30};
const Histogram::BucketBoundaries kCheckpointBuckets{0.01, 0.03, 0.1, 0.3, 1, 3, 10, 30, 100};
const Histogram::BucketBoundaries kWalBuckets{0.0001, 0.0003, 0.001, 0.003, 0.01, 0.03, 0.1, 0.3};
const Histogram::BucketBoundaries kRpcBuckets{0.001, 0.005, 0.01, 0.05, 0.1, 0.5,
                                              1,     5,     10,   60,   300, 3600};

std::string RejectReason(absl::StatusCode code) {
  switch (code) {
    case absl::StatusCode::kInvalidArgument:
      return "invalid_argument";
    case absl::StatusCode::kResourceExhausted:
      return "resource_exhausted";
    case absl::StatusCode::kFailedPrecondition:
      return "failed_precondition";
    default:
      return "other";
  }
}

uint64_t ResidentBytes() {
  FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long size = 0, resident = 0;
  const int n = std::fscanf(f, "%lu %lu", &size, &resident);
  std::fclose(f);
  return n == 2 ? uint64_t(resident) * uint64_t(sysconf(_SC_PAGESIZE)) : 0;
}

// A family read from the sessions when Prometheus scrapes: gauges, or counters whose values the
// sessions keep.
prometheus::MetricFamily CollectedFamily(const std::string& name, const std::string& help,
                                         prometheus::MetricType type) {
  prometheus::MetricFamily f;
  f.name = name;
  f.help = help;
  f.type = type;
  return f;
}

prometheus::MetricFamily GaugeFamily(const std::string& name, const std::string& help) {
  return CollectedFamily(name, help, prometheus::MetricType::Gauge);
}

void AddValue(prometheus::MetricFamily* f, std::vector<prometheus::ClientMetric::Label> labels,
              double value) {
  prometheus::ClientMetric m;
  m.label = std::move(labels);
  if (f->type == prometheus::MetricType::Counter) {
    m.counter.value = value;
  } else {
    m.gauge.value = value;
  }
  f->metric.push_back(std::move(m));
}

void AddGauge(prometheus::MetricFamily* f, std::vector<prometheus::ClientMetric::Label> labels,
              double value) {
  AddValue(f, std::move(labels), value);
}

}  // namespace

// Event-driven families, registered once.
struct ServerMetrics::Families {
  explicit Families(prometheus::Registry& r)
      : accepted(prometheus::BuildCounter()
                     .Name("rim_scans_accepted_total")
                     .Help("Scans validated and written to the write-ahead log (ACCEPTED acks)")
                     .Register(r)),
        rejected(prometheus::BuildCounter()
                     .Name("rim_scans_rejected_total")
                     .Help("Scans answered with a REJECTED ack, by cause")
                     .Register(r)),
        integrated(prometheus::BuildCounter()
                       .Name("rim_scans_integrated_total")
                       .Help("Scans trained into the map (INTEGRATED acks)")
                       .Register(r)),
        frame(prometheus::BuildHistogram()
                  .Name("rim_frame_integration_seconds")
                  .Help("Time to integrate one frame: slide, preprocess, train, and the distance "
                        "field's refresh when the frame had one")
                  .Register(r)),
        stage(prometheus::BuildHistogram()
                  .Name("rim_training_stage_seconds")
                  .Help("Time one frame spent in a stage, summed over its iterations")
                  .Register(r)),
        between_iterations(prometheus::BuildCounter()
                               .Name("rim_between_frames_iterations_total")
                               .Help("Training iterations run between frames, while a robot "
                                     "streaming in real time had not sent its next scan")
                               .Register(r)),
        between_rays(prometheus::BuildCounter()
                         .Name("rim_between_frames_rays_total")
                         .Help("Rays those iterations trained on")
                         .Register(r)),
        between_seconds(prometheus::BuildCounter()
                            .Name("rim_between_frames_training_seconds_total")
                            .Help("Wall time of those iterations")
                            .Register(r)),
        refresh(prometheus::BuildHistogram()
                    .Name("rim_distance_refresh_seconds")
                    .Help("Time of one refresh of a session's distance field (surfel extraction, "
                          "normal fits, search trees)")
                    .Register(r)),
        query_points(prometheus::BuildCounter()
                         .Name("rim_query_points_total")
                         .Help("Points answered by QuerySdf and StreamQuerySdf")
                         .Register(r)),
        query_latency(prometheus::BuildHistogram()
                          .Name("rim_query_latency_seconds")
                          .Help("Server time to answer one query message")
                          .Register(r)),
        tiles(prometheus::BuildCounter()
                  .Name("rim_mesh_tiles_encoded_total")
                  .Help("Mesh tiles meshed and Draco-encoded (tile cache misses)")
                  .Register(r)),
        tile_bytes(prometheus::BuildCounter()
                       .Name("rim_mesh_tile_bytes_total")
                       .Help("Draco bytes produced by tile encodings")
                       .Register(r)),
        meshing(prometheus::BuildHistogram()
                    .Name("rim_meshing_seconds")
                    .Help("Meshing plus Draco encoding of one tile")
                    .Register(r)),
        blocks_remeshed(prometheus::BuildCounter()
                            .Name("rim_mesh_blocks_remeshed_total")
                            .Help("Mesh blocks meshed anew for tile encodings (the others were "
                                  "reused from the mesh block cache)")
                            .Register(r)),
        watch_cpu(prometheus::BuildCounter()
                      .Name("rim_meshing_cpu_seconds_total")
                      .Help("CPU time watchers spent meshing and encoding tiles (what the "
                            "meshing budget is charged)")
                      .Register(r)),
        watch_budget_wait(prometheus::BuildCounter()
                              .Name("rim_meshing_budget_wait_seconds_total")
                              .Help("Time watchers waited for the server's meshing budget "
                                    "(--meshing-cores) before meshing a tile")
                              .Register(r)),
        push_delay(prometheus::BuildHistogram()
                       .Name("rim_mesh_tile_push_delay_seconds")
                       .Help("From the integration of the frame that made a tile version to "
                             "its push to a watcher")
                       .Register(r)),
        checkpoint(prometheus::BuildHistogram()
                       .Name("rim_checkpoint_seconds")
                       .Help("Time to write one checkpoint")
                       .Register(r)),
        wal(prometheus::BuildHistogram()
                .Name("rim_wal_append_seconds")
                .Help("Time to append and fdatasync one scan to the write-ahead log")
                .Register(r)),
        requests(prometheus::BuildCounter()
                     .Name("rim_grpc_requests_total")
                     .Help("Finished RPCs by method and gRPC status code")
                     .Register(r)),
        request_seconds(prometheus::BuildHistogram()
                            .Name("rim_grpc_request_seconds")
                            .Help("RPC duration from start to final status (long for streams)")
                            .Register(r)) {}

  prometheus::Family<prometheus::Counter>& accepted;
  prometheus::Family<prometheus::Counter>& rejected;
  prometheus::Family<prometheus::Counter>& integrated;
  prometheus::Family<Histogram>& frame;
  prometheus::Family<Histogram>& stage;
  prometheus::Family<prometheus::Counter>& between_iterations;
  prometheus::Family<prometheus::Counter>& between_rays;
  prometheus::Family<prometheus::Counter>& between_seconds;
  prometheus::Family<Histogram>& refresh;
  prometheus::Family<prometheus::Counter>& query_points;
  prometheus::Family<Histogram>& query_latency;
  prometheus::Family<prometheus::Counter>& tiles;
  prometheus::Family<prometheus::Counter>& tile_bytes;
  prometheus::Family<Histogram>& meshing;
  prometheus::Family<prometheus::Counter>& blocks_remeshed;
  prometheus::Family<prometheus::Counter>& watch_cpu;
  prometheus::Family<prometheus::Counter>& watch_budget_wait;
  prometheus::Family<Histogram>& push_delay;
  prometheus::Family<Histogram>& checkpoint;
  prometheus::Family<Histogram>& wal;
  prometheus::Family<prometheus::Counter>& requests;
  prometheus::Family<Histogram>& request_seconds;
};

// Gauges read from the sessions when Prometheus scrapes.
class ServerMetrics::SessionCollector : public prometheus::Collectable {
 public:
  explicit SessionCollector(uint64_t budget) : budget_(budget) {}
  void Watch(const SessionManager* sessions) { sessions_ = sessions; }

  std::vector<prometheus::MetricFamily> Collect() const override {
    auto build = GaugeFamily("rim_build_info", "Always 1; the labels say what is running");
    AddGauge(&build,
             {{"version", kRimVersion},
              {"build", gpu::BuiltWithCuda() ? "cuda" : "cpu"},
              {"libtorch", TorchVersion()}},
             1);
    auto active = GaugeFamily("rim_sessions_active", "Sessions currently open");
    auto queue = GaugeFamily("rim_ingest_queue_depth", "Accepted scans waiting for the trainer");
    auto lag = GaugeFamily("rim_training_lag_frames", "Accepted minus integrated scans");
    auto iterations =
        GaugeFamily("rim_iterations_per_frame", "Training iterations used for the last frame");
    auto rays =
        GaugeFamily("rim_rays_per_iteration", "Rays in each training batch of the last frame");
    auto loss = GaugeFamily("rim_training_loss", "Training loss of the last frame");
    auto real_time = GaugeFamily("rim_session_real_time",
                                 "1: iterations keep up with a real-time stream's sensor clock; "
                                 "0: a replay or upload, full iterations and backpressure");
    auto submaps = GaugeFamily("rim_submaps", "Sub-maps of the global map, by state");
    auto memory = GaugeFamily("rim_session_host_memory_bytes",
                              "Host memory held by one session's maps and buffers");
    auto checkpoint = GaugeFamily("rim_checkpoint_bytes", "Size of the session's last checkpoint");
    auto wal = GaugeFamily("rim_wal_bytes", "Size of the session's write-ahead log on disk");
    auto transient = CollectedFamily(
        "rim_transient_points_removed_total",
        "Returns dropped because later rays passed clearly through them (moving things), by store",
        prometheus::MetricType::Counter);
    auto checked = CollectedFamily(
        "rim_mesh_blocks_checked_total",
        "Cached mesh blocks that a map change reached, whose SDF at the mesh grid was evaluated "
        "again and compared with the values they were meshed from",
        prometheus::MetricType::Counter);
    auto skipped = CollectedFamily(
        "rim_mesh_blocks_skipped_total",
        "Of the checked mesh blocks, those kept without re-meshing: no SDF value moved by more "
        "than mesh.remesh_tolerance_m",
        prometheus::MetricType::Counter);
    auto skipped_share = GaugeFamily(
        "rim_mesh_blocks_skipped_share",
        "Share of the checked mesh blocks kept without re-meshing, since the session started");
    auto session_device =
        GaugeFamily("rim_session_device_info",
                    "Always 1; the label says where the session trains: cpu, or the GPU's name");
    double sessions = 0, device_bytes = 0;
    if (sessions_ != nullptr) {
      for (const auto& session : sessions_->List()) {
        ++sessions;
        const SessionStats s = session->Stats();
        const MapperStats m = session->mapper().Stats();
        const std::vector<prometheus::ClientMetric::Label> id{{"session", session->robot_id()}};
        AddGauge(&queue, id, double(s.queue_depth));
        AddGauge(&lag, id, double(s.accepted - s.integrated - s.failed));
        AddGauge(&iterations, id, s.iterations_per_frame);
        AddGauge(&rays, id, s.rays_per_iteration);
        AddGauge(&loss, id, s.last_loss);
        AddGauge(&real_time, id, s.real_time ? 1 : 0);
        AddGauge(&session_device, {id[0], {"device", m.device}}, 1);
        device_bytes += double(m.device_bytes);
        AddGauge(&submaps, {id[0], {"state", "active"}}, m.submaps_active);
        AddGauge(&submaps, {id[0], {"state", "frozen"}}, m.submaps_frozen);
        AddGauge(&submaps, {id[0], {"state", "on_disk"}}, m.submaps_on_disk);
        AddGauge(&memory, id, double(SessionHostBytes(*session)));
        AddGauge(&checkpoint, id, double(s.last_checkpoint_bytes));
        AddGauge(&wal, id, double(s.wal_bytes));
        AddValue(&transient, {id[0], {"store", "buffer"}}, double(m.transient_buffer_removed));
        AddValue(&transient, {id[0], {"store", "deferred"}}, double(m.transient_deferred_removed));
        const MeshCacheTotals mesh = session->mapper().MeshTotals();
        AddValue(&checked, id, double(mesh.blocks_checked));
        AddValue(&skipped, id, double(mesh.blocks_skipped));
        AddGauge(&skipped_share, id,
                 mesh.blocks_checked > 0 ? double(mesh.blocks_skipped) / mesh.blocks_checked : 0);
      }
    }
    AddGauge(&active, {}, sessions);
    auto budget = GaugeFamily("rim_host_memory_budget_bytes",
                              "The server's host memory budget; 0 when none is set");
    AddGauge(&budget, {}, double(budget_));
    auto rss = GaugeFamily("rim_process_resident_memory_bytes", "Resident set size of rim_server");
    AddGauge(&rss, {}, double(ResidentBytes()));
    auto device = GaugeFamily("rim_device_memory_bytes",
                              "GPU memory allocated by the server; 0 on the CPU build");
    AddGauge(&device, {}, device_bytes);
    return {build,     active,        queue,  lag,        iterations, rays,          loss,
            real_time, submaps,       memory, checkpoint, wal,        transient,     checked,
            skipped,   skipped_share, budget, rss,        device,     session_device};
  }

 private:
  const uint64_t budget_;
  const SessionManager* sessions_ = nullptr;
};

namespace {

// Counts one RPC when its final status goes out. Created by gRPC for every call.
class CountingInterceptor : public grpc::experimental::Interceptor {
 public:
  CountingInterceptor(ServerMetrics* metrics, std::string method)
      : metrics_(metrics), method_(std::move(method)), start_(std::chrono::steady_clock::now()) {}

  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    using grpc::experimental::InterceptionHookPoints;
    if (methods->QueryInterceptionHookPoint(InterceptionHookPoints::PRE_SEND_STATUS)) {
      const double seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
      metrics_->RpcFinished(method_, int(methods->GetSendStatus().error_code()), seconds);
    }
    methods->Proceed();
  }

 private:
  ServerMetrics* metrics_;
  const std::string method_;
  const std::chrono::steady_clock::time_point start_;
};

class CountingInterceptorFactory : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit CountingInterceptorFactory(ServerMetrics* metrics) : metrics_(metrics) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(
      grpc::experimental::ServerRpcInfo* info) override {
    return new CountingInterceptor(metrics_, info->method() ? info->method() : "unknown");
  }

 private:
  ServerMetrics* metrics_;
};

}  // namespace

std::string MetricMethodName(const std::string& path) {
  std::string name = path;
  if (!name.empty() && name[0] == '/') name.erase(0, 1);
  constexpr char kRim[] = "rim.v1.Rim/";
  if (name.rfind(kRim, 0) == 0) name.erase(0, sizeof(kRim) - 1);
  return name;
}

std::string GrpcCodeName(int code) {
  static const char* const kNames[] = {"OK",
                                       "CANCELLED",
                                       "UNKNOWN",
                                       "INVALID_ARGUMENT",
                                       "DEADLINE_EXCEEDED",
                                       "NOT_FOUND",
                                       "ALREADY_EXISTS",
                                       "PERMISSION_DENIED",
                                       "RESOURCE_EXHAUSTED",
                                       "FAILED_PRECONDITION",
                                       "ABORTED",
                                       "OUT_OF_RANGE",
                                       "UNIMPLEMENTED",
                                       "INTERNAL",
                                       "UNAVAILABLE",
                                       "DATA_LOSS",
                                       "UNAUTHENTICATED"};
  if (code >= 0 && code < int(sizeof(kNames) / sizeof(kNames[0]))) return kNames[code];
  return absl::StrCat("CODE_", code);
}

ServerMetrics::ServerMetrics(uint64_t host_memory_budget_bytes)
    : registry_(std::make_shared<prometheus::Registry>()),
      families_(std::make_unique<Families>(*registry_)),
      collector_(std::make_shared<SessionCollector>(host_memory_budget_bytes)) {}

ServerMetrics::~ServerMetrics() = default;

void ServerMetrics::WatchSessions(const SessionManager* sessions) { collector_->Watch(sessions); }

absl::StatusOr<int> ServerMetrics::Serve(const std::string& address) {
  try {
    exposer_ = std::make_unique<prometheus::Exposer>(address, 1);
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(
        absl::StrCat("--metrics ", address, ": cannot listen: ", e.what()));
  }
  exposer_->RegisterCollectable(registry_);
  exposer_->RegisterCollectable(collector_);
  const std::vector<int> ports = exposer_->GetListeningPorts();
  if (ports.empty())
    return absl::InvalidArgumentError(absl::StrCat("--metrics ", address, ": cannot listen"));
  return ports[0];
}

void ServerMetrics::StopServing() { exposer_.reset(); }

std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>>
ServerMetrics::InterceptorFactories() {
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> out;
  out.push_back(std::make_unique<CountingInterceptorFactory>(this));
  return out;
}

std::string ServerMetrics::Text() const {
  std::vector<prometheus::MetricFamily> all = registry_->Collect();
  for (auto& f : collector_->Collect()) all.push_back(std::move(f));
  return prometheus::TextSerializer().Serialize(all);
}

void ServerMetrics::ScanAccepted(const std::string& robot) {
  families_->accepted.Add({{"session", robot}}).Increment();
}

void ServerMetrics::ScanRejected(const std::string& robot, absl::StatusCode code) {
  families_->rejected.Add({{"session", robot}, {"reason", RejectReason(code)}}).Increment();
}

void ServerMetrics::FrameIntegrated(const std::string& robot, const StageTimings& t) {
  families_->integrated.Add({{"session", robot}}).Increment();
  // At 0 from the first frame, so that a session that never trains between frames (an upload)
  // shows that rather than no series.
  families_->between_iterations.Add({{"session", robot}});
  families_->between_rays.Add({{"session", robot}});
  families_->between_seconds.Add({{"session", robot}});
  families_->frame.Add({{"session", robot}}, kFrameBuckets).Observe(t.total_s);
  const double known = t.slide_s + t.preprocess_s + t.sample_s + t.encode_s + t.forward_s +
                       t.backward_s + t.step_s + t.distance_s;
  const std::pair<const char*, double> stages[] = {{"slide", t.slide_s},
                                                   {"preprocess", t.preprocess_s},
                                                   {"sample", t.sample_s},
                                                   {"encode", t.encode_s},
                                                   {"forward", t.forward_s},
                                                   {"backward", t.backward_s},
                                                   {"step", t.step_s},
                                                   {"distance", t.distance_s},
                                                   {"other", std::max(0.0, t.total_s - known)}};
  for (const auto& [stage, seconds] : stages)
    families_->stage.Add({{"session", robot}, {"stage", stage}}, kStageBuckets).Observe(seconds);
}

void ServerMetrics::TrainedBetweenFrames(const std::string& robot, const StageTimings& t) {
  families_->between_iterations.Add({{"session", robot}}).Increment(t.iterations);
  families_->between_rays.Add({{"session", robot}})
      .Increment(double(t.iterations) * t.rays_per_iteration);
  families_->between_seconds.Add({{"session", robot}}).Increment(t.train_s);
}

void ServerMetrics::DistanceRefreshed(const std::string& robot, double seconds) {
  families_->refresh.Add({{"session", robot}}, kRefreshBuckets).Observe(seconds);
}

void ServerMetrics::FrameFailed(const std::string& robot) {
  // A failed frame still leaves the queue; it shows as lag that never clears, and in the logs.
}

void ServerMetrics::WalAppended(const std::string& robot, double seconds) {
  families_->wal.Add({{"session", robot}}, kWalBuckets).Observe(seconds);
}

void ServerMetrics::CheckpointWritten(const std::string& robot, double seconds, uint64_t bytes) {
  families_->checkpoint.Add({{"session", robot}}, kCheckpointBuckets).Observe(seconds);
}

void ServerMetrics::TileEncoded(const std::string& robot, size_t bytes, double seconds,
                                int blocks_remeshed) {
  families_->tiles.Add({{"session", robot}}).Increment();
  families_->blocks_remeshed.Add({{"session", robot}}).Increment(double(blocks_remeshed));
  families_->tile_bytes.Add({{"session", robot}}).Increment(double(bytes));
  families_->meshing.Add({{"session", robot}}, kMeshBuckets).Observe(seconds);
}

void ServerMetrics::WatchMeshed(const std::string& robot, double cpu_seconds,
                                double budget_wait_seconds) {
  families_->watch_cpu.Add({{"session", robot}}).Increment(std::max(0.0, cpu_seconds));
  families_->watch_budget_wait.Add({{"session", robot}})
      .Increment(std::max(0.0, budget_wait_seconds));
}

void ServerMetrics::TilePushed(const std::string& robot, double delay_seconds) {
  families_->push_delay.Add({{"session", robot}}, kPushDelayBuckets).Observe(delay_seconds);
}

void ServerMetrics::QueryAnswered(const std::string& robot, size_t points, double seconds) {
  families_->query_points.Add({{"session", robot}}).Increment(double(points));
  families_->query_latency.Add({{"session", robot}}, kQueryBuckets).Observe(seconds);
}

void ServerMetrics::RpcFinished(const std::string& method, int code, double seconds) {
  const std::string name = MetricMethodName(method);
  families_->requests.Add({{"method", name}, {"code", GrpcCodeName(code)}}).Increment();
  families_->request_seconds.Add({{"method", name}}, kRpcBuckets).Observe(seconds);
}

}  // namespace rim::server
