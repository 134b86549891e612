// rimctl's subcommands (DESIGN.md §5.5). Each takes the words after its name, parses its own
// flags plus the global ones (--server, --token, --timeout, --connect-timeout) and returns the
// process exit code.
#pragma once

#include <iosfwd>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/client.h"
#include "rimctl/args.h"

namespace rim::rimctl {

// Exit codes, documented in docs/clients.md.
inline constexpr int kExitOk = 0;
inline constexpr int kExitFailed = 1;       // the server refused, or a local file failed
inline constexpr int kExitUsage = 2;        // bad command line
inline constexpr int kExitUnreachable = 3;  // no server at --server (or it went away)
inline constexpr int kExitRejected = 4;     // stream: some scans were rejected
inline constexpr int kExitNotServing = 5;   // health: the server answers but is not SERVING

struct Io {
  std::ostream& out;
  std::ostream& err;
};

// The flags every command accepts.
const std::vector<FlagSpec>& GlobalFlags();
// `specs` plus the global flags.
std::vector<FlagSpec> WithGlobalFlags(std::vector<FlagSpec> specs);

// Connects as the global flags say: --server (default $RIM_SERVER, else 127.0.0.1:50051),
// --token (default $RIM_TOKEN), --timeout and --connect-timeout in seconds, and TLS from --tls-ca,
// --tls-cert and --tls-key.
absl::StatusOr<Client> ConnectFromArgs(const Args& args);

// Prints "rimctl: <message>" and returns kExitUnreachable for UNAVAILABLE, else kExitFailed.
int Fail(const Io& io, const absl::Status& status);
// Prints `usage` on stdout (for --help) and returns kExitOk.
int PrintHelp(const Io& io, const std::string& usage);
// Prints "rimctl <command>: <message>" and the synopsis of `usage` on stderr; returns kExitUsage.
int UsageError(const Io& io, const std::string& command, const std::string& message,
               const std::string& usage);

int RunInfo(const std::vector<std::string>& words, const Io& io);
int RunHealth(const std::vector<std::string>& words, const Io& io);
int RunSession(const std::vector<std::string>& words, const Io& io);
int RunStream(const std::vector<std::string>& words, const Io& io);
int RunQuery(const std::vector<std::string>& words, const Io& io);
int RunMesh(const std::vector<std::string>& words, const Io& io);
int RunWatch(const std::vector<std::string>& words, const Io& io);

// The whole command line (argv[0] is the program name): dispatches to the commands above.
int RunRimctl(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

}  // namespace rim::rimctl
