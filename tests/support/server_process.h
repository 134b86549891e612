// The real rim_server as a child process for black-box tests: started on a free loopback port
// with its own data directory, stopped with SIGTERM (the graceful path) or killed (a crash).
//
//   auto server = ServerProcess::Start();
//   ASSERT_TRUE(server.ok()) << server.status();
//   auto client = rim::Client::Connect((*server)->address());
//   ...
//   EXPECT_EQ((*server)->Stop().value_or(-1), 0);  // or let the destructor stop it
#pragma once

#include <sys/types.h>

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace rim::testing_support {

struct ServerProcessOptions {
  // The rim_server binary; empty: the one this build made.
  std::string binary;
  // --data-dir; empty: a new temporary directory (removed when the test process exits). Pass the
  // data_dir() of a stopped server to restart on its sessions.
  std::string data_dir;
  // More flags, e.g. {"--max-sessions", "4"}.
  std::vector<std::string> args;
  // Start returns once standard health checking says SERVING (the server warms up after it starts
  // listening); false: as soon as it listens, e.g. to test the warm-up itself.
  bool wait_until_serving = true;
  // For listening and, when asked, SERVING.
  std::chrono::seconds startup_timeout{60};
};

class ServerProcess {
 public:
  // Runs `binary --listen 127.0.0.1:0 --data-dir DIR ARGS...` with stdout and stderr going to a
  // log file, waits for its "rim_server listening on HOST:PORT" line and then (by default) for
  // its health check to say SERVING. The error holds the server's log when it exits or does not
  // get there within startup_timeout.
  static absl::StatusOr<std::unique_ptr<ServerProcess>> Start(
      const ServerProcessOptions& options = {});
  // A new server on the data dir of a stopped or killed one (a restart), default options.
  static absl::StatusOr<std::unique_ptr<ServerProcess>> StartOn(const std::string& data_dir);

  // Stops the server (SIGTERM, then SIGKILL after 30 s) if it still runs.
  ~ServerProcess();
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  const std::string& address() const { return address_; }  // "127.0.0.1:PORT"
  const std::string& data_dir() const { return data_dir_; }
  pid_t pid() const { return pid_; }
  bool running() const { return pid_ > 0; }

  // SIGTERM and waits for the exit (SIGKILL after `timeout`). Returns the exit code, or an error
  // saying the server died from a signal or had to be killed.
  absl::StatusOr<int> Stop(std::chrono::seconds timeout = std::chrono::seconds(30));

  // SIGKILL, as a crash would; waits for the process to go.
  void Kill();

  // Everything the server printed so far.
  std::string Log() const;

 private:
  ServerProcess() = default;

  pid_t pid_ = -1;
  std::string address_;
  std::string data_dir_;
  std::string log_path_;
};

}  // namespace rim::testing_support
