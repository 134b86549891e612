#include "server/config/server_config.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "absl/strings/string_view.h"
#include "rim/base/flags.h"

namespace rim::server {
namespace {

absl::Status ParseInt(const std::string& name, const std::string& value, int min, int* out) {
  int v = 0;
  if (!absl::SimpleAtoi(value, &v) || v < min)
    return absl::InvalidArgumentError(
        absl::StrCat("--", name, ": expected an integer >= ", min, ", got '", value, "'"));
  *out = v;
  return absl::OkStatus();
}

// Applies one setting; `name` uses dashes (max-sessions).
absl::Status Apply(const std::string& raw_name, const std::string& value, ServerConfig* c) {
  const std::string name = absl::StrReplaceAll(raw_name, {{"_", "-"}});
  if (name == "listen") {
    c->listen = value;
  } else if (name == "data-dir") {
    c->data_dir = value;
  } else if (name == "metrics") {
    c->metrics = value;
  } else if (name == "http") {
    c->http = value;
  } else if (name == "web-root") {
    c->web_root = value;
  } else if (name == "preset") {
    c->default_preset = value;
  } else if (name == "max-sessions") {
    return ParseInt(name, value, 1, &c->max_sessions);
  } else if (name == "queue-length") {
    return ParseInt(name, value, 1, &c->queue_length);
  } else if (name == "checkpoint-every") {
    return ParseInt(name, value, 0, &c->checkpoint_every_frames);
  } else if (name == "max-query-points") {
    return ParseInt(name, value, 1, &c->max_query_points);
  } else if (name == "max-streams") {
    return ParseInt(name, value, 1, &c->max_streams);
  } else if (name == "max-points-per-scan") {
    return ParseInt(name, value, 1, &c->max_points_per_scan);
  } else if (name == "warmup-frames") {
    return ParseInt(name, value, 0, &c->warmup_frames);
  } else if (name == "train-slots") {
    return ParseInt(name, value, 0, &c->train_slots);
  } else if (name == "background-nice") {
    if (absl::Status s = ParseInt(name, value, 0, &c->background_nice); !s.ok()) return s;
    if (c->background_nice > 19)
      return absl::InvalidArgumentError(
          absl::StrCat("--background-nice: expected an integer in [0, 19], got '", value, "'"));
    return absl::OkStatus();
  } else if (name == "meshing-cores") {
    double v = 0;
    if (!absl::SimpleAtod(value, &v) || !std::isfinite(v) || v < 0 || v > 1024)
      return absl::InvalidArgumentError(absl::StrCat(
          "--meshing-cores: expected a number of cores in [0, 1024] (0 = no budget), got '", value,
          "'"));
    c->meshing_cores = v;
    return absl::OkStatus();
  } else if (name == "shutdown-deadline") {
    return ParseInt(name, value, 0, &c->shutdown_deadline_s);
  } else if (name == "tokens") {
    c->tokens_file = value;
  } else if (name == "tls-cert") {
    c->tls_cert = value;
  } else if (name == "tls-key") {
    c->tls_key = value;
  } else if (name == "tls-client-ca") {
    c->tls_client_ca = value;
  } else if (name == "replica-id") {
    // Written into session lease files and shown to other replicas: one printable word.
    const bool ok = !value.empty() && value.size() <= 128 &&
                    std::all_of(value.begin(), value.end(), [](char ch) {
                      return absl::ascii_isalnum(ch) || ch == '_' || ch == '.' || ch == '-' ||
                             ch == ':' || ch == '/';
                    });
    if (!ok)
      return absl::InvalidArgumentError(
          absl::StrCat("--replica-id: expected 1-128 characters of [A-Za-z0-9_.:/-], got '",
                       value.substr(0, 80), "'"));
    c->replica_id = value;
  } else if (name == "shared-sessions") {
    if (value != "true" && value != "false")
      return absl::InvalidArgumentError(
          absl::StrCat("--shared-sessions: expected true or false, got '", value, "'"));
    c->shared_sessions = value == "true";
  } else if (name == "insecure") {
    if (value != "true" && value != "false")
      return absl::InvalidArgumentError(
          absl::StrCat("--insecure: expected true or false, got '", value, "'"));
    c->insecure = value == "true";
  } else if (name == "host-memory-budget-bytes") {
    if (!absl::SimpleAtoi(value, &c->host_memory_budget_bytes))
      return absl::InvalidArgumentError(absl::StrCat("--", name, ": bad value '", value, "'"));
  } else {
    return absl::InvalidArgumentError(absl::StrCat("unknown setting --", raw_name));
  }
  return absl::OkStatus();
}

absl::Status ApplyFile(const std::string& path, ServerConfig* c) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("--config: cannot read ", path));
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) line.resize(hash);
    const absl::string_view trimmed = absl::StripAsciiWhitespace(line);
    if (trimmed.empty()) continue;
    const size_t eq = trimmed.find('=');
    if (eq == std::string::npos)
      return absl::InvalidArgumentError(
          absl::StrCat(path, ":", line_no, ": expected 'key = value'"));
    const std::string key(absl::StripAsciiWhitespace(trimmed.substr(0, eq)));
    const std::string value(absl::StripAsciiWhitespace(trimmed.substr(eq + 1)));
    absl::Status s = Apply(key, value, c);
    if (!s.ok())
      return absl::InvalidArgumentError(absl::StrCat(path, ":", line_no, ": ", s.message()));
  }
  return absl::OkStatus();
}

// The settings the command line takes, as the config file's keys (with dashes).
struct Setting {
  const char* name;
  bool is_switch;  // given alone on the command line (--insecure), true or false in the file
};
constexpr Setting kSettings[] = {
    {"config", false},
    {"listen", false},
    {"data-dir", false},
    {"metrics", false},
    {"http", false},
    {"web-root", false},
    {"preset", false},
    {"max-sessions", false},
    {"queue-length", false},
    {"checkpoint-every", false},
    {"max-query-points", false},
    {"max-streams", false},
    {"max-points-per-scan", false},
    {"warmup-frames", false},
    {"train-slots", false},
    {"background-nice", false},
    {"meshing-cores", false},
    {"shutdown-deadline", false},
    {"tokens", false},
    {"tls-cert", false},
    {"tls-key", false},
    {"tls-client-ca", false},
    {"replica-id", false},
    {"shared-sessions", true},
    {"insecure", true},
    {"host-memory-budget-bytes", false},
};

}  // namespace

std::string ServerUsage() {
  return "usage: rim_server --listen ADDR --data-dir DIR [--metrics ADDR] [--config FILE]\n"
         "                  [--http ADDR (browser dashboard and JSON API) [--web-root DIR]]\n"
         "                  [--preset NAME] [--max-sessions N] [--queue-length N]\n"
         "                  [--max-query-points N] [--max-points-per-scan N]\n"
         "                  [--max-streams N (open scan, query and watch streams; default 128)]\n"
         "                  [--checkpoint-every FRAMES (default 100, 0 = only on save)]\n"
         "                  [--host-memory-budget-bytes N (default 0 = none)]\n"
         "                  [--warmup-frames N (default 2; health is NOT_SERVING until done)]\n"
         "                  [--shutdown-deadline SECONDS (default 10)]\n"
         "                  [--train-slots N (frames training at once; default 0 = cores / 2)]\n"
         "                  [--background-nice N (0-19, default 5: training and meshing yield\n"
         "                   the cores to queries)]\n"
         "                  [--meshing-cores F (CPU-seconds per second all watchers' meshing\n"
         "                   may use; default a quarter of the cores, 0 = no budget)]\n"
         "                  [--tokens FILE] [--tls-cert FILE --tls-key FILE [--tls-client-ca "
         "FILE]]\n"
         "                  [--insecure (serve a non-loopback --listen without --tokens)]\n"
         "                  [--shared-sessions (replicas share --data-dir: open a session no\n"
         "                   live replica holds on its first call)] [--replica-id NAME]\n"
         "       rim_server --hash-token TOKEN|-   (SHA-256 for a --tokens line; '-': from stdin)\n"
         "access control and TLS: docs/security.md\n";
}

std::string ServerConfig::ToString() const {
  std::ostringstream s;
  s << "listen = " << listen << "\n"
    << "data_dir = " << data_dir << "\n"
    << "metrics = " << metrics << "\n"
    << "http = " << http << "\n"
    << "web_root = " << web_root << "\n"
    << "config = " << config_file << "\n"
    << "preset = " << default_preset << "\n"
    << "max_sessions = " << max_sessions << "\n"
    << "queue_length = " << queue_length << "\n"
    << "checkpoint_every_frames = " << checkpoint_every_frames << "\n"
    << "max_query_points = " << max_query_points << "\n"
    << "max_points_per_scan = " << max_points_per_scan << "\n"
    << "host_memory_budget_bytes = " << host_memory_budget_bytes << "\n"
    << "warmup_frames = " << warmup_frames << "\n"
    << "shutdown_deadline = " << shutdown_deadline_s << "\n"
    << "train_slots = " << train_slots << "\n"
    << "background_nice = " << background_nice << "\n"
    << "meshing_cores = " << meshing_cores << "\n"
    << "max_streams = " << max_streams << "\n"
    << "tokens = " << tokens_file << "\n"
    << "tls_cert = " << tls_cert << "\n"
    << "tls_key = " << tls_key << "\n"
    << "tls_client_ca = " << tls_client_ca << "\n"
    << "insecure = " << (insecure ? "true" : "false") << "\n"
    << "replica_id = " << replica_id << "\n"
    << "shared_sessions = " << (shared_sessions ? "true" : "false") << "\n";
  return s.str();
}

absl::StatusOr<ServerConfig> ParseServerConfig(int argc, char** argv) {
  // CLI11 reads the command line (rim/base/flags.h); Apply checks each value, as it does the
  // config file's. A flag given twice keeps its last value; every flag also answers to its name
  // with underscores (--data_dir), as the config file's keys do.
  CLI::App app("", "rim_server");
  std::map<std::string, std::string> given;  // setting (with dashes) -> value
  for (const Setting& setting : kSettings) {
    std::string names = absl::StrCat("--", setting.name);
    if (const std::string underscored = absl::StrReplaceAll(setting.name, {{"-", "_"}});
        underscored != setting.name)
      absl::StrAppend(&names, ",--", underscored);
    CLI::Option* option = app.add_option_function<std::string>(
        names, [&given, name = std::string(setting.name)](const std::string& value) {
          given[name] = value;
        });
    option->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
    // --insecure alone means true; --insecure=false as the config file's `insecure = false`.
    if (setting.is_switch) option->expected(0, 1);
  }
  if (absl::Status parsed = cli::Parse(app, argc, argv); !parsed.ok()) {
    // rim_server's main prints the usage for -h/--help before it asks for the config.
    if (absl::IsCancelled(parsed)) return absl::InvalidArgumentError("-h/--help is not a setting");
    return parsed;
  }
  std::vector<std::pair<std::string, std::string>> flags;
  for (const auto& [name, value] : given) {
    const bool is_switch = name == "insecure" || name == "shared-sessions";
    flags.emplace_back(name, is_switch && value.empty() ? "true" : value);
  }
  ServerConfig config;
  for (const auto& [name, value] : flags) {
    if (name == "config") config.config_file = value;
  }
  if (!config.config_file.empty()) {
    absl::Status s = ApplyFile(config.config_file, &config);
    if (!s.ok()) return s;
  }
  for (const auto& [name, value] : flags) {
    if (name == "config") continue;
    absl::Status s = Apply(name, value, &config);
    if (!s.ok()) return s;
  }
  if (config.data_dir.empty()) return absl::InvalidArgumentError("--data-dir is required");
  if (config.listen.empty()) return absl::InvalidArgumentError("--listen must not be empty");
  if (config.tls_cert.empty() != config.tls_key.empty())
    return absl::InvalidArgumentError("--tls-cert and --tls-key must be given together");
  if (!config.tls_client_ca.empty() && config.tls_cert.empty())
    return absl::InvalidArgumentError("--tls-client-ca needs --tls-cert and --tls-key");
  return config;
}

}  // namespace rim::server
