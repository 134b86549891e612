// rimctl info, health and session create|list|get|save|load|close.
#include <iostream>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "rimctl/commands.h"

namespace rim::rimctl {
namespace {

constexpr char kInfoUsage[] = "usage: rimctl [--server ADDR] info\n";

constexpr char kHealthUsage[] = R"(usage: rimctl [--server ADDR] health [--service NAME]

Calls grpc.health.v1.Health/Check and prints SERVING, NOT_SERVING, SERVICE_UNKNOWN or UNKNOWN.
Exit 0 only when SERVING (5 otherwise, 3 when the server cannot be reached), so that container
health checks and Kubernetes probes can run it as is. --service "" (default) asks about the
whole server.
)";

constexpr char kSessionUsage[] = R"(usage:
  rimctl session create ROBOT_ID [--preset NAME] [--set key=value ...]
  rimctl session list
  rimctl session get ROBOT_ID [--config]
  rimctl session save ROBOT_ID
  rimctl session load ROBOT_ID
  rimctl session close ROBOT_ID [--save]

A session is named by its robot id. --set overrides a config value by its dotted name (e.g.
--set train.iterations=10); get --config also prints the effective config. load restores a saved
(or crashed) session from the server's data directory; close --save writes a checkpoint first.
)";

// The session's state as `name: value` lines; scripts read `integrated frames: N`.
void PrintSession(const rim::v1::SessionInfo& s, bool with_config, std::ostream& out) {
  out << "robot id: " << s.robot_id() << "\n"
      << "preset: " << s.preset() << "\n"
      << "accepted frames: " << s.accepted_frames() << "\n"
      << "rejected frames: " << s.rejected_frames() << "\n"
      << "integrated frames: " << s.integrated_frames() << "\n"
      << "map frames: " << s.map_frames() << "\n"
      << "queue depth: " << s.queue_depth() << "\n"
      << "iterations per frame: " << s.iterations_per_frame() << " of " << s.rays_per_iteration()
      << " rays\n"
      << "map version: " << s.map_version() << "\n"
      << "buffer points: " << s.buffer_points() << "\n"
      << absl::StrFormat("submaps: %u active, %u frozen, %u on disk\n", s.submaps_active(),
                         s.submaps_frozen(), s.submaps_on_disk())
      << absl::StrFormat("host memory: %.1f MiB\n", double(s.host_memory_bytes()) / (1 << 20))
      << "decoder frozen: " << (s.decoder_frozen() ? "yes" : "no") << "\n"
      << absl::StrFormat("last loss: %.6g\n", s.last_loss());
  out << "mesh levels:";
  for (float level : s.mesh_levels_m()) out << absl::StrFormat(" %g", level);
  out << " m\n";
  if (with_config) out << "config:\n" << s.config();
}

absl::StatusOr<std::vector<std::pair<std::string, std::string>>> ParseOverrides(
    const std::vector<std::string>& items) {
  std::vector<std::pair<std::string, std::string>> overrides;
  for (const std::string& item : items) {
    const size_t eq = item.find('=');
    if (eq == std::string::npos || eq == 0) {
      return absl::InvalidArgumentError(absl::StrCat("--set '", item, "' is not key=value"));
    }
    overrides.emplace_back(item.substr(0, eq), item.substr(eq + 1));
  }
  return overrides;
}

}  // namespace

int RunInfo(const std::vector<std::string>& words, const Io& io) {
  auto args = Args::Parse(words, GlobalFlags());
  if (!args.ok()) return UsageError(io, "info", std::string(args.status().message()), kInfoUsage);
  if (args->help()) return PrintHelp(io, kInfoUsage);
  if (!args->positional().empty()) {
    return UsageError(io, "info", "takes no arguments", kInfoUsage);
  }
  auto client = ConnectFromArgs(*args);
  if (!client.ok()) return Fail(io, client.status());
  auto info = client->Info();
  if (!info.ok()) return Fail(io, info.status());
  io.out << "server: " << client->address() << "\n"
         << "version: " << info->version() << "\n"
         << "build: " << info->build() << "\n"
         << "device: " << info->device() << "\n"
         << "libtorch: " << info->libtorch_version() << "\n"
         << "max sessions: " << info->max_sessions() << "\n"
         << "max points per scan: " << info->max_points_per_scan() << "\n"
         << "max query points: " << info->max_query_points() << "\n"
         << "queue length: " << info->queue_length() << "\n"
         << "host memory budget: "
         << (info->host_memory_budget_bytes() == 0
                 ? std::string("none")
                 : absl::StrFormat("%.1f MiB",
                                   double(info->host_memory_budget_bytes()) / (1 << 20)))
         << "\n"
         << "presets: " << absl::StrJoin(info->presets(), ", ") << "\n";
  return kExitOk;
}

int RunHealth(const std::vector<std::string>& words, const Io& io) {
  auto args = Args::Parse(words, WithGlobalFlags({{"service", FlagKind::kValue}}));
  if (!args.ok()) {
    return UsageError(io, "health", std::string(args.status().message()), kHealthUsage);
  }
  if (args->help()) return PrintHelp(io, kHealthUsage);
  if (!args->positional().empty()) {
    return UsageError(io, "health", "takes no arguments", kHealthUsage);
  }
  auto client = ConnectFromArgs(*args);
  if (!client.ok()) return Fail(io, client.status());
  auto status = client->Health(args->Get("service"));
  if (!status.ok()) return Fail(io, status.status());
  io.out << ServingStatusName(*status) << "\n";
  return *status == ServingStatus::kServing ? kExitOk : kExitNotServing;
}

namespace {

// Runs one validated session subcommand against the server.
int RunSessionCall(const Client& client, const std::string& sub, const std::string& robot,
                   const Args& args,
                   const std::vector<std::pair<std::string, std::string>>& overrides,
                   const Io& io) {
  if (sub == "create") {
    auto info = client.CreateSession(robot, args.Get("preset"), overrides);
    if (!info.ok()) return Fail(io, info.status());
    io.out << "created session " << robot << "\n";
    PrintSession(*info, false, io.out);
  } else if (sub == "list") {
    auto sessions = client.ListSessions();
    if (!sessions.ok()) return Fail(io, sessions.status());
    io.out << absl::StrFormat("%-24s %-16s %10s %10s %6s %12s\n", "ROBOT_ID", "PRESET",
                              "INTEGRATED", "REJECTED", "QUEUE", "MAP_VERSION");
    for (const auto& s : *sessions) {
      io.out << absl::StrFormat("%-24s %-16s %10u %10u %6u %12u\n", s.robot_id(), s.preset(),
                                s.integrated_frames(), s.rejected_frames(), s.queue_depth(),
                                s.map_version());
    }
    io.out << sessions->size() << " session(s)\n";
  } else if (sub == "get") {
    auto info = client.GetSession(robot);
    if (!info.ok()) return Fail(io, info.status());
    PrintSession(*info, args.Has("config"), io.out);
  } else if (sub == "save") {
    auto saved = client.SaveSession(robot);
    if (!saved.ok()) return Fail(io, saved.status());
    io.out << "saved session " << robot << ": checkpoint " << saved->checkpoint()
           << ", map version " << saved->map_version() << "\n";
  } else if (sub == "load") {
    auto info = client.LoadSession(robot);
    if (!info.ok()) return Fail(io, info.status());
    io.out << "loaded session " << robot << "\n";
    PrintSession(*info, false, io.out);
  } else {
    const absl::Status closed = client.CloseSession(robot, args.Has("save"));
    if (!closed.ok()) return Fail(io, closed);
    io.out << "closed session " << robot << (args.Has("save") ? " (saved)" : "") << "\n";
  }
  return kExitOk;
}

// The subcommand and its flags agree; a message for UsageError otherwise.
absl::Status CheckSessionWords(const Args& args) {
  const std::vector<std::string>& pos = args.positional();
  if (pos.empty()) return absl::InvalidArgumentError("missing subcommand");
  const std::string& sub = pos[0];
  const bool is_list = sub == "list";
  if (sub != "create" && sub != "list" && sub != "get" && sub != "save" && sub != "load" &&
      sub != "close") {
    return absl::InvalidArgumentError(absl::StrCat("unknown subcommand '", sub, "'"));
  }
  if (pos.size() != (is_list ? 1u : 2u)) {
    return absl::InvalidArgumentError(
        absl::StrCat(sub, is_list ? " takes no arguments" : " needs exactly one ROBOT_ID"));
  }
  // Flags that only one subcommand understands are an error elsewhere rather than ignored.
  const std::vector<std::pair<const char*, const char*>> owners = {
      {"preset", "create"}, {"set", "create"}, {"save", "close"}, {"config", "get"}};
  for (const auto& [flag, owner] : owners) {
    if (args.Has(flag) && sub != owner) {
      return absl::InvalidArgumentError(
          absl::StrCat("--", flag, " only applies to 'session ", owner, "'"));
    }
  }
  return absl::OkStatus();
}

}  // namespace

int RunSession(const std::vector<std::string>& words, const Io& io) {
  auto args = Args::Parse(words, WithGlobalFlags({{"preset", FlagKind::kValue},
                                                  {"set", FlagKind::kRepeated},
                                                  {"save", FlagKind::kBool},
                                                  {"config", FlagKind::kBool}}));
  if (!args.ok()) {
    return UsageError(io, "session", std::string(args.status().message()), kSessionUsage);
  }
  if (args->help()) return PrintHelp(io, kSessionUsage);
  const absl::Status words_ok = CheckSessionWords(*args);
  if (!words_ok.ok())
    return UsageError(io, "session", std::string(words_ok.message()), kSessionUsage);
  auto overrides = ParseOverrides(args->GetAll("set"));
  if (!overrides.ok()) {
    return UsageError(io, "session", std::string(overrides.status().message()), kSessionUsage);
  }
  auto client = ConnectFromArgs(*args);
  if (!client.ok()) return Fail(io, client.status());
  const std::vector<std::string>& pos = args->positional();
  return RunSessionCall(*client, pos[0], pos.size() > 1 ? pos[1] : "", *args, *overrides, io);
}

}  // namespace rim::rimctl
