// Shared pieces of the rim benchmark suite (tests/bench/README.md): the run options, the fixed
// synthetic sequence every benchmark reads, a mapper trained on it for the read-side benchmarks,
// and small helpers (resident memory, temporary folders).
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "rim/base/scan.h"
#include "rim/mapper.h"

namespace rim::bench {

// Set once by main from the command line, before any benchmark is registered.
struct BenchOptions {
  int sequence_frames = 120;  // frames of the synthetic city generated at start
  uint64_t seed = 1;          // city seed: fixed so that numbers compare run to run
  int warmup_frames = 5;      // integrated before a per-frame or per-stage measurement starts
  int measured_frames = 20;   // frames timed by each per-frame benchmark
  int map_frames = 20;     // frames integrated into the map that queries, meshing and saving read
  bool long_mode = false;  // also run the whole sequence, recording memory per frame
  std::string rss_csv;     // long mode: per-frame CSV (frame, ms, RSS, sub-map bytes); optional
};

const BenchOptions& Options();
void SetOptions(const BenchOptions& options);

// Which synthetic city a benchmark drives through.
enum class CityKind {
  kDefault,     // rim_sim's building set-backs (0-3.5 m): many facades inside the local box
  kFarReturns,  // facades set back 4-10 m (13.5-19.5 m from the street centre line): beyond the
                // default box, so most returns off buildings end outside it
};
// The building set-backs of a kind of city, "MIN-MAX m", for benchmark context lines.
const char* CityKindName(CityKind kind);

// The 64-beam city drive, `sequence_frames` frames 1 m apart, ray cast once (per kind, on first
// use) and kept in memory.
const std::vector<PosedScan>& CitySequence(CityKind kind = CityKind::kDefault);

// A preset by name; aborts on an unknown name (benchmark set-up, not user input).
MapperConfig Preset(const std::string& name);

// A maicity_online mapper that integrated the first `map_frames` frames of the sequence, built on
// first use and shared by the query, meshing and persistence benchmarks (which do not change it).
const Mapper& TrainedMapper();

// Resident set size of this process, bytes (/proc/self/statm).
int64_t ResidentBytes();

// Wall time summed over Start/Stop pairs.
class WallClock {
 public:
  void Start() { start_ = std::chrono::steady_clock::now(); }
  void Stop() { total_ += std::chrono::steady_clock::now() - start_; }
  double seconds() const { return std::chrono::duration<double>(total_).count(); }

 private:
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::duration total_{};
};

// A new empty folder under the system temporary directory; removed by the destructor.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }
  int64_t SizeBytes() const;  // all regular files below it

 private:
  std::string path_;
};

// Aborts with the status message when `status` is not OK: a benchmark whose set-up failed must
// not report numbers.
void CheckOk(const absl::Status& status, const char* what);

// Registration hooks, one per benchmark file; main calls them after parsing the options.
void RegisterStageBenchmarks();
void RegisterReferenceBenchmarks();
void RegisterFrameBenchmarks();
void RegisterFrameStageBenchmarks();  // Stage/Slide, Stage/Preprocess (bench_frames.cc)
void RegisterMapBenchmarks();
void RegisterSequenceBenchmarks();

}  // namespace rim::bench
