// rim_map: offline mapping of a dataset with the core mapper, no server.
//
//   rim_map DATASET --preset NAME --out DIR [--frames A:B] [--set key=value ...]
//           [--config FILE] [--tiles] [--probe metric|neural] [--query-points FILE]
//
// --probe scores the distances the final map answers against the dataset's ground truth
// (rim_sim's gt.ply and gt_observed.ply) at free-space points on its rays (eval/distance_probe.h):
// `metric` asks QuerySdf, `neural` the network's own values. Writes DIR/probe.json.
// --query-points reads CSV x,y,z (header optional) and writes DIR/query.csv with the final map's
// answers, x,y,z,sdf,observed,gx,gy,gz,gt_distance: g is the distance's gradient (so the nearest
// mapped surface lies at p - sdf * g), gt_distance the exact distance to the dataset's gt.ply
// (empty when it has none), for checks at chosen places (where people walked, say).
// Writes DIR/mesh.ply (all tiles, welded), DIR/tiles/*.ply with --tiles, DIR/timing.json
// (per-stage mean times, ms/frame, frames/s, peak and per-frame memory) and DIR/run.json (config
// and versions), and prints the per-stage table in the layout of the paper's module-time table.
#include <sys/resource.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "rim/base/binary_io.h"
#include "rim/base/flags.h"
#include "rim/base/status_macros.h"
#include "rim/base/version.h"
#include "rim/config/config.h"
#include "rim/eval/distance_probe.h"
#include "rim/io/dataset.h"
#include "rim/io/json.h"
#include "rim/io/mesh_io.h"
#include "rim/io/ply_points.h"
#include "rim/map/submap_store.h"
#include "rim/mapper.h"

namespace rim {
namespace {

struct Args {
  std::string dataset, preset = "maicity", out, config_file;
  std::vector<std::string> overrides;
  long first = 0, last = -1;  // [first, last), last < 0: to the end
  bool tiles = false;
  std::string probe;  // "", "metric" or "neural"
  std::string query_points;
  std::string device;  // "": the config's train.device
};

constexpr char kSynopsis[] =
    "usage: rim_map DATASET --preset NAME --out DIR [--frames A:B] [--set key=value ...]\n"
    "               [--config FILE] [--tiles] [--probe metric|neural] [--query-points FILE]\n"
    "               [--device cpu|cuda|cuda:N]";
constexpr char kDescription[] =
    "Offline mapping of a dataset with the core mapper, no server. Writes DIR/mesh.ply (all\n"
    "tiles, welded), DIR/timing.json (per-stage mean times, ms/frame, frames/s, peak and\n"
    "per-frame memory) and DIR/run.json (config and versions), and prints the per-stage table.";

// rim_map's flags (rim/base/flags.h), into A. A flag given twice keeps its last value, as rim_map
// always did; --set adds one override each time.
void AddFlags(CLI::App& app, Args& a) {
  cli::SetHelp(app, kSynopsis, kDescription, 25);
  auto last = [](CLI::Option* o) {
    return o->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  };
  app.add_option("DATASET", a.dataset, "the dataset folder, any layout rim::io::Dataset reads")
      ->type_name("");
  last(app.add_option("--preset", a.preset,
                      "the config preset (default maicity; with --config the file's\n"
                      "preset = X line chooses)")
           ->type_name("NAME"));
  last(app.add_option("--out", a.out, "output folder (required)")->type_name("DIR"));
  cli::AddFrameRange(app, &a.first, &a.last);
  app.add_option("--set", a.overrides,
                 "a config override, applied after the preset or the config file; one per\n"
                 "--set, repeatable")
      ->type_name("key=value")
      ->allow_extra_args(false);  // one value per --set
  last(app.add_option("--config", a.config_file,
                      "a config file: key = value lines, # comments, a preset = X line selects\n"
                      "the base")
           ->type_name("FILE"));
  app.add_flag("--tiles", a.tiles, "also write DIR/tiles/*.ply");
  last(app.add_option("--device", a.device,
                      "where the training iterations run: cpu, or cuda / cuda:N in a build with\n"
                      "-DRIM_CUDA=ON (docs/gpu.md); sets train.device after --set")
           ->type_name("cpu|cuda[:N]"));
  last(app.add_option("--probe", a.probe,
                      "score the final map's distances against the dataset's ground truth\n"
                      "(rim_sim's gt.ply and gt_observed.ply) at free-space points on its rays:\n"
                      "metric asks QuerySdf, neural the network's own values; writes\n"
                      "DIR/probe.json")
           ->type_name("metric|neural")
           ->transform(cli::Check([](std::string& v) { return v == "metric" || v == "neural"; },
                                  [](const std::string& v) {
                                    return absl::StrCat("--probe '", v,
                                                        "' is not metric or neural");
                                  })));
  last(
      app.add_option("--query-points", a.query_points,
                     "read CSV x,y,z (header optional) and write DIR/query.csv with the final\n"
                     "map's answers, x,y,z,sdf,observed,gx,gy,gz,gt_distance: g is the\n"
                     "distance's gradient, gt_distance the exact distance to the dataset's gt.ply\n"
                     "(empty when it has none)")
          ->type_name("FILE"));
}

absl::Status CheckArgs(const Args& a) {
  if (a.dataset.empty()) return absl::InvalidArgumentError("missing DATASET");
  if (a.out.empty()) return absl::InvalidArgumentError("missing --out DIR");
  return absl::OkStatus();
}

double CurrentRssMb() {
  std::ifstream statm("/proc/self/statm");
  long pages = 0, resident = 0;
  statm >> pages >> resident;
  return double(resident) * double(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

double PeakRssMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;  // kilobytes on Linux
}

void ProgressBar(size_t done, size_t total, double ms_per_frame, float loss) {
  const int width = 30;
  const int filled = total ? int(width * done / total) : width;
  std::fprintf(stderr, "\r[%s%s] %zu/%zu frames  %.0f ms/frame  loss %.4f ",
               std::string(filled, '#').c_str(), std::string(width - filled, '.').c_str(), done,
               total, ms_per_frame, loss);
  std::fflush(stderr);
}

// --query-points: the final map's answers at the file's points, beside the exact distance to
// the dataset's ground truth when it has one.
absl::Status AnswerQueryPoints(const Args& args, const Mapper& mapper) {
  std::ifstream in(args.query_points);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read ", args.query_points));
  std::vector<float> xyz;
  std::string line;
  for (int row = 1; std::getline(in, line); ++row) {
    if (line.empty()) continue;
    std::vector<std::string> f = absl::StrSplit(line, ',');
    float v[3];
    if (f.size() != 3 || !absl::SimpleAtof(f[0], &v[0]) || !absl::SimpleAtof(f[1], &v[1]) ||
        !absl::SimpleAtof(f[2], &v[2])) {
      if (row == 1 && xyz.empty()) continue;  // a header
      return absl::InvalidArgumentError(
          absl::StrCat(args.query_points, ":", row, ": expected x,y,z, got '", line, "'"));
    }
    xyz.insert(xyz.end(), {v[0], v[1], v[2]});
  }
  QueryResult q;
  RIM_RETURN_IF_ERROR(mapper.QuerySdf(xyz.data(), xyz.size() / 3, true, &q));
  std::unique_ptr<eval::MeshDistance> gt;
  if (std::ifstream(args.dataset + "/gt.ply").good()) {
    RIM_ASSIGN_OR_RETURN(Mesh mesh, ReadMeshPly(args.dataset + "/gt.ply"));
    gt = std::make_unique<eval::MeshDistance>(mesh);
  }
  std::string out = "x,y,z,sdf,observed,gx,gy,gz,gt_distance\n";
  for (size_t i = 0; i < q.sdf.size(); ++i) {
    absl::StrAppendFormat(&out, "%.4f,%.4f,%.4f,%.4f,%d,%.4f,%.4f,%.4f,", xyz[3 * i],
                          xyz[3 * i + 1], xyz[3 * i + 2], q.sdf[i], q.observed[i] ? 1 : 0,
                          q.gradient[3 * i], q.gradient[3 * i + 1], q.gradient[3 * i + 2]);
    if (gt) {
      std::array<float, 3> nearest;
      absl::StrAppendFormat(&out, "%.4f",
                            gt->Nearest({xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]}, &nearest));
    }
    out += "\n";
  }
  std::ofstream f(args.out + "/query.csv");
  f << out;
  if (!f) return absl::InternalError(absl::StrCat("cannot write ", args.out, "/query.csv"));
  return absl::OkStatus();
}

absl::Status Run(const Args& args) {
  MapperConfig config;
  std::vector<std::string> overrides = args.overrides;
  if (!args.device.empty()) overrides.push_back("train.device=" + args.device);
  if (!args.config_file.empty()) {
    RIM_ASSIGN_OR_RETURN(config, LoadConfigFile(args.config_file, overrides));
  } else {
    RIM_ASSIGN_OR_RETURN(config, MakePreset(args.preset));
    RIM_RETURN_IF_ERROR(ApplyOverrides(overrides, &config));
  }
  RIM_ASSIGN_OR_RETURN(auto dataset, io::Dataset::Open(args.dataset));
  const long n = long(dataset->size());
  const long first = std::min(args.first, n), last = args.last < 0 ? n : std::min(args.last, n);
  if (first >= last)
    return absl::InvalidArgumentError(absl::StrCat("--frames selects no frame of ", n));
  RIM_RETURN_IF_ERROR(MakeDirs(args.out));
  std::fprintf(stderr, "rim_map: %s (%s, %ld frames), preset %s\n", args.dataset.c_str(),
               io::LayoutName(dataset->layout()), last - first, config.preset.c_str());
  RIM_ASSIGN_OR_RETURN(auto mapper, Mapper::Create(config));

  StageTimings sum;
  std::vector<double> rss_mb, submap_mb, deferred_mb, distance_mb, ms_per_frame;
  const auto start = std::chrono::steady_clock::now();
  for (long i = first; i < last; ++i) {
    RIM_ASSIGN_OR_RETURN(PosedScan scan, dataset->Read(size_t(i)));
    StageTimings t;
    RIM_RETURN_IF_ERROR(mapper->IntegrateScan(scan, -1, &t));
    sum += t;
    rss_mb.push_back(CurrentRssMb());
    const MapperStats stats = mapper->Stats();
    submap_mb.push_back(double(stats.submap_bytes) / (1024.0 * 1024.0));
    deferred_mb.push_back(double(stats.deferred_bytes) / (1024.0 * 1024.0));
    distance_mb.push_back(double(stats.distance_bytes) / (1024.0 * 1024.0));
    ms_per_frame.push_back(1e3 * t.total_s);
    ProgressBar(size_t(i - first + 1), size_t(last - first),
                1e3 * sum.total_s / double(i - first + 1), t.loss);
  }
  std::fprintf(stderr, "\n");
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  // Queries after the run see the final map.
  const double final_refresh_s = mapper->RefreshDistanceField();

  // Mesh every tile and weld the shared border vertices.
  const auto mesh_start = std::chrono::steady_clock::now();
  Mesh merged;
  if (args.tiles) RIM_RETURN_IF_ERROR(MakeDirs(args.out + "/tiles"));
  for (const TileInfo& tile : mapper->ListTiles(0)) {
    RIM_ASSIGN_OR_RETURN(Mesh mesh, mapper->ExtractMeshTile(tile.key));
    if (mesh.empty()) continue;
    if (args.tiles)
      RIM_RETURN_IF_ERROR(WriteMeshPly(
          absl::StrCat(args.out, "/tiles/tile_", SubmapKeyName(tile.key), ".ply"), mesh));
    AppendMesh(mesh, &merged);
  }
  merged = WeldIdenticalVertices(merged);
  RIM_RETURN_IF_ERROR(WriteMeshPly(args.out + "/mesh.ply", merged));
  const double mesh_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - mesh_start).count();

  const double frames = double(last - first);
  const double iters = std::max(1, sum.iterations);
  struct Row {
    const char* name;
    double seconds;
    bool per_iteration;
  };
  // "transient" is part of "preprocess": the moving-things filter. With a GPU, "step" is the
  // iterations on the device and "sync" its part that moves rows to and from the host map.
  std::vector<Row> rows = {
      {"slide", sum.slide_s, false},         {"preprocess", sum.preprocess_s, false},
      {"transient", sum.transient_s, false}, {"sample", sum.sample_s, true},
      {"encode", sum.encode_s, true},        {"forward", sum.forward_s, true},
      {"backward", sum.backward_s, true},    {"step", sum.step_s, true},
      {"distance", sum.distance_s, false}};
  if (config.train.device != "cpu") rows.insert(rows.end() - 1, {"sync", sum.sync_s, false});
  std::printf("\n%-12s %12s %12s\n", "module", "ms/frame", "ms/iter");
  for (const Row& r : rows) {
    if (r.per_iteration)
      std::printf("%-12s %12.2f %12.3f\n", r.name, 1e3 * r.seconds / frames,
                  1e3 * r.seconds / iters);
    else
      std::printf("%-12s %12.2f %12s\n", r.name, 1e3 * r.seconds / frames, "-");
  }
  std::printf("%-12s %12.2f %12s\n", "total", 1e3 * sum.total_s / frames, "-");
  std::printf("\n%.0f frames, %.1f iterations/frame, %.2f frames/s, peak RSS %.0f MB\n", frames,
              iters / frames, frames / wall_s, PeakRssMb());
  std::printf("mesh: %zu vertices, %zu faces in %.1f s -> %s/mesh.ply\n", merged.vertices.size(),
              merged.faces.size(), mesh_s, args.out.c_str());
  const MapperStats final_stats = mapper->Stats();
  std::printf("distance field: %lld surfels, %lld returns, %.1f MB, final refresh %.0f ms\n",
              (long long)final_stats.distance_surfels, (long long)final_stats.distance_returns,
              double(final_stats.distance_bytes) / 1e6, 1e3 * final_refresh_s);
  std::printf(
      "moving things: %lld buffered returns (%lld of them new where an earlier scan saw free, "
      "%lld in busy places by passes added up), %lld deferred rays and %lld voxels the box had "
      "left seen through, dropped\n",
      (long long)final_stats.transient_buffer_removed,
      (long long)final_stats.transient_past_removed, (long long)final_stats.transient_busy_removed,
      (long long)final_stats.transient_deferred_removed,
      (long long)final_stats.transient_departed_removed);

  // timing.json: the table above, the memory and the time of every frame.
  using Json = nlohmann::ordered_json;
  using io::JsonNumber;
  Json per_frame = Json::object(), per_iteration = Json::object();
  for (const Row& r : rows) {
    per_frame[r.name] = JsonNumber(1e3 * r.seconds / frames, 4);
    if (r.per_iteration) per_iteration[r.name] = JsonNumber(1e3 * r.seconds / iters, 4);
  }
  auto series = [](const std::vector<double>& values) {
    Json out = Json::array();
    for (double v : values) out.push_back(JsonNumber(v, 1));
    return out;
  };
  const Json timing = {
      {"stages_ms_per_frame", per_frame},
      {"stages_ms_per_iteration", per_iteration},
      {"ms_per_frame", JsonNumber(1e3 * sum.total_s / frames, 3)},
      {"frames_per_s", JsonNumber(frames / wall_s, 4)},
      {"frames", last - first},
      {"iterations_per_frame", JsonNumber(iters / frames, 3)},
      {"peak_rss_mb", JsonNumber(PeakRssMb(), 1)},
      {"device_memory_mb",
       final_stats.device == "cpu" ? Json(nullptr) : JsonNumber(final_stats.device_bytes / 1e6, 1)},
      {"mesh_s", JsonNumber(mesh_s, 3)},
      {"transient_buffer_removed", final_stats.transient_buffer_removed},
      {"transient_deferred_removed", final_stats.transient_deferred_removed},
      {"transient_departed_removed", final_stats.transient_departed_removed},
      {"transient_past_removed", final_stats.transient_past_removed},
      {"transient_busy_removed", final_stats.transient_busy_removed},
      {"rss_mb_per_frame", series(rss_mb)},
      // The global map grows with the area explored; RSS minus it should stay flat.
      {"submap_mb_per_frame", series(submap_mb)},
      // The deferred rays (seen outside the box, waiting for it) are part of the global map too.
      {"deferred_mb_per_frame", series(deferred_mb)},
      {"distance_mb_per_frame", series(distance_mb)},
      {"ms_per_frame_series", series(ms_per_frame)}};

  // run.json: versions, the frames mapped and the whole config, one key a line.
  Json config_json = Json::object();
  for (absl::string_view line : absl::StrSplit(config.ToString(), '\n', absl::SkipEmpty())) {
    std::vector<std::string> kv = absl::StrSplit(line, absl::MaxSplits(" = ", 1));
    if (kv.size() == 2) config_json[kv[0]] = kv[1];
  }
  const Json run = {{"rim_version", kRimVersion}, {"libtorch_version", TorchVersion()},
                    {"dataset", args.dataset},    {"layout", io::LayoutName(dataset->layout())},
                    {"frames", {first, last}},    {"device", final_stats.device},
                    {"config", config_json}};
  for (const auto& [name, text] :
       {std::pair<std::string, std::string>{"timing.json", io::DumpJson(timing)},
        {"run.json", io::DumpJson(run, 2)}}) {
    std::ofstream f(args.out + "/" + name);
    f << text;
    if (!f) return absl::InternalError(absl::StrCat("cannot write ", args.out, "/", name));
  }
  if (!args.probe.empty()) {
    RIM_ASSIGN_OR_RETURN(Mesh gt, ReadMeshPly(args.dataset + "/gt.ply"));
    RIM_ASSIGN_OR_RETURN(io::PointCloud hits, io::ReadPlyPoints(args.dataset + "/gt_observed.ply"));
    std::vector<std::array<float, 3>> seen(hits.points.size());
    for (size_t i = 0; i < seen.size(); ++i)
      seen[i] = {hits.points[i].x(), hits.points[i].y(), hits.points[i].z()};
    const bool neural = args.probe == "neural";
    auto query = [&](const std::vector<float>& xyz, std::vector<float>* sdf,
                     std::vector<float>* grad, std::vector<uint8_t>* observed) -> absl::Status {
      QueryResult q;
      RIM_RETURN_IF_ERROR(neural ? mapper->QueryNeural(xyz.data(), xyz.size() / 3, true, &q)
                                 : mapper->QuerySdf(xyz.data(), xyz.size() / 3, true, &q));
      *sdf = std::move(q.sdf);
      *grad = std::move(q.gradient);
      *observed = std::move(q.observed);
      return absl::OkStatus();
    };
    eval::ProbeOptions options;
    options.threads = config.train.threads;
    RIM_ASSIGN_OR_RETURN(eval::ProbeReport report,
                         eval::RunDistanceProbe(*dataset, gt, seen, query, options));
    std::printf("\nprobe (%s):\n%s", args.probe.c_str(), eval::ProbeReportTable(report).c_str());
    std::ofstream f(args.out + "/probe.json");
    f << eval::ProbeReportJson(report);
    if (!f) return absl::InternalError(absl::StrCat("cannot write ", args.out, "/probe.json"));
  }
  if (!args.query_points.empty()) RIM_RETURN_IF_ERROR(AnswerQueryPoints(args, *mapper));
  return absl::OkStatus();
}

}  // namespace
}  // namespace rim

int main(int argc, char** argv) {
  rim::Args args;
  CLI::App app("", "rim_map");
  rim::AddFlags(app, args);
  absl::Status parsed = rim::cli::Parse(app, argc, argv);
  if (absl::IsCancelled(parsed)) {
    std::fputs(app.help().c_str(), stdout);
    return 0;
  }
  if (parsed.ok()) parsed = rim::CheckArgs(args);
  if (!parsed.ok()) {
    std::fprintf(stderr, "rim_map: %s\n%s", std::string(parsed.message()).c_str(),
                 app.help().c_str());
    return 2;
  }
  const absl::Status s = rim::Run(args);
  if (!s.ok()) {
    std::fprintf(stderr, "rim_map: %s\n", s.ToString().c_str());
    return 1;
  }
  return 0;
}
