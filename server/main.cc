// rim_server: the gRPC mapping service (DESIGN.md §5). Serves rim.v1.Rim, standard health checking
// and reflection, and Prometheus metrics on --metrics. Health says SERVING once warmed up; on
// SIGTERM or SIGINT it goes NOT_SERVING, stops accepting, finishes in-flight RPCs within
// --shutdown-deadline, then drains and saves every session and exits 0.
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <signal.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>
#include <thread>

#include "rim/version.h"
#include "server/compute_scheduler.h"
#include "server/metrics.h"
#include "server/server_config.h"
#include "server/service.h"
#include "server/session_manager.h"
#include "server/warmup.h"

namespace {

int Run(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << rim::server::ServerUsage();
      return 0;
    }
  }
  auto config = rim::server::ParseServerConfig(argc, argv);
  if (!config.ok()) {
    std::cerr << "rim_server: " << config.status().message() << "\n" << rim::server::ServerUsage();
    return 2;
  }
  std::cerr << "rim_server " << rim::kRimVersion << " effective config:\n"
            << config->ToString() << std::flush;

  // Block the shutdown signals in every thread (gRPC's included); one thread waits for them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  rim::server::ServerMetrics metrics(config->host_memory_budget_bytes);
  rim::server::ComputeScheduler scheduler(
      config->train_slots > 0
          ? config->train_slots
          : rim::server::DefaultTrainSlots(std::thread::hardware_concurrency()));
  std::cerr << "rim_server: " << scheduler.slots() << " training slot(s) shared by the sessions\n";
  rim::server::SessionManagerOptions manager_options;
  manager_options.host_memory_budget_bytes = config->host_memory_budget_bytes;
  manager_options.events = &metrics;
  manager_options.scheduler = &scheduler;
  manager_options.data_dir = config->data_dir;
  manager_options.default_preset = config->default_preset;
  manager_options.max_sessions = config->max_sessions;
  manager_options.queue_length = config->queue_length;
  manager_options.checkpoint_every_frames = config->checkpoint_every_frames;
  rim::server::SessionManager sessions(manager_options);
  metrics.WatchSessions(&sessions);
  if (!config->metrics.empty()) {
    auto metrics_port = metrics.Serve(config->metrics);
    if (!metrics_port.ok()) {
      std::cerr << "rim_server: " << metrics_port.status().message() << "\n";
      return 1;
    }
    const std::string metrics_host = config->metrics.substr(0, config->metrics.rfind(':'));
    std::printf("rim_server metrics on http://%s:%d/metrics\n", metrics_host.c_str(),
                *metrics_port);
    std::fflush(stdout);
  }

  rim::server::ServiceLimits limits;
  limits.max_points_per_scan = config->max_points_per_scan;
  limits.max_query_points = config->max_query_points;
  limits.queue_length = config->queue_length;
  limits.max_sessions = config->max_sessions;
  limits.host_memory_budget_bytes = config->host_memory_budget_bytes;
  rim::server::RimService service(&sessions, limits);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(config->listen, grpc::InsecureServerCredentials(), &port);
  builder.RegisterService(&service);
  builder.experimental().SetInterceptorCreators(metrics.InterceptorFactories());
  // Scans and query batches are large; the size limits are enforced by the handlers.
  builder.SetMaxReceiveMessageSize(256 << 20);
  builder.SetMaxSendMessageSize(256 << 20);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (server == nullptr || port == 0) {
    std::cerr << "rim_server: cannot listen on " << config->listen << "\n";
    return 1;
  }
  const std::string host = config->listen.substr(0, config->listen.rfind(':'));
  // Not serving until warmed up: load balancers and probes wait, clients may already connect.
  server->GetHealthCheckService()->SetServingStatus(false);
  // Tests and scripts wait for this line (the port is resolved when --listen asks for port 0).
  std::printf("rim_server listening on %s:%d\n", host.c_str(), port);
  std::fflush(stdout);
  const auto warm = rim::server::WarmUp(config->warmup_frames);
  if (!warm.ok()) {
    std::cerr << "rim_server: warm-up failed: " << warm.status().message() << "\n";
    server->Shutdown();
    return 1;
  }
  std::cerr << "rim_server: warmed up in " << *warm << " s; serving\n";
  server->GetHealthCheckService()->SetServingStatus(true);

  std::thread signal_thread([&] {
    int signal = 0;
    sigwait(&signals, &signal);
    std::cerr << "rim_server: signal " << signal << ", shutting down\n";
    server->GetHealthCheckService()->SetServingStatus(false);
    server->Shutdown(std::chrono::system_clock::now() +
                     std::chrono::seconds(config->shutdown_deadline_s));
  });
  server->Wait();
  signal_thread.join();
  const absl::Status saved = sessions.CloseAll(/*save=*/true);
  if (!saved.ok()) {
    std::cerr << "rim_server: saving sessions failed: " << saved.message() << "\n";
    return 1;
  }
  std::cerr << "rim_server: stopped\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) { return Run(argc, argv); }
