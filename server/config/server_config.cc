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
#include "rim/gpu/device_map.h"

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
  } else if (name == "device") {
    if (value != "cpu") {
      absl::StatusOr<int> index = gpu::CudaDeviceIndex(value);
      if (!index.ok())
        return absl::InvalidArgumentError(
            absl::StrCat("--device: '", value, "' is not cpu, cuda or cuda:N"));
    }
    c->device = value;
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

// The settings the command line takes, as the config file's keys (with dashes), and their help.
struct Setting {
  const char* name;
  bool is_switch;    // given alone on the command line (--insecure), true or false in the file
  const char* type;  // the value's name in the help
  const char* help;
};
constexpr Setting kSettings[] = {
    {"listen", false, "ADDR", "host:port to serve gRPC on (default 127.0.0.1:50051)"},
    {"data-dir", false, "DIR", "sessions, checkpoints and write-ahead logs (required)"},
    {"metrics", false, "ADDR", "host:port of the Prometheus /metrics endpoint (default none)"},
    {"config", false, "FILE",
     "`key = value` lines ('#' comments), keys named like the flags; the\n"
     "flags override it"},
    {"http", false, "ADDR", "host:port of the browser dashboard and its JSON API (default none)"},
    {"web-root", false, "DIR", "the dashboard's files (default: found next to the binary)"},
    {"preset", false, "NAME", "the sessions' default config preset (default maicity)"},
    {"device", false, "cpu|cuda[:N]",
     "where sessions train unless their config sets train.device\n"
     "(default cpu; cuda needs a -DRIM_CUDA=ON build, docs/gpu.md)"},
    {"max-sessions", false, "N", "sessions open at once (default 16)"},
    {"queue-length", false, "N", "scans queued per session before backpressure (default 8)"},
    {"max-query-points", false, "N", "points in one query (default 1048576)"},
    {"max-points-per-scan", false, "N", "points in one scan (default 2097152)"},
    {"max-streams", false, "N", "open scan, query and watch streams (default 128)"},
    {"checkpoint-every", false, "FRAMES",
     "a checkpoint every FRAMES frames (default 100, 0 = only on save)"},
    {"host-memory-budget-bytes", false, "N", "host memory for all sessions (default 0 = none)"},
    {"warmup-frames", false, "N",
     "frames trained at start (default 2; health is NOT_SERVING until\ndone)"},
    {"shutdown-deadline", false, "SECONDS", "SIGTERM: in-flight calls get this long (default 10)"},
    {"train-slots", false, "N", "frames training at once (default 0 = cores / 2)"},
    {"background-nice", false, "N",
     "0-19, default 5: training and meshing yield the cores to queries"},
    {"meshing-cores", false, "F",
     "CPU-seconds per second all watchers' meshing may use (default a\n"
     "tenth of the cores, 0 = no budget)"},
    {"tokens", false, "FILE", "`ROLE SUBJECT SHA256HEX` lines; callers must present a token"},
    {"tls-cert", false, "FILE", "PEM certificate chain: serve TLS (with --tls-key)"},
    {"tls-key", false, "FILE", "PEM private key of --tls-cert"},
    {"tls-client-ca", false, "FILE", "require client certificates signed by it (mTLS)"},
    {"insecure", true, "", "serve a non-loopback --listen without --tokens"},
    {"shared-sessions", true, "",
     "replicas share --data-dir: open a session no live replica holds on\n"
     "its first call"},
    {"replica-id", false, "NAME",
     "this replica's name in session leases (default: host name and\n"
     "process id)"},
};

constexpr char kSynopsis[] =
    "usage: rim_server --listen ADDR --data-dir DIR [--metrics ADDR] [--config FILE] [flags]\n"
    "       rim_server --hash-token TOKEN|-   (SHA-256 for a --tokens line; '-': from stdin)";

// The help shows each flag by its name with dashes; the underscored one (--data_dir) also works.
class ServerHelp : public cli::HelpFormatter {
 public:
  using cli::HelpFormatter::HelpFormatter;
  std::string make_option_name(const CLI::Option* option, bool) const override {
    std::string names;
    for (const std::string& s : option->get_snames()) absl::StrAppend(&names, "-", s, ",");
    return absl::StrCat(names, "--", option->get_lnames().front());
  }
};

// rim_server's flags; each given one lands in GIVEN (setting with dashes -> value, the last one).
void AddFlags(CLI::App& app, std::map<std::string, std::string>* given) {
  auto help = std::make_shared<ServerHelp>(kSynopsis, "");
  help->column_width(32);
  app.formatter(help);
  app.set_help_flag("-h,--help", "print this help and exit");
  app.footer("access control and TLS: docs/security.md");
  for (const Setting& setting : kSettings) {
    std::string names = absl::StrCat("--", setting.name);
    if (const std::string underscored = absl::StrReplaceAll(setting.name, {{"-", "_"}});
        underscored != setting.name)
      absl::StrAppend(&names, ",--", underscored);
    CLI::Option* option = app.add_option_function<std::string>(
        names,
        [given, name = std::string(setting.name)](const std::string& value) {
          (*given)[name] = value;
        },
        setting.help);
    option->type_name(setting.type)->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
    // --insecure alone means true; --insecure=false as the config file's `insecure = false`.
    if (setting.is_switch) option->expected(0, 1);
  }
  // Not a setting: a mode of its own (ParseServerConfig).
  app.add_option_function<std::string>(
         "--hash-token", [given](const std::string& value) { (*given)["hash-token"] = value; },
         "print TOKEN's digest for a --tokens line and exit ('-': from stdin)")
      ->type_name("TOKEN|-");
}

}  // namespace

std::string ServerUsage() {
  CLI::App app("", "rim_server");
  std::map<std::string, std::string> given;
  AddFlags(app, &given);
  return app.help();
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
    << "device = " << device << "\n"
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
  AddFlags(app, &given);
  // Cancelled for -h/--help: the caller prints ServerUsage().
  if (absl::Status parsed = cli::Parse(app, argc, argv); !parsed.ok()) return parsed;
  if (auto it = given.find("hash-token"); it != given.end()) {
    if (given.size() != 1) return absl::InvalidArgumentError("--hash-token takes no other flag");
    ServerConfig config;
    config.hash_token = it->second;
    return config;
  }
  std::vector<std::pair<std::string, std::string>> flags;
  for (const auto& [name, value] : given) {
    const bool is_switch = name == "insecure" || name == "shared-sessions";  // given alone
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
