// Moving things leave no trace (train/transient.h): returns that later rays pass clearly through
// are dropped, while static surfaces (a thin pole, walls and ground at grazing angles, a facade
// seen once from afar, a surface hidden behind something nearer) keep every point.
#include "rim/train/transient.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdio>
#include <map>
#include <mutex>
#include <random>

#include "rim/config/config.h"
#include "rim/map/map_geometry.h"
#include "rim/mapper.h"
#include "support/analytic_scene.h"

namespace rim {
namespace {

using testing::HasSubstr;
using testing_support::AnalyticScene;
using testing_support::Box;
using testing_support::Cylinder;

// A 64-beam spinning LiDAR like the simulator's car sensor (0.43° between rings, 0.2° columns).
testing_support::LidarModel CarLidar(float noise_m = 0.f) {
  testing_support::LidarModel lidar;
  lidar.beams = 64;
  lidar.columns = 1800;
  lidar.elev_min_deg = -25.f;
  lidar.elev_max_deg = 2.f;
  lidar.max_range_m = 60.f;
  lidar.noise_stddev_m = noise_m;
  return lidar;
}

Eigen::Isometry3f PoseAt(float x, float y, float z = 1.7f) {
  Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
  T.translation() = Eigen::Vector3f(x, y, z);
  return T;
}

// A scan's points in the sensor frame and in the world frame.
struct Scan {
  std::vector<Vec3f> points_S, points_W, origins_W;
  Eigen::Isometry3f T;
};

Scan Take(const AnalyticScene& scene, const Eigen::Isometry3f& T, uint32_t seed,
          const testing_support::LidarModel& lidar = CarLidar()) {
  Scan s;
  s.T = T;
  for (const Eigen::Vector3f& p : testing_support::SimulateScan(scene, lidar, T, seed)) {
    s.points_S.push_back(p);
    s.points_W.push_back(T * p);
    s.origins_W.push_back(T.translation());
  }
  return s;
}

AnalyticScene Ground() {
  AnalyticScene scene;
  scene.ground_z = 0.f;
  return scene;
}

// A buffer holding every return of `first` (no per-frame subset, no bound in the way).
PointBuffer BufferOf(const Scan& first) {
  BufferConfig config;
  config.max_points = 10000000;
  config.max_points_per_frame = 10000000;
  PointBuffer buffer(config, 1);
  buffer.AddFrame(first.points_W, first.origins_W);
  return buffer;
}

// Applies the filter of `later` to the buffer; returns how many of the points matching `in`
// (before) were dropped, and how many matched.
template <typename Pred>
std::pair<int, int> DroppedWhere(const Scan& later, PointBuffer* buffer, Pred in,
                                 TransientConfig config = TransientConfig()) {
  config.period_frames = 1;
  config.quiet_turns = 1;  // the rule alone: every point judged (the turns' schedule is apart)
  int matched_before = 0, matched_after = 0;
  for (const Vec3f& p : buffer->points()) matched_before += in(p);
  TransientFilter filter(config);
  std::mutex mu;
  filter.Apply(later.points_S, later.T, 0.3f, 60.f, 0, buffer, nullptr, nullptr, &mu, nullptr);
  for (const Vec3f& p : buffer->points()) matched_after += in(p);
  return {matched_before - matched_after, matched_before};
}

// The range image holds, per bin of direction, the nearest return in it (to the centimetre, 0
// nearer than the minimum range) and where in the bin that return lies; points beyond the maximum
// range are left out. Checked point by point through PlaceOf on 1003 random points (the eight-wide
// path and its scalar tail), many sharing a bin, filled with and without a pool.
TEST(RangeImageTest, EachBinHoldsTheNearestReturnInItsDirection) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.f, 1.f), range(0.2f, 50.f);
  std::vector<Vec3f> points;
  for (int i = 0; i < 1000; ++i) {
    Vec3f d(u(rng), u(rng), 0.3f * u(rng));
    if (i % 3 == 1) d = points.back().normalized() + Vec3f::Constant(1e-4f * u(rng));
    points.push_back(d.normalized() * range(rng));
  }
  points.push_back(Vec3f::Zero());
  points.push_back(Vec3f(0.f, 0.f, 7.f));
  points.push_back(Vec3f(-3.f, 0.f, 0.f));
  const float min_range = 1.f, max_range = 40.f;
  RangeImage image(0.4f), pooled(0.4f);
  image.Fill(points, min_range, max_range);
  WorkerPool pool(2);
  std::vector<Vec3f> many;
  for (int k = 0; k < 5; ++k) many.insert(many.end(), points.begin(), points.end());
  pooled.Fill(many, min_range, max_range, &pool);  // 5015 points: over the pool
  std::map<std::pair<int, int>, uint16_t> nearest;
  for (const Vec3f& p : points) {
    const float r = p.norm();
    if (!(r > 0.f && r <= max_range)) continue;
    float fa, fe;
    image.PlaceOf(p, &fa, &fe);
    const std::pair<int, int> bin(std::min(int(fa), image.azimuth_bins() - 1),
                                  std::min(int(fe), image.elevation_bins() - 1));
    const uint16_t cm = r < min_range ? 0 : uint16_t(100.f * r);
    auto [it, fresh] = nearest.emplace(bin, cm);
    if (!fresh) it->second = std::min(it->second, cm);
  }
  ASSERT_GT(nearest.size(), 500u);
  for (const auto& [bin, cm] : nearest) {
    SCOPED_TRACE(testing::Message() << "bin " << bin.first << ", " << bin.second);
    EXPECT_EQ(image.At(bin.first, bin.second), 0.01f * float(cm));
    EXPECT_EQ(pooled.At(bin.first, bin.second), 0.01f * float(cm));
    if (cm > 0) {
      float da, de, pda, pde;
      image.OffsetAt(bin.first, bin.second, &da, &de);
      pooled.OffsetAt(bin.first, bin.second, &pda, &pde);
      EXPECT_EQ(da, pda);
      EXPECT_EQ(de, pde);
      EXPECT_TRUE(da > 0.f && da < 1.f && de > 0.f && de < 1.f);
    }
  }
  // Every other bin of the rows is empty.
  int held = 0;
  for (int e = 0; e < image.elevation_bins(); ++e)
    for (int a = 0; a < image.azimuth_bins(); ++a) held += std::isfinite(image.At(a, e)) ? 1 : 0;
  EXPECT_EQ(held, int(nearest.size()));
}

// A point below the scan's lowest ring (beside the sensor, on or above the ground) can never have
// returns below it in its window: it is kept, and reported as something there when a return of
// the ring lies within the near distance of it (only those bins are read for it).
TEST(TransientTest, PointsBelowTheLowestRingAreKeptOrSomethingIsThere) {
  const Scan scan = Take(Ground(), PoseAt(0.f, 0.f), 3);
  RangeImage image(TransientConfig().bin_deg);
  image.Fill(scan.points_S, 1.f, 60.f);
  // The lowest ring's return straight ahead (x > 0, y about 0).
  Vec3f ring = Vec3f::Zero();
  for (const Vec3f& q : scan.points_S) {
    if (q.x() <= 0.f || std::abs(q.y()) > 0.05f * q.x()) continue;
    if (ring.isZero() || q.z() / q.norm() < ring.z() / ring.norm()) ring = q;
  }
  ASSERT_FALSE(ring.isZero());
  int e_ring, e_below, a;
  image.BinOf(ring, &a, &e_ring);
  ASSERT_EQ(e_ring, image.first_row());
  const TransientConfig config;
  // 3.5 cm below the ring's return: a row below the image's rows, the return within reach.
  const Vec3f just_below = ring - Vec3f(0.f, 0.f, 0.035f);
  image.BinOf(just_below, &a, &e_below);
  ASSERT_LT(e_below, image.first_row());
  EXPECT_EQ(Judge(image, config, just_below), Verdict::kSomethingThere);
  // 30 cm below it, and a ground point 2 m from the sensor (40° below the ring): nothing near.
  EXPECT_EQ(Judge(image, config, ring - Vec3f(0.f, 0.f, 0.3f)), Verdict::kKept);
  EXPECT_EQ(Judge(image, config, Vec3f(2.f, 0.3f, -1.7f)), Verdict::kKept);
  // Returns nearer than the minimum range block the ring's row: kept, not something there.
  RangeImage blocked(TransientConfig().bin_deg);
  blocked.Fill(scan.points_S, ring.norm() + 0.2f, 60.f);
  EXPECT_TRUE(blocked.RowBlocked(blocked.first_row()));
  EXPECT_EQ(Judge(blocked, config, just_below), Verdict::kKept);
}

TEST(TransientTest, AWallSeenThenARayThroughItIsDropped) {
  AnalyticScene before = Ground();
  before.boxes.push_back({Eigen::Vector3f(8.f, -1.f, -0.05f), Eigen::Vector3f(8.5f, 1.f, 2.f)});
  before.boxes.push_back({Eigen::Vector3f(20.f, -8.f, -0.05f), Eigen::Vector3f(21.f, 8.f, 6.f)});
  AnalyticScene after = before;
  after.boxes.erase(after.boxes.begin());  // the near wall has gone; the far one stays

  PointBuffer buffer = BufferOf(Take(before, PoseAt(0, 0), 1));
  const Scan later = Take(after, PoseAt(1.f, 0.2f), 2);
  auto on_wall = [](const Vec3f& p) { return p.x() < 8.6f && p.x() > 7.9f && p.z() > 0.3f; };
  auto static_ = [](const Vec3f& p) { return !(p.x() < 8.6f && p.x() > 7.9f && p.z() > 0.05f); };
  const auto [wall_dropped, wall] = DroppedWhere(later, &buffer, on_wall);
  ASSERT_GT(wall, 500);
  EXPECT_GE(wall_dropped, int(0.95 * wall)) << wall_dropped << " of " << wall;
  // Nothing static goes: not the ground in front of, beside or behind the wall, nor the far wall.
  PointBuffer again = BufferOf(Take(before, PoseAt(0, 0), 1));
  const auto [static_dropped, statics] = DroppedWhere(later, &again, static_);
  ASSERT_GT(statics, 10000);
  EXPECT_EQ(static_dropped, 0) << "of " << statics;
}

// The buffer's turns (TransientConfig::quiet_turns, active_frames, active_period_frames): where
// nothing was dropped lately a point is judged in one turn of quiet_turns; within a column of a
// drop of the last active_frames frames, every active_period_frames frames. A wall that has gone
// loses a quiet share of its points at the first turn, and the rest at the next, since those drops
// made its columns active; the far wall and the ground away from it are judged a quarter as often,
// and keep every point.
TEST(TransientTest, AGoneWallIsClearedWithinTwoTurnsAndQuietPlacesAreJudgedLessOften) {
  AnalyticScene before = Ground();
  before.boxes.push_back({Eigen::Vector3f(8.f, -1.f, -0.05f), Eigen::Vector3f(8.5f, 1.f, 2.f)});
  before.boxes.push_back({Eigen::Vector3f(20.f, -8.f, -0.05f), Eigen::Vector3f(21.f, 8.f, 6.f)});
  AnalyticScene after = before;
  after.boxes.erase(after.boxes.begin());
  auto on_wall = [](const Vec3f& p) { return p.x() < 8.6f && p.x() > 7.9f && p.z() > 0.3f; };
  auto far_wall = [](const Vec3f& p) { return p.x() > 19.9f; };
  auto count = [](const PointBuffer& b, auto pred) {
    int n = 0;
    for (const Vec3f& p : b.points()) n += pred(p);
    return n;
  };
  const Scan first = Take(before, PoseAt(0, 0), 1);
  const Scan later = Take(after, PoseAt(1.f, 0.2f), 2);
  TransientConfig config;
  config.period_frames = 1;
  ASSERT_EQ(config.quiet_turns, 4);
  ASSERT_GT(config.active_frames, 1);
  PointBuffer buffer = BufferOf(first);
  const int wall = count(buffer, on_wall), far = count(buffer, far_wall);
  const int64_t all = int64_t(buffer.points().size());
  ASSERT_GT(wall, 500);
  ASSERT_GT(far, 1000);
  TransientFilter filter(config);
  std::mutex mu;
  filter.Apply(later.points_S, later.T, 0.3f, 60.f, 0, &buffer, nullptr, nullptr, &mu, nullptr);
  const int after_first = count(buffer, on_wall);
  const int64_t judged_first = filter.Stats().judged;
  // Nothing active yet: a quarter of the points judged, and of the wall's a quarter dropped.
  EXPECT_NEAR(double(judged_first), all / 4.0, all * 0.01);
  EXPECT_NEAR(double(wall - after_first), wall / 4.0, wall * 0.05);
  filter.Apply(later.points_S, later.T, 0.3f, 60.f, 1, &buffer, nullptr, nullptr, &mu, nullptr);
  EXPECT_LE(count(buffer, on_wall), int(0.05 * wall)) << "of " << wall;
  EXPECT_EQ(count(buffer, far_wall), far);
  // The second turn judged the wall's columns whole and a quarter elsewhere.
  const int64_t second = filter.Stats().judged - judged_first;
  EXPECT_LT(second, int64_t(buffer.points().size()) / 2);
  EXPECT_GT(second, int64_t(buffer.points().size()) / 4);
  // With the default period (a quarter of the points a frame, a sixteenth where quiet) and
  // active_period_frames=1, places where things move are judged in every frame: the wall goes in
  // the two frames after its first drops, not in a turn four frames later.
  {
    TransientConfig defaults;
    ASSERT_EQ(defaults.period_frames, 4);
    ASSERT_EQ(defaults.active_period_frames, 0);  // every period_frames
    defaults.active_period_frames = 1;
    PointBuffer each = BufferOf(first);
    TransientFilter filter4(defaults);
    filter4.Apply(later.points_S, later.T, 0.3f, 60.f, 0, &each, nullptr, nullptr, &mu, nullptr);
    EXPECT_NEAR(double(filter4.Stats().judged), all / 16.0, all * 0.01);
    const int left0 = count(each, on_wall);
    EXPECT_NEAR(double(wall - left0), wall / 16.0, wall * 0.03);
    filter4.Apply(later.points_S, later.T, 0.3f, 60.f, 1, &each, nullptr, nullptr, &mu, nullptr);
    filter4.Apply(later.points_S, later.T, 0.3f, 60.f, 2, &each, nullptr, nullptr, &mu, nullptr);
    EXPECT_LE(count(each, on_wall), int(0.05 * wall)) << "of " << wall;
    EXPECT_EQ(count(each, far_wall), far);
  }
  // Every turn judges every point when the gate is off, and the verdicts are the rule's.
  config.quiet_turns = 1;
  PointBuffer again = BufferOf(first);
  TransientFilter every(config);
  every.Apply(later.points_S, later.T, 0.3f, 60.f, 0, &again, nullptr, nullptr, &mu, nullptr);
  EXPECT_EQ(every.Stats().judged, all);
  EXPECT_LE(count(again, on_wall), int(0.05 * wall));
}

// A person's lowest part stands on the road: the rays below it end on the road in front of where
// it stood, so not every return about it ends beyond. The road around its direction is one plane
// that passes it by more than the margin, and that decides.
TEST(TransientTest, TheFeetOfAPersonWhoWalkedOffAreDropped) {
  for (float distance : {8.f, 12.f, 18.f}) {
    AnalyticScene before = Ground();
    before.cylinders.push_back({Eigen::Vector2f(distance, 0.f), 0.27f, -0.05f, 1.7f});
    auto feet = [&](const Vec3f& p) {
      return (p.head<2>() - Eigen::Vector2f(distance, 0)).norm() < 0.35f && p.z() > 0.12f &&
             p.z() < 0.4f;
    };
    auto ground = [](const Vec3f& p) { return p.z() < 0.05f; };
    const Scan later = Take(Ground(), PoseAt(1.f, 0.3f), 2, CarLidar(0.03f));
    PointBuffer buffer = BufferOf(Take(before, PoseAt(0, 0), 1, CarLidar(0.03f)));
    const auto [feet_dropped, all_feet] = DroppedWhere(later, &buffer, feet);
    ASSERT_GT(all_feet, 10) << distance;
    EXPECT_GE(feet_dropped, int(0.9 * all_feet))
        << feet_dropped << " of " << all_feet << " at " << distance << " m";
    TransientConfig no_fit;
    no_fit.surface_fit = false;
    PointBuffer again = BufferOf(Take(before, PoseAt(0, 0), 1, CarLidar(0.03f)));
    const int without = DroppedWhere(later, &again, feet, no_fit).first;
    EXPECT_LT(without, int(0.8 * all_feet)) << "without the fit, at " << distance << " m";
    std::printf("feet at %.0f m: %d of %d dropped (%d without the fit)\n", distance, feet_dropped,
                all_feet, without);
    PointBuffer road = BufferOf(Take(before, PoseAt(0, 0), 1, CarLidar(0.03f)));
    const auto [road_dropped, roads] = DroppedWhere(later, &road, ground);
    EXPECT_EQ(road_dropped, 0) << "of " << roads << " road points, at " << distance << " m";
  }
}

TEST(TransientTest, DroppedPointsJoinTheClearedSetAndExpire) {
  AnalyticScene before = Ground();
  before.boxes.push_back({Eigen::Vector3f(6.f, -0.3f, -0.05f), Eigen::Vector3f(6.5f, 0.3f, 1.8f)});
  PointBuffer buffer = BufferOf(Take(before, PoseAt(0, 0), 1));
  TransientConfig config;
  config.period_frames = 1;
  config.quiet_turns = 1;
  TransientFilter filter(config);
  std::mutex mu;
  const Scan later = Take(Ground(), PoseAt(0, 0), 2);
  filter.Apply(later.points_S, later.T, 0.3f, 60.f, 7, &buffer, nullptr, nullptr, &mu, nullptr);
  const size_t cleared = filter.cleared().size();
  EXPECT_GT(cleared, 100u);
  EXPECT_EQ(int64_t(cleared), filter.Stats().buffer_removed);
  // Samples lie around the dropped points, labelled free.
  SampleBatch batch;
  FastRng rng(3);
  filter.cleared().Sample(500, 0.15f, 0.15f, Vec3f::Constant(-100), Vec3f::Constant(100), &rng,
                          &batch);
  ASSERT_EQ(batch.size(), 500u);
  for (size_t i = 0; i < batch.size(); ++i) {
    EXPECT_EQ(batch.labels[i], 0.15f);
    EXPECT_NEAR(batch.xyz[3 * i], 6.f, 0.3f);
  }
  const Vec3d lo = Vec3d::Constant(-100), hi = Vec3d::Constant(100);
  filter.cleared().Expire(7 + 10, 10, 1000000, lo, hi);
  EXPECT_EQ(filter.cleared().size(), cleared);  // dropped at frame 7: still cleared at 17
  filter.cleared().Expire(7 + 11, 10, 1000000, lo, hi);
  EXPECT_EQ(filter.cleared().size(), 0u);
}

// Earlier evidence (JudgeNewest): the filter judges each frame's newly buffered returns against
// the scans past_frames, 2 · past_frames, ... before. `scans` are applied as frames 0, 1, ...; the
// buffer takes the last one's returns; returns how many of those matching `in` were dropped, and
// how many matched.
template <typename Pred>
std::pair<int, int> DroppedOnArrival(const std::vector<Scan>& scans, Pred in,
                                     TransientConfig config) {
  config.period_frames = 1;
  TransientFilter filter(config);
  std::mutex mu;
  PointBuffer buffer = BufferOf(scans.back());
  PointBuffer empty = BufferOf(Scan());
  for (size_t f = 0; f < scans.size(); ++f) {
    const bool last = f + 1 == scans.size();
    filter.Apply(scans[f].points_S, scans[f].T, 0.3f, 60.f, int64_t(f), last ? &buffer : &empty,
                 nullptr, nullptr, &mu, nullptr);
  }
  int before = 0, after = 0;
  for (const Vec3f& p : buffer.points()) before += in(p);
  filter.JudgeNewest(int64_t(scans.size() - 1), &buffer, nullptr, &mu, nullptr);
  for (const Vec3f& p : buffer.points()) after += in(p);
  EXPECT_GE(filter.Stats().past_removed, int64_t(before - after));
  return {before - after, before};
}

// A person steps into the robot's path where its scans a few frames before saw the road and the
// building beyond: their returns are dropped as they arrive, before they train. The road, the
// building and a wall that the earlier scans saw only in part (from farther away) keep every
// return. A person who has stood there since the earlier scan is kept.
TEST(TransientTest, APersonWhoStepsWhereEarlierScansSawFreeIsDroppedOnArrival) {
  AnalyticScene scene = Ground();
  scene.boxes.push_back({Eigen::Vector3f(30.f, -12.f, -0.05f), Eigen::Vector3f(31.f, 12.f, 9.f)});
  scene.boxes.push_back({Eigen::Vector3f(14.f, 5.f, -0.05f), Eigen::Vector3f(20.f, 6.f, 3.f)});
  AnalyticScene with_person = scene;
  with_person.boxes.push_back(
      {Eigen::Vector3f(12.f, -0.3f, -0.05f), Eigen::Vector3f(12.5f, 0.3f, 1.8f)});
  auto on_person = [](const Vec3f& p) {
    return p.x() > 11.9f && p.x() < 12.6f && std::abs(p.y()) < 0.4f && p.z() > 0.15f;
  };
  auto static_ = [](const Vec3f& p) {
    return !(p.x() > 11.9f && p.x() < 12.6f && std::abs(p.y()) < 0.4f && p.z() > 0.05f);
  };
  TransientConfig config;
  config.past_frames = 2;
  config.past_scans = 2;
  // Frames 0-4, 1 m apart; the person is there only in the last.
  std::vector<Scan> scans;
  for (int f = 0; f < 5; ++f)
    scans.push_back(
        Take(f == 4 ? with_person : scene, PoseAt(float(f), 0.1f * f), 10 + f, CarLidar(0.03f)));
  const auto [person_dropped, person] = DroppedOnArrival(scans, on_person, config);
  ASSERT_GT(person, 300);
  EXPECT_GE(person_dropped, int(0.9 * person)) << person_dropped << " of " << person;
  const auto [static_dropped, statics] = DroppedOnArrival(scans, static_, config);
  ASSERT_GT(statics, 50000);
  EXPECT_EQ(static_dropped, 0) << "of " << statics;
  // There since frame 2, the scan past_frames before the last: it saw them, and they stay.
  std::vector<Scan> standing = scans;
  for (int f = 2; f < 5; ++f)
    standing[size_t(f)] = Take(with_person, PoseAt(float(f), 0.1f * f), 10 + f, CarLidar(0.03f));
  config.past_scans = 1;  // frame 0, which did not see them, is not asked
  const auto [stood_dropped, stood] = DroppedOnArrival(standing, on_person, config);
  ASSERT_GT(stood, 300);
  EXPECT_EQ(stood_dropped, 0) << "of " << stood;
  // Off: nothing is judged.
  config.past_frames = 0;
  EXPECT_EQ(DroppedOnArrival(scans, on_person, config).first, 0);
}

TEST(TransientTest, AThinPoleHitByAFewBeamsAndGrazedByManyIsKept) {
  AnalyticScene scene = Ground();
  // A 5 cm-radius pole: about three columns of every ring hit it from 8 m, and the columns
  // beside them pass within a few centimetres on to the building behind.
  scene.cylinders.push_back({Eigen::Vector2f(10.f, 0.f), 0.05f, -0.05f, 3.f});
  scene.boxes.push_back({Eigen::Vector3f(25.f, -10.f, -0.05f), Eigen::Vector3f(26.f, 10.f, 8.f)});
  auto on_pole = [](const Vec3f& p) {
    return (p.head<2>() - Eigen::Vector2f(10, 0)).norm() < 0.1f;
  };
  for (const Eigen::Isometry3f& later_pose : {PoseAt(2.f, 1.f), PoseAt(-4.f, -1.f), PoseAt(5, 2)}) {
    PointBuffer buffer = BufferOf(Take(scene, PoseAt(0, 0), 1));
    const auto [dropped, pole] =
        DroppedWhere(Take(scene, later_pose, 2, CarLidar(0.03f)), &buffer, on_pole);
    ASSERT_GT(pole, 20);
    EXPECT_EQ(dropped, 0) << "of " << pole << " from " << later_pose.translation().transpose();
  }
}

// Busy places (TransientConfig::busy_drops): a person stood beside the edge of a parked car and
// walked off. The points of the person whose window holds the car's edge (returns in front of
// them) are kept by the rule at every frame. Where the rule dropped many returns (the rest of the
// person) the place is busy, and there a point goes once, in busy_passes frames since the last
// that hit it, a ray of the bins about its direction passed within busy_radius_m of it and ended
// beyond it by the margin. The car, a thin pole beside the person and the ground stay whole.
TEST(TransientTest, InBusyPlacesPassesAddUpOverFramesAndStaticSurfacesStay) {
  AnalyticScene scene = Ground();
  scene.boxes.push_back({Eigen::Vector3f(3.5f, 0.18f, -0.05f), Eigen::Vector3f(5.f, 2.f, 1.5f)});
  scene.cylinders.push_back({Eigen::Vector2f(6.5f, -0.6f), 0.05f, -0.05f, 3.f});
  scene.boxes.push_back({Eigen::Vector3f(25.f, -10.f, -0.05f), Eigen::Vector3f(26.f, 10.f, 8.f)});
  AnalyticScene with_person = scene;
  with_person.cylinders.push_back({Eigen::Vector2f(6.f, 0.f), 0.25f, -0.05f, 1.7f});
  auto on_person = [](const Vec3f& p) {
    return (p.head<2>() - Eigen::Vector2f(6, 0)).norm() < 0.35f && p.z() > 0.15f;
  };
  // Static: all but the person and the ground under it (its feet are within the normal margin).
  auto is_static = [](const Vec3f& p) {
    return (p.head<2>() - Eigen::Vector2f(6, 0)).norm() >= 0.35f;
  };
  auto count = [](const PointBuffer& b, auto pred) {
    int n = 0;
    for (const Vec3f& p : b.points()) n += pred(p);
    return n;
  };
  const Scan first = Take(with_person, PoseAt(0, 0), 1, CarLidar(0.03f));
  // The car's edge lies at 2.06° of azimuth from the sensor; a bin (0.4°) inside it, rays of the
  // bins about a point's direction end on the car, in front of it, as they would along a surface
  // the rays graze: those points are left to the rule.
  const float kBesideEdge = 1.5f * float(M_PI) / 180.f;
  struct Left {
    int person, person_clear_of_edge, statics;
    int64_t busy;
  };
  auto run = [&](int busy_drops) {
    TransientConfig config;
    config.period_frames = 1;
    config.quiet_turns = 1;
    config.busy_drops = busy_drops;
    PointBuffer buffer = BufferOf(first);
    TransientFilter filter(config);
    std::mutex mu;
    for (int frame = 0; frame < 5; ++frame) {
      const Scan later = Take(scene, PoseAt(0, 0), 10 + frame, CarLidar(0.03f));
      filter.Apply(later.points_S, later.T, 0.3f, 60.f, frame, &buffer, nullptr, nullptr, &mu,
                   nullptr);
    }
    return Left{count(buffer, on_person),
                count(buffer,
                      [&](const Vec3f& p) {
                        return on_person(p) && std::atan2(p.y(), p.x()) < kBesideEdge;
                      }),
                count(buffer, is_static), filter.Stats().busy_removed};
  };
  const int person = count(BufferOf(first), on_person);
  const int statics = count(BufferOf(first), is_static);
  ASSERT_GT(person, 300);
  ASSERT_EQ(TransientConfig().busy_drops, 0);  // off by default
  const Left off = run(0), on = run(6);
  // The rule alone leaves the person's side by the car's edge.
  EXPECT_GT(off.person, 20) << "of " << person;
  EXPECT_EQ(off.busy, 0);
  EXPECT_GT(off.person_clear_of_edge, 20);
  // Passes added up take it, all but the points within a bin of the car's edge.
  EXPECT_EQ(on.person_clear_of_edge, 0) << off.person_clear_of_edge << " left by the rule alone";
  EXPECT_LE(on.person, off.person / 2) << off.person << " left by the rule alone, of " << person;
  EXPECT_GT(on.busy, 0);
  // Nothing static goes either way: the car (its edge beside the person), the pole, the ground.
  EXPECT_EQ(off.statics, statics);
  EXPECT_EQ(on.statics, statics);
}

TEST(TransientTest, GroundAndWallsAtGrazingAnglesAreKept) {
  AnalyticScene scene = Ground();
  // A street: long facades 6 m either side, seen at grazing angles far along it.
  scene.boxes.push_back({Eigen::Vector3f(-60.f, 6.f, -0.05f), Eigen::Vector3f(60.f, 7.f, 10.f)});
  scene.boxes.push_back({Eigen::Vector3f(-60.f, -8.f, -0.05f), Eigen::Vector3f(60.f, -6.f, 4.f)});
  for (float noise : {0.f, 0.03f}) {
    PointBuffer buffer = BufferOf(Take(scene, PoseAt(0, 0), 1, CarLidar(noise)));
    for (const Eigen::Isometry3f& later_pose :
         {PoseAt(1, 0.3f), PoseAt(10, -0.5f), PoseAt(-7, 1)}) {
      const auto [dropped, all] = DroppedWhere(Take(scene, later_pose, 5, CarLidar(noise)), &buffer,
                                               [](const Vec3f&) { return true; });
      ASSERT_GT(all, 50000);
      EXPECT_EQ(dropped, 0) << "noise " << noise << ", from "
                            << later_pose.translation().transpose();
    }
  }
}

TEST(TransientTest, SurfacesHiddenOrSeenOnceFromAfarAreKept) {
  AnalyticScene scene = Ground();
  // A high facade, seen from afar by a sensor that looks up, later only from below its field.
  scene.boxes.push_back({Eigen::Vector3f(30.f, -10.f, 4.f), Eigen::Vector3f(31.f, 10.f, 12.f)});
  testing_support::LidarModel up = CarLidar();
  up.elev_max_deg = 20.f;
  PointBuffer buffer = BufferOf(Take(scene, PoseAt(0, 0), 1, up));
  auto high = [](const Vec3f& p) { return p.z() > 3.9f; };
  const auto [dropped_high, highs] = DroppedWhere(Take(scene, PoseAt(12, 0), 2), &buffer, high);
  ASSERT_GT(highs, 1000);
  EXPECT_EQ(dropped_high, 0);

  // A wall behind a van parked in front of it later: the van's returns are nearer.
  AnalyticScene street = Ground();
  street.boxes.push_back({Eigen::Vector3f(12.f, -4.f, -0.05f), Eigen::Vector3f(13.f, 4.f, 3.f)});
  AnalyticScene parked = street;
  parked.boxes.push_back({Eigen::Vector3f(6.f, -1.5f, -0.05f), Eigen::Vector3f(7.f, 1.5f, 2.5f)});
  PointBuffer wall = BufferOf(Take(street, PoseAt(0, 0), 1));
  auto on_wall = [](const Vec3f& p) { return p.x() > 11.9f; };
  const auto [dropped_wall, walls] = DroppedWhere(Take(parked, PoseAt(0, 0), 2), &wall, on_wall);
  ASSERT_GT(walls, 1000);
  EXPECT_EQ(dropped_wall, 0);
}

// The filter judges its points eight at a time over the pool (their places at once): it drops
// exactly the points that Judge, one at a time, sees through, and keeps the rest in their order.
TEST(TransientTest, TheFilterDropsExactlyThePointsJudgeSeesThrough) {
  AnalyticScene before = Ground();
  before.boxes.push_back({Eigen::Vector3f(8.f, -1.f, -0.05f), Eigen::Vector3f(8.5f, 1.f, 2.f)});
  before.boxes.push_back({Eigen::Vector3f(-6.f, 5.f, -0.05f), Eigen::Vector3f(9.f, 6.f, 7.f)});
  before.cylinders.push_back({Eigen::Vector2f(4.f, -3.f), 0.1f, -0.05f, 3.f});
  AnalyticScene after = before;
  after.boxes.erase(after.boxes.begin());  // the near wall has gone
  const Scan first = Take(before, PoseAt(0, 0), 1, CarLidar(0.03f));
  const Scan later = Take(after, PoseAt(1.3f, 0.4f), 2, CarLidar(0.03f));
  PointBuffer buffer = BufferOf(first);
  const std::vector<Vec3f> points = buffer.points();
  TransientConfig config;
  config.period_frames = 1;
  config.quiet_turns = 1;
  TransientFilter filter(config);
  WorkerPool pool(2);
  std::mutex mu;
  filter.Apply(later.points_S, later.T, 0.3f, 60.f, 0, &buffer, nullptr, nullptr, &mu, &pool);
  const Eigen::Isometry3f S_W = later.T.inverse();
  std::vector<Vec3f> kept;
  int seen_through = 0;
  for (const Vec3f& p : points) {
    if (SeenThrough(filter.image(), config, S_W * p)) {
      ++seen_through;
    } else {
      kept.push_back(p);
    }
  }
  ASSERT_GT(points.size(), 50000u);
  ASSERT_GT(seen_through, 500);  // the near wall
  ASSERT_EQ(buffer.points().size(), kept.size());
  for (size_t i = 0; i < kept.size(); ++i) ASSERT_EQ(buffer.points()[i], kept[i]) << i;
}

// The window read eight bins at a time (where the processor has AVX2) gives the verdict of the
// reference that reads it one bin at a time, for every point: a noisy scan's own points and those
// of a scan before it where a wall has gone, and random points around the sensor, in every
// direction (windows across the azimuth seam, up to the widest near the sensor), judged against
// images with and without blocked bins (a minimum range of 0.3 and 4 m), with empty bins as free
// space and not.
TEST(TransientTest, TheVectorizedWindowGivesTheReferenceVerdicts) {
  AnalyticScene before = Ground();
  before.boxes.push_back({Eigen::Vector3f(8.f, -1.f, -0.05f), Eigen::Vector3f(8.5f, 1.f, 2.f)});
  before.boxes.push_back({Eigen::Vector3f(-6.f, 5.f, -0.05f), Eigen::Vector3f(9.f, 6.f, 7.f)});
  before.boxes.push_back({Eigen::Vector3f(-9.f, -8.f, -0.05f), Eigen::Vector3f(-7.f, 8.f, 4.f)});
  before.cylinders.push_back({Eigen::Vector2f(4.f, -3.f), 0.1f, -0.05f, 3.f});
  AnalyticScene after = before;
  after.boxes.erase(after.boxes.begin());  // the near wall has gone
  const Scan first = Take(before, PoseAt(0, 0), 1, CarLidar(0.03f));
  const Scan later = Take(after, PoseAt(1.3f, 0.4f), 2, CarLidar(0.03f));
  const Eigen::Isometry3f S_W = later.T.inverse();
  std::vector<Vec3f> points_S;
  for (const Vec3f& p : first.points_W) points_S.push_back(S_W * p);
  points_S.insert(points_S.end(), later.points_S.begin(), later.points_S.end());
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> xy(-12.f, 12.f), z(-1.8f, 3.f);
  for (int i = 0; i < 100000; ++i) points_S.emplace_back(xy(rng), xy(rng), z(rng));
  for (const float min_range : {0.3f, 4.f}) {
    for (const bool empty_is_free : {true, false}) {
      TransientConfig config;
      config.empty_is_free = empty_is_free;
      RangeImage image(config.bin_deg);
      image.Fill(later.points_S, min_range, 60.f);
      std::map<Verdict, int> count;
      for (size_t i = 0; i < points_S.size(); ++i) {
        const Verdict v = Judge(image, config, points_S[i]);
        ASSERT_EQ(int(v), int(JudgeReference(image, config, points_S[i])))
            << "point " << i << " (" << points_S[i].transpose() << "), minimum range " << min_range
            << ", empty_is_free " << empty_is_free;
        ++count[v];
      }
      // Every verdict, many times over.
      EXPECT_GT(count[Verdict::kKept], 10000);
      EXPECT_GT(count[Verdict::kSomethingThere], 10000);
      EXPECT_GT(count[Verdict::kSeenThrough], 1000);
    }
  }
}

TEST(TransientTest, DeferredRaysSeenThroughAreDroppedAndStaticOnesKept) {
  auto config = MakePreset("maicity");
  ASSERT_TRUE(config.ok());
  MapGeometry geometry(config->grid);
  DeferredPoints deferred(geometry, config->grid, config->deferred);
  // A person 25 m ahead (outside the ±10 m box) in front of a building 40 m ahead.
  AnalyticScene before = Ground();
  before.boxes.push_back({Eigen::Vector3f(40.f, -10.f, -0.05f), Eigen::Vector3f(41.f, 10.f, 8.f)});
  AnalyticScene after = before;
  before.cylinders.push_back({Eigen::Vector2f(25.f, 0.f), 0.25f, -0.05f, 1.8f});
  const Scan first = Take(before, PoseAt(0, 0), 1);
  std::vector<Vec3f> outside_p, outside_o;
  for (size_t i = 0; i < first.points_W.size(); ++i) {
    if (first.points_W[i].x() < 10.f) continue;
    outside_p.push_back(first.points_W[i]);
    outside_o.push_back(first.origins_W[i]);
  }
  deferred.Add(outside_p, outside_o, first.T.translation());
  auto count = [&](auto pred) {
    int n = 0;
    for (const Vec3f& p : outside_p) n += pred(p);
    return n;
  };
  ASSERT_GT(count([](const Vec3f& p) { return p.x() < 26.f && p.z() > 0.3f; }), 20);
  const size_t held = deferred.size();
  TransientConfig tc;
  tc.period_frames = 1;
  TransientFilter filter(tc);
  PointBuffer empty(config->buffer, 1);
  std::mutex mu;
  const Scan later = Take(after, PoseAt(5, 0), 2);
  // Each frame walks every other sub-map of the deferred store (period 1: two frames for all).
  filter.Apply(later.points_S, later.T, 0.3f, 60.f, 0, &empty, &deferred, nullptr, &mu, nullptr);
  filter.Apply(later.points_S, later.T, 0.3f, 60.f, 1, &empty, &deferred, nullptr, &mu, nullptr);
  const int64_t removed = filter.Stats().deferred_removed;
  EXPECT_GT(removed, 0);
  EXPECT_EQ(deferred.size(), held - size_t(removed));
  // What is left: the building and the ground, and at most the person's feet (within 0.3 m of
  // the ground, which rays below end in front of).
  std::vector<uint32_t> voxels;
  std::vector<float> rays;
  int person_left = 0, kept = 0;
  for (int x = -4; x <= 4; ++x) {
    for (int y = -4; y <= 4; ++y) {
      for (int z = -2; z <= 2; ++z) {
        deferred.Rays(Int3(x, y, z), &voxels, &rays);
        for (size_t i = 0; i < voxels.size(); ++i) {
          ++kept;
          const Vec3f p(rays[6 * i], rays[6 * i + 1], rays[6 * i + 2]);
          person_left += (p.head<2>() - Eigen::Vector2f(25, 0)).norm() < 0.5f && p.z() > 0.3f;
        }
      }
    }
  }
  EXPECT_EQ(person_left, 0);
  EXPECT_EQ(size_t(kept), deferred.size());
}

TEST(TransientTest, BadConfigValuesNameTheField) {
  for (const char* kv : {"transient.margin_m=0",
                         "transient.bin_deg=NaN",
                         "transient.window_elevation_bins=0",
                         "transient.max_range_m=0.5",
                         "transient.period_frames=0",
                         "transient.clear_label_m=-1",
                         "transient.clear_samples_per_iteration=-3",
                         "transient.max_cleared_points=-1",
                         "transient.fit_rms_m=0",
                         "transient.fit_rms_per_m=NaN",
                         "transient.fit_normal_margin_m=-0.1",
                         "transient.near_m=2",
                         "transient.near_bins=-1",
                         "transient.surface_fit=maybe",
                         "transient.empty_is_free=2",
                         "transient.past_frames=-1",
                         "transient.past_frames=101",
                         "transient.past_scans=5",
                         "transient.active_frames=-1",
                         "transient.active_cell_m=0",
                         "transient.active_cell_m=NaN",
                         "transient.quiet_turns=0",
                         "transient.active_period_frames=-1",
                         "transient.active_period_frames=5",
                         "transient.busy_drops=-1",
                         "transient.busy_passes=0",
                         "transient.busy_passes=256",
                         "transient.busy_radius_m=NaN",
                         "transient.busy_max_range_m=-1"}) {
    auto config = MakePreset("maicity");
    ASSERT_TRUE(config.ok());
    const absl::Status s = ApplyOverrides({kv}, &*config);
    EXPECT_FALSE(s.ok()) << kv;
    const std::string key(kv, std::string(kv).find('='));
    EXPECT_THAT(std::string(s.message()), HasSubstr(key)) << kv;
  }
}

// The whole mapper: a person stands in front of a stationary robot for a few frames, then walks
// off. Later scans see through where they stood: the mesh and the network forget them. Without
// the filter the same run keeps them, so the test shows the filter is what clears them.
struct PersonRun {
  int mesh_vertices_in_person = 0;
  float min_sdf_on_person_face = -1.f;
  int64_t buffer_removed = 0;
};

PersonRun RunPerson(bool enabled) {
  auto config = MakePreset("maicity");
  EXPECT_TRUE(ApplyOverrides({"train.iterations=10", "decoder.freeze_after_frames=5",
                              std::string("transient.enabled=") + (enabled ? "true" : "false")},
                             &*config)
                  .ok());
  auto mapper = Mapper::Create(*config);
  EXPECT_TRUE(mapper.ok());
  AnalyticScene scene = Ground();
  scene.boxes.push_back({Eigen::Vector3f(8.f, -6.f, -0.05f), Eigen::Vector3f(9.f, 6.f, 4.f)});
  AnalyticScene with_person = scene;
  with_person.boxes.push_back(
      {Eigen::Vector3f(4.f, -0.3f, -0.05f), Eigen::Vector3f(4.5f, 0.3f, 1.8f)});
  testing_support::LidarModel lidar = CarLidar(0.01f);
  lidar.columns = 900;
  for (int f = 0; f < 24; ++f) {
    const Eigen::Isometry3f T = PoseAt(0.05f * float(f % 3), 0.f);
    PosedScan scan;
    scan.T_world_sensor = T.cast<double>();
    scan.points_S = testing_support::SimulateScan(f < 6 ? with_person : scene, lidar, T, 10 + f);
    EXPECT_TRUE((*mapper)->IntegrateScan(scan).ok());
  }
  PersonRun run;
  for (const TileInfo& t : (*mapper)->ListTiles(0)) {
    auto mesh = (*mapper)->ExtractMeshTile(t.key);
    EXPECT_TRUE(mesh.ok());
    for (const auto& v : mesh->vertices)
      run.mesh_vertices_in_person +=
          v[0] > 3.9f && v[0] < 4.6f && std::abs(v[1]) < 0.35f && v[2] > 0.3f && v[2] < 1.7f;
  }
  std::vector<float> xyz;
  for (float y = -0.2f; y <= 0.2f; y += 0.1f)
    for (float z = 0.5f; z <= 1.5f; z += 0.25f) xyz.insert(xyz.end(), {4.f, y, z});
  QueryResult q;
  EXPECT_TRUE((*mapper)->QueryNeural(xyz.data(), xyz.size() / 3, false, &q).ok());
  float lowest = 1e9f;
  for (float s : q.sdf) lowest = std::min(lowest, s);
  run.min_sdf_on_person_face = lowest;
  run.buffer_removed = (*mapper)->Stats().transient_buffer_removed;
  return run;
}

TEST(TransientTest, AMapperForgetsAPersonWhoWalkedOff) {
  const PersonRun with = RunPerson(true);
  const PersonRun without = RunPerson(false);
  EXPECT_GT(with.buffer_removed, 100);
  EXPECT_EQ(without.buffer_removed, 0);
  // Without the filter the person stays in the mesh as a wall, and the network reads the face
  // as surface; with it, no vertex is left there and the face reads free.
  EXPECT_GT(without.mesh_vertices_in_person, 50);
  EXPECT_EQ(with.mesh_vertices_in_person, 0);
  EXPECT_GT(with.min_sdf_on_person_face, 0.05f);
}

// A robot driving 1 m a frame along +x for 26 frames past a facade 8 m to its left, while a
// person stands 3 m to its left at x = 2 from frame `first` to frame `last`; the box (±10 m)
// holds x = 2 until about frame 12. The facade is long enough that every ray through where the
// person stood ends on it (rays into the sky are no evidence). `settings`: more overrides,
// separated by commas.
std::unique_ptr<Mapper> DriveByAPerson(const std::string& settings, int first, int last,
                                       uint64_t seed) {
  auto config = MakePreset("maicity");
  std::vector<std::string> overrides = {"train.iterations=8", "decoder.freeze_after_frames=5"};
  for (size_t at = 0; at <= settings.size();) {  // comma-separated
    const size_t end = std::min(settings.find(',', at), settings.size());
    overrides.push_back(settings.substr(at, end - at));
    at = end + 1;
  }
  EXPECT_TRUE(ApplyOverrides(overrides, &*config).ok());
  auto mapper = Mapper::Create(*config);
  EXPECT_TRUE(mapper.ok());
  AnalyticScene scene = Ground();
  scene.boxes.push_back({Eigen::Vector3f(-80.f, 8.f, -0.05f), Eigen::Vector3f(60.f, 9.f, 5.f)});
  AnalyticScene with_person = scene;
  with_person.boxes.push_back(
      {Eigen::Vector3f(2.f, 3.f, -0.05f), Eigen::Vector3f(2.5f, 3.6f, 1.8f)});
  testing_support::LidarModel lidar = CarLidar(0.01f);
  lidar.columns = 900;
  for (int f = 0; f < 26; ++f) {
    const Eigen::Isometry3f T = PoseAt(float(f), 0.f);
    PosedScan scan;
    scan.T_world_sensor = T.cast<double>();
    const bool there = f >= first && f <= last;
    scan.points_S = testing_support::SimulateScan(there ? with_person : scene, lidar, T, seed + f);
    EXPECT_TRUE((*mapper)->IntegrateScan(scan).ok());
  }
  return std::move(*mapper);
}

// The mesh's vertices where DriveByAPerson's person stood, 0.3-1.7 m up.
int MeshVerticesWherePersonStood(const Mapper& mapper) {
  int in_person = 0;
  for (const TileInfo& t : mapper.ListTiles(0)) {
    auto mesh = mapper.ExtractMeshTile(t.key);
    EXPECT_TRUE(mesh.ok());
    for (const auto& v : mesh->vertices)
      in_person +=
          v[0] > 1.9f && v[0] < 2.6f && v[1] > 2.9f && v[1] < 3.7f && v[2] > 0.3f && v[2] < 1.7f;
  }
  return in_person;
}

// A person beside the road stays until the robot's box has left them behind (until frame 14),
// then walks off: the rays that later pass where they stood come from a box that no longer holds
// the place. Their voxels in the global map read seen free, and the tile there meshes without
// them.
int MeshVerticesWherePersonStoodAfterDriving(int departed_frames) {
  std::unique_ptr<Mapper> mapper =
      DriveByAPerson("transient.departed_frames=" + std::to_string(departed_frames), 0, 14, 40);
  EXPECT_EQ(departed_frames > 0, mapper->Stats().transient_departed_removed > 0);
  return MeshVerticesWherePersonStood(*mapper);
}

TEST(TransientTest, APersonLeftBehindByTheBoxIsClearedFromTheGlobalMap) {
  EXPECT_GT(MeshVerticesWherePersonStoodAfterDriving(0), 50);
  EXPECT_EQ(MeshVerticesWherePersonStoodAfterDriving(30), 0);
}

// Without departed points (departed_frames=0), a person who walks off in one of the last frames
// the box holds them: the next frames' rays pass where they stood as the box leaves the place.
// The buffer drops what those rays see through (judged after the box moved), and the global map
// clears it. When it did not (the points were outside the new box, so the live map's unmarking
// passed them by), 319 and 1454 vertices stayed there for the last frames 10 and 12; now 0 and
// 36, specks where the person's edge met the ground. Every buffered point takes every turn here
// (quiet_turns=1): the person vanishes where nothing moved before, and with the default quarter
// of the turns a quiet place gets, the buffer saw through 195 of their returns before the box
// left; the departed points, on by default, clear the rest (the last check).
TEST(TransientTest, APersonSeenThroughAsTheBoxLeavesIsClearedFromTheGlobalMap) {
  for (int last : {10, 12}) {
    std::unique_ptr<Mapper> mapper =
        DriveByAPerson("transient.departed_frames=0,transient.quiet_turns=1", 0, last, 40);
    EXPECT_GT(mapper->Stats().transient_buffer_removed, 500) << "person until frame " << last;
    EXPECT_LE(MeshVerticesWherePersonStood(*mapper), 60) << "person until frame " << last;
  }
  for (int last : {10, 12}) {
    std::unique_ptr<Mapper> mapper = DriveByAPerson("transient.enabled=true", 0, last, 40);
    EXPECT_LE(MeshVerticesWherePersonStood(*mapper), 60) << "defaults, person until " << last;
  }
}

// A person who steps, behind the robot, onto a place its box saw free earlier: the box has left,
// so their returns wait in the deferred store, and the rays that later pass where they stood are
// not judged this time (the filter is off). A box's evidence of free space outweighs later returns
// from afar: they are not in the planner's distances there.
TEST(TransientTest, ReturnsFromAfarWhereABoxSawFreeSpaceAreNotDistances) {
  // The person stands there from frame 15 to 20, 13-18 m behind the sensor.
  std::unique_ptr<Mapper> mapper = DriveByAPerson("transient.enabled=false", 15, 20, 70);
  mapper->RefreshDistanceField();
  EXPECT_GT(mapper->Stats().deferred_points, 0);
  // In front of where the person stood: the ground is the nearest true surface.
  std::vector<float> xyz;
  for (float x : {2.1f, 2.25f, 2.4f})
    for (float z : {0.6f, 1.f, 1.4f}) xyz.insert(xyz.end(), {x, 2.75f, z});
  QueryResult q;
  ASSERT_TRUE(mapper->QuerySdf(xyz.data(), xyz.size() / 3, false, &q).ok());
  for (size_t i = 0; i < q.sdf.size(); ++i)
    EXPECT_GT(q.sdf[i], xyz[3 * i + 2] - 0.1f) << "at z " << xyz[3 * i + 2];
}

}  // namespace
}  // namespace rim
