// rim_tsdf: the TSDF reference mapper (tsdf_reference.h) over a dataset, for benchmarks.
//
//   rim_tsdf DATASET --out DIR [--frames A:B] [--voxel M] [--trunc M] [--carve]
//            [--min-weight W] [--max-range M] [--min-range M]
//
// Reads the dataset with rim's readers (any layout rim_map reads), integrates every frame on one
// thread, extracts the mesh, and writes DIR/mesh.ply and DIR/timing.json: frames,
// ms_per_frame_integrate, ms_extract, ms_per_frame ((integration + extraction) / frames; reading
// and writing files are left out, as rim_map leaves them out), peak_rss_mib, grid_mib and the
// options. The minimum weight defaults to 1 with --carve and 5 without.
#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "rim/base/binary_io.h"
#include "rim/base/flags.h"
#include "rim/base/status_macros.h"
#include "rim/io/dataset.h"
#include "rim/io/mesh_io.h"
#include "tsdf/tsdf_reference.h"

namespace rim::bench {
namespace {

constexpr char kSynopsis[] =
    "usage: rim_tsdf DATASET --out DIR [--frames A:B] [--voxel M] [--trunc M] [--carve]\n"
    "                [--min-weight W] [--max-range M] [--min-range M]";

struct Args {
  std::string dataset, out;
  long first = 0, last = -1;  // [first, last), last < 0: to the end
  TsdfOptions options;
};

// The command line (rim/base/flags.h): APP's options fill ARGS.
void AddFlags(CLI::App& app, Args& a) {
  cli::SetHelp(app, kSynopsis, "", 18);
  auto finite = [](const char* flag) {
    return cli::Finite([flag](const std::string& text) {
      return absl::StrCat(flag, " '", text, "' is not a finite number");
    });
  };
  // Every flag keeps its last value when given twice, as rim_tsdf always did.
  auto last = [](CLI::Option* o) {
    return o->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  };
  app.add_option("DATASET", a.dataset, "the dataset, any layout rim_map reads")->type_name("");
  last(app.add_option("--out", a.out, "output folder: mesh.ply and timing.json")->type_name("DIR"));
  cli::AddFrameRange(app, &a.first, &a.last);
  last(app.add_option("--voxel", a.options.voxel_m, "voxel size in metres (default 0.1)")
           ->type_name("M")
           ->transform(finite("--voxel")));
  last(app.add_option("--trunc", a.options.truncation_m,
                      "truncation distance in metres, at least the voxel (default 0.3)")
           ->type_name("M")
           ->transform(finite("--trunc")));
  app.add_flag("--carve", a.options.space_carving,
               "space carving: rays clear the free space from the sensor on");
  last(app.add_option("--min-weight", a.options.min_weight,
                      "mesh only cubes whose corners have this weight (default 1 with --carve,\n"
                      "5 without)")
           ->type_name("W")
           ->transform(finite("--min-weight")));
  last(app.add_option("--max-range", a.options.max_range_m,
                      "skip returns farther than this (default 60)")
           ->type_name("M")
           ->transform(finite("--max-range")));
  last(app.add_option("--min-range", a.options.min_range_m,
                      "skip returns nearer than this (default 0.3)")
           ->type_name("M")
           ->transform(finite("--min-range")));
}

absl::Status CheckArgs(const CLI::App& app, Args& a) {
  if (a.dataset.empty()) return absl::InvalidArgumentError("missing DATASET");
  if (a.out.empty()) return absl::InvalidArgumentError("missing --out DIR");
  if (app.count("--min-weight") == 0) a.options.min_weight = a.options.space_carving ? 1.f : 5.f;
  const TsdfOptions& o = a.options;
  if (!(o.voxel_m > 0)) return absl::InvalidArgumentError("--voxel must be > 0 metres");
  if (o.voxel_m < 1e-3)  // voxel indices are 32-bit
    return absl::InvalidArgumentError("--voxel must be at least 0.001 metres");
  if (!(o.truncation_m >= o.voxel_m))
    return absl::InvalidArgumentError(
        absl::StrCat("--trunc ", o.truncation_m, " must be at least the voxel (", o.voxel_m, ")"));
  if (!(o.min_weight > 0)) return absl::InvalidArgumentError("--min-weight must be > 0");
  if (!(o.min_range_m >= 0)) return absl::InvalidArgumentError("--min-range must be >= 0 metres");
  if (!(o.max_range_m > o.min_range_m))
    return absl::InvalidArgumentError(
        absl::StrCat(app.count("--max-range") ? "--max-range" : "--min-range", " leaves no range: ",
                     "--max-range ", o.max_range_m, " must exceed --min-range ", o.min_range_m));
  return absl::OkStatus();
}

double PeakRssMib() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;  // kilobytes on Linux
}

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

absl::Status Run(const Args& args) {
  RIM_ASSIGN_OR_RETURN(auto dataset, io::Dataset::Open(args.dataset));
  const long n = long(dataset->size());
  const long first = std::min(args.first, n), last = args.last < 0 ? n : std::min(args.last, n);
  if (first >= last)
    return absl::InvalidArgumentError(absl::StrCat("--frames selects no frame of ", n));
  RIM_RETURN_IF_ERROR(MakeDirs(args.out));
  const TsdfOptions& o = args.options;
  std::fprintf(stderr,
               "rim_tsdf: %s (%s, %ld frames), voxel %.3g m, truncation %.3g m, %s, min weight "
               "%g\n",
               args.dataset.c_str(), io::LayoutName(dataset->layout()), last - first, o.voxel_m,
               o.truncation_m, o.space_carving ? "space carving" : "no carving",
               double(o.min_weight));

  TsdfIntegrator tsdf(o);
  double integrate_s = 0;
  std::vector<Eigen::Vector3d> points_W;
  for (long i = first; i < last; ++i) {
    RIM_ASSIGN_OR_RETURN(PosedScan scan, dataset->Read(size_t(i)));
    const auto start = std::chrono::steady_clock::now();
    const Eigen::Isometry3d& T = scan.T_world_sensor;
    if (scan.origins_S.empty()) {
      points_W.resize(scan.points_S.size());
      for (size_t k = 0; k < scan.points_S.size(); ++k)
        points_W[k] = T * scan.points_S[k].cast<double>();
      tsdf.Integrate(points_W, T.translation());
    } else {
      for (size_t k = 0; k < scan.points_S.size(); ++k)
        tsdf.IntegrateRay(T * scan.origins_S[k].cast<double>(),
                          T * scan.points_S[k].cast<double>());
    }
    integrate_s += Seconds(start);
    const long done = i - first + 1;
    std::fprintf(stderr, "\r%ld/%ld frames  %.0f ms/frame  %.1f MiB of grids ", done, last - first,
                 1e3 * integrate_s / double(done), double(tsdf.MemoryBytes()) / (1 << 20));
    std::fflush(stderr);
  }
  std::fprintf(stderr, "\n");

  const auto extract_start = std::chrono::steady_clock::now();
  const Mesh mesh = tsdf.Extract(o.min_weight);
  const double extract_s = Seconds(extract_start);
  RIM_RETURN_IF_ERROR(WriteMeshPly(args.out + "/mesh.ply", mesh));

  const double frames = double(last - first);
  const double grid_mib = double(tsdf.MemoryBytes()) / (1024.0 * 1024.0);
  nlohmann::json timing = {
      {"frames", long(frames)},
      {"ms_per_frame_integrate", 1e3 * integrate_s / frames},
      {"ms_extract", 1e3 * extract_s},
      {"ms_per_frame", 1e3 * (integrate_s + extract_s) / frames},
      {"peak_rss_mib", PeakRssMib()},
      {"grid_mib", grid_mib},
      {"active_voxels", tsdf.ActiveVoxels()},
      {"rays", tsdf.rays()},
      {"voxel_updates", tsdf.voxel_updates()},
      {"vertices", mesh.vertices.size()},
      {"faces", mesh.faces.size()},
      {"voxel_m", o.voxel_m},
      {"truncation_m", o.truncation_m},
      {"space_carving", o.space_carving},
      {"min_weight", o.min_weight},
      {"min_range_m", o.min_range_m},
      {"max_range_m", o.max_range_m},
      {"threads", 1},
      {"dataset", args.dataset},
      {"frame_range", {first, last}},
  };
  std::ofstream f(args.out + "/timing.json");
  f << timing.dump(2) << "\n";
  if (!f) return absl::InternalError(absl::StrCat("cannot write ", args.out, "/timing.json"));
  std::printf(
      "%.0f frames: %.1f ms/frame integration, extraction %.0f ms, %.1f ms/frame in all; grids "
      "%.1f MiB (%zu voxels), peak RSS %.0f MiB\nmesh: %zu vertices, %zu faces -> %s/mesh.ply\n",
      frames, 1e3 * integrate_s / frames, 1e3 * extract_s, 1e3 * (integrate_s + extract_s) / frames,
      grid_mib, tsdf.ActiveVoxels(), PeakRssMib(), mesh.vertices.size(), mesh.faces.size(),
      args.out.c_str());
  return absl::OkStatus();
}

}  // namespace
}  // namespace rim::bench

int main(int argc, char** argv) {
  rim::bench::Args args;
  CLI::App app;
  rim::bench::AddFlags(app, args);
  absl::Status parsed = rim::cli::Parse(app, argc, argv);
  if (absl::IsCancelled(parsed)) {
    std::fputs(app.help().c_str(), stdout);
    return 0;
  }
  if (parsed.ok()) parsed = rim::bench::CheckArgs(app, args);
  if (!parsed.ok()) {
    std::fprintf(stderr, "rim_tsdf: %s\n%s", std::string(parsed.message()).c_str(),
                 app.help().c_str());
    return 2;
  }
  const absl::Status s = rim::bench::Run(args);
  if (!s.ok()) {
    std::fprintf(stderr, "rim_tsdf: %s\n", s.ToString().c_str());
    return 1;
  }
  return 0;
}
