// rim_bench: the benchmark suite (tests/bench/README.md). Google Benchmark's own flags
// (--benchmark_filter, --benchmark_repetitions, --benchmark_out, ...) pass through; the rim_*
// flags below size the workload and are read first.
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench/bench_common.h"
#include "rim/base/version.h"

namespace {

constexpr char kUsage[] =
    "rim_bench [benchmark flags] [rim flags]\n"
    "  --rim_long                 also run Sequence/*: the whole sequence, memory per frame\n"
    "                             (or RIM_BENCH_LONG=1 in the environment)\n"
    "  --rim_rss_csv=PREFIX       long mode: write PREFIX.<preset>.csv, one row per frame\n"
    "  --rim_sequence_frames=N    city frames generated at start (default 120)\n"
    "  --rim_warmup_frames=N      frames integrated before timing (default 5)\n"
    "  --rim_measured_frames=N    frames timed by Frame/* (default 20)\n"
    "  --rim_map_frames=N         frames in the map that Query/Mesh/Session read (default 20)\n"
    "  --rim_seed=S               city seed (default 1)\n";

// Parses "--name=value" into *value; false when `arg` is another flag.
bool IntFlag(const char* arg, const char* name, int* value) {
  const size_t len = std::strlen(name);
  if (std::strncmp(arg, name, len) != 0 || arg[len] != '=') return false;
  char* end = nullptr;
  const long v = std::strtol(arg + len + 1, &end, 10);
  if (*end != '\0' || v < 0) {
    std::fprintf(stderr, "rim_bench: bad value in %s\n%s", arg, kUsage);
    std::exit(2);
  }
  *value = int(v);
  return true;
}

// Takes the rim_* flags out of argv; the rest go to Google Benchmark.
rim::bench::BenchOptions ParseRimFlags(int* argc, char** argv) {
  rim::bench::BenchOptions o;
  const char* env_long = std::getenv("RIM_BENCH_LONG");
  o.long_mode = env_long != nullptr && std::strcmp(env_long, "0") != 0 && *env_long != '\0';
  int seed = int(o.seed);
  int kept = 1;
  for (int i = 1; i < *argc; ++i) {
    const char* a = argv[i];
    if (std::strcmp(a, "--help") == 0) std::fputs(kUsage, stdout);  // then the library's help
    if (std::strcmp(a, "--rim_long") == 0) {
      o.long_mode = true;
    } else if (std::strncmp(a, "--rim_rss_csv=", 14) == 0) {
      o.rss_csv = a + 14;
    } else if (IntFlag(a, "--rim_sequence_frames", &o.sequence_frames) ||
               IntFlag(a, "--rim_warmup_frames", &o.warmup_frames) ||
               IntFlag(a, "--rim_measured_frames", &o.measured_frames) ||
               IntFlag(a, "--rim_map_frames", &o.map_frames) || IntFlag(a, "--rim_seed", &seed)) {
    } else if (std::strncmp(a, "--rim_", 6) == 0) {
      std::fprintf(stderr, "rim_bench: unknown flag %s\n%s", a, kUsage);
      std::exit(2);
    } else {
      argv[kept++] = argv[i];
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
