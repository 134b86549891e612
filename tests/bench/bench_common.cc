#include "bench/bench_common.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>

#include "sim/city_frames.h"

namespace rim::bench {
namespace {

BenchOptions& MutableOptions() {
  static BenchOptions options;
  return options;
}

}  // namespace

const BenchOptions& Options() { return MutableOptions(); }
void SetOptions(const BenchOptions& options) { MutableOptions() = options; }

void CheckOk(const absl::Status& status, const char* what) {
  if (status.ok()) return;
  std::fprintf(stderr, "rim_bench: %s failed: %s\n", what, status.ToString().c_str());
  std::abort();
}

const char* CityKindName(CityKind kind) {
  return kind == CityKind::kFarReturns ? "set-backs 4-10 m (far returns)" : "set-backs 0-3.5 m";
}

const std::vector<PosedScan>& CitySequence(CityKind kind) {
  auto make = [](CityKind kind) {
    const auto start = std::chrono::steady_clock::now();
    sim::CityFrameOptions city;
    city.frames = Options().sequence_frames;
    city.seed = Options().seed;
    if (kind == CityKind::kFarReturns) {
      city.buildings.setback_min = 4.0;
      city.buildings.setback_max = 10.0;
    }
    const sim::CityFrames source(city);
    auto* out = new std::vector<PosedScan>();
    out->reserve(source.size());
    size_t points = 0;
    for (size_t k = 0; k < source.size(); ++k) {
      out->push_back(source.Frame(k));
      points += out->back().points_S.size();
    }
    const double s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(
        stderr, "rim_bench: city sequence, seed %llu, %s: %zu frames, %zu points, %.1f s\n",
        static_cast<unsigned long long>(city.seed), CityKindName(kind), out->size(), points, s);
    return out;
  };
  static std::mutex mu;
  static std::map<CityKind, const std::vector<PosedScan>*> cities;
  std::lock_guard<std::mutex> lock(mu);
  auto it = cities.find(kind);
  if (it == cities.end()) it = cities.emplace(kind, make(kind)).first;
  return *it->second;
}

MapperConfig Preset(const std::string& name) {
  absl::StatusOr<MapperConfig> config = MakePreset(name);
  CheckOk(config.status(), "MakePreset");
  return *config;
}

const Mapper& TrainedMapper() {
  static const Mapper* mapper = [] {
    const auto start = std::chrono::steady_clock::now();
    absl::StatusOr<std::unique_ptr<Mapper>> created = Mapper::Create(Preset("maicity_online"));
    CheckOk(created.status(), "Mapper::Create");
    const std::vector<PosedScan>& frames = CitySequence();
    const int n = std::min<int>(Options().map_frames, int(frames.size()));
    for (int k = 0; k < n; ++k) CheckOk((*created)->IntegrateScan(frames[k]), "IntegrateScan");
    const double s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr, "rim_bench: trained map, maicity_online, %d frames, %.1f s\n", n, s);
    return created->release();
  }();
  return *mapper;
}

int64_t ResidentBytes() {
  std::ifstream statm("/proc/self/statm");
  int64_t size_pages = 0, resident_pages = 0;
  statm >> size_pages >> resident_pages;
  return resident_pages * int64_t(sysconf(_SC_PAGESIZE));
}

TempDir::TempDir() {
  std::string pattern = (std::filesystem::temp_directory_path() / "rim_bench.XXXXXX").string();
  if (mkdtemp(pattern.data()) == nullptr) {
    std::perror("rim_bench: mkdtemp");
    std::abort();
  }
  path_ = pattern;
}

TempDir::~TempDir() {
  std::error_code ec;
  std::filesystem::remove_all(path_, ec);
}

int64_t TempDir::SizeBytes() const {
  int64_t total = 0;
  for (const auto& e : std::filesystem::recursive_directory_iterator(path_))
    if (e.is_regular_file()) total += int64_t(e.file_size());
  return total;
}

}  // namespace rim::bench
