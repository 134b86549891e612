// rim_sim: writes a synthetic dataset with ground truth.
//
//   rim_sim --scene city --out DIR [--frames N] [--noise M] [--walkers K] [--crossers K]
//           [--movers K] [--seed S] [--step M] [--columns C] [--gt-margin M]
//           [--observed-box HX,HY,ZMIN,ZMAX|none] [--building-setback MIN,MAX]
//           [--building-height MIN,MAX] [--parked-cars F] [--balconies F] [--annexes F]
//           [--yawed F] [--canopies F] [--threads T]
//   rim_sim --scene room --out DIR [--frames N] [--noise M] [--seed S] [--step M] [--threads T]
//
// city: a procedural city scanned by a 64-beam spinning LiDAR driving round a loop of streets,
//       written in the KITTI odometry layout (velodyne/NNNNNN.bin, poses.txt, calib.txt,
//       times.txt) plus gt.ply.
// room: a furnished room seen by a 320x240 depth camera, written in the 7-Scenes layout
//       (frame-NNNNNN.depth.png, frame-NNNNNN.pose.txt, camera-intrinsics.txt) plus gt.ply.
// Both also write gt_observed.ply, the surface the sensor actually saw: the noise-free hits on the
// static scene (city: only those inside each frame's local mapping box, unless it is disabled),
// averaged per 1 cm voxel, as a point cloud; and scene.json (the parameters) and README.txt (the
// conventions).
#pragma once

#include <cstdint>
#include <ostream>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "sim/city.h"

namespace rim::sim {

enum class SceneKind { kCity, kRoom };

// City: the local mapping box of a frame, about the sensor position along the world axes (the
// sensor's heading is ignored): |x - sx| < hx, |y - sy| < hy, sz + z_min <= z < sz + z_max. The
// defaults are the maicity preset's local map. Disabled, every hit of every frame is kept.
struct ObservedBox {
  double hx = 10.0, hy = 10.0;
  double z_min = -3.0, z_max = 3.0;
  bool enabled = true;
};

struct SimOptions {
  SceneKind scene = SceneKind::kCity;
  std::string out_dir;
  int frames = 100;
  double noise = 0.0;  // Gaussian range (city) or depth (room) noise, standard deviation in m
  int walkers = 0;     // city only
  int crossers = 0;    // city only: pedestrians crossing the drive's street
  int movers = 0;      // city only: cars driving the opposite lane
  uint64_t seed = 1;
  double step = 0.0;         // metres per frame; 0 picks the scene's default (city 1, room 0.1)
  int columns = 1800;        // city only: LiDAR azimuth steps per revolution
  double gt_margin = -1;     // city only: gt.ply covers the drive's bounds plus this; <0: max range
  ObservedBox observed_box;  // city only: what of each frame goes into gt_observed.ply
  BuildingOptions buildings;  // city only: set-back and height ranges
  CityFeatures features;      // city only: parked cars, balconies, annexes, yaw, broad crowns
  int threads = 0;            // 0: all hardware threads
};

struct SimSummary {
  int frames = 0;
  uint64_t points = 0;  // LiDAR returns (city) or valid depth pixels (room) in all frames
  uint64_t gt_vertices = 0;
  uint64_t gt_faces = 0;
  uint64_t observed_points = 0;  // points in gt_observed.ply
  double seconds = 0.0;          // wall time of the whole run
};

// Generates the dataset into options.out_dir (created if missing). Files an earlier rim_sim run
// left there are removed first (see RemovePreviousOutput), so that the folder stays consistent;
// nothing else in it is touched. Same options, same bytes, whatever the thread count.
absl::StatusOr<SimSummary> RunSim(const SimOptions& options);

// Parses rim_sim's command line (argv[0] is the program name). InvalidArgument with a message
// naming the flag for anything wrong. *help is set when --help / -h is given.
absl::StatusOr<SimOptions> ParseSimArgs(int argc, const char* const* argv, bool* help);

std::string SimUsage();

// The whole command: parse, run, report. Returns the process exit code: 0 on success, 2 for a
// usage error, 1 when generation or writing fails. Messages go to `err`, the summary to `out`.
int RunSimCli(int argc, const char* const* argv, std::ostream& out, std::ostream& err);

}  // namespace rim::sim
