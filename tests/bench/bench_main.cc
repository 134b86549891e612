// rim_bench: the benchmark suite (tests/bench/README.md). Google Benchmark's own flags
// (--benchmark_filter, --benchmark_repetitions, --benchmark_out, ...) pass through; the rim_*
// flags below size the workload and are read first.
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "bench/bench_common.h"
#include "rim/base/flags.h"
#include "rim/base/version.h"

namespace {

constexpr char kSynopsis[] = "rim_bench [benchmark flags] [rim flags]";

// Takes the rim_* flags out of argv (CLI11, rim/base/flags.h); the rest go to Google Benchmark.
rim::bench::BenchOptions ParseRimFlags(int* argc, char** argv) {
  rim::bench::BenchOptions o;
  const char* env_long = std::getenv("RIM_BENCH_LONG");
  o.long_mode = env_long != nullptr && std::strcmp(env_long, "0") != 0 && *env_long != '\0';
  int seed = int(o.seed);
  CLI::App app("", "rim_bench");
  rim::cli::SetHelp(app, kSynopsis, "", 29);
  app.set_help_flag();  // --help goes on to the library, which prints its own flags after ours
  auto count = [&app](const char* flag, int* value, const char* description) {
    app.add_option(flag, *value, description)
        ->type_name("N")
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast)
        ->transform(
            rim::cli::IntegerIn(0, std::numeric_limits<int>::max(), [flag](const std::string& v) {
              return std::string("bad value in ") + flag + "=" + v;
            }));
  };
  app.add_flag("--rim_long", o.long_mode,
               "also run Sequence/*: the whole sequence, memory per frame\n"
               "(or RIM_BENCH_LONG=1 in the environment)");
  app.add_option("--rim_rss_csv", o.rss_csv,
                 "long mode: write PREFIX.<preset>.csv, one row per frame")
      ->type_name("PREFIX")
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  count("--rim_sequence_frames", &o.sequence_frames,
        "city frames generated at start (default 120)");
  count("--rim_warmup_frames", &o.warmup_frames, "frames integrated before timing (default 5)");
  count("--rim_measured_frames", &o.measured_frames, "frames timed by Frame/* (default 20)");
  count("--rim_map_frames", &o.map_frames,
        "frames in the map that Query/Mesh/Session read (default 20)");
  count("--rim_seed", &seed, "city seed (default 1)");
  std::vector<std::string> rest;  // Google Benchmark's flags, in their order
  const absl::Status parsed =
      rim::cli::Parse(app, std::vector<std::string>(argv + 1, argv + *argc), &rest);
  if (!parsed.ok()) {
    std::fprintf(stderr, "rim_bench: %s\n%s", std::string(parsed.message()).c_str(),
                 app.help().c_str());
    std::exit(2);
  }
  for (const std::string& word : rest) {
    if (word == "--help") std::fputs(app.help().c_str(), stdout);  // then the library's help
    if (word.rfind("--rim_", 0) == 0) {
      std::fprintf(stderr, "rim_bench: unknown flag %s\n%s", word.c_str(), app.help().c_str());
      std::exit(2);
    }
  }
  // argv keeps its own strings: the words CLI11 left, in order, are a subsequence of it.
  int kept = 1;
  for (int i = 1, next = 0; i < *argc && next < int(rest.size()); ++i) {
    if (rest[size_t(next)] == argv[i]) {
      argv[kept++] = argv[i];
      ++next;
    }
  }
  *argc = kept;
  o.seed = uint64_t(seed);
  if (o.measured_frames < 1 || o.sequence_frames < o.warmup_frames + o.measured_frames) {
    std::fprintf(stderr,
                 "rim_bench: need measured_frames >= 1 and sequence_frames >= "
                 "warmup_frames + measured_frames\n");
    std::exit(2);
  }
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  rim::bench::SetOptions(ParseRimFlags(&argc, argv));
  const rim::bench::BenchOptions& o = rim::bench::Options();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;

  benchmark::AddCustomContext("rim_version", rim::kRimVersion);
  benchmark::AddCustomContext("torch_version", rim::TorchVersion());
  benchmark::AddCustomContext("rim_sequence", "city seed " + std::to_string(o.seed) + ", " +
                                                  std::to_string(o.sequence_frames) +
                                                  " frames, 64 beams x 1800 columns");
  benchmark::AddCustomContext("rim_frames", "warm-up " + std::to_string(o.warmup_frames) +
                                                ", measured " + std::to_string(o.measured_frames) +
                                                ", map " + std::to_string(o.map_frames));

  rim::bench::CitySequence();  // made before anything is timed
  rim::bench::RegisterStageBenchmarks();
  rim::bench::RegisterFrameStageBenchmarks();
  rim::bench::RegisterReferenceBenchmarks();
  rim::bench::RegisterFrameBenchmarks();
  rim::bench::RegisterMapBenchmarks();
  if (o.long_mode) rim::bench::RegisterSequenceBenchmarks();

  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
