#include "support/server_process.h"

#include <fcntl.h>
#include <grpcpp/grpcpp.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fstream>
#include <sstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "support/temp_dir.h"

namespace rim::testing_support {
namespace {

constexpr char kListening[] = "rim_server listening on ";

// Waits up to `timeout` for `pid` to exit; true with *status set when it did.
bool WaitForExit(pid_t pid, std::chrono::milliseconds timeout, int* status) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    const pid_t r = waitpid(pid, status, WNOHANG);
    if (r == pid || r < 0) return true;
    if (std::chrono::steady_clock::now() >= deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

// Polls grpc.health.v1.Health/Check at `address` until it answers SERVING or `deadline` passes.
bool WaitUntilServing(const std::string& address, std::chrono::steady_clock::time_point deadline) {
  auto stub = grpc::health::v1::Health::NewStub(
      grpc::CreateChannel(address, grpc::InsecureChannelCredentials()));
  while (std::chrono::steady_clock::now() < deadline) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
    grpc::health::v1::HealthCheckResponse response;
    const grpc::Status s = stub->Check(&context, grpc::health::v1::HealthCheckRequest(), &response);
    if (s.ok() && response.status() == grpc::health::v1::HealthCheckResponse::SERVING) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return false;
}

}  // namespace

absl::StatusOr<std::unique_ptr<ServerProcess>> ServerProcess::Start(
    const ServerProcessOptions& options) {
  std::unique_ptr<ServerProcess> server(new ServerProcess());
  const std::string binary = options.binary.empty() ? RIM_SERVER_PROCESS_BIN : options.binary;
  server->data_dir_ = options.data_dir.empty() ? MakeTempDir("rim_server") : options.data_dir;
  // The log goes to a file, not a pipe: a pipe nobody drains would block a chatty server.
  server->log_path_ = MakeTempDir("rim_server_log") + "/server.log";

  std::vector<std::string> args = {binary, "--listen", "127.0.0.1:0", "--data-dir",
                                   server->data_dir_};
  args.insert(args.end(), options.args.begin(), options.args.end());
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);

  const int log_fd = open(server->log_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  if (log_fd < 0) return absl::InternalError(absl::StrCat("cannot create ", server->log_path_));
  const pid_t pid = fork();
  if (pid < 0) {
    close(log_fd);
    return absl::InternalError("fork failed");
  }
  if (pid == 0) {
    dup2(log_fd, STDOUT_FILENO);
    dup2(log_fd, STDERR_FILENO);
    close(log_fd);
    execv(argv[0], argv.data());
    _exit(127);
  }
  close(log_fd);
  server->pid_ = pid;

  const auto deadline = std::chrono::steady_clock::now() + options.startup_timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    const std::string log = server->Log();
    const size_t at = log.find(kListening);
    const size_t eol = at == std::string::npos ? at : log.find('\n', at);
    if (eol != std::string::npos) {
      const size_t begin = at + sizeof(kListening) - 1;
      server->address_ = log.substr(begin, eol - begin);
      if (!options.wait_until_serving || WaitUntilServing(server->address_, deadline)) {
        return server;
      }
      break;
    }
    int status = 0;
    if (WaitForExit(pid, std::chrono::milliseconds(0), &status)) {
      server->pid_ = -1;
      return absl::InternalError(
          absl::StrCat(binary, " exited before listening (status ", status, "):\n", log));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  const std::string log = server->Log();
  server->Kill();
  return absl::DeadlineExceededError(absl::StrCat(
      binary, " did not ", server->address_.empty() ? "report listening" : "become SERVING",
      " within ", options.startup_timeout.count(), " s:\n", log));
}

ServerProcess::~ServerProcess() {
  if (running()) Stop().IgnoreError();
}

absl::StatusOr<int> ServerProcess::Stop(std::chrono::seconds timeout) {
  if (!running()) return absl::FailedPreconditionError("the server is not running");
  kill(pid_, SIGTERM);
  int status = 0;
  if (!WaitForExit(pid_, timeout, &status)) {
    Kill();
    return absl::DeadlineExceededError(
        absl::StrCat("rim_server did not exit within ", timeout.count(), " s of SIGTERM"));
  }
  pid_ = -1;
  if (WIFSIGNALED(status)) {
    return absl::InternalError(absl::StrCat("rim_server died from signal ", WTERMSIG(status)));
  }
  return WEXITSTATUS(status);
}

void ServerProcess::Kill() {
  if (!running()) return;
  kill(pid_, SIGKILL);
  waitpid(pid_, nullptr, 0);
  pid_ = -1;
}

std::string ServerProcess::Log() const {
  std::ifstream in(log_path_);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

absl::StatusOr<std::unique_ptr<ServerProcess>> ServerProcess::StartOn(const std::string& data_dir) {
  ServerProcessOptions options;
  options.data_dir = data_dir;
  return Start(options);
}

}  // namespace rim::testing_support
