// Tests of rim_sim: the analytic geometry, the ray caster, the ground-truth mesh and the
// written datasets (KITTI city, 7-Scenes room), and the command line.
#include "sim/sim.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <unordered_map>
#include <variant>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "rim/io/mesh_io.h"
#include "sim/city.h"
#include "sim/city_frames.h"
#include "sim/geometry.h"
#include "sim/rng.h"
#include "sim/room.h"
#include "sim/scene.h"
#include "sim/sensors.h"
#include "sim/writers.h"
#include "support/temp_dir.h"

namespace rim::sim {
namespace {

// A fresh, empty folder per test and process (ctest runs test cases in parallel processes).
std::string TempDir(const std::string& name) {
  return rim::testing_support::MakeTempDir("rim_sim_test_" + name);
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// dir/scene.json, parsed (keys in the order written); the test fails on a parse error.
nlohmann::ordered_json ReadScene(const std::string& dir) {
  return nlohmann::ordered_json::parse(ReadFile(dir + "/scene.json"));
}

// The keys of a scene.json object, in the order written.
std::vector<std::string> Keys(const nlohmann::ordered_json& object) {
  std::vector<std::string> keys;
  for (auto it = object.begin(); it != object.end(); ++it) keys.push_back(it.key());
  return keys;
}

// Every regular file under dir, as relative path -> bytes.
std::map<std::string, std::string> ReadTree(const std::string& dir) {
  std::map<std::string, std::string> files;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir)) {
    if (e.is_regular_file()) {
      files[std::filesystem::relative(e.path(), dir).string()] = ReadFile(e.path().string());
    }
  }
  return files;
}

std::vector<LidarPoint> ReadScan(const std::string& path) {
  const std::string bytes = ReadFile(path);
  EXPECT_EQ(bytes.size() % sizeof(LidarPoint), 0u) << path;
  std::vector<LidarPoint> points(bytes.size() / sizeof(LidarPoint));
  std::memcpy(points.data(), bytes.data(), points.size() * sizeof(LidarPoint));
  return points;
}

std::vector<Eigen::Isometry3d> ReadKittiPoses(const std::string& path) {
  std::vector<Eigen::Isometry3d> poses;
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) EXPECT_TRUE(static_cast<bool>(ls >> p.matrix()(r, c))) << line;
    }
    double extra;
    EXPECT_FALSE(static_cast<bool>(ls >> extra)) << "more than 12 numbers: " << line;
    poses.push_back(p);
  }
  return poses;
}

std::string ScanPath(const std::string& dir, int frame) {
  return absl::StrFormat("%s/velodyne/%06d.bin", dir, frame);
}

SimOptions SmallCity(const std::string& dir) {
  SimOptions o;
  o.scene = SceneKind::kCity;
  o.out_dir = dir;
  o.frames = 3;
  o.columns = 450;
  o.gt_margin = 30.0;
  o.threads = 2;
  return o;
}

// Exact distance from points to a triangle mesh, through a uniform grid of triangle lists.
class MeshDistance {
 public:
  explicit MeshDistance(const Mesh& mesh, double cell = 1.0) : mesh_(mesh), cell_(cell) {
    for (size_t f = 0; f < mesh.faces.size(); ++f) {
      Eigen::Vector3d lo = V(mesh.faces[f][0]), hi = lo;
      for (int k = 1; k < 3; ++k) {
        lo = lo.cwiseMin(V(mesh.faces[f][k]));
        hi = hi.cwiseMax(V(mesh.faces[f][k]));
      }
      const Eigen::Vector3i a = Cell(lo), b = Cell(hi);
      for (int x = a.x(); x <= b.x(); ++x) {
        for (int y = a.y(); y <= b.y(); ++y) {
          for (int z = a.z(); z <= b.z(); ++z) cells_[Key(x, y, z)].push_back(f);
        }
      }
    }
  }

  // Distance to the nearest triangle, exact when it is below `reach`; otherwise some value
  // >= reach.
  double Distance(const Eigen::Vector3d& p, double reach = 0.05) const {
    double best = std::numeric_limits<double>::infinity();
    const Eigen::Vector3i a = Cell(p - Eigen::Vector3d::Constant(reach));
    const Eigen::Vector3i b = Cell(p + Eigen::Vector3d::Constant(reach));
    for (int x = a.x(); x <= b.x(); ++x) {
      for (int y = a.y(); y <= b.y(); ++y) {
        for (int z = a.z(); z <= b.z(); ++z) {
          const auto it = cells_.find(Key(x, y, z));
          if (it == cells_.end()) continue;
          for (size_t f : it->second) {
            const auto& t = mesh_.faces[f];
            best = std::min(best, PointTriangle(p, V(t[0]), V(t[1]), V(t[2])));
          }
        }
      }
    }
    return best;
  }

 private:
  Eigen::Vector3d V(uint32_t i) const {
    return Eigen::Vector3d(mesh_.vertices[i][0], mesh_.vertices[i][1], mesh_.vertices[i][2]);
  }
  Eigen::Vector3i Cell(const Eigen::Vector3d& p) const {
    return Eigen::Vector3i(static_cast<int>(std::floor(p.x() / cell_)),
                           static_cast<int>(std::floor(p.y() / cell_)),
                           static_cast<int>(std::floor(p.z() / cell_)));
  }
  static int64_t Key(int x, int y, int z) {
    return (static_cast<int64_t>(x & 0x1FFFFF) << 42) | (static_cast<int64_t>(y & 0x1FFFFF) << 21) |
           static_cast<int64_t>(z & 0x1FFFFF);
  }
  // Closest point on a triangle (Ericson, Real-Time Collision Detection 5.1.5).
  static double PointTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                              const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
    const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
    const double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return (p - a).norm();
    const Eigen::Vector3d bp = p - b;
    const double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return (p - b).norm();
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + d1 / (d1 - d3) * ab)).norm();
    const Eigen::Vector3d cp = p - c;
    const double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return (p - c).norm();
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + d2 / (d2 - d6) * ac)).norm();
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
      return (p - (b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b))).norm();
    }
    const double denom = 1.0 / (va + vb + vc);
    return (p - (a + ab * (vb * denom) + ac * (vc * denom))).norm();
  }

  const Mesh& mesh_;
  double cell_;
  std::unordered_map<int64_t, std::vector<size_t>> cells_;
};

// ---------------------------------------------------------------------------------------------
// Geometry

TEST(SimGeometryTest, RayHitsLieOnTheSurfaceOfEveryShape) {
  const std::vector<Shape> shapes = {
      MakeBox(Vec3(1, 2, 3), Vec3(1.5, 0.5, 2), 0.7),
      Cylinder{Vec2(-1, 0.5), 0.3, -1.0, 2.0},
      Sphere{Vec3(0.5, -0.5, 1), 1.2},
      Cone{Vec2(0.2, 0.1), 1.5, 0.5, 4.0},
  };
  Rng rng(7);
  for (size_t s = 0; s < shapes.size(); ++s) {
    const Aabb b = Bounds(shapes[s]);
    const Vec3 mid = 0.5 * (b.min + b.max);
    int hits = 0;
    for (int i = 0; i < 2000; ++i) {
      const Vec3 dir = Vec3(rng.Normal(), rng.Normal(), rng.Normal()).normalized();
      const Vec3 target = mid + Vec3(rng.Uniform(-1, 1), rng.Uniform(-1, 1), rng.Uniform(-1, 1));
      const Vec3 o = target - 20.0 * dir;
      double t;
      Vec3 n;
      if (!Intersect(shapes[s], o, dir, 0.0, 100.0, &t, &n)) continue;
      ++hits;
      const Vec3 p = o + t * dir;
      EXPECT_TRUE(Contains(shapes[s], p, -1e-6)) << "shape " << s << " point " << p.transpose();
      EXPECT_FALSE(Contains(shapes[s], p, 1e-6)) << "shape " << s << " point " << p.transpose();
      EXPECT_NEAR(n.norm(), 1.0, 1e-9);
      EXPECT_LT(n.dot(dir), 1e-9) << "normal must face the incoming ray";
      EXPECT_FALSE(Contains(shapes[s], p + 1e-4 * n, 0.0)) << "normal must point outward";
    }
    EXPECT_GT(hits, 200) << "shape " << s;
  }
}

TEST(SimGeometryTest, RoomShellIsHitFromInside) {
  const RoomShell room{Vec3(-2, -1, 0), Vec3(3, 2, 2.5)};
  Rng rng(3);
  for (int i = 0; i < 500; ++i) {
    const Vec3 o(rng.Uniform(-1.9, 2.9), rng.Uniform(-0.9, 1.9), rng.Uniform(0.1, 2.4));
    const Vec3 d = Vec3(rng.Normal(), rng.Normal(), rng.Normal()).normalized();
    double t;
    Vec3 n;
    ASSERT_TRUE(Intersect(room, o, d, 0.0, 100.0, &t, &n));
    const Vec3 p = o + t * d;
    const double to_wall =
        std::min({p.x() + 2, 3 - p.x(), p.y() + 1, 2 - p.y(), p.z(), 2.5 - p.z()});
    EXPECT_NEAR(to_wall, 0.0, 1e-9);
    EXPECT_LT(n.dot(d), 0.0);
  }
}

TEST(SimGeometryTest, SubtractConvexKeepsExactlyTheAreaOutsideTheHole) {
  const std::vector<Vec2> square = {Vec2(0, 0), Vec2(2, 0), Vec2(2, 2), Vec2(0, 2)};
  // A rotated square overlapping a corner.
  std::vector<Vec2> hole;
  for (int i = 0; i < 4; ++i) {
    const double a = 0.3 + i * M_PI / 2;
    hole.push_back(Vec2(2, 2) + 0.8 * Vec2(std::cos(a), std::sin(a)));
  }
  const auto pieces = SubtractConvex(square, hole);
  double area = 0;
  for (const auto& p : pieces) {
    EXPECT_GT(PolygonArea(p), 0.0);
    area += PolygonArea(p);
  }
  std::vector<Vec2> overlap = square;
  for (size_t i = 0; i < hole.size(); ++i) overlap = ClipLeft(overlap, hole[i], hole[(i + 1) % 4]);
  EXPECT_NEAR(area + PolygonArea(overlap), 4.0, 1e-12);
  EXPECT_GT(PolygonArea(overlap), 0.1);
  // Disjoint hole: the polygon comes back whole; covering hole: nothing is left.
  const std::vector<Vec2> far = {Vec2(5, 5), Vec2(6, 5), Vec2(6, 6), Vec2(5, 6)};
  double far_area = 0;
  for (const auto& p : SubtractConvex(square, far)) far_area += PolygonArea(p);
  EXPECT_NEAR(far_area, 4.0, 1e-12);
  const std::vector<Vec2> big = {Vec2(-1, -1), Vec2(3, -1), Vec2(3, 3), Vec2(-1, 3)};
  EXPECT_TRUE(SubtractConvex(square, big).empty());
}

TEST(SimGeometryTest, TessellationStaysWithinTolerance) {
  // Vertices of curved shapes lie on the surface and face centres no deeper than the tolerance.
  const double tol = 0.005;
  const std::vector<Shape> shapes = {Sphere{Vec3(0, 0, 3), 2.2}, Cylinder{Vec2(0, 0), 0.25, 0, 3},
                                     Cone{Vec2(0, 0), 1.8, 2, 8}};
  for (const Shape& s : shapes) {
    TessellationOptions opt;
    opt.tolerance = tol;
    std::vector<Polygon> polys;
    Tessellate(s, opt, &polys);
    ASSERT_FALSE(polys.empty());
    for (const Polygon& p : polys) {
      Vec3 c = Vec3::Zero();
      for (const Vec3& v : p.corners) {
        EXPECT_TRUE(Contains(s, v, -1e-9));
        c += v;
      }
      c /= p.corners.size();
      EXPECT_TRUE(Contains(s, c, -1e-9));
      EXPECT_FALSE(Contains(s, c, tol)) << "face centre deeper than the tolerance";
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Scene and ray caster

TEST(SimSceneTest, GridRayCasterMatchesBruteForce) {
  const City city = GenerateCity(CityOptions{});
  const RayCaster caster(city.scene, 4.0);
  Scene one;  // one primitive at a time, for the brute force
  Rng rng(11);
  for (int i = 0; i < 3000; ++i) {
    const Vec3 o(rng.Uniform(-20, 180), rng.Uniform(-20, 100), rng.Uniform(0.5, 25));
    const Vec3 d = Vec3(rng.Normal(), rng.Normal(), 0.5 * rng.Normal()).normalized();
    double best = 80.0;
    bool any = false;
    if (d.z() < 0) {
      best = std::min(best, -o.z() / d.z());
      any = best < 80.0;
    }
    for (const Primitive& p : city.scene.primitives) {
      double t;
      Vec3 n;
      if (Intersect(p.shape, o, d, 0.0, best, &t, &n)) {
        best = t;
        any = true;
      }
    }
    RayHit hit;
    const bool got = caster.Cast(o, d, 0.0, 80.0, &hit);
    ASSERT_EQ(got, any) << "ray " << i;
    if (got) EXPECT_NEAR(hit.t, best, 1e-9) << "ray " << i;
  }
}

// A building's main box, not an annex or a balcony slab (both thinner than 5 m one way).
bool MainBuilding(const Primitive& p) {
  const Box* box = std::get_if<Box>(&p.shape);
  return p.material == Material::kBuilding && box != nullptr && box->half.x() >= 2.5 &&
         box->half.y() >= 2.5;
}

TEST(SimSceneTest, CityIsDeterministicAndVariesWithSeed) {
  const City a = GenerateCity(CityOptions{});
  const City b = GenerateCity(CityOptions{});
  CityOptions other;
  other.seed = 2;
  const City c = GenerateCity(other);
  ASSERT_EQ(a.scene.primitives.size(), b.scene.primitives.size());
  EXPECT_GT(a.scene.primitives.size(), 300u);
  int buildings = 0, trees = 0, poles = 0, cars = 0;
  for (size_t i = 0; i < a.scene.primitives.size(); ++i) {
    const Aabb x = Bounds(a.scene.primitives[i].shape), y = Bounds(b.scene.primitives[i].shape);
    EXPECT_EQ(x.min, y.min);
    EXPECT_EQ(x.max, y.max);
    switch (a.scene.primitives[i].material) {
      case Material::kBuilding:
        ++buildings;
        // Annexes and balconies are lower than the building they belong to.
        if (MainBuilding(a.scene.primitives[i])) {
          EXPECT_GE(x.max.z(), BuildingOptions{}.height_min);
        }
        EXPECT_LE(x.max.z(), BuildingOptions{}.height_max);
        break;
      case Material::kTree:
        ++trees;
        break;
      case Material::kPole:
        ++poles;
        break;
      case Material::kCar:
        ++cars;
        break;
      default:
        break;
    }
  }
  EXPECT_GT(buildings, 50);
  EXPECT_GT(trees, 50);
  EXPECT_GT(poles, 10);
  EXPECT_GT(cars, 20);
  bool differs = c.scene.primitives.size() != a.scene.primitives.size();
  for (size_t i = 0; !differs && i < a.scene.primitives.size(); ++i) {
    differs = Bounds(a.scene.primitives[i].shape).min != Bounds(c.scene.primitives[i].shape).min;
  }
  EXPECT_TRUE(differs);
}

// The footprint corners of a box, in the world's xy plane.
std::array<Vec2, 4> FootprintCorners(const Box& b) {
  std::array<Vec2, 4> corners;
  for (int k = 0; k < 4; ++k) {
    const double x = (k == 1 || k == 2) ? b.half.x() : -b.half.x();
    const double y = k >= 2 ? b.half.y() : -b.half.y();
    corners[k] = b.center.head<2>() + BoxToWorld(b, x, y);
  }
  return corners;
}

// Distance from p to the nearest street centre line (x = i * pitch or y = j * pitch).
double StreetDistance(const Vec2& p) {
  const double dx = std::abs(p.x() - kBlockPitch * std::round(p.x() / kBlockPitch));
  const double dy = std::abs(p.y() - kBlockPitch * std::round(p.y() / kBlockPitch));
  return std::min(dx, dy);
}

TEST(SimSceneTest, BuildingsRespectTheHeightAndSetBackRanges) {
  CityOptions tall_and_far;
  tall_and_far.buildings = {5.0, 6.0, 30.0, 40.0};
  for (const CityOptions& co : {CityOptions{}, tall_and_far}) {
    ASSERT_TRUE(ValidateCityOptions(co).ok());
    const BuildingOptions& b = co.buildings;
    const City city = GenerateCity(co);
    int buildings = 0;
    double lowest = 1e9, highest = 0, nearest = 1e9, farthest = 0;
    for (const Primitive& p : city.scene.primitives) {
      if (!MainBuilding(p)) continue;  // annexes and balconies: SimFeaturesTest
      ++buildings;
      const Box& box = std::get<Box>(p.shape);
      const Aabb bounds = Bounds(p.shape);
      lowest = std::min(lowest, bounds.max.z());
      highest = std::max(highest, bounds.max.z());
      EXPECT_LT(bounds.min.z(), 0.0) << "solids reach below the ground";
      EXPECT_GT(bounds.min.z(), -0.1);
      // Every corner keeps the set-back from every street; the one nearest its own street is
      // set back by this building's set-back exactly, which is in range.
      double closest = 1e9;
      for (const Vec2& c : FootprintCorners(box)) closest = std::min(closest, StreetDistance(c));
      nearest = std::min(nearest, closest);
      farthest = std::max(farthest, closest);
    }
    EXPECT_GT(buildings, 50) << "set-back " << b.setback_min;
    EXPECT_GE(lowest, b.height_min);
    EXPECT_LE(highest, b.height_max);
    EXPECT_GE(nearest, kFrontage + b.setback_min - 1e-6);
    EXPECT_LE(farthest, kFrontage + b.setback_max + 1e-6);
    // The ranges are used, not just respected.
    EXPECT_LT(lowest, b.height_min + 0.2 * (b.height_max - b.height_min));
    EXPECT_GT(highest, b.height_max - 0.2 * (b.height_max - b.height_min));
    EXPECT_LT(nearest, kFrontage + b.setback_min + 0.2 * (b.setback_max - b.setback_min));
  }
  // Out-of-range options are refused, naming the field.
  CityOptions bad;
  bad.buildings.height_min = 0.5;
  EXPECT_NE(ValidateCityOptions(bad).message().find("height_min"), std::string::npos);
  bad = CityOptions{};
  bad.buildings.setback_max = std::nan("");
  EXPECT_NE(ValidateCityOptions(bad).message().find("setback_max"), std::string::npos);
  bad = CityOptions{};
  bad.buildings.setback_min = 3.0;
  bad.buildings.setback_max = 2.0;
  EXPECT_FALSE(ValidateCityOptions(bad).ok());
  SimOptions o = SmallCity(TempDir("bad_buildings"));
  o.buildings.height_max = 101.0;
  const absl::StatusOr<SimSummary> run = RunSim(o);
  EXPECT_EQ(run.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(run.status().message().find("height_max"), std::string::npos) << run.status();
}

TEST(SimSceneTest, DefaultGroundTruthStaysSmall) {
  // The 100-frame default run's gt.ply must stay a few MB (binary PLY: 12 B/vertex, 13 B/face).
  const City city = GenerateCity(CityOptions{});
  const auto poses = CityTrajectory(city, 100, 1.0, 1.73);
  GroundTruthOptions opt;
  Vec2 lo = Vec2::Constant(1e9), hi = Vec2::Constant(-1e9);
  for (const auto& p : poses) {
    lo = lo.cwiseMin(p.translation().head<2>());
    hi = hi.cwiseMax(p.translation().head<2>());
  }
  opt.region_min = lo - Vec2::Constant(80);
  opt.region_max = hi + Vec2::Constant(80);
  const Mesh gt = BuildGroundTruthMesh(city.scene, opt);
  const double bytes = 12.0 * gt.vertices.size() + 13.0 * gt.faces.size();
  EXPECT_LT(bytes, 6e6);
  EXPECT_GT(gt.faces.size(), 10000u);
}

// Hidden surface is removed: no face of gt.ply lies inside a solid, and the ground and floors
// have the footprints of what stands on them cut out.
void ExpectNoBuriedFaces(const Scene& scene, const Mesh& gt) {
  const GridIndex index(scene.primitives, 4.0);
  int buried = 0, covered = 0;
  for (const auto& f : gt.faces) {
    Vec3 v[3];
    for (int k = 0; k < 3; ++k) {
      v[k] = Vec3(gt.vertices[f[k]][0], gt.vertices[f[k]][1], gt.vertices[f[k]][2]);
    }
    const Vec3 c = (v[0] + v[1] + v[2]) / 3.0;
    const bool flat_up = std::abs(v[0].z() - v[1].z()) < 1e-6 &&
                         std::abs(v[0].z() - v[2].z()) < 1e-6 &&
                         (v[1] - v[0]).cross(v[2] - v[0]).z() > 0;
    auto check = [&](int i) {
      const Shape& s = scene.primitives[i].shape;
      buried += ContainsAll(s, v, 3, 1e-3);
      // An upward face (ground, roof, table top) is never covered by a solid standing on it.
      // (Slivers thinner than the tessellation tolerance stay: they meet the inscribed polygon
      // of a curved solid.)
      if (flat_up && Contains(s, c + Vec3(0, 0, 1e-3), 0.006)) ++covered;
    };
    index.ForEachInRect(c.head<2>() - Vec2::Constant(1), c.head<2>() + Vec2::Constant(1), check);
    for (int i : index.unbounded()) check(i);
  }
  EXPECT_EQ(buried, 0);
  EXPECT_EQ(covered, 0);
}

TEST(SimSceneTest, GroundTruthHasNoHiddenFaces) {
  const City city = GenerateCity(CityOptions{});
  GroundTruthOptions opt;
  opt.region_min = Vec2(60, -30);
  opt.region_max = Vec2(170, 40);
  const Mesh gt = BuildGroundTruthMesh(city.scene, opt);
  ExpectNoBuriedFaces(city.scene, gt);
  const Room room = GenerateRoom(1);
  ExpectNoBuriedFaces(room.scene, BuildGroundTruthMesh(room.scene, GroundTruthOptions{}));
}

TEST(SimSceneTest, TrajectoryIsSmoothAndStaysOnTheRoad) {
  const City city = GenerateCity(CityOptions{});
  const auto poses = CityTrajectory(city, 600, 1.0, 1.73);  // more than one lap
  const RayCaster caster(city.scene, 4.0);
  for (size_t k = 0; k < poses.size(); ++k) {
    const Eigen::Isometry3d& p = poses[k];
    EXPECT_NEAR(p.translation().z(), 1.73, 1e-12);
    // Nothing solid at the sensor, nor within 0.5 m of it horizontally.
    RayHit hit;
    for (int a = 0; a < 8; ++a) {
      const Vec3 d(std::cos(a * M_PI / 4), std::sin(a * M_PI / 4), 0);
      EXPECT_FALSE(caster.Cast(p.translation(), d, 0.0, 0.5, &hit)) << "frame " << k;
    }
    if (k == 0) continue;
    const double dist = (p.translation() - poses[k - 1].translation()).norm();
    EXPECT_NEAR(dist, 1.0, 2e-3) << "frame " << k;
    const Eigen::AngleAxisd turn(poses[k - 1].linear().transpose() * p.linear());
    EXPECT_LT(turn.angle(), 0.1) << "yaw changes smoothly, frame " << k;
  }
}

// ---------------------------------------------------------------------------------------------
// Datasets written by RunSim

TEST(SimCityTest, SameSeedSameBytesWhateverTheThreadCount) {
  SimOptions a = SmallCity(TempDir("det_a"));
  a.walkers = 5;
  a.noise = 0.02;
  a.threads = 1;
  SimOptions b = a;
  b.out_dir = TempDir("det_b");
  b.threads = 3;
  ASSERT_TRUE(RunSim(a).ok());
  ASSERT_TRUE(RunSim(b).ok());
  const auto fa = ReadTree(a.out_dir), fb = ReadTree(b.out_dir);
  // 3 scans, poses, calib, times, gt, gt_observed, gt_moving_last (walkers move), scene.json,
  // README
  EXPECT_EQ(fa.size(), 3u + 8u);
  EXPECT_TRUE(fa.count("gt_moving_last.ply"));
  ASSERT_EQ(fa.size(), fb.size());
  for (const auto& [name, bytes] : fa) {
    ASSERT_TRUE(fb.count(name)) << name;
    EXPECT_TRUE(bytes == fb.at(name)) << name << " differs";
  }
  // Running again into the same folder with fewer frames leaves no stale scans.
  a.frames = 2;
  ASSERT_TRUE(RunSim(a).ok());
  EXPECT_FALSE(std::filesystem::exists(ScanPath(a.out_dir, 2)));
  EXPECT_EQ(ReadFile(ScanPath(a.out_dir, 1)), fb.at("velodyne/000001.bin"));
}

TEST(SimCityTest, RerunningReplacesThePreviousDataset) {
  const std::string dir = TempDir("rerun");
  SimOptions city = SmallCity(dir);
  ASSERT_TRUE(RunSim(city).ok());
  { std::ofstream(dir + "/notes.txt") << "mine"; }
  SimOptions room;
  room.scene = SceneKind::kRoom;
  room.out_dir = dir;
  room.frames = 2;
  ASSERT_TRUE(RunSim(room).ok());
  // Only the room's 7-Scenes files (and the user's own file) are left.
  std::vector<std::string> names;
  for (const auto& [name, bytes] : ReadTree(dir)) names.push_back(name);
  EXPECT_EQ(names, (std::vector<std::string>{
                       "README.txt", "camera-intrinsics.txt", "frame-000000.depth.png",
                       "frame-000000.pose.txt", "frame-000001.depth.png", "frame-000001.pose.txt",
                       "gt.ply", "gt_observed.ply", "notes.txt", "scene.json"}));
  EXPECT_FALSE(std::filesystem::exists(dir + "/velodyne"));
  ASSERT_TRUE(RunSim(city).ok());
  EXPECT_FALSE(std::filesystem::exists(dir + "/camera-intrinsics.txt"));
  EXPECT_FALSE(std::filesystem::exists(dir + "/frame-000000.depth.png"));
  EXPECT_TRUE(std::filesystem::exists(dir + "/notes.txt"));
  EXPECT_TRUE(std::filesystem::exists(ScanPath(dir, 2)));
}

TEST(SimCityTest, DifferentSeedsGiveDifferentData) {
  SimOptions a = SmallCity(TempDir("seed_a"));
  SimOptions b = a;
  b.out_dir = TempDir("seed_b");
  b.seed = 2;
  ASSERT_TRUE(RunSim(a).ok());
  ASSERT_TRUE(RunSim(b).ok());
  EXPECT_NE(ReadFile(a.out_dir + "/gt.ply"), ReadFile(b.out_dir + "/gt.ply"));
  EXPECT_NE(ReadFile(ScanPath(a.out_dir, 0)), ReadFile(ScanPath(b.out_dir, 0)));
  // The drive is the same: only the scene changes.
  EXPECT_EQ(ReadFile(a.out_dir + "/poses.txt"), ReadFile(b.out_dir + "/poses.txt"));
}

TEST(SimCityTest, EveryLidarHitLiesOnTheGroundTruthMesh) {
  SimOptions o = SmallCity(TempDir("hits"));
  o.frames = 2;
  o.columns = 900;
  ASSERT_TRUE(RunSim(o).ok());
  const auto gt = ReadMeshPly(o.out_dir + "/gt.ply");
  ASSERT_TRUE(gt.ok()) << gt.status();
  const MeshDistance dist(*gt);
  const auto poses = ReadKittiPoses(o.out_dir + "/poses.txt");
  ASSERT_EQ(poses.size(), 2u);
  // gt.ply covers the drive's extent grown by gt_margin; hits beyond it are not checked.
  Vec2 lo = Vec2::Constant(1e9), hi = Vec2::Constant(-1e9);
  for (const auto& p : poses) {
    lo = lo.cwiseMin(p.translation().head<2>());
    hi = hi.cwiseMax(p.translation().head<2>());
  }
  int checked = 0, far = 0;
  double worst = 0;
  for (int k = 0; k < 2; ++k) {
    const auto points = ReadScan(ScanPath(o.out_dir, k));
    EXPECT_GT(points.size(), 0.8 * 64 * 900);
    for (const LidarPoint& lp : points) {
      const Vec3 w = poses[k] * Vec3(lp.x, lp.y, lp.z);
      if ((w.head<2>().array() > lo.array() - o.gt_margin + 0.5).all() &&
          (w.head<2>().array() < hi.array() + o.gt_margin - 0.5).all()) {
        const double d = dist.Distance(w);
        worst = std::max(worst, d);
        if (d >= 0.01) ++far;
        ++checked;
        EXPECT_GE(lp.intensity, 0.0f);
        EXPECT_LE(lp.intensity, 1.0f);
      }
    }
  }
  EXPECT_GT(checked, 50000);
  EXPECT_EQ(far, 0) << "worst distance " << worst;
  EXPECT_LT(worst, 0.01);
}

TEST(SimCityTest, WalkersAppearInScansButNotInGroundTruth) {
  SimOptions with = SmallCity(TempDir("walkers_with"));
  with.walkers = 60;
  with.frames = 4;
  SimOptions without = with;
  without.out_dir = TempDir("walkers_without");
  without.walkers = 0;
  ASSERT_TRUE(RunSim(with).ok());
  ASSERT_TRUE(RunSim(without).ok());
  const std::string gt_bytes = ReadFile(with.out_dir + "/gt.ply");
  EXPECT_EQ(gt_bytes, ReadFile(without.out_dir + "/gt.ply")) << "gt.ply must not contain walkers";

  CityOptions co;
  co.seed = with.seed;
  co.walkers = with.walkers;
  const City city = GenerateCity(co);
  const auto gt = ReadMeshPly(with.out_dir + "/gt.ply");
  ASSERT_TRUE(gt.ok());
  const MeshDistance dist(*gt);
  const auto poses = ReadKittiPoses(with.out_dir + "/poses.txt");
  int walker_hits = 0, frames_with_walkers = 0;
  for (int k = 0; k < with.frames; ++k) {
    const std::vector<Primitive> walkers = WalkersAt(city, k / kFrameRateHz);
    int in_frame = 0;
    for (const LidarPoint& lp : ReadScan(ScanPath(with.out_dir, k))) {
      const Vec3 w = poses[k] * Vec3(lp.x, lp.y, lp.z);
      bool on_walker = false;
      for (const Primitive& p : walkers) on_walker = on_walker || Contains(p.shape, w, -0.01);
      if (!on_walker) continue;
      ++in_frame;
      // Walker points are off the static surface (unless they are where a walker meets the
      // ground or stands in front of something within a centimetre).
      if (w.z() > 0.05) EXPECT_GT(dist.Distance(w), 0.05) << w.transpose();
    }
    walker_hits += in_frame;
    frames_with_walkers += in_frame > 0;
  }
  EXPECT_GT(walker_hits, 100);
  EXPECT_EQ(frames_with_walkers, with.frames);
  // And the scans differ from the walker-free ones.
  EXPECT_NE(ReadFile(ScanPath(with.out_dir, 0)), ReadFile(ScanPath(without.out_dir, 0)));
}

TEST(SimCityTest, NoiseHasTheRequestedStandardDeviation) {
  SimOptions clean = SmallCity(TempDir("noise_clean"));
  clean.frames = 2;
  SimOptions noisy = clean;
  noisy.out_dir = TempDir("noise_noisy");
  noisy.noise = 0.05;
  ASSERT_TRUE(RunSim(clean).ok());
  ASSERT_TRUE(RunSim(noisy).ok());
  double sum = 0, sum2 = 0;
  int n = 0;
  for (int k = 0; k < clean.frames; ++k) {
    const auto a = ReadScan(ScanPath(clean.out_dir, k));
    const auto b = ReadScan(ScanPath(noisy.out_dir, k));
    ASSERT_EQ(a.size(), b.size()) << "the same rays return with and without noise";
    for (size_t i = 0; i < a.size(); ++i) {
      const Vec3 pa(a[i].x, a[i].y, a[i].z), pb(b[i].x, b[i].y, b[i].z);
      // Noise is along the ray: same direction, different range.
      EXPECT_NEAR(pa.normalized().dot(pb.normalized()), 1.0, 1e-6);
      const double e = pb.norm() - pa.norm();
      sum += e;
      sum2 += e * e;
      ++n;
    }
  }
  ASSERT_GT(n, 10000);
  const double mean = sum / n, stddev = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 0.0, 0.002);
  EXPECT_NEAR(stddev, 0.05, 0.0025);
}

// gt_observed.ply as a list of points; checks that it is a binary little-endian PLY with float
// x, y, z and no face element.
std::vector<Vec3> ReadObserved(const std::string& dir) {
  const std::string path = dir + "/gt_observed.ply";
  const std::string bytes = ReadFile(path);
  const size_t end = bytes.find("end_header\n");
  EXPECT_NE(end, std::string::npos) << path;
  if (end == std::string::npos) return {};
  const std::string header = bytes.substr(0, end);
  EXPECT_EQ(header.rfind("ply\nformat binary_little_endian 1.0\nelement vertex ", 0), 0u) << header;
  EXPECT_NE(header.find("property float x\nproperty float y\nproperty float z\n"),
            std::string::npos)
      << header;
  EXPECT_EQ(header.find("face"), std::string::npos) << "a point cloud has no faces: " << header;
  const auto cloud = ReadMeshPly(path);
  EXPECT_TRUE(cloud.ok()) << cloud.status();
  if (!cloud.ok()) return {};
  EXPECT_TRUE(cloud->faces.empty());
  EXPECT_EQ(bytes.size() - end - 11, 12 * cloud->vertices.size());
  std::vector<Vec3> points;
  for (const auto& v : cloud->vertices) points.emplace_back(v[0], v[1], v[2]);
  return points;
}

// Inside the mapping box about sensor position s, with `slack` to spare for rounding.
bool InBox(const Vec3& p, const Vec3& s, const ObservedBox& box, double slack) {
  return std::abs(p.x() - s.x()) < box.hx + slack && std::abs(p.y() - s.y()) < box.hy + slack &&
         p.z() >= s.z() + box.z_min - slack && p.z() < s.z() + box.z_max + slack;
}

TEST(SimCityTest, ObservedGroundTruthIsTheNoiseFreeStaticSurfaceInsideTheFrameBoxes) {
  SimOptions o = SmallCity(TempDir("observed"));
  o.frames = 4;
  o.columns = 900;
  o.walkers = 60;
  o.noise = 0.05;
  o.step = 3.0;
  ASSERT_TRUE(RunSim(o).ok());
  const std::vector<Vec3> points = ReadObserved(o.out_dir);
  ASSERT_GT(points.size(), 50000u);
  const auto gt = ReadMeshPly(o.out_dir + "/gt.ply");
  ASSERT_TRUE(gt.ok()) << gt.status();
  const MeshDistance dist(*gt);
  const auto poses = ReadKittiPoses(o.out_dir + "/poses.txt");
  ASSERT_EQ(poses.size(), 4u);
  CityOptions co;
  co.seed = o.seed;
  co.walkers = o.walkers;
  const City city = GenerateCity(co);
  std::vector<std::vector<Primitive>> walkers;
  for (int k = 0; k < o.frames; ++k) walkers.push_back(WalkersAt(city, k / kFrameRateHz));

  const ObservedBox box;  // the defaults: +-10 m, z -3..+3 m about the sensor
  int far = 0, outside = 0, on_walkers = 0;
  double worst = 0;
  std::vector<int> per_frame(o.frames, 0);
  for (const Vec3& p : points) {
    // On the static surface: noise-free (with 5 cm noise in the scans) and no walkers.
    const double d = dist.Distance(p);
    worst = std::max(worst, d);
    far += d >= 0.01;
    // Inside the mapping box of some frame (1e-4 for the float output and poses.txt's digits).
    bool inside = false;
    for (int k = 0; k < o.frames; ++k) {
      if (InBox(p, poses[k].translation(), box, 1e-4)) {
        inside = true;
        ++per_frame[k];
      }
    }
    outside += !inside;
    bool on_walker = false;
    for (const auto& frame_walkers : walkers) {
      for (const Primitive& w : frame_walkers) on_walker = on_walker || Contains(w.shape, p, -0.01);
    }
    on_walkers += on_walker && p.z() > 0.05;
  }
  EXPECT_EQ(far, 0) << "worst distance to gt.ply " << worst;
  EXPECT_LT(worst, 0.01);
  EXPECT_EQ(outside, 0);
  EXPECT_EQ(on_walkers, 0);
  for (int k = 0; k < o.frames; ++k) EXPECT_GT(per_frame[k], 10000) << "frame " << k;
  // The boxes are full: the ground reaches their sides, and there is more than ground.
  double max_dx = 0;
  int above_ground = 0;
  for (const Vec3& p : points) {
    max_dx = std::max(max_dx, std::abs(p.x() - poses[0].translation().x()));
    EXPECT_GE(p.z(), -1e-6);
    above_ground += p.z() > 0.5;
  }
  EXPECT_GT(max_dx, 9.5);
  EXPECT_GT(above_ground, 1000);
  // ...and the walkers were in view: the scans hit them.
  int walker_hits = 0;
  for (int k = 0; k < o.frames; ++k) {
    for (const LidarPoint& lp : ReadScan(ScanPath(o.out_dir, k))) {
      const Vec3 w = poses[k] * Vec3(lp.x, lp.y, lp.z);
      if (!InBox(w, poses[k].translation(), box, 0.0)) continue;
      for (const Primitive& p : walkers[k]) walker_hits += Contains(p.shape, w, -0.1);
    }
  }
  EXPECT_GT(walker_hits, 100) << "no walker inside the boxes: the test proves nothing";

  // Noise-free: the same file without noise; deterministic whatever the thread count.
  SimOptions clean = o;
  clean.out_dir = TempDir("observed_clean");
  clean.noise = 0.0;
  clean.threads = 3;
  ASSERT_TRUE(RunSim(clean).ok());
  EXPECT_TRUE(ReadFile(o.out_dir + "/gt_observed.ply") ==
              ReadFile(clean.out_dir + "/gt_observed.ply"));
  // scene.json reports it.
  nlohmann::ordered_json scene = ReadScene(o.out_dir);
  EXPECT_EQ(scene["gt_observed"]["points"], points.size()) << scene.dump();
  EXPECT_EQ(scene["gt_observed"]["kind"], "points") << scene.dump();
}

TEST(SimCityTest, ObservedBoxOptionShrinksTheObservedSurface) {
  SimOptions o = SmallCity(TempDir("observed_box"));
  o.frames = 2;
  o.observed_box = {4.0, 6.0, -2.0, 0.5};
  ASSERT_TRUE(RunSim(o).ok());
  const std::vector<Vec3> points = ReadObserved(o.out_dir);
  ASSERT_GT(points.size(), 1000u);
  const auto poses = ReadKittiPoses(o.out_dir + "/poses.txt");
  for (const Vec3& p : points) {
    bool inside = false;
    for (const auto& pose : poses)
      inside = inside || InBox(p, pose.translation(), o.observed_box, 1e-4);
    ASSERT_TRUE(inside) << p.transpose();
  }
  SimOptions wide = o;
  wide.out_dir = TempDir("observed_box_wide");
  wide.observed_box = ObservedBox{};
  ASSERT_TRUE(RunSim(wide).ok());
  const size_t wide_points = ReadObserved(wide.out_dir).size();
  EXPECT_GT(wide_points, 1.5 * points.size());
  // No box: every static hit of every frame, far ones included.
  SimOptions all = o;
  all.out_dir = TempDir("observed_box_none");
  all.observed_box.enabled = false;
  ASSERT_TRUE(RunSim(all).ok());
  EXPECT_GT(ReadObserved(all.out_dir).size(), 1.3 * wide_points);
  EXPECT_TRUE(ReadScene(all.out_dir)["gt_observed"]["box"].is_null());
  const std::string readme = ReadFile(all.out_dir + "/README.txt");
  EXPECT_NE(readme.find("no mapping box"), std::string::npos) << readme;
}

// Above the sensor's top beam (+2 deg: about 2.1 m at 10 m), the facades inside the mapping boxes
// along the drive are seen only from frames farther away. Without the box they are in
// gt_observed.ply; with it they are not.
TEST(SimCityTest, ObservedWithoutBoxCoversFacadesSeenOnlyFromAfar) {
  SimOptions o = SmallCity(TempDir("facades_none"));
  o.frames = 30;
  o.columns = 900;
  o.observed_box.enabled = false;
  SimOptions boxed = o;
  boxed.out_dir = TempDir("facades_boxed");
  boxed.observed_box = ObservedBox{};
  ASSERT_TRUE(RunSim(o).ok());
  ASSERT_TRUE(RunSim(boxed).ok());
  const auto poses = ReadKittiPoses(o.out_dir + "/poses.txt");
  ASSERT_EQ(poses.size(), 30u);
  const City city = GenerateCity(CityOptions{});
  // Points 2.5-4.5 m up, inside the union of the default boxes, on a building's side.
  auto facade_points = [&](const std::vector<Vec3>& points) {
    int count = 0;
    for (const Vec3& p : points) {
      if (p.z() < 2.5 || p.z() > 4.5) continue;
      bool in_union = false;
      for (const auto& pose : poses) {
        in_union = in_union || InBox(p, pose.translation(), ObservedBox{}, 0.0);
      }
      if (!in_union) continue;
      for (const Primitive& prim : city.scene.primitives) {
        if (prim.material == Material::kBuilding && Contains(prim.shape, p, -0.01) &&
            !Contains(prim.shape, p, 0.01) && p.z() < Bounds(prim.shape).max.z() - 0.01) {
          ++count;
          break;
        }
      }
    }
    return count;
  };
  const std::vector<Vec3> all = ReadObserved(o.out_dir);
  const std::vector<Vec3> in_boxes = ReadObserved(boxed.out_dir);
  EXPECT_GT(all.size(), in_boxes.size());
  const int seen_from_afar = facade_points(all);
  // 260 points with this seed and these options (514 at 1800 columns).
  EXPECT_GT(seen_from_afar, 130);
  EXPECT_EQ(facade_points(in_boxes), 0);
}

TEST(SimCityTest, PosesCalibAndTimesParseBack) {
  SimOptions o = SmallCity(TempDir("poses"));
  o.frames = 5;
  o.step = 1.5;
  ASSERT_TRUE(RunSim(o).ok());
  const auto poses = ReadKittiPoses(o.out_dir + "/poses.txt");
  ASSERT_EQ(poses.size(), 5u);
  const City city = GenerateCity(CityOptions{});
  const auto expected = CityTrajectory(city, 5, 1.5, 1.73);
  for (int k = 0; k < 5; ++k) {
    EXPECT_TRUE(poses[k].matrix().isApprox(expected[k].matrix(), 1e-11)) << "frame " << k;
    const Eigen::Matrix3d r = poses[k].linear();
    EXPECT_TRUE((r.transpose() * r).isIdentity(1e-11));
    EXPECT_NEAR(r.determinant(), 1.0, 1e-11);
  }
  // calib.txt: P0..P3 and an identity Tr.
  std::ifstream calib(o.out_dir + "/calib.txt");
  std::string line;
  std::vector<std::string> keys;
  while (std::getline(calib, line)) {
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    keys.push_back(key);
    std::vector<double> v;
    double x;
    while (ls >> x) v.push_back(x);
    ASSERT_EQ(v.size(), 12u) << line;
    if (key == "Tr:") {
      const std::vector<double> identity = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
      EXPECT_EQ(v, identity);
    }
  }
  EXPECT_EQ(keys, (std::vector<std::string>{"P0:", "P1:", "P2:", "P3:", "Tr:"}));
  std::ifstream times(o.out_dir + "/times.txt");
  std::vector<double> t;
  double x;
  while (times >> x) t.push_back(x);
  ASSERT_EQ(t.size(), 5u);
  EXPECT_DOUBLE_EQ(t[4], 0.4);
  EXPECT_EQ(ReadScene(o.out_dir)["frames"], 5);
}

TEST(SimRoomTest, DepthPixelsBackProjectOntoTheGroundTruth) {
  SimOptions o;
  o.scene = SceneKind::kRoom;
  o.out_dir = TempDir("room");
  o.frames = 3;
  o.step = 1.0;  // frames far apart round the room
  ASSERT_TRUE(RunSim(o).ok());
  const auto gt = ReadMeshPly(o.out_dir + "/gt.ply");
  ASSERT_TRUE(gt.ok()) << gt.status();
  const MeshDistance dist(*gt, 0.25);
  std::ifstream kin(o.out_dir + "/camera-intrinsics.txt");
  Eigen::Matrix3d K;
  for (int i = 0; i < 9; ++i) ASSERT_TRUE(static_cast<bool>(kin >> K(i / 3, i % 3)));
  EXPECT_EQ(K(0, 0), 300.0);
  EXPECT_EQ(K(2, 2), 1.0);
  // scene.json records the camera the images were taken with.
  nlohmann::ordered_json scene = ReadScene(o.out_dir);
  EXPECT_EQ(scene["layout"], "7scenes");
  EXPECT_EQ(scene["frames"], 3);
  EXPECT_EQ(scene["camera"]["width"], 320);
  EXPECT_EQ(scene["camera"]["fx"], K(0, 0));
  EXPECT_EQ(scene["camera"]["cx"], K(0, 2));
  EXPECT_EQ(scene["room_size_m"].size(), 3u);
  EXPECT_TRUE(scene["gt_observed"]["box"].is_null());
  for (int k = 0; k < o.frames; ++k) {
    const std::string stem = o.out_dir + absl::StrFormat("/frame-%06d", k);
    const auto png = ReadPng16(stem + ".depth.png");
    ASSERT_TRUE(png.ok()) << png.status();
    ASSERT_EQ(png->width, 320);
    ASSERT_EQ(png->height, 240);
    std::ifstream pin(stem + ".pose.txt");
    Eigen::Matrix4d m;
    for (int i = 0; i < 16; ++i) ASSERT_TRUE(static_cast<bool>(pin >> m(i / 4, i % 4)));
    EXPECT_EQ(m.row(3), Eigen::RowVector4d(0, 0, 0, 1));
    Eigen::Isometry3d pose(m);
    // Camera looks forward along +z and slightly down: its z axis points below the horizon.
    EXPECT_LT(pose.linear().col(2).z(), 0.0);
    EXPECT_NEAR(pose.linear().col(0).z(), 0.0, 1e-12) << "no roll: x axis stays horizontal";
    int valid = 0, far = 0;
    double worst = 0;
    for (int v = 0; v < png->height; ++v) {
      for (int u = 0; u < png->width; ++u) {
        const uint16_t mm = png->pixels[v * png->width + u];
        if (mm == 0) continue;
        ++valid;
        if ((u + v) % 3 != 0) continue;  // a third of the pixels is plenty
        const double z = mm / 1000.0;
        const Vec3 pc((u - K(0, 2)) * z / K(0, 0), (v - K(1, 2)) * z / K(1, 1), z);
        const double d = dist.Distance(pose * pc);
        worst = std::max(worst, d);
        far += d >= 0.01;
      }
    }
    EXPECT_GT(valid, 0.99 * 320 * 240) << "a closed room returns almost everywhere";
    EXPECT_EQ(far, 0) << "frame " << k << " worst " << worst;
  }
}

TEST(SimRoomTest, ObservedPointsLieOnTheGroundTruth) {
  SimOptions o;
  o.scene = SceneKind::kRoom;
  o.out_dir = TempDir("room_observed");
  o.frames = 3;
  o.step = 1.0;
  o.noise = 0.02;
  ASSERT_TRUE(RunSim(o).ok());
  const std::vector<Vec3> points = ReadObserved(o.out_dir);
  ASSERT_GT(points.size(), 50000u);
  const auto gt = ReadMeshPly(o.out_dir + "/gt.ply");
  ASSERT_TRUE(gt.ok()) << gt.status();
  const MeshDistance dist(*gt, 0.25);
  int far = 0;
  double worst = 0;
  for (size_t i = 0; i < points.size(); i += 2) {  // half the points is plenty
    const double d = dist.Distance(points[i]);
    worst = std::max(worst, d);
    far += d >= 0.01;
  }
  EXPECT_EQ(far, 0) << "worst " << worst;
}

TEST(SimRoomTest, RoomHasFurnitureAndAClearPath) {
  for (uint64_t seed : {1, 2, 3}) {
    const Room room = GenerateRoom(seed);
    EXPECT_GE(room.scene.primitives.size(), 10u) << "seed " << seed;
    const RayCaster caster(room.scene, 0.5);
    for (const auto& p : RoomTrajectory(room, 200, 0.1)) {
      for (const Primitive& prim : room.scene.primitives) {
        EXPECT_FALSE(Contains(prim.shape, p.translation(), -0.3)) << "seed " << seed;
      }
    }
  }
}

TEST(SimPngTest, SixteenBitRoundTrip) {
  const std::string path = TempDir("png") + "/d.png";
  std::vector<uint16_t> px(7 * 5);
  for (size_t i = 0; i < px.size(); ++i) px[i] = static_cast<uint16_t>(i * 1871 + 3);
  px[0] = 0;
  px[1] = 65535;
  ASSERT_TRUE(WritePng16(path, 7, 5, px).ok());
  const auto back = ReadPng16(path);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->width, 7);
  EXPECT_EQ(back->height, 5);
  EXPECT_EQ(back->pixels, px);
  EXPECT_FALSE(ReadPng16(path + ".missing").ok());
  EXPECT_EQ(DepthToMillimetres({0.0f, 1.2344f, 70.0f, std::nanf("")}),
            (std::vector<uint16_t>{0, 1234, 0, 0}));
}

// ---------------------------------------------------------------------------------------------
// Moving things: crossers and movers

// ---------------------------------------------------------------------------------------------
// CityFeatures: kerb-side parked cars, balconies, annexes, yawed buildings, broad crowns

CityOptions FeatureCity(uint64_t seed, double share) {
  CityOptions co;
  co.seed = seed;
  co.features = {share, share, share, share, share};
  return co;
}

// What each feature adds, counted in the static scene.
struct FeatureCounts {
  int kerb_cars = 0;  // car bodies with their kerb side within 19 cm of the kerb line
  int balconies = 0;  // building slabs from kLowestBalcony up
  int annexes = 0;    // building boxes on the ground thinner than a main building
  int yawed = 0;      // main buildings more than 5 degrees off their street
  int canopies = 0;   // broad crowns: tree cylinders wider than any trunk
  int buildings = 0, cars = 0, trees = 0;
};

FeatureCounts CountFeatures(const City& city) {
  FeatureCounts n;
  for (const Primitive& p : city.scene.primitives) {
    const Aabb b = Bounds(p.shape);
    if (p.material == Material::kCar && b.min.z() < 0) {
      ++n.cars;
      double nearest = 1e9;  // of the footprint's corners, to the street centre line
      double farthest = 0;
      for (const Vec2& c : FootprintCorners(std::get<Box>(p.shape))) {
        nearest = std::min(nearest, StreetDistance(c));
        farthest = std::max(farthest, StreetDistance(c));
      }
      n.kerb_cars += farthest > 4.5 - 0.15 - 0.04 && farthest < 4.5 && nearest > 2.4;
    } else if (p.material == Material::kBuilding) {
      if (MainBuilding(p)) {
        ++n.buildings;
        const double yaw = std::get<Box>(p.shape).yaw;
        const double off = std::abs(std::remainder(yaw, M_PI / 2));
        n.yawed += off > 5.0 * M_PI / 180;
      } else if (b.min.z() >= kLowestBalcony) {
        ++n.balconies;
      } else {
        ++n.annexes;
      }
    } else if (p.material == Material::kTree) {
      ++n.trees;
      const auto* cyl = std::get_if<Cylinder>(&p.shape);
      n.canopies += cyl != nullptr && cyl->radius > 1.0;
    }
  }
  return n;
}

TEST(SimFeaturesTest, OptionsAreValidatedNamingTheField) {
  for (const char* name : {"parked_cars", "balconies", "annexes", "yawed", "canopies"}) {
    for (double bad : {-0.01, 1.01, std::nan(""), std::numeric_limits<double>::infinity()}) {
      CityOptions o;
      CityFeatures& f = o.features;
      double* share = std::string(name) == "parked_cars" ? &f.parked_cars
                      : std::string(name) == "balconies" ? &f.balconies
                      : std::string(name) == "annexes"   ? &f.annexes
                      : std::string(name) == "yawed"     ? &f.yawed
                                                         : &f.canopies;
      for (double ok : {0.0, 1.0}) {
        *share = ok;
        EXPECT_TRUE(ValidateCityOptions(o).ok()) << name;
      }
      *share = bad;
      const absl::Status status = ValidateCityOptions(o);
      EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << name << " " << bad;
      EXPECT_NE(
          status.message().find(absl::StrCat("CityOptions.features.", name, " must be in [0, 1]")),
          std::string::npos)
          << status;
    }
  }
  SimOptions o = SmallCity(TempDir("bad_features"));
  o.features.annexes = 3.0;
  const absl::StatusOr<SimSummary> run = RunSim(o);
  EXPECT_EQ(run.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(run.status().message().find("features.annexes"), std::string::npos) << run.status();
}

TEST(SimFeaturesTest, EachFeatureIsThereWhenAskedAndGoneAtZero) {
  const CityFeatures defaults;
  EXPECT_GT(defaults.parked_cars, 0.3);
  EXPECT_GT(defaults.balconies, 0.2);
  EXPECT_GT(defaults.annexes, 0.2);
  EXPECT_GT(defaults.yawed, 0.25);
  EXPECT_GT(defaults.canopies, 0.3);
  for (uint64_t seed : {1, 7}) {
    const FeatureCounts none = CountFeatures(GenerateCity(FeatureCity(seed, 0.0)));
    const FeatureCounts all = CountFeatures(GenerateCity(FeatureCity(seed, 1.0)));
    CityOptions co;
    co.seed = seed;
    const FeatureCounts mix = CountFeatures(GenerateCity(co));
    EXPECT_EQ(none.balconies, 0);
    EXPECT_EQ(none.annexes, 0);
    EXPECT_EQ(none.yawed, 0);
    EXPECT_EQ(none.canopies, 0);
    EXPECT_GT(none.cars, 60);  // the scattered parked cars stay
    EXPECT_GT(all.balconies, 300) << "seed " << seed;
    EXPECT_GT(all.annexes, 0.4 * all.buildings) << "seed " << seed;
    EXPECT_GT(all.yawed, 0.7 * all.buildings) << "seed " << seed;
    EXPECT_GT(all.canopies, 0.7 * all.trees / 3) << "seed " << seed;  // trunk, disc, cone
    EXPECT_GT(all.kerb_cars, 2.5 * none.kerb_cars) << "seed " << seed;
    EXPECT_GT(all.cars, 2.5 * none.cars) << "seed " << seed;
    // The default mix has some of everything.
    EXPECT_GT(mix.balconies, 50);
    EXPECT_GT(mix.annexes, 0.15 * mix.buildings);
    EXPECT_GT(mix.yawed, 0.1 * mix.buildings);
    EXPECT_LT(mix.yawed, 0.5 * mix.buildings);
    EXPECT_GT(mix.canopies, 20);
    EXPECT_GT(mix.kerb_cars, 150);
  }
  // One feature at a time: only it changes.
  CityOptions only_canopies = FeatureCity(3, 0.0);
  only_canopies.features.canopies = 1.0;
  const FeatureCounts c = CountFeatures(GenerateCity(only_canopies));
  EXPECT_GT(c.canopies, 30);
  EXPECT_EQ(c.balconies + c.annexes + c.yawed, 0);
}

TEST(SimFeaturesTest, PartsKeepTheirPlaces) {
  const City city = GenerateCity(FeatureCity(2, 1.0));
  const RayCaster caster(city.scene, 4.0);
  int balconies_hit = 0;
  for (const Primitive& p : city.scene.primitives) {
    const Aabb b = Bounds(p.shape);
    if (p.material == Material::kBuilding && !MainBuilding(p)) {
      double nearest = 1e9;
      for (const Vec2& c : FootprintCorners(std::get<Box>(p.shape))) {
        nearest = std::min(nearest, StreetDistance(c));
      }
      if (b.min.z() >= kLowestBalcony) {
        // A balcony: thin, overhanging the frontage by at most kMaxBalconyDepth.
        EXPECT_GE(nearest, kFrontage - kMaxBalconyDepth - 1e-6);
        EXPECT_LE(b.max.z() - b.min.z(), 0.2 + 1e-9);
        // Seen from below, outside its building: its underside.
        const Box& slab = std::get<Box>(p.shape);
        const Vec2 under = slab.center.head<2>() + BoxToWorld(slab, 0, -0.9 * slab.half.y());
        RayHit hit;
        if (caster.Cast(Vec3(under.x(), under.y(), 1.0), Vec3::UnitZ(), 0.0, 100.0, &hit) &&
            std::abs(hit.t - (b.min.z() - 1.0)) < 1e-9 && hit.normal.z() < -0.999) {
          ++balconies_hit;
        }
      } else {
        // An annex: on the ground, behind the frontage, 2.5-4.5 m tall.
        EXPECT_LT(b.min.z(), 0.0);
        EXPECT_GE(nearest, kFrontage - 1e-6);
        EXPECT_GE(b.max.z(), 2.5);
        EXPECT_LE(b.max.z(), 4.5);
      }
    } else if (p.material == Material::kTree) {
      const auto* disc = std::get_if<Cylinder>(&p.shape);
      if (disc != nullptr && disc->radius > 1.0) {
        EXPECT_GE(disc->z_min, 2.5);
        EXPECT_LE(disc->z_min, 3.5);
        EXPECT_LE(disc->radius, 4.0);
        // It leaves the sensor's lane open.
        EXPECT_GE(StreetDistance(disc->center) - disc->radius, kLaneOffset);
      }
    }
  }
  EXPECT_GT(balconies_hit, 100);
}

// The union's surface, exactly: a facade hidden behind a balcony slab or an annex, the slab's
// and the annex's ends inside the building and the slab's underside there are all cut away.
TEST(SimFeaturesTest, GroundTruthCutsWhatBalconiesAndAnnexesHide) {
  Scene scene;
  scene.has_ground = true;
  // A 10 x 10 x 10 m building, a 3 m wide slab 1.5 m deep and 0.2 m thick reaching 3 cm into its
  // facade at y = 0, and a 4 x 2 x 3 m annex reaching 3 cm into it.
  scene.primitives.push_back(
      {MakeBoxZ(Vec2(5, 5), Vec2(5, 5), 0.0, -0.03, 10.0), Material::kBuilding});
  scene.primitives.push_back(
      {MakeBoxZ(Vec2(3.5, -0.735), Vec2(1.5, 0.765), 0.0, 3.0, 3.2), Material::kBuilding});
  scene.primitives.push_back(
      {MakeBoxZ(Vec2(8.0, -0.985), Vec2(1.5, 1.015), 0.0, -0.03, 3.0), Material::kBuilding});
  GroundTruthOptions opt;
  opt.region_min = Vec2(-5, -5);
  opt.region_max = Vec2(15, 15);
  const Mesh gt = BuildGroundTruthMesh(scene, opt);
  double area = 0;
  for (const auto& f : gt.faces) {
    Vec3 v[3];
    for (int k = 0; k < 3; ++k) {
      v[k] = Vec3(gt.vertices[f[k]][0], gt.vertices[f[k]][1], gt.vertices[f[k]][2]);
    }
    area += 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).norm();
  }
  const double ground = 20 * 20 - 100 - 3 * 2;
  const double building = 4 * 10 * 10 + 100 - 3 * 0.2 - 3 * 3;  // less what the parts hide
  const double slab = 2 * 3 * 1.5 + 3 * 0.2 + 2 * 1.5 * 0.2;
  const double annex = 3 * 2 + 3 * 3 + 2 * 2 * 3;
  EXPECT_NEAR(area, ground + building + slab + annex, 1e-6);
  ExpectNoBuriedFaces(scene, gt);
}

TEST(SimFeaturesTest, RichCityGroundTruthHasNoHiddenFaces) {
  const City city = GenerateCity(FeatureCity(4, 1.0));
  GroundTruthOptions opt;
  opt.region_min = Vec2(60, -30);
  opt.region_max = Vec2(170, 40);
  ExpectNoBuriedFaces(city.scene, BuildGroundTruthMesh(city.scene, opt));
}

CityOptions MovingCity(uint64_t seed, int crossers, int movers, int frames);
int StaticContacts(const City& city, const GridIndex& index, const std::vector<Primitive>& moving,
                   double gap, int* pairs);

TEST(SimFeaturesTest, NothingMovingMeetsTheRichCity) {
  for (double share : {-1.0, 1.0}) {  // the defaults, then every feature everywhere
    CityOptions co = MovingCity(11, 12, 6, 500);
    co.walkers = 40;
    if (share >= 0) co.features = {share, share, share, share, share};
    const City city = GenerateCity(co);
    const GridIndex index(city.scene.primitives, 4.0);
    int pairs = 0, contacts = 0;
    for (int k = 0; k < 500; k += 2) {
      contacts += StaticContacts(city, index, MovingAt(city, k / kFrameRateHz), 0.05, &pairs);
    }
    EXPECT_EQ(contacts, 0) << "share " << share;
    EXPECT_GT(pairs, 1000) << "share " << share;
  }
}

TEST(SimFeaturesTest, SameSeedSameCity) {
  const City a = GenerateCity(FeatureCity(9, 0.7)), b = GenerateCity(FeatureCity(9, 0.7));
  ASSERT_EQ(a.scene.primitives.size(), b.scene.primitives.size());
  for (size_t i = 0; i < a.scene.primitives.size(); ++i) {
    EXPECT_EQ(Bounds(a.scene.primitives[i].shape).min, Bounds(b.scene.primitives[i].shape).min);
    EXPECT_EQ(Bounds(a.scene.primitives[i].shape).max, Bounds(b.scene.primitives[i].shape).max);
  }
}

CityOptions MovingCity(uint64_t seed, int crossers, int movers, int frames) {
  CityOptions co;
  co.seed = seed;
  co.crossers = crossers;
  co.movers = movers;
  co.frames = frames;
  co.step = 1.0;
  return co;
}

// Signed distance from p to the street centre lines round the drive loop (a rounded rectangle
// round the 2 x 1 blocks), positive outside the loop, where the drive's lane is.
double LoopOffset(const Vec2& p) {
  const Vec2 center(kBlockPitch, 0.5 * kBlockPitch), half(kBlockPitch, 0.5 * kBlockPitch);
  const Vec2 q = (p - center).cwiseAbs() - (half - Vec2::Constant(kLoopCornerRadius));
  return q.cwiseMax(0.0).norm() + std::min(std::max(q.x(), q.y()), 0.0) - kLoopCornerRadius;
}

// True if the convex polygons (counter-clockwise) are at least `gap` apart along one of their edge
// normals (separating axes): then they are at least that far apart.
bool ConvexApart(const std::vector<Vec2>& a, const std::vector<Vec2>& b, double gap) {
  for (const auto* poly : {&a, &b}) {
    for (size_t i = 0; i < poly->size(); ++i) {
      const Vec2 e = (*poly)[(i + 1) % poly->size()] - (*poly)[i];
      if (e.norm() < 1e-12) continue;
      const Vec2 n = Vec2(e.y(), -e.x()).normalized();  // outward for counter-clockwise
      double amax = -1e300, bmin = 1e300;
      for (const Vec2& p : *poly) amax = std::max(amax, n.dot(p));
      for (const Vec2& p : (poly == &a ? b : a)) bmin = std::min(bmin, n.dot(p));
      if (bmin - amax >= gap) return true;
    }
  }
  return false;
}

// Counts the moving solids that come within `gap` of a static solid: their horizontal sections
// are compared every 5 cm of height where both are. *pairs receives the number of (moving,
// static) pairs whose bounds come within 1 m of each other, the ones compared.
int StaticContacts(const City& city, const GridIndex& index, const std::vector<Primitive>& moving,
                   double gap, int* pairs) {
  TessellationOptions fine;
  fine.tolerance = 0.003;
  int contacts = 0;
  for (const Primitive& m : moving) {
    const Aabb mb = Bounds(m.shape);
    bool contact = false;
    const Vec2 lo = mb.min.head<2>() - Vec2::Constant(1.0),
               hi = mb.max.head<2>() + Vec2::Constant(1.0);
    index.ForEachInRect(lo, hi, [&](int i) {
      const Shape& s = city.scene.primitives[i].shape;
      const Aabb sb = Bounds(s);
      if (sb.min.z() > mb.max.z() || sb.max.z() < mb.min.z()) return;
      if ((sb.min.head<2>().array() > hi.array()).any() ||
          (sb.max.head<2>().array() < lo.array()).any()) {
        return;
      }
      ++*pairs;
      for (double z = std::max(mb.min.z(), sb.min.z()) + 1e-3; z < std::min(mb.max.z(), sb.max.z());
           z += 0.05) {
        const std::vector<Vec2> a = Footprint(m.shape, z, fine), b = Footprint(s, z, fine);
        if (!a.empty() && !b.empty() && !ConvexApart(a, b, gap)) contact = true;
      }
    });
    contacts += contact;
  }
  return contacts;
}

TEST(SimMovingTest, ConvexApartSeesOverlapsAndGaps) {
  // The check the contact counts rely on: two unit squares 0.1 m apart, then overlapping.
  auto square = [](double x) {
    return std::vector<Vec2>{Vec2(x, 0), Vec2(x + 1, 0), Vec2(x + 1, 1), Vec2(x, 1)};
  };
  EXPECT_TRUE(ConvexApart(square(0), square(1.1), 0.05));
  EXPECT_FALSE(ConvexApart(square(0), square(1.1), 0.2));
  EXPECT_FALSE(ConvexApart(square(0), square(0.9), 0.0));
  EXPECT_FALSE(ConvexApart(square(1.1), square(0), 0.2));
}

TEST(SimMovingTest, NearestFindsTheClosestPointOfALoop) {
  const LoopPath loop(Vec2(80, 40), Vec2(78.7, 38.7), 8.7);
  Rng rng(5);
  for (int i = 0; i < 300; ++i) {
    const Vec2 p(rng.Uniform(-20, 180), rng.Uniform(-20, 100));
    const double s = loop.Nearest(p);
    ASSERT_GE(s, 0.0);
    ASSERT_LT(s, loop.length());
    Vec2 q;
    double heading;
    loop.Eval(s, &q, &heading);
    double best = 1e300;
    for (double u = 0; u < loop.length(); u += 0.05) {
      Vec2 r;
      loop.Eval(u, &r, &heading);
      best = std::min(best, (p - r).norm());
    }
    EXPECT_LE((p - q).norm(), best + 1e-9) << p.transpose();
    // A point on the loop is its own nearest point.
    const double on = rng.Uniform(0, loop.length());
    loop.Eval(on, &q, &heading);
    EXPECT_NEAR(loop.Nearest(q), on, 1e-6);
  }
}

TEST(SimMovingTest, CrossersCrossTheDrivenStreetInFrontOfTheSensor) {
  for (uint64_t seed : {1, 7, 11}) {
    const City city = GenerateCity(MovingCity(seed, 6, 0, 60));
    ASSERT_EQ(city.crossers.size(), 6u);
    const auto poses = CityTrajectory(city, 60, 1.0, 1.73);
    std::vector<double> lines;
    for (const Crosser& c : city.crossers) {
      // On the drive's street, across it, somewhere the 60-frame run drives ahead of its start.
      EXPECT_GE(c.drive_s, city.start_s + kMovingAhead - 1e-9) << "seed " << seed;
      EXPECT_LE(c.drive_s, city.start_s + 59.0 + 1e-9) << "seed " << seed;
      Vec2 lane;
      double heading;
      city.drive_path.Eval(c.drive_s, &lane, &heading);
      EXPECT_LT((c.center + kLaneOffset * c.across - lane).norm(), 1e-9);
      EXPECT_NEAR(c.street.dot(Vec2(std::cos(heading), std::sin(heading))), 1.0, 1e-9);
      EXPECT_NEAR(c.street.dot(c.across), 0.0, 1e-12);
      EXPECT_LT(c.street.x() * c.across.y() - c.street.y() * c.across.x(), 0.0)
          << "across points to the right of the street, to the drive's lane";
      // Clear of the intersections.
      const double along = c.street.x() != 0 ? c.center.x() : c.center.y();
      const double from_intersection =
          std::abs(along - kBlockPitch * std::round(along / kBlockPitch));
      EXPECT_GE(from_intersection, 14.0 - 1e-9);
      EXPECT_GE(c.speed, 1.0);
      EXPECT_LE(c.speed, 1.6);
      EXPECT_GE(c.radius, 0.22);
      EXPECT_LE(c.radius, 0.28);
      EXPECT_GE(c.height, 1.6);
      EXPECT_LE(c.height, 1.9);
      lines.push_back(c.drive_s);
    }
    // Spread along the stretch, each crossing line its own, far enough from the next for two
    // crossers (radius <= 0.28 m) never to meet.
    std::sort(lines.begin(), lines.end());
    for (size_t i = 1; i < lines.size(); ++i) EXPECT_GE(lines[i] - lines[i - 1], 0.6 - 1e-9);
    EXPECT_GT(lines.back() - lines.front(), 20.0) << "seed " << seed;

    // 200 frames at 10 Hz: on the crossing line, within the sidewalks, often on the road.
    int on_road = 0, samples = 0;
    for (int k = 0; k < 200; ++k) {
      const std::vector<Primitive> prims = CrossersAt(city, k / kFrameRateHz);
      ASSERT_EQ(prims.size(), city.crossers.size());
      for (size_t i = 0; i < prims.size(); ++i) {
        const Crosser& c = city.crossers[i];
        const Cylinder& cyl = std::get<Cylinder>(prims[i].shape);
        EXPECT_EQ(prims[i].material, Material::kPerson);
        EXPECT_EQ(cyl.radius, c.radius);
        EXPECT_NEAR(cyl.z_max, c.height, 1e-12);
        EXPECT_LT(cyl.z_min, 0.0);
        const double lateral = (cyl.center - c.center).dot(c.across);
        EXPECT_NEAR((cyl.center - c.center).dot(c.street), 0.0, 1e-9);
        EXPECT_NEAR(lateral, CrosserLateral(c, k / kFrameRateHz), 1e-9);
        EXPECT_LE(std::abs(lateral), 7.8);
        on_road += std::abs(lateral) < 4.5;
        ++samples;
      }
    }
    EXPECT_GT(on_road, 0.45 * samples) << "seed " << seed;
    EXPECT_LT(on_road, 0.85 * samples) << "seed " << seed << ": they reach the sidewalks too";
    // The 60-frame run sees every one of them on the road ahead of it, and never drives into one.
    std::vector<bool> seen(city.crossers.size(), false);
    for (int k = 0; k < 60; ++k) {
      const Vec2 sensor = poses[k].translation().head<2>();
      const Vec2 forward = poses[k].linear().col(0).head<2>();
      const std::vector<Primitive> prims = CrossersAt(city, k / kFrameRateHz);
      for (size_t i = 0; i < prims.size(); ++i) {
        const Cylinder& cyl = std::get<Cylinder>(prims[i].shape);
        const double lateral = (cyl.center - city.crossers[i].center).dot(city.crossers[i].across);
        const double ahead = (cyl.center - sensor).dot(forward);
        if (std::abs(lateral) < 4.5 && ahead > 2.0 && ahead < 40.0) seen[i] = true;
        EXPECT_GT((cyl.center - sensor).norm(), cyl.radius + 1.0)
            << "seed " << seed << " frame " << k;
      }
    }
    for (size_t i = 0; i < seen.size(); ++i) EXPECT_TRUE(seen[i]) << "seed " << seed << " #" << i;
  }
}

// The least distance, along the street, from a crossing line to a parked car whose side reaches
// the crossing line's span across the street.
double ParkedCarGap(const City& city, const Crosser& c) {
  double least = 1e300;
  for (const Primitive& p : city.scene.primitives) {
    if (p.material != Material::kCar) continue;
    double along_min = 1e300, along_max = -1e300, lat_min = 1e300, lat_max = -1e300;
    for (const Vec2& corner : FootprintCorners(std::get<Box>(p.shape))) {
      along_min = std::min(along_min, (corner - c.center).dot(c.street));
      along_max = std::max(along_max, (corner - c.center).dot(c.street));
      lat_min = std::min(lat_min, (corner - c.center).dot(c.across));
      lat_max = std::max(lat_max, (corner - c.center).dot(c.across));
    }
    if (lat_max < -c.half_span - 1.0 || lat_min > c.half_span + 1.0) continue;
    least = std::min(least, along_min > 0 ? along_min : along_max < 0 ? -along_max : 0.0);
  }
  return least;
}

TEST(SimMovingTest, CrossingLinesKeepClearOfParkedCars) {
  int lines = 0, wide = 0, near_cars = 0;
  for (uint64_t seed : {1, 2, 3, 4}) {
    // Short runs (lines packed into a short stretch) and a long one (lines all round the loop).
    for (const auto& [crossers, frames] :
         {std::pair{6, 60}, std::pair{10, 60}, std::pair{40, 500}}) {
      const City city = GenerateCity(MovingCity(seed, crossers, 0, frames));
      ASSERT_EQ(city.crossers.size(), static_cast<size_t>(crossers));
      for (const Crosser& c : city.crossers) {
        const double gap = ParkedCarGap(city, c);
        EXPECT_GE(gap, kCrossCarGapMin - 1e-9)
            << "seed " << seed << " crossing at " << c.center.transpose();
        ++lines;
        wide += gap >= kCrossCarGap - 1e-9;
        near_cars += gap < 6.0;
      }
    }
  }
  // Most keep the wide gap; some pass close to parked cars (or the test proves nothing).
  EXPECT_GT(wide, 0.7 * lines);
  EXPECT_GT(near_cars, 20);
}

TEST(SimMovingTest, CrossersAndMoversNeverMeetAStaticSolid) {
  for (uint64_t seed : {1, 2, 3}) {
    const City city = GenerateCity(MovingCity(seed, 12, 6, 200));
    const GridIndex index(city.scene.primitives, 4.0);
    int pairs = 0, crosser_contacts = 0, mover_contacts = 0;
    for (int k = 0; k < 200; ++k) {
      const double t = k / kFrameRateHz;
      crosser_contacts += StaticContacts(city, index, CrossersAt(city, t), 0.05, &pairs);
      mover_contacts += StaticContacts(city, index, MoversAt(city, t), 0.05, &pairs);
      // And no point of them lies inside a static solid: their centres, nor the sensor's lane.
      for (const Primitive& m : MovingAt(city, t)) {
        const Aabb b = Bounds(m.shape);
        const Vec3 mid(0.5 * (b.min.x() + b.max.x()), 0.5 * (b.min.y() + b.max.y()), 0.5);
        for (const Primitive& s : city.scene.primitives) {
          ASSERT_FALSE(Contains(s.shape, mid, 0.0)) << "seed " << seed << " t " << t;
        }
      }
    }
    EXPECT_EQ(crosser_contacts, 0) << "seed " << seed;
    EXPECT_EQ(mover_contacts, 0) << "seed " << seed;
    EXPECT_GT(pairs, 300) << "seed " << seed << ": nothing static nearby, the test proves nothing";
  }
  // The check itself finds a contact: a crosser moved onto a parked car.
  const City city = GenerateCity(MovingCity(1, 1, 0, 60));
  const GridIndex index(city.scene.primitives, 4.0);
  for (const Primitive& p : city.scene.primitives) {
    if (p.material != Material::kCar) continue;
    const Box& car = std::get<Box>(p.shape);
    const std::vector<Primitive> fake = {
        {Cylinder{car.center.head<2>() + BoxToWorld(car, car.half.x() + 0.2, 0), 0.25, -0.03, 1.8},
         Material::kPerson}};
    int pairs = 0;
    EXPECT_EQ(StaticContacts(city, index, fake, 0.05, &pairs), 1);
    break;
  }
}

TEST(SimMovingTest, MoversDriveTheOppositeLaneAndMeetTheSensor) {
  for (uint64_t seed : {1, 5, 9}) {
    const City city = GenerateCity(MovingCity(seed, 0, 5, 60));
    ASSERT_EQ(city.movers.size(), 5u);
    for (const Mover& m : city.movers) {
      EXPECT_GE(m.speed, 7.0);
      EXPECT_LE(m.speed, 12.0);
      EXPECT_EQ(m.size, Vec3(kMoverLength, kMoverWidth, kMoverHeight));
    }
    // Over 200 frames: in the other lane, clear of the centre line and of the parked cars'
    // lane, clockwise round the loop at their speed, yawed along their heading.
    for (int k = 0; k < 200; ++k) {
      const double t = k / kFrameRateHz;
      const std::vector<Primitive> now = MoversAt(city, t), next = MoversAt(city, t + 0.01);
      ASSERT_EQ(now.size(), city.movers.size());
      for (size_t i = 0; i < now.size(); ++i) {
        EXPECT_EQ(now[i].material, Material::kCar);
        const Box& box = std::get<Box>(now[i].shape);
        const Vec2 c = box.center.head<2>();
        EXPECT_NEAR(LoopOffset(c), -kMoverOffset, 1e-6);
        EXPECT_NEAR(box.center.z() + box.half.z(), kMoverHeight, 1e-9);
        for (const Vec2& corner : FootprintCorners(box)) {
          EXPECT_LT(LoopOffset(corner), -0.1) << "seed " << seed << " t " << t;
          EXPECT_GT(LoopOffset(corner), -(3.45 - 1.04) + 0.1) << "seed " << seed << " t " << t;
        }
        const Vec2 v = (std::get<Box>(next[i].shape).center.head<2>() - c) / 0.01;
        EXPECT_NEAR(v.norm(), city.movers[i].speed, 0.01 * city.movers[i].speed);
        EXPECT_GT(v.normalized().dot(Vec2(box.cos_yaw, box.sin_yaw)), 0.99);
        const Vec2 r = c - Vec2(kBlockPitch, 0.5 * kBlockPitch);
        EXPECT_LT(r.x() * v.y() - r.y() * v.x(), 0.0) << "clockwise";
      }
    }
    // Each meets the sensor (passes it closely) at its own time within the 60-frame run.
    const auto poses = CityTrajectory(city, 60, 1.0, 1.73);
    std::vector<int> meet;
    for (size_t i = 0; i < city.movers.size(); ++i) {
      double closest = 1e300;
      int frame = -1;
      for (int k = 0; k < 60; ++k) {
        const Box box = std::get<Box>(MoversAt(city, k / kFrameRateHz)[i].shape);
        const double d = (box.center.head<2>() - poses[k].translation().head<2>()).norm();
        if (d < closest) {
          closest = d;
          frame = k;
        }
      }
      EXPECT_LT(closest, 6.0) << "seed " << seed << " mover " << i;
      EXPECT_GT(frame, 0);
      EXPECT_LT(frame, 59);
      meet.push_back(frame);
    }
    std::sort(meet.begin(), meet.end());
    for (size_t i = 1; i < meet.size(); ++i) EXPECT_GT(meet[i], meet[i - 1]) << "seed " << seed;
    EXPECT_GT(meet.back() - meet.front(), 20) << "seed " << seed;
  }
}

TEST(SimMovingTest, StaticSceneAndWalkersStayAsTheyWere) {
  CityOptions plain;
  plain.seed = 3;
  plain.walkers = 7;
  CityOptions busy = plain;
  busy.crossers = 5;
  busy.movers = 4;
  const City a = GenerateCity(plain), b = GenerateCity(busy), c = GenerateCity(busy);
  EXPECT_TRUE(a.crossers.empty());
  EXPECT_TRUE(a.movers.empty());
  ASSERT_EQ(a.scene.primitives.size(), b.scene.primitives.size());
  for (size_t i = 0; i < a.scene.primitives.size(); ++i) {
    EXPECT_EQ(Bounds(a.scene.primitives[i].shape).min, Bounds(b.scene.primitives[i].shape).min);
    EXPECT_EQ(Bounds(a.scene.primitives[i].shape).max, Bounds(b.scene.primitives[i].shape).max);
  }
  for (double t : {0.0, 1.3, 7.9}) {
    const std::vector<Primitive> wa = WalkersAt(a, t), wb = WalkersAt(b, t);
    ASSERT_EQ(wa.size(), wb.size());
    for (size_t i = 0; i < wa.size(); ++i) {
      EXPECT_EQ(std::get<Cylinder>(wa[i].shape).center, std::get<Cylinder>(wb[i].shape).center);
    }
    // MovingAt: walkers first, then crossers, then movers.
    const std::vector<Primitive> all = MovingAt(b, t);
    ASSERT_EQ(all.size(), 7u + 5u + 4u);
    EXPECT_EQ(std::get<Cylinder>(all[7].shape).center,
              std::get<Cylinder>(CrossersAt(b, t)[0].shape).center);
    EXPECT_EQ(std::get<Box>(all[12].shape).center, std::get<Box>(MoversAt(b, t)[0].shape).center);
  }
  // Deterministic; another seed, other crossers and movers.
  ASSERT_EQ(b.crossers.size(), c.crossers.size());
  for (size_t i = 0; i < b.crossers.size(); ++i) {
    EXPECT_EQ(b.crossers[i].center, c.crossers[i].center);
    EXPECT_EQ(b.crossers[i].phase, c.crossers[i].phase);
  }
  for (size_t i = 0; i < b.movers.size(); ++i) EXPECT_EQ(b.movers[i].s0, c.movers[i].s0);
  CityOptions other = busy;
  other.seed = 4;
  const City d = GenerateCity(other);
  EXPECT_NE(d.crossers[0].speed, b.crossers[0].speed);
  EXPECT_NE(d.movers[0].s0, b.movers[0].s0);
}

// gt_moving_last.ply is what moves as the last scan saw it: with gt.ply it explains every return
// of the last scan, and not those of the first (the cars and people have moved since).
TEST(SimCityTest, TheMovingThingsOfTheLastScanAreWrittenApart) {
  SimOptions o = SmallCity(TempDir("moving_last"));
  o.frames = 12;
  o.crossers = 4;
  o.movers = 3;
  o.walkers = 20;
  ASSERT_TRUE(RunSim(o).ok());
  const auto gt = ReadMeshPly(o.out_dir + "/gt.ply");
  const auto last = ReadMeshPly(o.out_dir + "/gt_moving_last.ply");
  ASSERT_TRUE(gt.ok() && last.ok()) << last.status();
  ASSERT_GT(last->faces.size(), 100u);
  const MeshDistance to_gt(*gt), to_last(*last);
  const auto poses = ReadKittiPoses(o.out_dir + "/poses.txt");
  // Returns off the static scene, and of those how many gt_moving_last.ply holds (noise-free: on
  // the tessellated surfaces within their 5 mm tolerance). Within 25 m: gt.ply reaches 30 m
  // (gt_margin) beyond the drive.
  auto count = [&](int frame, int* off_static, int* on_last) {
    *off_static = *on_last = 0;
    for (const LidarPoint& lp : ReadScan(ScanPath(o.out_dir, frame))) {
      if (Vec3(lp.x, lp.y, lp.z).norm() > 25.0) continue;
      const Vec3 w = poses[frame] * Vec3(lp.x, lp.y, lp.z);
      if (to_gt.Distance(w) < 0.01) continue;
      ++*off_static;
      *on_last += to_last.Distance(w) < 0.01;
    }
  };
  int off_static = 0, on_last = 0;
  count(o.frames - 1, &off_static, &on_last);
  EXPECT_GT(off_static, 100) << "the last scan sees nothing moving: the test proves nothing";
  EXPECT_EQ(on_last, off_static);
  count(0, &off_static, &on_last);
  EXPECT_GT(off_static, 100);
  EXPECT_LT(on_last, off_static / 2) << "the file holds the first scan's movers, not the last's";
  nlohmann::ordered_json scene = ReadScene(o.out_dir);
  EXPECT_EQ(scene["gt_moving_last"]["file"], "gt_moving_last.ply");
  EXPECT_DOUBLE_EQ(scene["gt_moving_last"]["time_s"].get<double>(), 1.1);
  EXPECT_EQ(scene["gt_moving_last"]["faces"], last->faces.size());
  EXPECT_NE(ReadFile(o.out_dir + "/README.txt").find("gt_moving_last.ply"), std::string::npos);
  // A static city written over it leaves no stale file.
  o.crossers = o.movers = o.walkers = 0;
  ASSERT_TRUE(RunSim(o).ok());
  EXPECT_FALSE(std::filesystem::exists(o.out_dir + "/gt_moving_last.ply"));
  EXPECT_FALSE(ReadScene(o.out_dir).contains("gt_moving_last"));
}

TEST(SimMovingTest, OptionsAreValidatedNamingTheField) {
  const std::vector<std::pair<std::function<void(CityOptions*)>, std::string>> cases = {
      {[](CityOptions* o) { o->crossers = -1; }, "CityOptions.crossers must be >= 0, got -1"},
      {[](CityOptions* o) { o->movers = -2; }, "CityOptions.movers must be >= 0, got -2"},
      {[](CityOptions* o) { o->frames = -1; }, "CityOptions.frames must be >= 0"},
      {[](CityOptions* o) { o->step = 0.0; }, "CityOptions.step must be finite and > 0"},
      {[](CityOptions* o) { o->step = std::nan(""); }, "CityOptions.step must be"},
  };
  for (const auto& [change, message] : cases) {
    CityOptions o;
    o.crossers = 2;
    o.movers = 2;
    ASSERT_TRUE(ValidateCityOptions(o).ok());
    change(&o);
    const absl::Status status = ValidateCityOptions(o);
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << message;
    EXPECT_NE(status.message().find(message), std::string::npos) << status;
  }
}

TEST(SimCityTest, CrossersAndMoversAppearInScansButNotInGroundTruth) {
  SimOptions with = SmallCity(TempDir("moving_with"));
  with.frames = 30;
  with.crossers = 4;
  with.movers = 3;
  with.observed_box = ObservedBox{};
  SimOptions without = with;
  without.out_dir = TempDir("moving_without");
  without.crossers = 0;
  without.movers = 0;
  ASSERT_TRUE(RunSim(with).ok());
  ASSERT_TRUE(RunSim(without).ok());
  EXPECT_EQ(ReadFile(with.out_dir + "/gt.ply"), ReadFile(without.out_dir + "/gt.ply"))
      << "gt.ply must not contain crossers or movers";

  CityOptions co = MovingCity(with.seed, with.crossers, with.movers, with.frames);
  const City city = GenerateCity(co);
  const auto poses = ReadKittiPoses(with.out_dir + "/poses.txt");
  ASSERT_EQ(poses.size(), 30u);
  std::vector<std::vector<Primitive>> crossers, movers;
  for (int k = 0; k < with.frames; ++k) {
    crossers.push_back(CrossersAt(city, k / kFrameRateHz));
    movers.push_back(MoversAt(city, k / kFrameRateHz));
  }
  // The scans hit them, inside the frames' mapping boxes too.
  int crosser_hits = 0, mover_hits = 0, in_boxes = 0;
  std::vector<bool> crosser_seen(city.crossers.size(), false), mover_seen(city.movers.size());
  for (int k = 0; k < with.frames; ++k) {
    for (const LidarPoint& lp : ReadScan(ScanPath(with.out_dir, k))) {
      const Vec3 w = poses[k] * Vec3(lp.x, lp.y, lp.z);
      bool hit = false;
      for (size_t i = 0; i < crossers[k].size(); ++i) {
        if (w.z() > 0.05 && Contains(crossers[k][i].shape, w, -0.01)) {
          ++crosser_hits;
          crosser_seen[i] = hit = true;
        }
      }
      for (size_t i = 0; i < movers[k].size(); ++i) {
        if (w.z() > 0.05 && Contains(movers[k][i].shape, w, -0.01)) {
          ++mover_hits;
          mover_seen[i] = hit = true;
        }
      }
      in_boxes += hit && InBox(w, poses[k].translation(), with.observed_box, 0.0);
    }
  }
  EXPECT_GT(crosser_hits, 200);
  EXPECT_GT(mover_hits, 1000);
  EXPECT_GT(in_boxes, 200) << "nothing moving inside the boxes: the test proves nothing";
  for (bool seen : crosser_seen) EXPECT_TRUE(seen);
  for (bool seen : mover_seen) EXPECT_TRUE(seen);
  EXPECT_NE(ReadFile(ScanPath(with.out_dir, 10)), ReadFile(ScanPath(without.out_dir, 10)));

  // gt_observed.ply has no point on them (above the ground they stand on), at any frame's time.
  const std::vector<Vec3> observed = ReadObserved(with.out_dir);
  ASSERT_GT(observed.size(), 50000u);
  int on_moving = 0;
  for (const Vec3& p : observed) {
    if (p.z() <= 0.05 || p.z() > 2.0) continue;  // the ground they stand on; above them
    for (int k = 0; k < with.frames; ++k) {
      for (const auto* prims : {&crossers[k], &movers[k]}) {
        for (const Primitive& m : *prims) on_moving += Contains(m.shape, p, -0.01);
      }
    }
  }
  EXPECT_EQ(on_moving, 0);

  // scene.json and README.txt describe them.
  nlohmann::ordered_json scene = ReadScene(with.out_dir);
  // They come after the walkers and before the buildings.
  EXPECT_EQ(Keys(scene),
            (std::vector<std::string>{"generator", "scene", "layout", "seed", "frames", "step_m",
                                      "frame_rate_hz", "noise_stddev_m", "walkers", "crossers",
                                      "movers", "buildings", "features", "lidar", "poses",
                                      "gt_mesh", "gt_observed", "gt_moving_last"}));
  nlohmann::ordered_json& crosser_json = scene["crossers"];
  EXPECT_EQ(Keys(crosser_json),
            (std::vector<std::string>{"count", "in", "motion", "shape", "list"}));
  EXPECT_EQ(crosser_json["count"], 4);
  ASSERT_EQ(crosser_json["list"].size(), 4u);
  nlohmann::ordered_json& mover_json = scene["movers"];
  EXPECT_EQ(Keys(mover_json),
            (std::vector<std::string>{"count", "in", "motion", "shape", "loop", "list"}));
  EXPECT_EQ(mover_json["count"], 3);
  ASSERT_EQ(mover_json["list"].size(), 3u);
  // Written to 4 decimals (the street direction exactly).
  const Crosser& c0 = city.crossers[0];
  nlohmann::ordered_json& j0 = crosser_json["list"][0];
  EXPECT_EQ(Keys(j0), (std::vector<std::string>{"x_m", "y_m", "street_dir", "speed_mps", "radius_m",
                                                "height_m", "phase"}));
  EXPECT_NEAR(j0["x_m"].get<double>(), c0.center.x(), 5e-5);
  EXPECT_NEAR(j0["y_m"].get<double>(), c0.center.y(), 5e-5);
  EXPECT_EQ(j0["street_dir"], nlohmann::ordered_json::array({c0.street.x(), c0.street.y()}));
  EXPECT_NEAR(j0["speed_mps"].get<double>(), c0.speed, 5e-5);
  EXPECT_NEAR(j0["radius_m"].get<double>(), c0.radius, 5e-5);
  EXPECT_NEAR(j0["height_m"].get<double>(), c0.height, 5e-5);
  EXPECT_NEAR(j0["phase"].get<double>(), c0.phase, 5e-5);
  nlohmann::ordered_json& j2 = mover_json["list"][2];
  EXPECT_EQ(Keys(j2), (std::vector<std::string>{"speed_mps", "s0_m", "size_m"}));
  EXPECT_NEAR(j2["speed_mps"].get<double>(), city.movers[2].speed, 5e-5);
  EXPECT_NEAR(j2["s0_m"].get<double>(), city.movers[2].s0, 5e-5);
  EXPECT_EQ(j2["size_m"], nlohmann::ordered_json::array({4.4, 1.8, 1.5}));
  // The loop, as written, places a car where the simulator put it.
  const nlohmann::ordered_json& loop = mover_json["loop"];
  const LoopPath written(
      Vec2(loop["center_m"][0].get<double>(), loop["center_m"][1].get<double>()),
      Vec2(loop["half_extent_m"][0].get<double>(), loop["half_extent_m"][1].get<double>()),
      loop["corner_radius_m"].get<double>());
  EXPECT_NEAR(written.length(), city.movers[2].path.length(), 1e-3);
  for (double t : {0.0, 1.7, 9.9}) {
    const double s = j2["s0_m"].get<double>() - j2["speed_mps"].get<double>() * t;
    Vec2 p_written, p_sim;
    double h_written, h_sim;
    written.Eval(s, &p_written, &h_written);
    city.movers[2].path.Eval(city.movers[2].s0 - city.movers[2].speed * t, &p_sim, &h_sim);
    EXPECT_LT((p_written - p_sim).norm(), 2e-3) << "t " << t;
  }
  const std::string readme = ReadFile(with.out_dir + "/README.txt");
  EXPECT_NE(readme.find("Crossers: 4 pedestrians"), std::string::npos) << readme;
  EXPECT_NE(readme.find("Movers: 3 cars"), std::string::npos) << readme;
  // Without them, neither is mentioned (the files are those of a run without the options).
  EXPECT_FALSE(ReadScene(without.out_dir).contains("crossers"));
  EXPECT_FALSE(ReadScene(without.out_dir).contains("movers"));
  EXPECT_EQ(ReadFile(without.out_dir + "/README.txt").find("Crossers"), std::string::npos);
}

TEST(SimCityTest, CrossersAndMoversAreDeterministicAndStreamedAlike) {
  SimOptions a = SmallCity(TempDir("moving_det_a"));
  a.frames = 4;
  a.crossers = 3;
  a.movers = 2;
  a.walkers = 2;
  a.noise = 0.02;
  a.threads = 1;
  SimOptions b = a;
  b.out_dir = TempDir("moving_det_b");
  b.threads = 3;
  ASSERT_TRUE(RunSim(a).ok());
  ASSERT_TRUE(RunSim(b).ok());
  const auto fa = ReadTree(a.out_dir), fb = ReadTree(b.out_dir);
  ASSERT_EQ(fa.size(), fb.size());
  for (const auto& [name, bytes] : fa) {
    ASSERT_TRUE(fb.count(name)) << name;
    EXPECT_TRUE(bytes == fb.at(name)) << name << " differs";
  }
  // CityFrames (what rimctl streams) gives the same scans.
  CityFrameOptions options;
  options.frames = a.frames;
  options.columns = a.columns;
  options.noise = a.noise;
  options.walkers = a.walkers;
  options.crossers = a.crossers;
  options.movers = a.movers;
  options.threads = 2;
  const CityFrames frames(options);
  ASSERT_EQ(frames.size(), 4u);
  for (size_t k = 0; k < frames.size(); ++k) {
    const PosedScan scan = frames.Frame(k);
    const std::vector<LidarPoint> written = ReadScan(ScanPath(a.out_dir, static_cast<int>(k)));
    ASSERT_EQ(scan.points_S.size(), written.size()) << "frame " << k;
    for (size_t i = 0; i < written.size(); ++i) {
      ASSERT_EQ(scan.points_S[i].x(), written[i].x) << "frame " << k << " point " << i;
      ASSERT_EQ(scan.points_S[i].y(), written[i].y);
      ASSERT_EQ(scan.points_S[i].z(), written[i].z);
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Command line

struct CliResult {
  int code;
  std::string out, err;
};

CliResult Cli(std::vector<std::string> args) {
  args.insert(args.begin(), "rim_sim");
  std::vector<const char*> argv;
  for (const std::string& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  const int code = RunSimCli(static_cast<int>(argv.size()), argv.data(), out, err);
  return {code, out.str(), err.str()};
}

TEST(SimCliTest, BadArgumentsFailWithAMessage) {
  const std::string dir = TempDir("cli_bad");
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--scene", "forest", "--out", dir}, "unknown --scene 'forest'"},
      {{"--scene", "city", "--out", dir, "--frames", "-5"}, "--frames must be"},
      {{"--out", dir, "--frames", "0"}, "--frames must be"},
      {{"--out", dir, "--frames", "ten"}, "--frames must be"},
      {{"--out", dir, "--noise", "-0.1"}, "--noise must be"},
      {{"--out", dir, "--noise", "nan"}, "--noise must be"},
      {{"--out", dir, "--walkers", "-1"}, "--walkers must be"},
      {{"--out", dir, "--seed", "-3"}, "--seed must be"},
      {{"--out", dir, "--step", "0"}, "--step must be"},
      {{"--out", dir, "--threads", "0"}, "--threads must be"},
      {{"--scene", "city"}, "--out DIR is required"},
      {{"--out", dir, "--frames"}, "--frames needs a value"},
      {{"--out", dir, "--bogus", "1"}, "unknown flag '--bogus'"},
      {{"--out", dir, "stray"}, "unexpected argument 'stray'"},
      {{"--out", dir, "--seed", "1", "--seed", "2"}, "--seed given more than once"},
      {{"--scene", "room", "--out", dir, "--walkers", "3"},
       "--walkers only applies to --scene city"},
      {{"--out", dir, "--crossers", "-1"}, "--crossers must be an integer in [0, 1000], got '-1'"},
      {{"--out", dir, "--crossers", "1001"}, "--crossers must be"},
      {{"--out", dir, "--crossers", "two"}, "--crossers must be"},
      {{"--out", dir, "--movers", "-3"}, "--movers must be an integer in [0, 1000], got '-3'"},
      {{"--out", dir, "--movers=1.5"}, "--movers must be"},
      {{"--out", dir, "--movers"}, "--movers needs a value"},
      {{"--scene", "room", "--out", dir, "--crossers", "3"},
       "--crossers only applies to --scene city"},
      {{"--scene", "room", "--out", dir, "--movers", "1"}, "--movers only applies to --scene city"},
      {{"--out", dir, "--observed-box", "10,10,-3"}, "--observed-box must be"},
      {{"--out", dir, "--observed-box", "0,10,-3,3"}, "--observed-box must be"},
      {{"--out", dir, "--observed-box", "10,10,3,-3"}, "--observed-box must be"},
      {{"--out", dir, "--observed-box", "10,x,-3,3"}, "--observed-box must be"},
      {{"--out", dir, "--observed-box=10,10,-3,inf"}, "--observed-box must be"},
      {{"--scene", "room", "--out", dir, "--observed-box", "1,1,-1,1"},
       "--observed-box only applies to --scene city"},
      {{"--out", dir, "--observed-box", "off"}, "--observed-box must be none or HX,HY,ZMIN,ZMAX"},
      {{"--out", dir, "--building-setback", "3,1"},
       "--building-setback must be MIN,MAX with 0 <= MIN <= MAX <= 20, got '3,1'"},
      {{"--out", dir, "--building-setback", "-1,2"}, "--building-setback must be"},
      {{"--out", dir, "--building-setback", "0,21"}, "--building-setback must be"},
      {{"--out", dir, "--building-setback", "2"}, "--building-setback must be"},
      {{"--out", dir, "--building-setback=1,nan"}, "--building-setback must be"},
      {{"--out", dir, "--building-height", "0.5,10"},
       "--building-height must be MIN,MAX with 1 <= MIN <= MAX <= 100, got '0.5,10'"},
      {{"--out", dir, "--building-height", "10,5"}, "--building-height must be"},
      {{"--out", dir, "--building-height", "4,101"}, "--building-height must be"},
      {{"--out", dir, "--building-height", "4,x"}, "--building-height must be"},
      {{"--out", dir, "--building-height", "4,5,6"}, "--building-height must be"},
      {{"--scene", "room", "--out", dir, "--building-height", "4,5"},
       "--building-height only applies to --scene city"},
      {{"--scene", "room", "--out", dir, "--building-setback", "1,2"},
       "--building-setback only applies to --scene city"},
      {{"--out", dir, "--parked-cars", "1.5"},
       "--parked-cars must be a share in [0, 1], got '1.5'"},
      {{"--out", dir, "--balconies", "-0.1"}, "--balconies must be a share in [0, 1]"},
      {{"--out", dir, "--annexes", "nan"}, "--annexes must be a share in [0, 1]"},
      {{"--out", dir, "--yawed", "half"}, "--yawed must be a share in [0, 1]"},
      {{"--out", dir, "--canopies=2"}, "--canopies must be a share in [0, 1]"},
      {{"--out", dir, "--canopies"}, "--canopies needs a value"},
      {{"--scene", "room", "--out", dir, "--balconies", "0.5"},
       "--balconies only applies to --scene city"},
      {{"--scene", "room", "--out", dir, "--parked-cars", "0"},
       "--parked-cars only applies to --scene city"},
  };
  for (const auto& [args, message] : cases) {
    const CliResult r = Cli(args);
    EXPECT_EQ(r.code, 2) << message;
    EXPECT_NE(r.err.find(message), std::string::npos) << "stderr: " << r.err;
    EXPECT_NE(r.err.find("rim_sim: error: "), std::string::npos);
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir)) << "a usage error writes nothing";
}

TEST(SimCliTest, HelpAndSuccess) {
  const CliResult help = Cli({"--help"});
  EXPECT_EQ(help.code, 0);
  EXPECT_NE(help.out.find("usage: rim_sim --scene city --out DIR"), std::string::npos);
  EXPECT_NE(help.out.find("--crossers K "), std::string::npos);
  EXPECT_NE(help.out.find("--movers K "), std::string::npos);

  const std::string dir = TempDir("cli_ok");
  const CliResult ok =
      Cli({"--scene=city", "--out=" + dir, "--frames", "1", "--columns", "90", "--gt-margin", "5",
           "--seed", "4", "--walkers", "2", "--noise", "0.01"});
  EXPECT_EQ(ok.code, 0) << ok.err;
  EXPECT_NE(ok.out.find("wrote 1 LiDAR frames"), std::string::npos) << ok.out;
  EXPECT_TRUE(std::filesystem::exists(ScanPath(dir, 0)));
  EXPECT_EQ(ReadScene(dir)["seed"], 4);
  EXPECT_NE(ok.out.find("gt_observed.ply ("), std::string::npos) << ok.out;

  const CliResult boxed = Cli({"--out", dir, "--frames", "1", "--columns", "90", "--gt-margin", "5",
                               "--observed-box", "4,5.5,-1.5,0.5"});
  EXPECT_EQ(boxed.code, 0) << boxed.err;
  nlohmann::ordered_json box = ReadScene(dir)["gt_observed"]["box"];
  EXPECT_EQ(Keys(box), (std::vector<std::string>{"hx_m", "hy_m", "z_min_m", "z_max_m", "about"}));
  EXPECT_EQ(box["hx_m"], 4.0);
  EXPECT_EQ(box["hy_m"], 5.5);
  EXPECT_EQ(box["z_min_m"], -1.5);
  EXPECT_EQ(box["z_max_m"], 0.5);

  const CliResult city =
      Cli({"--out", dir, "--frames", "1", "--columns", "90", "--gt-margin", "5",
           "--building-setback", "1,2.5", "--building-height=6,7.5", "--observed-box", "none"});
  EXPECT_EQ(city.code, 0) << city.err;
  nlohmann::ordered_json scene = ReadScene(dir);
  nlohmann::ordered_json& buildings = scene["buildings"];
  EXPECT_EQ(Keys(buildings),
            (std::vector<std::string>{"setback_min_m", "setback_max_m", "height_min_m",
                                      "height_max_m", "setback_from"}));
  EXPECT_EQ(buildings["setback_min_m"], 1.0);
  EXPECT_EQ(buildings["setback_max_m"], 2.5);
  EXPECT_EQ(buildings["height_min_m"], 6.0);
  EXPECT_EQ(buildings["height_max_m"], 7.5);
  EXPECT_TRUE(scene["gt_observed"]["box"].is_null());
  const std::string readme = ReadFile(dir + "/README.txt");
  EXPECT_NE(readme.find("Buildings: 6..7.5 m high, facades set back 1..2.5 m beyond 9.5 m"),
            std::string::npos)
      << readme;
  EXPECT_NE(readme.find("(no mapping box: --observed-box none)"), std::string::npos) << readme;

  const CliResult moving = Cli({"--out", dir, "--frames", "2", "--columns", "90", "--gt-margin",
                                "5", "--crossers", "2", "--movers=1"});
  EXPECT_EQ(moving.code, 0) << moving.err;
  nlohmann::ordered_json moving_scene = ReadScene(dir);
  EXPECT_EQ(moving_scene["crossers"]["count"], 2);
  EXPECT_EQ(moving_scene["movers"]["count"], 1);

  // An output path under a regular file cannot be created: a runtime error, exit 1.
  const CliResult bad = Cli({"--out", dir + "/gt.ply/sub", "--frames", "1", "--columns", "90"});
  EXPECT_EQ(bad.code, 1);
  EXPECT_NE(bad.err.find("gt.ply"), std::string::npos) << bad.err;
}

}  // namespace
}  // namespace rim::sim
