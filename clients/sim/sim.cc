#include "sim/sim.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <memory>
#include <set>
#include <thread>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "rim/base/binary_io.h"
#include "rim/base/status_macros.h"
#include "rim/io/json.h"
#include "rim/io/mesh_io.h"
#include "sim/city.h"
#include "sim/rng.h"
#include "sim/room.h"
#include "sim/scene.h"
#include "sim/sensors.h"
#include "sim/writers.h"

namespace rim::sim {
namespace {

constexpr double kSensorHeight = 1.73;  // KITTI's Velodyne mount height
constexpr double kCityMeshTolerance = 0.005;
constexpr double kRoomMeshTolerance = 0.002;
constexpr double kCityGroundCell = 2.0;
constexpr double kCityGridCell = 4.0;
constexpr double kRoomGridCell = 0.5;
constexpr double kRoomFrameRateHz = 30.0;
constexpr uint64_t kNoiseStream = 0x7015Eull;
constexpr double kObservedVoxel = 0.01;  // gt_observed.ply: one averaged point per 1 cm voxel

std::string Join(const std::string& dir, const std::string& name) {
  if (dir.empty() || dir.back() == '/') return dir + name;
  return dir + "/" + name;
}

int ThreadCount(const SimOptions& o) {
  if (o.threads > 0) return o.threads;
  return std::max(1u, std::thread::hardware_concurrency());
}

absl::Status WriteGroundTruth(const std::string& dir, const rim::Mesh& gt) {
  return rim::WriteMeshPly(Join(dir, "gt.ply"), gt);
}

// Averages points per world-aligned voxel (the voxel of p is floor(p / size)). Points come in
// batches (a frame each); a batch is sorted by voxel and merged, and the sorted runs are merged
// like a binary counter (a run is merged into the previous one once it is at least half its size),
// so all accesses stream through memory and the result, in voxel order, does not depend on the
// batching or on threading: equal voxels are summed in the order their points came.
class VoxelAverager {
 public:
  explicit VoxelAverager(double size) : size_(size) {}

  // Adds a point to the current batch. False (and nothing added) when p is 2^20 voxels or more
  // from the origin along an axis.
  bool Add(const Vec3& p) {
    Entry e;
    e.key = 0;
    float* offset[3] = {&e.x, &e.y, &e.z};
    for (int a = 0; a < 3; ++a) {
      const double index = std::floor(p[a] / size_);
      if (!(std::abs(index) < kBias)) return false;
      e.key = (e.key << kBits) | static_cast<uint64_t>(static_cast<int64_t>(index) + kBias);
      *offset[a] = static_cast<float>(p[a] - index * size_);  // in [0, size)
    }
    e.count = 1;
    batch_.push_back(e);
    return true;
  }

  // Ends the current batch.
  void Flush() {
    if (batch_.empty()) return;
    std::stable_sort(batch_.begin(), batch_.end(),
                     [](const Entry& a, const Entry& b) { return a.key < b.key; });
    std::vector<Entry> run;
    Combine(batch_, {}, &run);
    batch_.clear();
    runs_.push_back(std::move(run));
    while (runs_.size() >= 2 && 2 * runs_.back().size() >= runs_[runs_.size() - 2].size()) {
      MergeLastTwo();
    }
  }

  // The voxel means, in voxel order (x index, then y, then z). The runs are merged on the fly
  // (there are only about log2(batches) of them), so no merged copy is made.
  std::vector<std::array<float, 3>> Means() {
    Flush();
    size_t total = 0;
    for (const auto& run : runs_) total += run.size();
    std::vector<std::array<float, 3>> out;
    out.reserve(total);
    std::vector<size_t> next(runs_.size(), 0);
    while (true) {
      uint64_t key = ~uint64_t{0};
      for (size_t r = 0; r < runs_.size(); ++r) {
        if (next[r] < runs_[r].size()) key = std::min(key, runs_[r][next[r]].key);
      }
      if (key == ~uint64_t{0}) break;  // keys use 63 bits: this one is never a voxel
      double sum[3] = {0, 0, 0};
      uint64_t count = 0;
      for (size_t r = 0; r < runs_.size(); ++r) {  // earlier runs hold earlier points
        if (next[r] == runs_[r].size() || runs_[r][next[r]].key != key) continue;
        const Entry& e = runs_[r][next[r]++];
        sum[0] += e.x;
        sum[1] += e.y;
        sum[2] += e.z;
        count += e.count;
      }
      std::array<float, 3> p;
      for (int a = 0; a < 3; ++a) {
        const int64_t index =
            static_cast<int64_t>((key >> (kBits * (2 - a))) & ((uint64_t{1} << kBits) - 1)) - kBias;
        p[a] = static_cast<float>(index * size_ + sum[a] / static_cast<double>(count));
      }
      out.push_back(p);
    }
    runs_.clear();
    return out;
  }

 private:
  static constexpr int kBits = 21;
  static constexpr int64_t kBias = int64_t{1} << (kBits - 1);
  struct Entry {
    uint64_t key;
    float x, y, z;  // sum of the offsets from the voxel's lower corner
    uint32_t count;
  };

  // Merges the key-sorted a and b (a's points came first) into *out, summing equal keys.
  static void Combine(const std::vector<Entry>& a, const std::vector<Entry>& b,
                      std::vector<Entry>* out) {
    out->clear();
    out->reserve(a.size() + b.size());
    size_t i = 0, j = 0;
    while (i < a.size() || j < b.size()) {
      const bool from_a = j == b.size() || (i < a.size() && a[i].key <= b[j].key);
      const Entry& e = from_a ? a[i++] : b[j++];
      if (!out->empty() && out->back().key == e.key) {
        Entry& sum = out->back();
        sum.x += e.x;
        sum.y += e.y;
        sum.z += e.z;
        sum.count += e.count;
      } else {
        out->push_back(e);
      }
    }
  }

  void MergeLastTwo() {
    std::vector<Entry> merged;
    Combine(runs_[runs_.size() - 2], runs_.back(), &merged);
    runs_.pop_back();
    runs_.back() = std::move(merged);
  }

  double size_;
  std::vector<Entry> batch_;
  std::vector<std::vector<Entry>> runs_;
};

absl::Status OutOfVoxelRange(const Vec3& p) {
  return absl::InternalError(absl::StrFormat(
      "observed point (%.1f, %.1f, %.1f) is too far from the origin for gt_observed.ply's voxel "
      "grid",
      p.x(), p.y(), p.z()));
}

bool InObservedBox(const Vec3& p, const Vec3& sensor, const ObservedBox& box) {
  if (!box.enabled) return true;
  return std::abs(p.x() - sensor.x()) < box.hx && std::abs(p.y() - sensor.y()) < box.hy &&
         p.z() >= sensor.z() + box.z_min && p.z() < sensor.z() + box.z_max;
}

using Json = nlohmann::ordered_json;

// scene.json's crossers and movers (each of them listed), added only when there are some, so that
// a run without them writes what it always did.
void AddMovingJson(const City& city, Json* scene) {
  if (city.crossers.empty() && city.movers.empty()) return;
  Json crossers = Json::array();
  for (const Crosser& c : city.crossers) {
    crossers.push_back({{"x_m", rim::io::JsonNumber(c.center.x(), 4)},
                        {"y_m", rim::io::JsonNumber(c.center.y(), 4)},
                        {"street_dir", Json::array({c.street.x(), c.street.y()})},
                        {"speed_mps", rim::io::JsonNumber(c.speed, 4)},
                        {"radius_m", rim::io::JsonNumber(c.radius, 4)},
                        {"height_m", rim::io::JsonNumber(c.height, 4)},
                        {"phase", rim::io::JsonNumber(c.phase, 4)}});
  }
  Json movers = Json::array();
  for (const Mover& m : city.movers) {
    movers.push_back({{"speed_mps", rim::io::JsonNumber(m.speed, 4)},
                      {"s0_m", rim::io::JsonNumber(m.s0, 4)},
                      {"size_m", Json::array({m.size.x(), m.size.y(), m.size.z()})}});
  }
  const char* in = "the scans only, not gt.ply or gt_observed.ply";
  Json& crosser_json = (*scene)["crossers"];
  crosser_json["count"] = city.crossers.size();
  crosser_json["in"] = in;
  crosser_json["motion"] = absl::StrFormat(
      "back and forth (turning at each end) across the street, on the line through (x_m, y_m) "
      "perpendicular to street_dir, lateral -%g..+%g m from the centre line, positive towards the "
      "drive's lane (right of street_dir); phase: the fraction of the cycle at t = 0, 0 at -%g m "
      "walking to +%g m",
      kCrossHalfSpan, kCrossHalfSpan, kCrossHalfSpan, kCrossHalfSpan);
  crosser_json["shape"] = "upright cylinder standing on the ground";
  crosser_json["list"] = std::move(crossers);
  const double loop_length = city.movers.empty() ? 0.0 : city.movers[0].path.length();
  Json& mover_json = (*scene)["movers"];
  mover_json["count"] = city.movers.size();
  mover_json["in"] = in;
  mover_json["motion"] = absl::StrFormat(
      "clockwise, against the drive: the centre is at arc length s0_m - speed_mps * t of the "
      "counter-clockwise loop %g m inside the street centre lines (length %.4f m; arc length 0 "
      "where its bottom straight starts, heading +x)",
      kMoverOffset, loop_length);
  mover_json["shape"] =
      "box (length, width, height) standing on the ground, length along the heading";
  // The loop itself, so that a script can place each car at any time: straights along x and y,
  // joined by quarter circles of corner_radius_m, inside the rectangle center_m +- half_extent_m.
  if (!city.movers.empty()) {
    const LoopPath& loop = city.movers[0].path;
    mover_json["loop"] = {
        {"center_m", Json::array({rim::io::JsonNumber(loop.center().x(), 4),
                                  rim::io::JsonNumber(loop.center().y(), 4)})},
        {"half_extent_m", Json::array({rim::io::JsonNumber(loop.half_extent().x(), 4),
                                       rim::io::JsonNumber(loop.half_extent().y(), 4)})},
        {"corner_radius_m", rim::io::JsonNumber(loop.corner_radius(), 4)}};
  }
  mover_json["list"] = std::move(movers);
}

// scene.json as rim_sim writes it: objects one member a line down to the crossers' and movers'
// lists, whose entries take a line each.
absl::Status WriteSceneJson(const std::string& dir, const Json& scene) {
  return WriteTextFile(Join(dir, "scene.json"), rim::io::DumpJson(scene, /*inline_depth=*/3));
}

// README.txt's paragraph on the crossers and movers, or nothing when there are none.
std::string MovingText(const City& city) {
  if (city.crossers.empty() && city.movers.empty()) return "";
  return absl::StrFormat(
      R"(Crossers: %d pedestrians walking back and forth across the drive's street, from sidewalk to
sidewalk (%g m either side of the centre line), each on its own crossing line along the drive.
Movers: %d cars (%g x %g x %g m boxes) driving the opposite lane against the drive, %g m from
the street centre line, each meeting the sensor at its own place along the drive. Both are in the
scans only: not in gt.ply, and their returns are left out of gt_observed.ply. scene.json lists
them.
)",
      city.crossers.size(), kCrossHalfSpan, city.movers.size(), kMoverLength, kMoverWidth,
      kMoverHeight, kMoverOffset);
}

absl::StatusOr<SimSummary> RunCity(const SimOptions& o) {
  SimSummary summary;
  const double step = o.step > 0 ? o.step : 1.0;
  const int threads = ThreadCount(o);
  LidarModel lidar;
  lidar.columns = o.columns;
  const double margin = o.gt_margin >= 0 ? o.gt_margin : lidar.max_range;

  CityOptions city_options;
  city_options.seed = o.seed;
  city_options.walkers = o.walkers;
  city_options.crossers = o.crossers;
  city_options.movers = o.movers;
  city_options.frames = o.frames;
  city_options.step = step;
  city_options.buildings = o.buildings;
  city_options.features = o.features;
  RIM_RETURN_IF_ERROR(ValidateCityOptions(city_options));
  const City city = GenerateCity(city_options);
  const std::vector<Eigen::Isometry3d> poses = CityTrajectory(city, o.frames, step, kSensorHeight);

  Vec2 lo = Vec2::Constant(1e300), hi = Vec2::Constant(-1e300);
  for (const auto& p : poses) {
    lo = lo.cwiseMin(p.translation().head<2>());
    hi = hi.cwiseMax(p.translation().head<2>());
  }
  GroundTruthOptions gt_options;
  gt_options.tessellation.tolerance = kCityMeshTolerance;
  gt_options.ground_cell = kCityGroundCell;
  gt_options.region_min = lo - Vec2::Constant(margin);
  gt_options.region_max = hi + Vec2::Constant(margin);
  const rim::Mesh gt = BuildGroundTruthMesh(city.scene, gt_options);
  summary.gt_vertices = gt.vertices.size();
  summary.gt_faces = gt.faces.size();

  const std::string velodyne = Join(o.out_dir, "velodyne");
  RIM_RETURN_IF_ERROR(rim::MakeDirs(o.out_dir));
  RIM_RETURN_IF_ERROR(RemovePreviousOutput(o.out_dir));
  RIM_RETURN_IF_ERROR(rim::MakeDirs(velodyne));

  std::unique_ptr<RayCaster> static_caster;
  if (city.walkers.empty() && city.crossers.empty() && city.movers.empty()) {
    static_caster = std::make_unique<RayCaster>(city.scene, kCityGridCell);
  }
  // The frame scenes list the static primitives first, then the moving ones.
  const int num_static = static_cast<int>(city.scene.primitives.size());
  VoxelAverager observed(kObservedVoxel);
  std::vector<SensorTruth> truth;
  for (int k = 0; k < o.frames; ++k) {
    NoiseOptions noise{o.noise, HashSeed(o.seed, static_cast<uint64_t>(k), kNoiseStream)};
    std::vector<LidarPoint> points;
    if (static_caster) {
      points = SimulateLidarScan(*static_caster, poses[k], lidar, noise, threads, &truth);
    } else {
      Scene frame_scene = city.scene;
      for (Primitive& m : MovingAt(city, k / kFrameRateHz)) frame_scene.primitives.push_back(m);
      const RayCaster caster(frame_scene, kCityGridCell);
      points = SimulateLidarScan(caster, poses[k], lidar, noise, threads, &truth);
    }
    summary.points += points.size();
    RIM_RETURN_IF_ERROR(WriteKittiScan(Join(velodyne, absl::StrFormat("%06d.bin", k)), points));
    // The observed surface: noise-free hits on static geometry (inside the frame's mapping box);
    // hits on moving things (primitives from num_static on) are left out.
    const Vec3 sensor = poses[k].translation();
    for (const SensorTruth& t : truth) {
      if (t.primitive >= num_static || !InObservedBox(t.world, sensor, o.observed_box)) continue;
      if (!observed.Add(t.world)) return OutOfVoxelRange(t.world);
    }
    observed.Flush();
  }
  const std::vector<std::array<float, 3>> observed_points = observed.Means();
  summary.observed_points = observed_points.size();
  RIM_RETURN_IF_ERROR(WriteKittiPoses(Join(o.out_dir, "poses.txt"), poses));
  RIM_RETURN_IF_ERROR(WriteKittiCalib(Join(o.out_dir, "calib.txt")));
  RIM_RETURN_IF_ERROR(WriteKittiTimes(Join(o.out_dir, "times.txt"), o.frames, kFrameRateHz));
  RIM_RETURN_IF_ERROR(WriteGroundTruth(o.out_dir, gt));
  RIM_RETURN_IF_ERROR(WritePointCloudPly(Join(o.out_dir, "gt_observed.ply"), observed_points));
  // The moving things where the last scan saw them: true surfaces at the end of the drive that
  // gt.ply leaves out. A mapper cannot know that a person standing in its last scans will walk
  // on, so an evaluation may count a map's surface there as no ghost (rim_eval --present).
  const bool moving = !static_caster;
  const double last_time = (o.frames - 1) / kFrameRateHz;
  size_t moving_last_faces = 0;
  if (moving) {
    Scene last;
    last.primitives = MovingAt(city, last_time);
    GroundTruthOptions last_options;
    last_options.tessellation.tolerance = kCityMeshTolerance;
    const rim::Mesh moving_last = BuildGroundTruthMesh(last, last_options);
    moving_last_faces = moving_last.faces.size();
    RIM_RETURN_IF_ERROR(rim::WriteMeshPly(Join(o.out_dir, "gt_moving_last.ply"), moving_last));
  }

  // The box as scene.json and README.txt (in its indented column) describe it.
  const ObservedBox& box = o.observed_box;
  Json box_json = nullptr;
  std::string box_text = absl::StrFormat(R"(, in every frame and
                       wherever it lies (no mapping box: --observed-box none); all frames
                       merged and averaged per %.6g m world-aligned voxel.)",
                                         kObservedVoxel);
  if (box.enabled) {
    box_json = {{"hx_m", box.hx},
                {"hy_m", box.hy},
                {"z_min_m", box.z_min},
                {"z_max_m", box.z_max},
                {"about", "each frame's sensor position, world axes"}};
    box_text = absl::StrFormat(R"( that lies in its
                       frame's local mapping box, |x - sx| < %.6g, |y - sy| < %.6g,
                       sz %+.6g <= z < sz %+.6g m about the sensor position (sx, sy, sz), world
                       axes; all frames merged and averaged per %.6g m world-aligned voxel.)",
                               box.hx, box.hy, box.z_min, box.z_max, kObservedVoxel);
  }
  Json scene = {{"generator", "rim_sim"},
                {"scene", "city"},
                {"layout", "kitti"},
                {"seed", o.seed},
                {"frames", o.frames},
                {"step_m", step},
                {"frame_rate_hz", kFrameRateHz},
                {"noise_stddev_m", o.noise},
                {"walkers", o.walkers}};
  AddMovingJson(city, &scene);
  scene["buildings"] = {
      {"setback_min_m", o.buildings.setback_min},
      {"setback_max_m", o.buildings.setback_max},
      {"height_min_m", o.buildings.height_min},
      {"height_max_m", o.buildings.height_max},
      {"setback_from",
       absl::StrFormat("the street frontage, %.6g m from the street centre line", kFrontage)}};
  scene["features"] = {
      {"parked_cars", o.features.parked_cars},
      {"balconies", o.features.balconies},
      {"annexes", o.features.annexes},
      {"yawed", o.features.yawed},
      {"canopies", o.features.canopies},
      {"about",
       "shares in [0, 1]: of each kerb in rows of kerb-side parked cars; of buildings with "
       "balconies, with an annex, yawed up to 35 deg off the street; of trees with a broad, low "
       "crown"}};
  scene["lidar"] = {{"beams", lidar.beams},
                    {"columns", lidar.columns},
                    {"elevation_max_deg", lidar.elev_max_deg},
                    {"elevation_min_deg", lidar.elev_min_deg},
                    {"min_range_m", lidar.min_range},
                    {"max_range_m", lidar.max_range},
                    {"sensor_height_m", kSensorHeight},
                    {"frame", "x forward, y left, z up"}};
  scene["poses"] = "world_from_lidar, world = gt.ply frame; calib Tr is identity";
  scene["gt_mesh"] = {
      {"file", "gt.ply"},
      {"region_min_xy", Json::array({rim::io::JsonNumber(gt_options.region_min.x(), 3),
                                     rim::io::JsonNumber(gt_options.region_min.y(), 3)})},
      {"region_max_xy", Json::array({rim::io::JsonNumber(gt_options.region_max.x(), 3),
                                     rim::io::JsonNumber(gt_options.region_max.y(), 3)})},
      {"tolerance_m", kCityMeshTolerance},
      {"vertices", gt.vertices.size()},
      {"faces", gt.faces.size()},
      {"includes_walkers", false}};
  scene["gt_observed"] = {
      {"file", "gt_observed.ply"}, {"kind", "points"}, {"points", observed_points.size()},
      {"voxel_m", kObservedVoxel}, {"box", box_json},  {"noise_free", true},
      {"includes_walkers", false}};
  if (moving) {
    scene["gt_moving_last"] = {
        {"file", "gt_moving_last.ply"},
        {"time_s", rim::io::JsonNumber(last_time, 4)},
        {"faces", moving_last_faces},
        {"about",
         "the walkers, crossers and passing cars as they stand at the last frame's time: there at "
         "the end of the drive, though not in gt.ply"}};
  }
  RIM_RETURN_IF_ERROR(WriteSceneJson(o.out_dir, scene));

  const std::string readme = absl::StrFormat(
      R"(Synthetic LiDAR sequence written by rim_sim (scene "city", seed %d).

Layout: KITTI odometry.
  velodyne/NNNNNN.bin  float32 x, y, z, intensity per point, little-endian, in the LiDAR frame
                       (x forward, y left, z up). Each scan is one full revolution taken from the
                       frame's pose (motion-compensated; no rolling-shutter skew). Points are
                       ring by ring (ring 0 = +%.3g deg), azimuth counter-clockwise from +x.
  poses.txt            one line per frame: the top 3x4 of world_from_sensor, row-major. The world
                       frame is the frame of gt.ply (z up, ground at z = 0); the first pose is not
                       the identity.
  calib.txt            P0..P3 copied from KITTI (unused) and Tr = identity, so the "camera" poses
                       of poses.txt are the LiDAR poses themselves (Tr^-1 P Tr = P).
  times.txt            timestamps in seconds, %.6g Hz.
  gt.ply               ground-truth surface of the static scene (no walkers), binary PLY, world
                       frame, cut to the drive's bounds grown by %.6g m. Curved surfaces are
                       inscribed polyhedra within %.6g m of the true shape; footprints of solids
                       are cut out of the ground and of roofs, and faces inside solids are dropped.
  gt_observed.ply      the surface the LiDAR actually saw, as a point cloud (binary PLY, float
                       x, y, z, world frame, no faces): the exact, noise-free hit of every return
                       on the static scene (returns from walkers left out)%s
  scene.json           the generation parameters.%s

Sensor: %d beams evenly spaced from +%.3g to %.3g deg, %d columns, range %.3g..%.3g m,
mounted %.3g m above the ground. Range noise: Gaussian, stddev %.6g m, added along each ray.
Drive: %d frames, %.6g m apart, counter-clockwise round a 2 x 1 ring of 80 m blocks in the
right-hand lane. Buildings: %.6g..%.6g m high, facades set back %.6g..%.6g m beyond %.6g m from
the street centre lines; %.3g of them with balconies, %.3g with a lower annex, %.3g yawed up to
35 deg off the street. Rows of cars parked at the kerb take %.3g of each kerb (scattered parked
cars on the rest); %.3g of the street trees have a broad, low crown. Walkers: %d pedestrians on the sidewalks all round the loop (in the scans
only, not in gt.ply).
%s)",
      o.seed, lidar.elev_max_deg, kFrameRateHz, margin, kCityMeshTolerance, box_text,
      moving ? R"(
  gt_moving_last.ply   the walkers, crossers and passing cars as they stand at the last frame's
                       time (binary PLY mesh, world frame): surfaces there at the end of the
                       drive, though not in gt.ply.)"
             : "",
      lidar.beams, lidar.elev_max_deg, lidar.elev_min_deg, lidar.columns, lidar.min_range,
      lidar.max_range, kSensorHeight, o.noise, o.frames, step, o.buildings.height_min,
      o.buildings.height_max, o.buildings.setback_min, o.buildings.setback_max, kFrontage,
      o.features.balconies, o.features.annexes, o.features.yawed, o.features.parked_cars,
      o.features.canopies, o.walkers, MovingText(city));
  RIM_RETURN_IF_ERROR(WriteTextFile(Join(o.out_dir, "README.txt"), readme));
  summary.frames = o.frames;
  return summary;
}

absl::StatusOr<SimSummary> RunRoom(const SimOptions& o) {
  SimSummary summary;
  const double step = o.step > 0 ? o.step : 0.1;
  const int threads = ThreadCount(o);
  const PinholeCamera camera;
  const Room room = GenerateRoom(o.seed);
  const std::vector<Eigen::Isometry3d> poses = RoomTrajectory(room, o.frames, step);
  GroundTruthOptions gt_options;
  gt_options.tessellation.tolerance = kRoomMeshTolerance;
  const rim::Mesh gt = BuildGroundTruthMesh(room.scene, gt_options);
  summary.gt_vertices = gt.vertices.size();
  summary.gt_faces = gt.faces.size();

  RIM_RETURN_IF_ERROR(rim::MakeDirs(o.out_dir));
  RIM_RETURN_IF_ERROR(RemovePreviousOutput(o.out_dir));
  const RayCaster caster(room.scene, kRoomGridCell);
  VoxelAverager observed(kObservedVoxel);
  std::vector<SensorTruth> truth;
  for (int k = 0; k < o.frames; ++k) {
    NoiseOptions noise{o.noise, HashSeed(o.seed, static_cast<uint64_t>(k), kNoiseStream)};
    const std::vector<uint16_t> mm =
        DepthToMillimetres(RenderDepth(caster, poses[k], camera, noise, threads, &truth));
    // The room has no moving parts and no mapping box: every noise-free hit was observed.
    for (const SensorTruth& t : truth) {
      if (!observed.Add(t.world)) return OutOfVoxelRange(t.world);
    }
    observed.Flush();
    for (uint16_t v : mm) summary.points += v != 0;
    const std::string stem = Join(o.out_dir, absl::StrFormat("frame-%06d", k));
    RIM_RETURN_IF_ERROR(WritePng16(stem + ".depth.png", camera.width, camera.height, mm));
    RIM_RETURN_IF_ERROR(WritePoseMatrix(stem + ".pose.txt", poses[k]));
  }
  RIM_RETURN_IF_ERROR(WriteIntrinsics(Join(o.out_dir, "camera-intrinsics.txt"), camera));
  RIM_RETURN_IF_ERROR(WriteGroundTruth(o.out_dir, gt));
  const std::vector<std::array<float, 3>> observed_points = observed.Means();
  summary.observed_points = observed_points.size();
  RIM_RETURN_IF_ERROR(WritePointCloudPly(Join(o.out_dir, "gt_observed.ply"), observed_points));

  Json scene = {{"generator", "rim_sim"},
                {"scene", "room"},
                {"layout", "7scenes"},
                {"seed", o.seed},
                {"frames", o.frames},
                {"step_m", step},
                {"frame_rate_hz", kRoomFrameRateHz},
                {"noise_stddev_m", o.noise},
                {"room_size_m", Json::array({rim::io::JsonNumber(room.size.x(), 4),
                                             rim::io::JsonNumber(room.size.y(), 4),
                                             rim::io::JsonNumber(room.size.z(), 4)})}};
  scene["camera"] = {{"width", camera.width},
                     {"height", camera.height},
                     {"fx", camera.fx},
                     {"fy", camera.fy},
                     {"cx", camera.cx},
                     {"cy", camera.cy},
                     {"min_depth_m", camera.min_depth},
                     {"max_depth_m", camera.max_depth},
                     {"depth", "uint16 millimetres along the optical axis, 0 = no return"},
                     {"frame", "x right, y down, z forward"}};
  scene["poses"] = "camera_to_world, world = gt.ply frame";
  scene["gt_mesh"] = {{"file", "gt.ply"},
                      {"tolerance_m", kRoomMeshTolerance},
                      {"vertices", gt.vertices.size()},
                      {"faces", gt.faces.size()}};
  scene["gt_observed"] = {
      {"file", "gt_observed.ply"}, {"kind", "points"}, {"points", observed_points.size()},
      {"voxel_m", kObservedVoxel}, {"box", nullptr},   {"noise_free", true}};
  RIM_RETURN_IF_ERROR(WriteSceneJson(o.out_dir, scene));

  const std::string readme = absl::StrFormat(
      R"(Synthetic depth sequence written by rim_sim (scene "room", seed %d).

Layout: 7-Scenes / 3DMatch.
  frame-NNNNNN.depth.png  16-bit grayscale PNG, depth along the optical axis in millimetres,
                          0 = no return. Pixel (u, v) looks along ((u-cx)/fx, (v-cy)/fy, 1).
  frame-NNNNNN.pose.txt   4x4 camera-to-world matrix, one row per line. Camera frame: x right,
                          y down, z forward. World frame: that of gt.ply (z up, floor at z = 0,
                          room centred on the origin).
  camera-intrinsics.txt   the 3x3 K: fx = %.6g, fy = %.6g, cx = %.6g, cy = %.6g (%dx%d image).
  gt.ply                  ground-truth surface (walls, floor, ceiling, furniture), binary PLY.
                          Curved surfaces are within %.6g m of the true shape.
  gt_observed.ply         the surface the camera actually saw, as a point cloud (binary PLY,
                          float x, y, z, world frame, no faces): the noise-free hit of every pixel
                          with a depth in every frame, averaged per %.6g m world-aligned voxel.
  scene.json              the generation parameters.

Room %.2f x %.2f x %.2f m. Camera: %d frames about %.6g m apart on an ellipse round the room,
looking inward and slightly down. Depth noise: Gaussian, stddev %.6g m.
)",
      o.seed, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height,
      kRoomMeshTolerance, kObservedVoxel, room.size.x(), room.size.y(), room.size.z(), o.frames,
      step, o.noise);
  RIM_RETURN_IF_ERROR(WriteTextFile(Join(o.out_dir, "README.txt"), readme));
  summary.frames = o.frames;
  return summary;
}

}  // namespace

absl::StatusOr<SimSummary> RunSim(const SimOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  absl::StatusOr<SimSummary> summary =
      options.scene == SceneKind::kCity ? RunCity(options) : RunRoom(options);
  if (summary.ok()) {
    summary->seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return summary;
}

}  // namespace rim::sim
