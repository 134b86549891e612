// rim_eval PRED.ply GT.ply [--json]: mesh accuracy against a ground truth (DESIGN.md §4.3).
// Prints Acc, Comp, Chamfer-L1 (cm) and precision, recall, F-score (%), with the drop and the cap
// of the paper's protocol ("standard") and without them ("strict"), as a table or as JSON, and
// the share (and area) of the prediction farther than 20 cm from the GT: its floaters.
// A PLY without faces (e.g. rim_sim's gt_observed.ply) is taken as a point cloud: its vertices are
// used as they are instead of area samples ("gt_kind": "points").
// --box HX,HY,ZMIN,ZMAX --seq DIR evaluates both inside the union of the local boxes about the
// sequence's sensor positions: what a mapper with that local map could have reconstructed.
// --present FILE (rim_sim's gt_moving_last.ply) also reports the ghosts: the floaters that are not
// something standing there at the end, such as a person in the last scans.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "rim/base/flags.h"
#include "rim/eval/box_union.h"
#include "rim/eval/mesh_eval.h"
#include "rim/io/dataset.h"
#include "rim/io/json.h"
#include "rim/io/mesh_io.h"

namespace {

using rim::eval::EvalOptions;
using rim::eval::EvalResult;
using rim::eval::InputKind;
using rim::eval::InputKindName;
using rim::eval::Metrics;

constexpr char kSynopsis[] =
    "usage: rim_eval PRED.ply GT.ply [--json] [--samples N] [--threads N] [--seed S]\n"
    "                [--voxel M] [--no-crop] [--region x0,y0,z0,x1,y1,z1]\n"
    "                [--box HX,HY,ZMIN,ZMAX --seq DIR] [--misses FILE] [--floaters FILE]\n"
    "                [--present FILE]";
constexpr char kFooter[] =
    "A PLY without faces is a point cloud: its vertices are used as they are (voxel-averaged, not\n"
    "sampled). rim_sim's gt_observed.ply is one: the surface its sensor actually saw.";

struct Args {
  std::vector<std::string> files;  // PRED.ply GT.ply
  std::string pred_path, gt_path;
  bool json = false;
  EvalOptions options;
  bool has_region = false;
  std::array<float, 3> region_min{}, region_max{};
  bool has_box = false;
  double box[4] = {0, 0, 0, 0};            // HX, HY, ZMIN, ZMAX
  std::string seq_dir;                     // empty: no --seq
  std::string misses_path, floaters_path;  // empty: not written
  std::string present_path;                // empty: no ghost share
};

// "bad value for --flag: 'VALUE'".
rim::cli::Message Bad(std::string flag) {
  return [flag = std::move(flag)](const std::string& value) {
    return absl::StrCat("bad value for ", flag, ": '", value, "'");
  };
}

// rim_eval's flags (rim/base/flags.h), into ARGS. Every flag keeps its last value when given twice,
// as rim_eval always did.
void AddFlags(CLI::App& app, Args* args) {
  rim::cli::SetHelp(app, kSynopsis, "", 17);
  app.footer(kFooter);
  auto last = [](CLI::Option* o) {
    return o->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  };
  auto path = [](const char* flag) {
    return rim::cli::Check([](std::string& v) { return !v.empty(); }, Bad(flag));
  };
  EvalOptions& o = args->options;
  app.add_option("FILES", args->files, "PRED.ply GT.ply: the prediction and the ground truth")
      ->type_name("");
  app.add_flag("--json", args->json, "print one JSON object instead of the table");
  last(app.add_option("--samples", o.samples,
                      "points sampled on each mesh before voxel averaging (default 1e7)")
           ->type_name("N")
           ->transform(rim::cli::Check(
               [](std::string& v) {
                 double d;  // accepts 1e7 as well as 10000000
                 if (!absl::SimpleAtod(v, &d) || !(d >= 1 && d <= 1e9) || d != std::floor(d))
                   return false;
                 v = std::to_string(static_cast<int64_t>(d));
                 return true;
               },
               Bad("--samples"))));
  last(app.add_option("--threads", o.threads, "worker threads (default: all cores)")
           ->type_name("N")
           ->transform(rim::cli::IntegerIn(1, std::numeric_limits<int>::max(), Bad("--threads"))));
  last(app.add_option("--seed", o.seed, "sampling seed (default 1)")
           ->type_name("S")
           ->transform(rim::cli::IntegerIn<uint64_t>(0, std::numeric_limits<uint64_t>::max(),
                                                     Bad("--seed"))));
  last(app.add_option("--voxel", o.voxel_m,
                      "voxel-averaging size in metres, 0 to disable (default 0.01)")
           ->type_name("M")
           ->transform(rim::cli::Check(
               [](std::string& v) {
                 double d;
                 return absl::SimpleAtod(v, &d) && d >= 0;  // ValidateEvalOptions does the rest
               },
               Bad("--voxel"))));
  app.add_flag_callback(
      "--no-crop", [&o] { o.crop_to_gt = false; },
      "do not crop the prediction to the GT bounding box");
  // Crops both meshes: the part of the world the mapper was asked to reconstruct.
  last(app.add_option_function<std::string>(
              "--region",
              [args](const std::string& v) {
                std::vector<std::string> parts = absl::StrSplit(v, ',');
                if (parts.size() != 6) throw rim::cli::UsageError(Bad("--region")(v));
                for (int k = 0; k < 6; ++k) {
                  double d;
                  if (!absl::SimpleAtod(parts[k], &d) || !std::isfinite(d))
                    throw rim::cli::UsageError(Bad("--region")(v));
                  (k < 3 ? args->region_min : args->region_max)[k % 3] = float(d);
                }
                for (int k = 0; k < 3; ++k)
                  if (!(args->region_min[k] < args->region_max[k]))
                    throw rim::cli::UsageError(Bad("--region")(v));
                args->has_region = true;
              },
              "evaluate only inside this box: both meshes are clipped to it first\n"
              "(a point cloud keeps its points inside it)")
           ->type_name("x0,y0,z0,x1,y1,z1"));
  last(app.add_option_function<std::string>(
              "--box",
              [args](const std::string& v) {
                std::vector<std::string> parts = absl::StrSplit(v, ',');
                if (parts.size() != 4) throw rim::cli::UsageError(Bad("--box")(v));
                for (int k = 0; k < 4; ++k) {
                  if (!absl::SimpleAtod(parts[k], &args->box[k]) || !std::isfinite(args->box[k]))
                    throw rim::cli::UsageError(Bad("--box")(v));
                }
                if (!(args->box[0] > 0 && args->box[1] > 0 && args->box[2] < args->box[3])) {
                  throw rim::cli::UsageError(absl::StrCat(
                      "--box HX,HY,ZMIN,ZMAX needs HX > 0, HY > 0 and ZMIN < ZMAX, got '", v, "'"));
                }
                args->has_box = true;
              },
              "with --seq DIR: evaluate only inside the union over the frames of the dataset DIR\n"
              "of the boxes |x - sx| < HX, |y - sy| < HY, sz + ZMIN <= z < sz + ZMAX about each\n"
              "sensor position (sx, sy, sz), world axes (rim_sim's --observed-box): both\n"
              "sides' samples and points outside it are left out. With rim_sim's\n"
              "gt_observed.ply from --observed-box none, this scores what a mapper with\n"
              "that local map could have seen, from near or far")
           ->type_name("HX,HY,ZMIN,ZMAX"));
  last(app.add_option("--seq", args->seq_dir, "the dataset whose sensor positions place --box")
           ->type_name("DIR")
           ->transform(path("--seq")));
  last(app.add_option("--misses", args->misses_path,
                      "write CSV x,y,z,distance_m of the GT points (voxel-averaged) farther than\n"
                      "10 cm from the prediction: where the map misses surface")
           ->type_name("FILE")
           ->transform(path("--misses")));
  last(app.add_option("--floaters", args->floaters_path,
                      "write the same for the prediction points farther than 20 cm from the GT")
           ->type_name("FILE")
           ->transform(path("--floaters")));
  last(app.add_option("--present", args->present_path,
                      "surfaces there at the end that the GT leaves out (rim_sim's\n"
                      "gt_moving_last.ply: the people and cars where the last scan saw them):\n"
                      "also report the ghosts, the floaters farther than 20 cm from these too")
           ->type_name("FILE")
           ->transform(path("--present")));
}

// Usage errors (after parsing) that name the flag; OK when ARGS are complete.
absl::Status CheckArgs(Args* args) {
  if (args->files.size() != 2) {
    return absl::InvalidArgumentError(absl::StrCat("expected PRED.ply and GT.ply, got ",
                                                   args->files.size(), " file argument(s)"));
  }
  if (args->has_box != !args->seq_dir.empty()) {
    return absl::InvalidArgumentError(
        args->has_box ? "--box needs --seq DIR, the sequence whose sensor positions place the boxes"
                      : "--seq needs --box HX,HY,ZMIN,ZMAX");
  }
  args->options.keep_outliers = !args->misses_path.empty() || !args->floaters_path.empty();
  args->pred_path = args->files[0];
  args->gt_path = args->files[1];
  return absl::OkStatus();
}

// The union of --box about the sensor positions of --seq's frames.
absl::StatusOr<std::shared_ptr<const rim::eval::BoxUnion>> LoadBoxUnion(const Args& args) {
  absl::StatusOr<std::unique_ptr<rim::io::Dataset>> seq = rim::io::Dataset::Open(args.seq_dir);
  if (!seq.ok()) return seq.status();
  std::vector<Eigen::Vector3d> centres;
  for (const Eigen::Isometry3d& pose : (*seq)->poses()) centres.push_back(pose.translation());
  absl::StatusOr<rim::eval::BoxUnion> box_union =
      rim::eval::BoxUnion::Create(args.box[0], args.box[1], args.box[2], args.box[3], centres);
  if (!box_union.ok()) return box_union.status();
  return std::make_shared<const rim::eval::BoxUnion>(*std::move(box_union));
}

using rim::io::JsonNumber;
using Json = nlohmann::ordered_json;

Json MetricsJson(const Metrics& m) {
  return {{"accuracy_cm", JsonNumber(100 * m.accuracy_m, 4)},
          {"completeness_cm", JsonNumber(100 * m.completeness_m, 4)},
          {"chamfer_l1_cm", JsonNumber(100 * m.chamfer_l1_m, 4)},
          {"precision_pct", JsonNumber(100 * m.precision, 3)},
          {"recall_pct", JsonNumber(100 * m.recall, 3)},
          {"fscore_pct", JsonNumber(100 * m.fscore, 3)}};
}

// A point cloud has no area: null.
Json AreaJson(InputKind kind, double area_m2) {
  return kind == InputKind::kPoints ? Json(nullptr) : JsonNumber(area_m2, 4);
}

// The box union of --box and --seq, or null.
Json BoxJson(const Args& args) {
  const rim::eval::BoxUnion* u = args.options.box_union.get();
  if (u == nullptr) return nullptr;
  return {{"hx", JsonNumber(u->hx(), 4)},
          {"hy", JsonNumber(u->hy(), 4)},
          {"z_min", JsonNumber(u->z_min(), 4)},
          {"z_max", JsonNumber(u->z_max(), 4)},
          {"frames", u->size()},
          {"seq", args.seq_dir}};
}

// One object, each top-level key on its own line and the objects within on one line each.
// Undefined values (no prediction point kept: NaN) are null, as JSON has no NaN.
std::string FormatJson(const Args& args, const EvalResult& r, double seconds) {
  const EvalOptions& o = args.options;
  Json json = {{"prediction", args.pred_path},
               {"ground_truth", args.gt_path},
               {"pred_kind", InputKindName(r.pred_kind)},
               {"gt_kind", InputKindName(r.gt_kind)},
               {"standard", MetricsJson(r.standard)},
               {"strict", MetricsJson(r.strict)},
               {"points",
                {{"pred_samples", r.pred_samples},
                 {"gt_samples", r.gt_samples},
                 {"pred", r.pred_points},
                 {"gt", r.gt_points},
                 {"pred_dropped", r.pred_dropped},
                 {"gt_capped", r.gt_capped}}},
               {"area_m2",
                {{"pred", AreaJson(r.pred_kind, r.pred_area_m2)},
                 {"gt", AreaJson(r.gt_kind, r.gt_area_m2)}}},
               {"protocol",
                {{"samples", o.samples},
                 {"voxel_cm", JsonNumber(100 * o.voxel_m, 3)},
                 {"drop_cm", JsonNumber(100 * o.drop_m, 3)},
                 {"cap_cm", JsonNumber(100 * o.cap_m, 3)},
                 {"fscore_threshold_cm", JsonNumber(100 * o.fscore_m, 3)},
                 {"crop_to_gt", o.crop_to_gt},
                 {"crop_margin_cm", JsonNumber(100 * o.crop_margin_m, 3)},
                 {"seed", o.seed},
                 {"floater_cm", JsonNumber(100 * o.floater_m, 3)}}},
               {"box", BoxJson(args)},
               {"seconds", JsonNumber(seconds, 3)},
               {"floater_share", JsonNumber(r.floater_share, 6)},
               {"floater_area_m2", AreaJson(r.pred_kind, r.floater_area_m2)}};
  if (r.has_present) {
    json["present"] = args.present_path;
    json["ghost_share"] = JsonNumber(r.ghost_share, 6);
    json["ghost_area_m2"] = AreaJson(r.pred_kind, r.ghost_area_m2);
  }
  return rim::io::DumpJson(json);
}

std::string TableRow(const char* name, const Metrics& m) {
  auto f = [](double v, int width, int decimals) {
    return std::isfinite(v) ? absl::StrFormat("%*.*f", width, decimals, v)
                            : absl::StrFormat("%*s", width, "n/a");
  };
  return absl::StrCat(absl::StrFormat("%-10s", name), f(100 * m.accuracy_m, 10, 3),
                      f(100 * m.completeness_m, 11, 3), f(100 * m.chamfer_l1_m, 11, 3),
                      f(100 * m.precision, 11, 2), f(100 * m.recall, 11, 2),
                      f(100 * m.fscore, 11, 2), "\n");
}

std::string FormatTable(const Args& args, const EvalResult& r, double seconds) {
  const EvalOptions& o = args.options;
  auto pct = [](int64_t part, int64_t whole) { return 100.0 * part / std::max<int64_t>(whole, 1); };
  auto kind = [](InputKind k) { return k == InputKind::kPoints ? " (point cloud)" : " (mesh)"; };
  // "N on A m^2" for a sampled mesh, "N points as given" for a point cloud.
  auto source = [](InputKind k, int64_t samples, double area_m2) {
    return k == InputKind::kPoints ? absl::StrFormat("%d points as given", samples)
                                   : absl::StrFormat("%d on %.2f m^2", samples, area_m2);
  };
  std::string out = absl::StrCat("prediction:   ", args.pred_path, kind(r.pred_kind),
                                 "\nground truth: ", args.gt_path, kind(r.gt_kind), "\n");
  absl::StrAppendFormat(&out,
                        "samples: pred %s -> %d points, GT %s -> %d points (%g cm voxel "
                        "averaging)\n",
                        source(r.pred_kind, r.pred_samples, r.pred_area_m2), r.pred_points,
                        source(r.gt_kind, r.gt_samples, r.gt_area_m2), r.gt_points,
                        100 * o.voxel_m);
  absl::StrAppend(&out,
                  "\n            Acc [cm]  Comp [cm]  C-L1 [cm]   Prec [%]    Rec [%]      F [%]\n",
                  TableRow("standard", r.standard), TableRow("strict", r.strict), "\n");
  absl::StrAppendFormat(&out,
                        "standard: pred->GT distances >= %g cm dropped (%d points, %.2f%%), "
                        "GT->pred capped at %g cm (%d points, %.2f%%)\n",
                        100 * o.drop_m, r.pred_dropped, pct(r.pred_dropped, r.pred_points),
                        100 * o.cap_m, r.gt_capped, pct(r.gt_capped, r.gt_points));
  absl::StrAppend(&out, "strict: no drop, no cap (floaters count)\n");
  absl::StrAppendFormat(&out, "Floaters (> %g cm): %.2f %% of predicted %s\n", 100 * o.floater_m,
                        100 * r.floater_share,
                        r.pred_kind == InputKind::kPoints
                            ? std::string("points")
                            : absl::StrFormat("area (%.2f m^2)", r.floater_area_m2));
  if (r.has_present) {
    absl::StrAppendFormat(&out, "Ghosts (floaters > %g cm from %s too): %.2f %% of predicted %s\n",
                          100 * o.floater_m, args.present_path, 100 * r.ghost_share,
                          r.pred_kind == InputKind::kPoints
                              ? std::string("points")
                              : absl::StrFormat("area (%.2f m^2)", r.ghost_area_m2));
  }
  absl::StrAppendFormat(
      &out, "F-score threshold %g cm; crop to GT box: %s; seed %d; %.1f s\n", 100 * o.fscore_m,
      o.crop_to_gt ? absl::StrFormat("on (+%g cm)", 100 * o.crop_margin_m) : std::string("off"),
      o.seed, seconds);
  if (const rim::eval::BoxUnion* u = o.box_union.get()) {
    absl::StrAppendFormat(&out,
                          "box union: |x - sx| < %g, |y - sy| < %g, sz %+g <= z < sz %+g m about "
                          "the %d sensor positions of %s\n",
                          u->hx(), u->hy(), u->z_min(), u->z_max(), u->size(), args.seq_dir);
  }
  return out;
}

// CSV x,y,z,distance_m, one line a point.
absl::Status WriteOutliers(const std::string& path,
                           const std::vector<EvalResult::OutlierPoint>& points) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) return absl::InvalidArgumentError(absl::StrCat("cannot write ", path));
  std::fputs("x,y,z,distance_m\n", f);
  for (const EvalResult::OutlierPoint& p : points) {
    std::fprintf(f, "%.4f,%.4f,%.4f,%.4f\n", p.x, p.y, p.z, p.distance_m);
  }
  if (std::fclose(f) != 0) return absl::DataLossError(absl::StrCat("cannot finish ", path));
  return absl::OkStatus();
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  args.options.threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  CLI::App app("", "rim_eval");
  AddFlags(app, &args);
  absl::Status parsed = rim::cli::Parse(app, argc, argv);
  if (absl::IsCancelled(parsed)) {
    std::fputs(app.help().c_str(), stdout);
    return 0;
  }
  if (parsed.ok()) parsed = CheckArgs(&args);
  if (!parsed.ok()) {
    std::fprintf(stderr, "rim_eval: %s\n%s", std::string(parsed.message()).c_str(),
                 app.help().c_str());
    return 2;
  }
  if (absl::Status s = rim::eval::ValidateEvalOptions(args.options); !s.ok()) {
    std::fprintf(stderr, "rim_eval: %s\n", std::string(s.message()).c_str());
    return 2;
  }
  const auto start = std::chrono::steady_clock::now();
  if (args.has_box) {
    absl::StatusOr<std::shared_ptr<const rim::eval::BoxUnion>> box_union = LoadBoxUnion(args);
    if (!box_union.ok()) {
      std::fprintf(stderr, "rim_eval: cannot place --box along --seq %s: %s\n",
                   args.seq_dir.c_str(), std::string(box_union.status().message()).c_str());
      return 1;
    }
    args.options.box_union = *std::move(box_union);
  }
  absl::StatusOr<rim::Mesh> pred = rim::ReadMeshPly(args.pred_path);
  if (!pred.ok()) {
    std::fprintf(stderr, "rim_eval: cannot read prediction: %s\n",
                 std::string(pred.status().message()).c_str());
    return 1;
  }
  absl::StatusOr<rim::Mesh> gt = rim::ReadMeshPly(args.gt_path);
  if (!gt.ok()) {
    std::fprintf(stderr, "rim_eval: cannot read ground truth: %s\n",
                 std::string(gt.status().message()).c_str());
    return 1;
  }
  if (!args.present_path.empty()) {
    absl::StatusOr<rim::Mesh> present = rim::ReadMeshPly(args.present_path);
    if (!present.ok()) {
      std::fprintf(stderr, "rim_eval: cannot read --present: %s\n",
                   std::string(present.status().message()).c_str());
      return 1;
    }
    args.options.present = std::make_shared<const rim::Mesh>(*std::move(present));
  }
  if (args.has_region) {
    *pred = rim::eval::CropMeshToBox(*pred, args.region_min, args.region_max);
    *gt = rim::eval::CropMeshToBox(*gt, args.region_min, args.region_max);
  }
  absl::StatusOr<EvalResult> result = rim::eval::EvaluateMeshes(*pred, *gt, args.options);
  if (!result.ok()) {
    std::fprintf(stderr, "rim_eval: %s\n", std::string(result.status().message()).c_str());
    return 1;
  }
  for (const auto& [path, points] :
       {std::pair{args.misses_path, &result->misses}, {args.floaters_path, &result->floaters}}) {
    if (path.empty()) continue;
    if (absl::Status s = WriteOutliers(path, *points); !s.ok()) {
      std::fprintf(stderr, "rim_eval: %s\n", std::string(s.message()).c_str());
      return 1;
    }
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const std::string out =
      args.json ? FormatJson(args, *result, seconds) : FormatTable(args, *result, seconds);
  std::fputs(out.c_str(), stdout);
  return 0;
}
