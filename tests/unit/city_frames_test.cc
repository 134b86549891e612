// sim::CityFrames (the in-memory city behind `rimctl stream ROBOT sim:city`) yields the frames
// rim_sim --scene city writes to disk: same points, same poses.
#include "sim/city_frames.h"

#include <cmath>

#include "gtest/gtest.h"
#include "rim/io/dataset.h"
#include "sim/sim.h"
#include "support/temp_dir.h"

namespace rim::sim {
namespace {

TEST(CityFramesTest, MatchesRimSimOutput) {
  SimOptions sim;
  sim.scene = SceneKind::kCity;
  sim.out_dir = testing_support::MakeTempDir("city_frames");
  sim.frames = 3;
  sim.columns = 180;  // a coarse LiDAR keeps the test fast
  sim.noise = 0.02;
  sim.seed = 5;
  sim.threads = 2;
  sim.gt_margin = 5;
  ASSERT_TRUE(RunSim(sim).ok());
  auto dataset = io::Dataset::Open(sim.out_dir);
  ASSERT_TRUE(dataset.ok()) << dataset.status();

  CityFrameOptions options;
  options.frames = 3;
  options.columns = 180;
  options.noise = 0.02;
  options.seed = 5;
  options.threads = 1;  // results do not depend on the thread count
  const CityFrames frames(options);
  ASSERT_EQ(frames.size(), (*dataset)->size());
  for (size_t k = 0; k < frames.size(); ++k) {
    const PosedScan streamed = frames.Frame(k);
    auto written = (*dataset)->Read(k);
    ASSERT_TRUE(written.ok()) << written.status();
    ASSERT_GT(streamed.points_S.size(), 1000u);
    EXPECT_EQ(streamed.points_S, written->points_S) << "frame " << k;
    // poses.txt holds the pose as text, so it matches to its printed precision.
    EXPECT_TRUE(streamed.T_world_sensor.isApprox(written->T_world_sensor, 1e-6)) << "frame " << k;
    EXPECT_NEAR(streamed.timestamp_s, written->timestamp_s, 1e-9);
  }
}

}  // namespace
}  // namespace rim::sim
