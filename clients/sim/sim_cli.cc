// rim_sim's command line: flags, usage text, and the run with its summary.
#include <cmath>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "rim/base/status_macros.h"
#include "sim/sim.h"

namespace rim::sim {
namespace {

// Flag value parsing with messages that name the flag and echo the value.
absl::Status BadValue(absl::string_view flag, absl::string_view value, absl::string_view want) {
  return absl::InvalidArgumentError(absl::StrCat(flag, " must be ", want, ", got '", value, "'"));
}

absl::Status ParseInt(absl::string_view flag, absl::string_view value, int lo, int hi, int* out,
                      absl::string_view want) {
  int v;
  if (!absl::SimpleAtoi(value, &v) || v < lo || v > hi) return BadValue(flag, value, want);
  *out = v;
  return absl::OkStatus();
}

absl::Status ParseDouble(absl::string_view flag, absl::string_view value, double lo, double hi,
                         bool lo_inclusive, double* out, absl::string_view want) {
  double v;
  if (!absl::SimpleAtod(value, &v) || !std::isfinite(v) || v > hi || v < lo ||
      (!lo_inclusive && v == lo)) {
    return BadValue(flag, value, want);
  }
  *out = v;
  return absl::OkStatus();
}

// MIN,MAX with lo <= MIN <= MAX <= hi.
absl::Status ParseRange(absl::string_view flag, absl::string_view value, double lo, double hi,
                        double* min, double* max) {
  const std::vector<std::string> parts = absl::StrSplit(value, ',');
  double v[2];
  bool ok = parts.size() == 2;
  for (size_t i = 0; ok && i < 2; ++i) {
    ok = absl::SimpleAtod(parts[i], &v[i]) && std::isfinite(v[i]);
  }
  if (!ok || !(lo <= v[0] && v[0] <= v[1] && v[1] <= hi)) {
    return BadValue(flag, value, absl::StrFormat("MIN,MAX with %g <= MIN <= MAX <= %g", lo, hi));
  }
  *min = v[0];
  *max = v[1];
  return absl::OkStatus();
}

}  // namespace

std::string SimUsage() {
  return R"(usage: rim_sim --scene city --out DIR [--frames N] [--noise M] [--walkers K] [--seed S]
                [--crossers K] [--movers K] [--step M] [--columns C] [--gt-margin M]
                [--observed-box HX,HY,ZMIN,ZMAX|none] [--building-setback MIN,MAX]
                [--building-height MIN,MAX] [--parked-cars F] [--balconies F]
                [--annexes F] [--yawed F] [--canopies F] [--threads T]
       rim_sim --scene room --out DIR [--frames N] [--noise M] [--seed S] [--step M] [--threads T]

Writes a synthetic dataset with its ground-truth mesh (gt.ply) and the observed surface
(gt_observed.ply: the noise-free hits on the static scene, averaged per 1 cm voxel, as a point
cloud without faces):
  city  procedural streets, buildings, trees, poles and parked cars scanned by a 64-beam spinning
        LiDAR driving round the block; KITTI layout (velodyne/, poses.txt, calib.txt, times.txt).
  room  a furnished room seen by a 320x240 depth camera; 7-Scenes layout (frame-NNNNNN.depth.png,
        frame-NNNNNN.pose.txt, camera-intrinsics.txt).

  --scene city|room  scene to generate (default city)
  --out DIR          output folder, created if missing (required)
  --frames N         number of frames, >= 1 (default 100)
  --noise M          Gaussian range/depth noise, standard deviation in metres (default 0)
  --walkers K        city: pedestrians walking along the sidewalks, in the scans only (default 0)
  --crossers K       city: pedestrians walking back and forth across the drive's street, their
                     crossing lines spread along the part of the loop the run drives; in the scans
                     only (default 0, at most 1000)
  --movers K         city: cars driving the opposite lane against the drive, each meeting the
                     sensor at its own place along the run; in the scans only (default 0, at most
                     1000)
  --seed S           scene seed, a non-negative integer (default 1)
  --step M           metres travelled per frame (default 1 for city, 0.1 for room)
  --columns C        city: LiDAR columns per revolution (default 1800)
  --gt-margin M      city: gt.ply covers the drive's extent grown by M metres (default 80, the
                     LiDAR's range)
  --observed-box HX,HY,ZMIN,ZMAX
                     city: gt_observed.ply keeps of each frame only the hits with |x - sx| < HX,
                     |y - sy| < HY and sz + ZMIN <= z < sz + ZMAX about the sensor position
                     (sx, sy, sz), world axes: the local mapping box (default 10,10,-3,3);
                     none keeps every hit of every frame, also what was only seen from afar
  --building-setback MIN,MAX
                     city: building facades stand MIN to MAX metres back from the street
                     frontage, which is 9.5 m from the street centre line (default 0,3.5;
                     0 <= MIN <= MAX <= 20)
  --building-height MIN,MAX
                     city: building heights in metres (default 4,25; 1 <= MIN <= MAX <= 100)
  --parked-cars F    city: share of each kerb in rows of cars parked right at the kerb, 0.5-3 m
                     apart (sedans, SUVs, vans); the rest keeps scattered parked cars (default
                     0.5; each share here is in [0, 1])
  --balconies F      city: share of buildings with balcony slabs on the street facade at every
                     floor from about 3 m up, overhanging the frontage by up to 1.5 m (default 0.4)
  --annexes F        city: share of buildings with a lower annex, 2.5-4.5 m tall, on the street
                     side or at the street corner (default 0.3)
  --yawed F          city: share of buildings yawed off the street by up to 35 degrees, the rest by
                     up to 4 (default 0.35; 0.25 with the other four at 0 gives the city of
                     rim_sim before these options, bit for bit)
  --canopies F       city: share of street trees with a broad, low crown (2.5-3.5 m up, radius
                     2-4 m where there is room) over the sidewalk and the parking lane (default 0.5)
  --threads T        worker threads (default: all cores); the output does not depend on it

Files that an earlier rim_sim run left in DIR (frames, index files, gt.ply, gt_observed.ply) are
replaced or removed; nothing else in DIR is touched.
)";
}

absl::StatusOr<SimOptions> ParseSimArgs(int argc, const char* const* argv, bool* help) {
  SimOptions o;
  *help = false;
  std::set<std::string> given;
  bool have_out = false;
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      *help = true;
      return o;
    }
    if (arg.rfind("--", 0) != 0) {
      return absl::InvalidArgumentError(absl::StrCat("unexpected argument '", arg, "'"));
    }
    std::string value;
    const size_t eq = arg.find('=');
    if (eq != std::string::npos) {
      value = arg.substr(eq + 1);
      arg = arg.substr(0, eq);
    } else {
      static const std::set<std::string> kKnown = {"--scene",
                                                   "--out",
                                                   "--frames",
                                                   "--noise",
                                                   "--walkers",
                                                   "--crossers",
                                                   "--movers",
                                                   "--seed",
                                                   "--step",
                                                   "--columns",
                                                   "--gt-margin",
                                                   "--observed-box",
                                                   "--building-setback",
                                                   "--building-height",
                                                   "--parked-cars",
                                                   "--balconies",
                                                   "--annexes",
                                                   "--yawed",
                                                   "--canopies",
                                                   "--threads"};
      if (kKnown.count(arg) == 0) {
        return absl::InvalidArgumentError(absl::StrCat("unknown flag '", arg, "'"));
      }
      if (i + 1 >= argc) return absl::InvalidArgumentError(absl::StrCat(arg, " needs a value"));
      value = argv[++i];
    }
    if (!given.insert(arg).second) {
      return absl::InvalidArgumentError(absl::StrCat(arg, " given more than once"));
    }
    if (arg == "--scene") {
      if (value == "city") {
        o.scene = SceneKind::kCity;
      } else if (value == "room") {
        o.scene = SceneKind::kRoom;
      } else {
        return absl::InvalidArgumentError(
            absl::StrCat("unknown --scene '", value, "' (expected city or room)"));
      }
    } else if (arg == "--out") {
      if (value.empty()) return BadValue(arg, value, "a folder path");
      o.out_dir = value;
      have_out = true;
    } else if (arg == "--frames") {
      RIM_RETURN_IF_ERROR(
          ParseInt(arg, value, 1, 1000000, &o.frames, "an integer in [1, 1000000]"));
    } else if (arg == "--noise") {
      RIM_RETURN_IF_ERROR(
          ParseDouble(arg, value, 0.0, 10.0, true, &o.noise, "a standard deviation in [0, 10] m"));
    } else if (arg == "--walkers") {
      RIM_RETURN_IF_ERROR(ParseInt(arg, value, 0, 10000, &o.walkers, "an integer in [0, 10000]"));
    } else if (arg == "--crossers") {
      RIM_RETURN_IF_ERROR(ParseInt(arg, value, 0, 1000, &o.crossers, "an integer in [0, 1000]"));
    } else if (arg == "--movers") {
      RIM_RETURN_IF_ERROR(ParseInt(arg, value, 0, 1000, &o.movers, "an integer in [0, 1000]"));
    } else if (arg == "--seed") {
      if (!absl::SimpleAtoi(value, &o.seed) || value.empty() || value[0] == '-') {
        return BadValue(arg, value, "a non-negative integer");
      }
    } else if (arg == "--step") {
      RIM_RETURN_IF_ERROR(ParseDouble(arg, value, 0.0, 100.0, false, &o.step, "in (0, 100] m"));
    } else if (arg == "--columns") {
      RIM_RETURN_IF_ERROR(ParseInt(arg, value, 16, 36000, &o.columns, "an integer in [16, 36000]"));
    } else if (arg == "--gt-margin") {
      RIM_RETURN_IF_ERROR(
          ParseDouble(arg, value, 0.0, 10000.0, true, &o.gt_margin, "in [0, 10000] m"));
    } else if (arg == "--observed-box" && value == "none") {
      o.observed_box.enabled = false;
    } else if (arg == "--observed-box") {
      const std::vector<std::string> parts = absl::StrSplit(value, ',');
      double v[4];
      bool ok = parts.size() == 4;
      for (size_t i = 0; ok && i < 4; ++i) {
        ok = absl::SimpleAtod(parts[i], &v[i]) && std::isfinite(v[i]) && std::abs(v[i]) <= 1e4;
      }
      if (!ok || !(v[0] > 0) || !(v[1] > 0) || !(v[2] < v[3])) {
        return BadValue(arg, value,
                        "none or HX,HY,ZMIN,ZMAX in metres with HX, HY > 0 and ZMIN < ZMAX "
                        "(|each| <= 10000)");
      }
      o.observed_box = {v[0], v[1], v[2], v[3]};
    } else if (arg == "--building-setback") {
      RIM_RETURN_IF_ERROR(ParseRange(arg, value, 0.0, kMaxBuildingSetback, &o.buildings.setback_min,
                                     &o.buildings.setback_max));
    } else if (arg == "--building-height") {
      RIM_RETURN_IF_ERROR(ParseRange(arg, value, kMinBuildingHeight, kMaxBuildingHeight,
                                     &o.buildings.height_min, &o.buildings.height_max));
    } else if (arg == "--parked-cars" || arg == "--balconies" || arg == "--annexes" ||
               arg == "--yawed" || arg == "--canopies") {
      CityFeatures& f = o.features;
      double* share = arg == "--parked-cars" ? &f.parked_cars
                      : arg == "--balconies" ? &f.balconies
                      : arg == "--annexes"   ? &f.annexes
                      : arg == "--yawed"     ? &f.yawed
                                             : &f.canopies;
      RIM_RETURN_IF_ERROR(ParseDouble(arg, value, 0.0, 1.0, true, share, "a share in [0, 1]"));
    } else if (arg == "--threads") {
      RIM_RETURN_IF_ERROR(ParseInt(arg, value, 1, 256, &o.threads, "an integer in [1, 256]"));
    } else {
      return absl::InvalidArgumentError(absl::StrCat("unknown flag '", arg, "'"));
    }
  }
  if (!have_out) return absl::InvalidArgumentError("--out DIR is required");
  if (o.scene == SceneKind::kRoom) {
    for (const char* city_only :
         {"--walkers", "--crossers", "--movers", "--columns", "--gt-margin", "--observed-box",
          "--building-setback", "--building-height", "--parked-cars", "--balconies", "--annexes",
          "--yawed", "--canopies"}) {
      if (given.count(city_only)) {
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
