// rim_server: the gRPC mapping service (DESIGN.md §5). Serves rim.v1.Rim, standard health checking
// and reflection, and Prometheus metrics on --metrics. Health says SERVING once warmed up; on
// SIGTERM or SIGINT it goes NOT_SERVING, stops accepting, finishes in-flight RPCs within
// --shutdown-deadline, then drains and saves every session and exits 0.
// Access control (--tokens), TLS (--tls-cert, --tls-key, --tls-client-ca) and the refusal to serve
// a non-loopback address without tokens are described in docs/security.md.
#include <fcntl.h>
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <poll.h>
#include <signal.h>
#include <sys/signalfd.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <memory>
#include <string>
#include <thread>

#include "absl/cleanup/cleanup.h"
#include "rim/base/version.h"
#include "rim/gpu/device_map.h"
#include "server/auth/security.h"
#include "server/config/server_config.h"
#include "server/http/http_api.h"
#include "server/metrics/metrics.h"
#include "server/service/service.h"
#include "server/session/compute_scheduler.h"
#include "server/session/meshing_budget.h"
#include "server/session/session_manager.h"
#include "server/warmup.h"

namespace {

int g_signal_pipe[2] = {-1, -1};

// Async-signal-safe: one byte down the pipe, read by the shutdown thread.
void OnShutdownSignal(int signal) {
  const char c = char(signal);
  const int saved = errno;
  [[maybe_unused]] const ssize_t n = write(g_signal_pipe[1], &c, 1);
  errno = saved;
}

// rim_server --hash-token TOKEN|-: the digest for a --tokens line ('-' reads the token from stdin,
// which keeps it out of the shell history and the process list).
int HashToken(std::string token) {
  if (token == "-" && !std::getline(std::cin, token)) token.clear();
  if (token.empty()) {
    std::cerr << "rim_server: --hash-token: empty token\n";
    return 2;
  }
  std::cout << rim::server::HashToken(token) << "\n";
  return 0;
}

int Run(int argc, char** argv) {
  auto config = rim::server::ParseServerConfig(argc, argv);
  if (absl::IsCancelled(config.status())) {  // -h/--help
    std::cout << rim::server::ServerUsage();
    return 0;
  }
  if (config.ok() && config->hash_token) return HashToken(*config->hash_token);
  if (!config.ok()) {
    std::cerr << "rim_server: " << config.status().message() << "\n" << rim::server::ServerUsage();
    return 2;
  }
  std::cerr << "rim_server " << rim::kRimVersion << " effective config:\n"
            << config->ToString() << std::flush;
  // A GPU that is not there is a bad setting, found now rather than at the first session.
  std::string device_name = "cpu";
  if (config->device != "cpu") {
    absl::StatusOr<int> index = rim::gpu::CudaDeviceIndex(config->device);
    absl::StatusOr<rim::gpu::DeviceInfo> device =
        index.ok() ? rim::gpu::OpenDevice(*index) : index.status();
    if (!device.ok()) {
      std::cerr << "rim_server: --device " << config->device << ": " << device.status().message()
                << "\n";
      return 2;
    }
    device_name = config->device + " (" + device->name + ")";
    std::cerr << "rim_server: sessions train on " << device_name << "\n";
  }

  // SIGTERM and SIGINT are blocked on every thread rim and gRPC start, and the main thread waits
  // for them with a signalfd: no signal handler has to run for a shutdown. A handler would run on
  // whichever thread the kernel picks, and under ThreadSanitizer a handler on a thread parked in a
  // futex inside gRPC or Abseil, or even on the main thread waiting in read(), is deferred until
  // that thread next enters TSan's runtime, which can be never (rim_server then ignored SIGTERM).
  // Threads started before main (OpenBLAS's pool) do not block the signals; one landing there
  // runs a handler that writes to a pipe, which the main thread also waits on. A full disk or a
  // file-size limit must give write errors, not kill the process: SIGXFSZ is ignored, like
  // SIGPIPE.
  if (pipe2(g_signal_pipe, O_CLOEXEC) != 0) {
    std::cerr << "rim_server: pipe2: " << std::strerror(errno) << "\n";
    return 1;
  }
  struct sigaction on_signal = {};
  on_signal.sa_handler = OnShutdownSignal;
  sigemptyset(&on_signal.sa_mask);
  on_signal.sa_flags = SA_RESTART;
  sigaction(SIGTERM, &on_signal, nullptr);
  sigaction(SIGINT, &on_signal, nullptr);
  signal(SIGXFSZ, SIG_IGN);
  signal(SIGPIPE, SIG_IGN);
  sigset_t shutdown_signals;
  sigemptyset(&shutdown_signals);
  sigaddset(&shutdown_signals, SIGTERM);
  sigaddset(&shutdown_signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &shutdown_signals, nullptr);
  // Readable while either signal is pending; one sent during warm-up waits here until it is over.
  const int signal_fd = signalfd(-1, &shutdown_signals, SFD_CLOEXEC);
  if (signal_fd < 0) {
    std::cerr << "rim_server: signalfd: " << std::strerror(errno) << "\n";
    return 1;
  }
  // Exposure rule, tokens and TLS credentials (docs/security.md); a bad setting is exit 2.
  auto security = rim::server::SetUpSecurity(*config);
  if (!security.ok()) {
    std::cerr << "rim_server: " << security.status().message() << "\n";
    return 2;
  }
  for (const std::string& line : security->log_lines) std::cerr << "rim_server: " << line << "\n";

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
  manager_options.background_nice = config->background_nice;
  rim::server::MeshingBudget meshing_budget(
      config->meshing_cores >= 0
          ? config->meshing_cores
          : rim::server::DefaultMeshingCores(std::thread::hardware_concurrency()));
  manager_options.meshing_budget = &meshing_budget;
  if (meshing_budget.limited())
    std::cerr << "rim_server: watchers mesh within " << meshing_budget.cores()
              << " CPU-seconds per second\n";
  manager_options.data_dir = config->data_dir;
  manager_options.default_preset = config->default_preset;
  manager_options.default_device = config->device;
  manager_options.max_sessions = config->max_sessions;
  manager_options.queue_length = config->queue_length;
  manager_options.checkpoint_every_frames = config->checkpoint_every_frames;
  manager_options.take_over = config->shared_sessions;
  manager_options.replica_id = config->replica_id;
  manager_options.log = [](const std::string& line) { std::cerr << "rim_server: " + line + "\n"; };
  if (manager_options.replica_id.empty()) {
    char host[256] = {};
    gethostname(host, sizeof(host) - 1);
    manager_options.replica_id = std::string(host) + "/" + std::to_string(getpid());
  }
  std::cerr << "rim_server: replica " << manager_options.replica_id
            << (config->shared_sessions ? ", sessions shared with other replicas\n" : "\n");
  rim::server::SessionManager sessions(manager_options);
  metrics.WatchSessions(&sessions);
  // Declared after `sessions`, so it runs before `sessions` is destroyed on every way out of Run:
  // a scrape arriving then would otherwise read a destroyed SessionManager.
  const absl::Cleanup stop_metrics = [&metrics] { metrics.StopServing(); };
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
  limits.max_streams = config->max_streams;
  limits.queue_length = config->queue_length;
  limits.max_sessions = config->max_sessions;
  limits.host_memory_budget_bytes = config->host_memory_budget_bytes;
  limits.device = device_name;
  rim::server::RimService service(&sessions, limits, &security->authorizer);

  // The browser dashboard and its JSON API (docs/dashboard.md), on civetweb's own threads.
  // Declared after `sessions`, so it stops before they are destroyed.
  std::unique_ptr<rim::server::HttpServer> http;
  if (!config->http.empty()) {
    const std::string web_root =
        config->web_root.empty() ? rim::server::DefaultWebRoot() : config->web_root;
    auto files = rim::server::StaticFiles::Load(web_root.empty() ? "(not found)" : web_root);
    if (!files.ok()) {
      std::cerr << "rim_server: --http: " << files.status().message() << "\n";
      return 2;
    }
    auto started = rim::server::HttpServer::Start(
        config->http,
        std::make_unique<rim::server::HttpApi>(&sessions, &security->authorizer, std::move(*files)),
        config->background_nice);
    if (!started.ok()) {
      std::cerr << "rim_server: " << started.status().message() << "\n";
      return 1;
    }
    http = std::move(*started);
    const std::string http_host = config->http.substr(0, config->http.rfind(':'));
    std::printf("rim_server dashboard on http://%s:%d/\n", http_host.c_str(), http->port());
    std::fflush(stdout);
  }

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(config->listen, security->credentials, &port);
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

  pollfd waits[2] = {{signal_fd, POLLIN, 0}, {g_signal_pipe[0], POLLIN, 0}};
  while (poll(waits, 2, -1) < 0 && errno == EINTR) {
  }
  int signal = 0;
  if (waits[0].revents & POLLIN) {
    signalfd_siginfo info = {};
    if (read(signal_fd, &info, sizeof(info)) == ssize_t(sizeof(info))) signal = int(info.ssi_signo);
  } else {
    char c = 0;
    if (read(g_signal_pipe[0], &c, 1) == 1) signal = c;
  }
  std::cerr << "rim_server: signal " << signal << ", shutting down\n";
  server->GetHealthCheckService()->SetServingStatus(false);
  http.reset();  // waits for dashboard requests in progress
  sessions.BeginShutdown();
  server->Shutdown(std::chrono::system_clock::now() +
                   std::chrono::seconds(config->shutdown_deadline_s));
  server->Wait();
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
