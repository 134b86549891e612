// rimctl's dispatch, global flags and error reporting.
#include <algorithm>
#include <cstdlib>
#include <iostream>

#include "absl/strings/str_cat.h"
#include "rim/base/flags.h"
#include "rimctl/commands.h"

namespace rim::rimctl {
namespace {

constexpr char kUsage[] = R"(usage: rimctl [--server ADDR] [--token T] COMMAND ...

Talks to a rim_server over gRPC.

commands:
  info                                   server version, build, device and limits
  health [--service NAME]                standard gRPC health check; exit 0 only when SERVING
  session create ROBOT_ID [--preset NAME] [--set key=value ...]
  session list | get ROBOT_ID | save ROBOT_ID | load ROBOT_ID | close ROBOT_ID [--save]
  stream ROBOT_ID DATASET [--rate HZ] [--frames A:B]
                                         DATASET: a dataset folder, or sim:city[?frames=N&...]
  query ROBOT_ID --points FILE|- [--gradient] [--format csv|npy] [--out FILE]
  query ROBOT_ID --grid x0,y0,z0,x1,y1,z1,res --out slice.png [--range M] [--contours M]
  mesh ROBOT_ID --out DIR [--since V]    .drc tiles and a merged, welded mesh.ply
  watch ROBOT_ID [--count N] [--duration S] [--since V]

global flags (anywhere on the line):
  --server ADDR           host:port of rim_server (default $RIM_SERVER, else 127.0.0.1:50051)
  --token T               bearer token sent with every call (default $RIM_TOKEN)
  --timeout S             deadline of each call in seconds (default 30)
  --connect-timeout S     how long to wait for the server to answer at all (default 10)
  --tls-ca FILE           use TLS, trusting the server certificates FILE signs (PEM)
  --tls-cert FILE --tls-key FILE
                          use TLS with this client certificate and key (servers with
                          --tls-client-ca); without --tls-ca the system roots are trusted

'rimctl COMMAND --help' describes a command. Exit codes: 0 ok, 1 failed, 2 bad command line,
3 server unreachable, 4 stream had rejected scans, 5 health not SERVING.
)";

}  // namespace

const std::vector<FlagSpec>& GlobalFlags() {
  static const std::vector<FlagSpec> flags = {
      {"server", FlagKind::kValue},  {"token", FlagKind::kValue},
      {"timeout", FlagKind::kValue}, {"connect-timeout", FlagKind::kValue},
      {"tls-ca", FlagKind::kValue},  {"tls-cert", FlagKind::kValue},
      {"tls-key", FlagKind::kValue}};
  return flags;
}

std::vector<FlagSpec> WithGlobalFlags(std::vector<FlagSpec> specs) {
  specs.insert(specs.end(), GlobalFlags().begin(), GlobalFlags().end());
  return specs;
}

absl::StatusOr<Client> ConnectFromArgs(const Args& args) {
  const char* env_server = std::getenv("RIM_SERVER");
  const char* env_token = std::getenv("RIM_TOKEN");
  const std::string server =
      args.Get("server", env_server && *env_server ? env_server : "127.0.0.1:50051");
  ClientOptions options;
  options.token = args.Get("token", env_token ? env_token : "");
  options.tls_ca_file = args.Get("tls-ca");
  options.tls_cert_file = args.Get("tls-cert");
  options.tls_key_file = args.Get("tls-key");
  if (options.tls_cert_file.empty() != options.tls_key_file.empty())
    return absl::InvalidArgumentError("--tls-cert and --tls-key must be given together");
  auto timeout = args.GetDouble("timeout", 30, 0.001, 1e6);
  if (!timeout.ok()) return timeout.status();
  auto connect_timeout = args.GetDouble("connect-timeout", 10, 0.001, 1e6);
  if (!connect_timeout.ok()) return connect_timeout.status();
  options.deadline = std::chrono::milliseconds(long(*timeout * 1000));
  options.connect_timeout = std::chrono::milliseconds(long(*connect_timeout * 1000));
  return Client::Connect(server, options);
}

int Fail(const Io& io, const absl::Status& status) {
  io.err << "rimctl: " << status.message() << "\n";
  return status.code() == absl::StatusCode::kUnavailable ? kExitUnreachable : kExitFailed;
}

int PrintHelp(const Io& io, const std::string& usage) {
  io.out << usage;
  return kExitOk;
}

int UsageError(const Io& io, const std::string& command, const std::string& message,
               const std::string& usage) {
  // The synopsis only (the usage text up to its first blank line); --help has the rest.
  const size_t blank = usage.find("\n\n");
  io.err << "rimctl " << command << ": " << message << "\n"
         << (blank == std::string::npos ? usage : usage.substr(0, blank + 1)) << "(rimctl "
         << command.substr(0, command.find(' ')) << " --help for more)\n";
  return kExitUsage;
}

int RunRimctl(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  const Io io{out, err};
  // The command is the first word that is neither a global flag nor a global flag's value, so
  // that `rimctl --server ADDR info` and `rimctl info --server ADDR` both work: CLI11 reads the
  // global flags up to the command (prefix_command), which gets them back with its own words.
  CLI::App app("", "rimctl");
  app.prefix_command();
  std::vector<std::string> words;  // the global flags before the command, as --name=value
  for (const FlagSpec& f : GlobalFlags()) {
    app.add_option_function<std::vector<std::string>>(
           "--" + f.name,
           [&words, name = f.name](const std::vector<std::string>& values) {
             for (const std::string& v : values) words.push_back("--" + name + "=" + v);
           })
        ->allow_extra_args(false);
  }
  std::vector<std::string> rest;
  const absl::Status parsed =
      cli::Parse(app, std::vector<std::string>(argv + std::min(argc, 1), argv + argc), &rest);
  if (absl::IsCancelled(parsed)) {
    out << kUsage;
    return kExitOk;
  }
  if (!parsed.ok()) {
    err << "rimctl: " << parsed.message() << "\n" << kUsage;
    return kExitUsage;
  }
  if (!rest.empty() && rest[0].size() > 1 && rest[0][0] == '-') {
    err << "rimctl: unknown flag '" << rest[0].substr(0, rest[0].find('='))
        << "' before the command\n"
        << kUsage;
    return kExitUsage;
  }
  if (rest.empty()) {
    err << "rimctl: no command given\n" << kUsage;
    return kExitUsage;
  }
  const size_t command_at = words.size();
  words.insert(words.end(), rest.begin(), rest.end());
  const std::string command = words[command_at];
  words.erase(words.begin() + long(command_at));
  if (command == "info") return RunInfo(words, io);
  if (command == "health") return RunHealth(words, io);
  if (command == "session") return RunSession(words, io);
  if (command == "stream") return RunStream(words, io);
  if (command == "query") return RunQuery(words, io);
  if (command == "mesh") return RunMesh(words, io);
  if (command == "watch") return RunWatch(words, io);
  err << "rimctl: unknown command '" << command << "'\n" << kUsage;
  return kExitUsage;
}

}  // namespace rim::rimctl
