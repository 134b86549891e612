// rim_sim's command line: flags, usage text, and the run with its summary.
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "rim/base/flags.h"
#include "rim/base/status_macros.h"
#include "sim/sim.h"

namespace rim::sim {
namespace {

constexpr char kSynopsis[] =
    R"(usage: rim_sim --scene city --out DIR [--frames N] [--noise M] [--walkers K] [--seed S]
                [--crossers K] [--movers K] [--step M] [--columns C] [--gt-margin M]
                [--observed-box HX,HY,ZMIN,ZMAX|none] [--building-setback MIN,MAX]
                [--building-height MIN,MAX] [--parked-cars F] [--balconies F]
                [--annexes F] [--yawed F] [--canopies F] [--threads T]
       rim_sim --scene room --out DIR [--frames N] [--noise M] [--seed S] [--step M] [--threads T])";

constexpr char kDescription[] =
    R"(Writes a synthetic dataset with its ground-truth mesh (gt.ply) and the observed surface
(gt_observed.ply: the noise-free hits on the static scene, averaged per 1 cm voxel, as a point
cloud without faces):
  city  procedural streets, buildings, trees, poles and parked cars scanned by a 64-beam spinning
        LiDAR driving round the block; KITTI layout (velodyne/, poses.txt, calib.txt, times.txt).
  room  a furnished room seen by a 320x240 depth camera; 7-Scenes layout (frame-NNNNNN.depth.png,
        frame-NNNNNN.pose.txt, camera-intrinsics.txt).)";

constexpr char kFooter[] =
    R"(Files that an earlier rim_sim run left in DIR (frames, index files, gt.ply, gt_observed.ply) are
replaced or removed; nothing else in DIR is touched.)";

// The flags that only the city has.
constexpr const char* kCityOnly[] = {"--walkers",          "--crossers",        "--movers",
                                     "--columns",          "--gt-margin",       "--observed-box",
                                     "--building-setback", "--building-height", "--parked-cars",
                                     "--balconies",        "--annexes",         "--yawed",
                                     "--canopies"};

// Messages that name the flag and echo the value: "--frames must be WANT, got 'VALUE'".
cli::Message Must(std::string flag, std::string want) {
  return [flag = std::move(flag), want = std::move(want)](const std::string& value) {
    return absl::StrCat(flag, " must be ", want, ", got '", value, "'");
  };
}

// MIN,MAX with lo <= MIN <= MAX <= hi.
void ParseRange(const std::string& flag, const std::string& value, double lo, double hi,
                double* min, double* max) {
  const std::vector<std::string> parts = absl::StrSplit(value, ',');
  double v[2];
  bool ok = parts.size() == 2;
  for (size_t i = 0; ok && i < 2; ++i) {
    ok = absl::SimpleAtod(parts[i], &v[i]) && std::isfinite(v[i]);
  }
  if (!ok || !(lo <= v[0] && v[0] <= v[1] && v[1] <= hi)) {
    throw cli::UsageError(
        Must(flag, absl::StrFormat("MIN,MAX with %g <= MIN <= MAX <= %g", lo, hi))(value));
  }
  *min = v[0];
  *max = v[1];
}

// rim_sim's flags, into O.
void AddSimFlags(CLI::App& app, SimOptions& o) {
  cli::SetHelp(app, kSynopsis, kDescription, 21);
  app.footer(kFooter);
  auto integer = [&app](const char* flag, int* out, int lo, int hi, const char* description) {
    const std::string want = absl::StrFormat("an integer in [%d, %d]", lo, hi);
    return app.add_option(flag, *out, description)
        ->transform(cli::IntegerIn(lo, hi, Must(flag, want)));
  };
  auto share = [&app](const char* flag, double* out, const char* description) {
    return app.add_option(flag, *out, description)
        ->type_name("F")
        ->transform(cli::NumberIn(0.0, 1.0, true, Must(flag, "a share in [0, 1]")));
  };

  app.add_option_function<std::string>(
         "--scene",
         [&o](const std::string& scene) {
           o.scene = scene == "room" ? SceneKind::kRoom : SceneKind::kCity;
         },
         "scene to generate (default city)")
      ->type_name("city|room")
      ->transform(cli::Check([](std::string& v) { return v == "city" || v == "room"; },
                             [](const std::string& v) {
                               return absl::StrCat("unknown --scene '", v,
                                                   "' (expected city or room)");
                             }));
  app.add_option("--out", o.out_dir, "output folder, created if missing (required)")
      ->type_name("DIR")
      ->transform(
          cli::Check([](std::string& v) { return !v.empty(); }, Must("--out", "a folder path")));
  integer("--frames", &o.frames, 1, 1000000, "number of frames, >= 1 (default 100)")
      ->type_name("N");
  app.add_option("--noise", o.noise,
                 "Gaussian range/depth noise, standard deviation in metres (default 0)")
      ->type_name("M")
      ->transform(
          cli::NumberIn(0.0, 10.0, true, Must("--noise", "a standard deviation in [0, 10] m")));
  integer("--walkers", &o.walkers, 0, 10000,
          "city: pedestrians walking along the sidewalks, in the scans only (default 0)")
      ->type_name("K");
  integer("--crossers", &o.crossers, 0, 1000,
          "city: pedestrians walking back and forth across the drive's street, their\n"
          "crossing lines spread along the part of the loop the run drives; in the scans\n"
          "only (default 0, at most 1000)")
      ->type_name("K");
  integer("--movers", &o.movers, 0, 1000,
          "city: cars driving the opposite lane against the drive, each meeting the\n"
          "sensor at its own place along the run; in the scans only (default 0, at most\n"
          "1000)")
      ->type_name("K");
  app.add_option("--seed", o.seed, "scene seed, a non-negative integer (default 1)")
      ->type_name("S")
      ->transform(cli::Check(
          [](std::string& v) {
            uint64_t seed;
            if (v.empty() || v[0] == '-' || !absl::SimpleAtoi(v, &seed)) return false;
            v = std::to_string(seed);
            return true;
          },
          Must("--seed", "a non-negative integer")));
  app.add_option("--step", o.step, "metres travelled per frame (default 1 for city, 0.1 for room)")
      ->type_name("M")
      ->transform(cli::NumberIn(0.0, 100.0, false, Must("--step", "in (0, 100] m")));
  integer("--columns", &o.columns, 16, 36000, "city: LiDAR columns per revolution (default 1800)")
      ->type_name("C");
  app.add_option("--gt-margin", o.gt_margin,
                 "city: gt.ply covers the drive's extent grown by M metres (default 80, the\n"
                 "LiDAR's range)")
      ->type_name("M")
      ->transform(cli::NumberIn(0.0, 10000.0, true, Must("--gt-margin", "in [0, 10000] m")));
  app.add_option_function<std::string>(
         "--observed-box",
         [&o](const std::string& value) {
           if (value == "none") {
             o.observed_box.enabled = false;
             return;
           }
           const std::vector<std::string> parts = absl::StrSplit(value, ',');
           double v[4];
           bool ok = parts.size() == 4;
           for (size_t i = 0; ok && i < 4; ++i) {
             ok = absl::SimpleAtod(parts[i], &v[i]) && std::isfinite(v[i]) && std::abs(v[i]) <= 1e4;
           }
           if (!ok || !(v[0] > 0) || !(v[1] > 0) || !(v[2] < v[3])) {
             throw cli::UsageError(Must("--observed-box",
                                        "none or HX,HY,ZMIN,ZMAX in metres with HX, HY > 0 and "
                                        "ZMIN < ZMAX (|each| <= 10000)")(value));
           }
           o.observed_box = {v[0], v[1], v[2], v[3]};
         },
         "city: gt_observed.ply keeps of each frame only the hits with |x - sx| < HX,\n"
         "|y - sy| < HY and sz + ZMIN <= z < sz + ZMAX about the sensor position\n"
         "(sx, sy, sz), world axes: the local mapping box (default 10,10,-3,3);\n"
         "none keeps every hit of every frame, also what was only seen from afar")
      ->type_name("HX,HY,ZMIN,ZMAX");
  app.add_option_function<std::string>(
         "--building-setback",
         [&o](const std::string& v) {
           ParseRange("--building-setback", v, 0.0, kMaxBuildingSetback, &o.buildings.setback_min,
                      &o.buildings.setback_max);
         },
         "city: building facades stand MIN to MAX metres back from the street\n"
         "frontage, which is 9.5 m from the street centre line (default 0,3.5;\n"
         "0 <= MIN <= MAX <= 20)")
      ->type_name("MIN,MAX");
  app.add_option_function<std::string>(
         "--building-height",
         [&o](const std::string& v) {
           ParseRange("--building-height", v, kMinBuildingHeight, kMaxBuildingHeight,
                      &o.buildings.height_min, &o.buildings.height_max);
         },
         "city: building heights in metres (default 4,25; 1 <= MIN <= MAX <= 100)")
      ->type_name("MIN,MAX");
  CityFeatures& f = o.features;
  share("--parked-cars", &f.parked_cars,
        "city: share of each kerb in rows of cars parked right at the kerb, 0.5-3 m\n"
        "apart (sedans, SUVs, vans); the rest keeps scattered parked cars (default\n"
        "0.5; each share here is in [0, 1])");
  share("--balconies", &f.balconies,
        "city: share of buildings with balcony slabs on the street facade at every\n"
        "floor from about 3 m up, overhanging the frontage by up to 1.5 m (default 0.4)");
  share("--annexes", &f.annexes,
        "city: share of buildings with a lower annex, 2.5-4.5 m tall, on the street\n"
        "side or at the street corner (default 0.3)");
  share("--yawed", &f.yawed,
        "city: share of buildings yawed off the street by up to 35 degrees, the rest by\n"
        "up to 4 (default 0.35; 0.25 with the other four at 0 gives the city of\n"
        "rim_sim before these options, bit for bit)");
  share("--canopies", &f.canopies,
        "city: share of street trees with a broad, low crown (2.5-3.5 m up, radius\n"
        "2-4 m where there is room) over the sidewalk and the parking lane (default 0.5)");
  integer("--threads", &o.threads, 1, 256,
          "worker threads (default: all cores); the output does not depend on it")
      ->type_name("T");
}

}  // namespace

std::string SimUsage() {
  SimOptions o;
  CLI::App app("", "rim_sim");
  AddSimFlags(app, o);
  return app.help();
}

absl::StatusOr<SimOptions> ParseSimArgs(int argc, const char* const* argv, bool* help) {
  SimOptions o;
  *help = false;
  CLI::App app("", "rim_sim");
  AddSimFlags(app, o);
  const absl::Status parsed = cli::Parse(app, argc, argv);
  if (absl::IsCancelled(parsed)) {
    *help = true;
    return o;
  }
  RIM_RETURN_IF_ERROR(parsed);
  if (app.count("--out") == 0) return absl::InvalidArgumentError("--out DIR is required");
  if (o.scene == SceneKind::kRoom) {
    for (const char* city_only : kCityOnly) {
      if (app.count(city_only)) {
        return absl::InvalidArgumentError(absl::StrCat(city_only, " only applies to --scene city"));
      }
    }
  }
  return o;
}

int RunSimCli(int argc, const char* const* argv, std::ostream& out, std::ostream& err) {
  bool help = false;
  absl::StatusOr<SimOptions> options = ParseSimArgs(argc, argv, &help);
  if (help) {
    out << SimUsage();
    return 0;
  }
  if (!options.ok()) {
    err << "rim_sim: error: " << options.status().message() << "\n"
        << "run 'rim_sim --help' for usage\n";
    return 2;
  }
  absl::StatusOr<SimSummary> summary = RunSim(*options);
  if (!summary.ok()) {
    err << "rim_sim: error: " << summary.status().message() << "\n";
    return 1;
  }
  const bool city = options->scene == SceneKind::kCity;
  out << absl::StrFormat(
      "rim_sim: wrote %d %s frames (%d %s), gt.ply (%d vertices, %d faces) and gt_observed.ply "
      "(%d points) to %s in %.2f s\n",
      summary->frames, city ? "LiDAR" : "depth", summary->points, city ? "points" : "valid pixels",
      summary->gt_vertices, summary->gt_faces, summary->observed_points, options->out_dir,
      summary->seconds);
  return 0;
}

}  // namespace rim::sim
