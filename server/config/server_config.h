// rim_server's own settings (DESIGN.md §5.5): command-line flags over an optional config file of
// `key = value` lines ('#' comments), keys named like the flags without the dashes
// (listen, data_dir or data-dir, max_sessions, ...).
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "absl/status/statusor.h"

namespace rim::server {

struct ServerConfig {
  std::string listen = "127.0.0.1:50051";
  std::string data_dir;
  std::string metrics;  // host:port of the Prometheus /metrics endpoint; empty: none
  // host:port of the browser dashboard and its read-only JSON API (docs/dashboard.md); empty: none
  std::string http;
  // The dashboard's files; empty: found next to the binary (the build tree's web/, or
  // ../share/rim/web when installed).
  std::string web_root;
  std::string config_file;  // --config
  // --hash-token TOKEN|-: print the token's digest and exit (no server is started).
  std::optional<std::string> hash_token;
  std::string default_preset = "maicity";
  // Where sessions train unless their config sets train.device: "cpu", "cuda" or "cuda:N"
  // (docs/gpu.md; a build with -DRIM_CUDA=ON). Checked at start.
  std::string device = "cpu";
  int max_sessions = 16;
  int queue_length = 8;
  int checkpoint_every_frames = 100;  // 0: only on SaveSession, close and shutdown
  int max_query_points = 1 << 20;
  int max_streams = 128;  // long-lived streams open at once (ServiceLimits::max_streams)
  int max_points_per_scan = 1 << 21;
  uint64_t host_memory_budget_bytes = 0;  // 0: no budget enforced
  // Frames of a built-in scene trained at start, before health reports SERVING, so that the first
  // robot does not pay for loading kernels and growing allocators. 0: none.
  int warmup_frames = 2;
  // SIGTERM: in-flight RPCs get this long to finish before they are cancelled.
  int shutdown_deadline_s = 10;
  // Access control and transport security (docs/security.md).
  std::string tokens_file;    // --tokens: `ROLE SUBJECT SHA256HEX` lines; empty: no tokens needed
  std::string tls_cert;       // --tls-cert: PEM certificate chain; empty: plaintext
  std::string tls_key;        // --tls-key: PEM private key of --tls-cert
  std::string tls_client_ca;  // --tls-client-ca: require client certificates signed by it (mTLS)
  bool insecure = false;      // --insecure: allow a non-loopback --listen without --tokens
  // Replicas sharing one data dir (docs/service.md, "Replicas and shared storage"): this
  // replica's name in session leases (empty: host name and process id), and whether a call about
  // a session no live replica holds opens it here.
  std::string replica_id;
  bool shared_sessions = false;
  // Frames that may train at once across all sessions (ComputeScheduler); 0: one per two cores.
  int train_slots = 0;
  // Nice value (0-19) of the background threads: training, distance-field refreshes and meshing
  // for watchers. Queries and ingest stay at the process's own priority (docs/service.md,
  // "Sharing the cores"). 0: all equal.
  int background_nice = 5;
  // CPU-seconds per second that all watchers' meshing may use together (MeshingBudget); 0: no
  // budget; below 0 (the default): a tenth of the machine's cores (DefaultMeshingCores).
  double meshing_cores = -1;

  // Every field as `key = value` lines.
  std::string ToString() const;
};

// Parses argv with CLI11 (rim/base/flags.h: flags as `--name value` or `--name=value`, also with
// underscores, `--data_dir`; --insecure alone means true); a --config file is read first and the
// flags override it. INVALID_ARGUMENT naming the flag for an unknown flag, a missing or bad value,
// a missing --data-dir, or TLS flags that do not go together. CANCELLED for -h/--help (print
// ServerUsage()). `--hash-token TOKEN|-`, alone, gives a config with hash_token set and nothing
// else read.
absl::StatusOr<ServerConfig> ParseServerConfig(int argc, char** argv);

// Usage text for --help and errors: the synopsis and every flag with its description, from the
// flags' declarations (CLI11).
std::string ServerUsage();

}  // namespace rim::server
