// Session: the trainer thread integrates queued scans in order, the bounded queue pushes back,
// iterations adapt to the queue depth, and closing drains every accepted scan.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <future>
#include <mutex>
#include <thread>
#include <vector>

#include "server/service/latest_queue.h"
#include "server/session/session.h"
#include "server/session/session_manager.h"
#include "server/session/tile_cache.h"
#include "support/analytic_scene.h"
#include "support/small_session.h"
#include "support/temp_dir.h"

namespace rim::server {
namespace {

MapperConfig SmallConfig() {
  auto config = MakePreset("maicity");
  EXPECT_TRUE(ApplyOverrides({"grid.half_extent_x_m=2", "grid.half_extent_y_m=2",
                              "grid.z_min_m=-1.2", "grid.z_max_m=1.2", "train.iterations=8",
                              "train.min_iterations=2", "sampler.rays_per_iteration=128"},
                             &*config)
                  .ok());
  return *config;
}

PosedScan Scan(float x) {
  testing_support::AnalyticScene scene;
  testing_support::LidarModel lidar;
  lidar.beams = 8;
  lidar.columns = 180;
  lidar.max_range_m = 6.f;
  Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
  T.translation() = Eigen::Vector3f(x, 0.f, 1.f);
  PosedScan scan;
  scan.T_world_sensor = T.cast<double>();
  for (const auto& p : testing_support::SimulateScan(scene, lidar, T, 1))
    scan.points_S.push_back(p);
  return scan;
}

TEST(SessionTest, IntegratesInOrderAndCountsFrames) {
  SessionOptions options;
  options.queue_length = 16;
  auto session = Session::Create("robot_a", SmallConfig(), options);
  ASSERT_TRUE(session.ok());
  std::mutex mu;
  std::vector<uint64_t> order;
  for (uint64_t i = 0; i < 5; ++i) {
    ASSERT_TRUE((*session)
                    ->Submit(i, Scan(0.2f * i),
                             [&](const IntegratedAck& ack) {
                               EXPECT_TRUE(ack.status.ok());
                               std::lock_guard<std::mutex> lock(mu);
                               order.push_back(ack.sequence);
                             })
                    .ok());
  }
  (*session)->Drain();
  EXPECT_EQ(order, (std::vector<uint64_t>{0, 1, 2, 3, 4}));
  const SessionStats stats = (*session)->Stats();
  EXPECT_EQ(stats.accepted, 5u);
  EXPECT_EQ(stats.integrated, 5u);
  EXPECT_EQ((*session)->mapper().frames(), 5);
}

TEST(SessionTest, FullQueuePushesBackAndSignalsSpace) {
  SessionOptions options;
  options.queue_length = 2;
  auto session = Session::Create("robot_b", SmallConfig(), options);
  ASSERT_TRUE(session.ok());
  int accepted = 0;
  absl::Status full;
  for (int i = 0; i < 50 && full.ok(); ++i) {
    full = (*session)->Submit(uint64_t(i), Scan(0.f), nullptr);
    accepted += full.ok();
  }
  EXPECT_EQ(full.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_NE(std::string(full.message()).find("robot_b"), std::string::npos);
  std::atomic<bool> space{false};
  (*session)->OnSpace([&] { space = true; });
  (*session)->Drain();
  EXPECT_TRUE(space.load());
  EXPECT_EQ((*session)->Stats().integrated, uint64_t(accepted));
}

TEST(SessionTest, IterationsAdaptToQueueDepth) {
  SessionOptions options;
  options.queue_length = 5;
  auto session = Session::Create("robot_c", SmallConfig(), options);
  ASSERT_TRUE(session.ok());
  EXPECT_EQ((*session)->AdaptiveIterations(0), 8);
  EXPECT_EQ((*session)->AdaptiveIterations(1), 8);
  EXPECT_EQ((*session)->AdaptiveIterations(5), 2);
  int previous = 8;
  for (size_t d = 1; d <= 5; ++d) {
    const int n = (*session)->AdaptiveIterations(d);
    EXPECT_LE(n, previous);
    EXPECT_GE(n, 2);
    previous = n;
  }
}

TEST(SessionTest, PacedIterationsFitThePeriodAndShrinkWithTheQueue) {
  // 10 Hz, 6 ms an iteration, 25 ms of the rest: 95 - 25 = 70 ms, 11 iterations.
  EXPECT_EQ(PacedIterationCount(0.1, 0.006, 0.025, 1, 2, 30), 11);
  EXPECT_EQ(PacedIterationCount(0.1, 0.006, 0.025, 0, 2, 30), 11);  // an empty queue: itself
  // Each scan waiting behind takes a quarter period away: 45 ms, then 20 ms.
  EXPECT_EQ(PacedIterationCount(0.1, 0.006, 0.025, 2, 2, 30), 7);
  EXPECT_EQ(PacedIterationCount(0.1, 0.006, 0.025, 3, 2, 30), 3);
  // Never below the minimum, never above the configured count.
  EXPECT_EQ(PacedIterationCount(0.1, 0.006, 0.025, 8, 2, 30), 2);
  EXPECT_EQ(PacedIterationCount(0.1, 0.020, 0.120, 1, 3, 30), 3);
  EXPECT_EQ(PacedIterationCount(0.1, 0.001, 0.0, 1, 3, 30), 30);
  // An upload (scans under 20 ms apart) and unknown costs are not paced.
  EXPECT_EQ(PacedIterationCount(0.01, 0.006, 0.025, 1, 3, 30), 30);
  EXPECT_EQ(PacedIterationCount(0.0, 0.006, 0.025, 1, 3, 30), 30);
  EXPECT_EQ(PacedIterationCount(0.1, 0.0, 0.025, 1, 3, 30), 30);
  EXPECT_EQ(PacedIterationCount(0.1, std::nan(""), 0.025, 1, 3, 30), 30);
  EXPECT_EQ(PacedIterationCount(std::nan(""), 0.006, 0.025, 1, 3, 30), 30);
  EXPECT_EQ(PacedIterationCount(0.1, 0.006, -1.0, 1, 3, 30), 30);
}

TEST(SessionTest, ARobotAtASensorsRateKeepsItsQueueShort) {
  // Far more iterations than the robot's interval leaves room for: queued by depth alone, the
  // queue would fill until the iterations fell far enough. Paced, the trainer plans each frame to
  // end before the next scan, so the queue stays short and the iterations settle between the
  // bounds.
  MapperConfig config = SmallConfig();
  ASSERT_TRUE(ApplyOverrides({"train.iterations=300"}, &config).ok());
  // The robot's interval: 50 ms (20 Hz), or five frames at the minimum iterations where this
  // build is slower (a sanitizer's), so that the minimum fits with room to spare.
  double slowest_s = 0;
  {
    auto mapper = Mapper::Create(config);
    ASSERT_TRUE(mapper.ok());
    for (int i = 0; i < 4; ++i) {
      const auto t0 = std::chrono::steady_clock::now();
      ASSERT_TRUE(
          (*mapper)->IntegrateScan(Scan(0.05f * float(i)), config.train.min_iterations).ok());
      if (i > 0)  // the first frame places the box
        slowest_s =
            std::max(slowest_s,
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
  }
  const auto interval =
      std::chrono::microseconds(int64_t(1e6 * std::clamp(5 * slowest_s, 0.05, 1.5)));
  SessionOptions options;
  options.queue_length = 8;
  auto session = Session::Create("robot_p", config, options);
  ASSERT_TRUE(session.ok());
  std::mutex mu;
  std::vector<int> iterations, depth;
  constexpr int kFrames = 40;
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < kFrames; ++i) {
    std::this_thread::sleep_until(start + i * interval);
    // A full queue pushes back, as flow control does on a stream: the robot sends again later.
    absl::Status submitted;
    do {
      submitted = (*session)->Submit(
          uint64_t(i), Scan(0.05f * float(i)),
          [&](const IntegratedAck& ack) {
            std::lock_guard<std::mutex> lock(mu);
            iterations.push_back(ack.iterations);
            depth.push_back(int(ack.queue_depth));
          },
          /*real_time=*/true);
      if (absl::IsResourceExhausted(submitted))
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    } while (absl::IsResourceExhausted(submitted));
    ASSERT_TRUE(submitted.ok()) << submitted;
  }
  (*session)->Drain();
  ASSERT_EQ(iterations.size(), size_t(kFrames));
  // The second half, once the pace and the costs are known.
  std::vector<int> it(iterations.begin() + kFrames / 2, iterations.end());
  std::vector<int> dp(depth.begin() + kFrames / 2, depth.end());
  std::sort(it.begin(), it.end());
  std::sort(dp.begin(), dp.end());
  EXPECT_LE(dp[dp.size() / 2], 1) << "median queue depth";
  EXPECT_GT(it[it.size() / 2], config.train.min_iterations);
  EXPECT_LT(it[it.size() / 2], config.train.iterations);
}

TEST(SessionTest, CloseDrainsEveryAcceptedScanThenRefuses) {
  SessionOptions options;
  options.queue_length = 8;
  auto session = Session::Create("robot_d", SmallConfig(), options);
  ASSERT_TRUE(session.ok());
  std::atomic<int> integrated{0};
  for (int i = 0; i < 6; ++i)
    ASSERT_TRUE((*session)
                    ->Submit(uint64_t(i), Scan(0.f), [&](const IntegratedAck&) { ++integrated; })
                    .ok());
  (*session)->Close();
  EXPECT_EQ(integrated.load(), 6);
  EXPECT_EQ((*session)->mapper().frames(), 6);
  EXPECT_EQ((*session)->Submit(7, Scan(0.f), nullptr).code(),
            absl::StatusCode::kFailedPrecondition);
}

// A robot standing still before a box that arrives at its 9th scan: points on the box's face.
PosedScan StillScan(bool with_box, int seed) {
  testing_support::AnalyticScene scene;
  if (with_box)
    scene.boxes.push_back({Eigen::Vector3f(1.0f, -0.6f, -0.1f), Eigen::Vector3f(1.6f, 0.6f, 1.2f)});
  testing_support::LidarModel lidar;
  lidar.beams = 16;
  lidar.columns = 360;
  lidar.max_range_m = 6.f;
  lidar.elev_min_deg = -60.f;
  Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
  T.translation() = Eigen::Vector3f(0.f, 0.f, 1.f);
  PosedScan scan;
  scan.T_world_sensor = T.cast<double>();
  for (const auto& p : testing_support::SimulateScan(scene, lidar, T, seed))
    scan.points_S.push_back(p);
  return scan;
}

// A client that half-closes its stream waits for Settle: every scan it sent is integrated and the
// distance field covers them, even where the refresh budget skipped the last frames' refreshes
// (here the field refreshes on its own only after frames 1, 2, 4 and 8, before the box came, and
// between frames when the budget allows, which depends on timing: this checks the promise, and
// fails on the runs where the budget skipped the last refresh and Settle did not make it up).
TEST(SessionTest, SettleAnswersOnceEveryScanIsIntegratedAndTheDistanceFieldCoversThem) {
  SessionOptions options;
  options.queue_length = 16;
  MapperConfig config = SmallConfig();
  config.query.refresh_frames = 10000;
  config.sampler.rays_per_iteration = 512;
  config.train.min_iterations = config.train.iterations;  // whatever the queue depth
  // The box appears in front of the still robot at scan 8, where the scans before saw free space:
  // earlier evidence would take it for something walking in and drop its first 5 scans' returns.
  config.transient.past_frames = 0;
  auto session = Session::Create("robot_s", config, options);
  ASSERT_TRUE(session.ok());
  constexpr int kScans = 14;
  std::vector<PosedScan> scans;
  for (int i = 0; i < kScans; ++i) scans.push_back(StillScan(i >= 8, i));
  for (int i = 0; i < kScans; ++i)
    ASSERT_TRUE((*session)->Submit(uint64_t(i), scans[size_t(i)], nullptr).ok());
  std::promise<std::pair<int64_t, bool>> settled;
  (*session)->Settle([&] {
    settled.set_value({(*session)->mapper().frames(), (*session)->mapper().DistanceFieldBehind()});
  });
  const auto [frames, behind] = settled.get_future().get();
  EXPECT_EQ(frames, kScans);
  EXPECT_FALSE(behind);
  // The box's face, which only the last six scans saw, reads as the surface it is.
  std::vector<float> face;
  for (float y = -0.3f; y <= 0.31f; y += 0.3f)
    for (float z = 0.4f; z <= 0.81f; z += 0.2f) face.insert(face.end(), {1.0f, y, z});
  QueryResult result;
  ASSERT_TRUE((*session)->mapper().QuerySdf(face.data(), face.size() / 3, false, &result).ok());
  for (size_t i = 0; i < result.sdf.size(); ++i) {
    EXPECT_NE(result.observed[i], 0) << i;
    EXPECT_LT(std::abs(result.sdf[i]), 0.05f) << i;
  }
  // A closing session answers at once, on the caller's thread.
  (*session)->Close();
  bool called = false;
  (*session)->Settle([&] { called = true; });
  EXPECT_TRUE(called);
}

// Concurrent Close() calls used to read the trainer's thread object while another call joined it,
// and could join it twice.
TEST(SessionTest, ConcurrentClosesEachReturnAfterTheTrainerStopped) {
  SessionOptions options;
  options.queue_length = 8;
  auto session = Session::Create("robot_f", SmallConfig(), options);
  ASSERT_TRUE(session.ok());
  for (int i = 0; i < 4; ++i) ASSERT_TRUE((*session)->Submit(uint64_t(i), Scan(0.f), nullptr).ok());
  std::vector<std::thread> closers;
  std::atomic<int> returned_early{0};
  for (int t = 0; t < 4; ++t)
    closers.emplace_back([&] {
      (*session)->Close();
      if ((*session)->mapper().frames() != 4) ++returned_early;
    });
  for (std::thread& t : closers) t.join();
  EXPECT_EQ(returned_early.load(), 0);
}

// A client that retries CloseSession sends two at once: one closes (and here saves) the session,
// the other finds nothing to close. Both used to go on to close and save (or delete) the same
// session, joining its trainer twice.
TEST(SessionManagerTest, ConcurrentClosesOfOneSessionCloseItOnce) {
  SessionManagerOptions options;
  options.data_dir = testing_support::MakeTempDir("rim_manager_close");
  SessionManager manager(options);
  auto session = manager.Create("robot_g", "", testing_support::SmallMapOverrides());
  ASSERT_TRUE(session.ok()) << session.status();
  for (int i = 0; i < 4; ++i)
    ASSERT_TRUE(
        (*session)->Submit(uint64_t(i), testing_support::GroundScan(0.05 * i), nullptr).ok());
  session->reset();
  std::vector<absl::Status> closed(2);
  std::vector<std::thread> closers;
  for (size_t t = 0; t < closed.size(); ++t)
    closers.emplace_back([&, t] { closed[t] = manager.Close("robot_g", /*save=*/true); });
  for (std::thread& t : closers) t.join();
  const int ok = int(closed[0].ok()) + int(closed[1].ok());
  EXPECT_EQ(ok, 1) << closed[0] << " / " << closed[1];
  for (const absl::Status& s : closed)
    if (!s.ok()) EXPECT_EQ(s.code(), absl::StatusCode::kNotFound) << s;
  auto loaded = manager.Load("robot_g");
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ((*loaded)->mapper().frames(), 4);
}

TEST(TileCacheTest, ReencodesOnlyWhenTheVersionMoves) {
  auto mapper = Mapper::Create(SmallConfig());
  ASSERT_TRUE(mapper.ok());
  ASSERT_TRUE((*mapper)->IntegrateScan(Scan(0.f)).ok());
  TileCache cache;
  const std::vector<TileInfo> tiles = (*mapper)->ListTiles(0);
  ASSERT_FALSE(tiles.empty());
  auto first = cache.Get(**mapper, tiles[0]);
  ASSERT_TRUE(first.ok());
  auto again = cache.Get(**mapper, tiles[0]);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(first->get(), again->get());  // same version: the cached bytes
  EXPECT_EQ(cache.hits(), 1u);
  EXPECT_EQ(cache.misses(), 1u);
  ASSERT_TRUE((*mapper)->IntegrateScan(Scan(0.1f)).ok());
  TileInfo moved = tiles[0];
  for (const TileInfo& t : (*mapper)->ListTiles(0))
    if (t.key == tiles[0].key) moved = t;
  ASSERT_GT(moved.version, tiles[0].version);
  auto newer = cache.Get(**mapper, moved);
  ASSERT_TRUE(newer.ok());
  EXPECT_NE(newer->get(), first->get());
  EXPECT_EQ((*newer)->version, moved.version);
  EXPECT_EQ(cache.misses(), 2u);
}

TEST(LatestPerKeyQueueTest, HoldsOneValuePerKeyTheNewestInFirstComeOrder) {
  LatestPerKeyQueue<Int3, int, Int3Hash, Int3Equal> q;
  const Int3 a(0, 0, 0), b(1, 0, 0);
  EXPECT_FALSE(q.Put(a, 1));
  EXPECT_FALSE(q.Put(b, 2));
  // A slow reader: many newer versions of both keys arrive before it reads.
  for (int v = 3; v < 1000; ++v) EXPECT_TRUE(q.Put(v % 2 ? a : b, v));
  EXPECT_EQ(q.size(), 2u);
  EXPECT_EQ(q.Pop(), 999);  // a kept its place, with its newest value
  EXPECT_EQ(q.Pop(), 998);
  EXPECT_TRUE(q.empty());
  EXPECT_EQ(q.Pop(), std::nullopt);
}

TEST(SessionTest, PeriodicCheckpointsKeepTheLogShort) {
  const std::string dir = testing_support::MakeTempDir("rim_session_ckpt");
  auto wal = WriteAheadLog::Open(dir + "/wal");
  ASSERT_TRUE(wal.ok());
  SessionOptions options;
  options.queue_length = 16;
  options.checkpoint_every_frames = 3;
  options.checkpoint_dir = dir;
  auto session = Session::Create("robot_e", SmallConfig(), options, std::move(*wal));
  ASSERT_TRUE(session.ok());
  for (int i = 0; i < 7; ++i) ASSERT_TRUE((*session)->Submit(uint64_t(i), Scan(0.f), nullptr).ok());
  (*session)->Close();
  EXPECT_TRUE((*session)->last_checkpoint_status().ok());
  // The checkpoint after frame 6 holds 6 frames; only the 7th scan is left to replay. (Whole log
  // segments below a checkpoint are deleted; here all records share one segment.)
  auto loaded = Mapper::Load(dir);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ((*loaded)->frames(), 6);
  auto reopened = WriteAheadLog::Open(dir + "/wal");
  ASSERT_TRUE(reopened.ok());
  int replayed = 0;
  ASSERT_TRUE((*reopened)
                  ->Replay(6,
                           [&](uint64_t index, uint64_t, PosedScan) {
                             EXPECT_EQ(index, 6u);
                             ++replayed;
                             return absl::OkStatus();
                           })
                  .ok());
  EXPECT_EQ(replayed, 1);
}

// A live sensor's scans arrive no earlier than its clock allows, whatever the network's jitter or
// a backlog it catches up on; a replay's run ahead of it, and stay ahead while the session holds
// the sender back.
TEST(SensorClockTest, TellsALiveSensorFromAReplay) {
  SensorClock live;
  for (int i = 0; i < 50; ++i) {
    // 10 Hz, each scan up to 80 ms late, the first one 190 ms late.
    const double late = i == 0 ? 0.19 : 0.08 * ((i * 7) % 5) / 4.0;
    live.Arrive(100 + 0.1 * i + late, 5 + 0.1 * i, false);
    EXPECT_FALSE(live.ahead()) << i;
  }
  // Held back for a second by a full queue, then catching up: late, never ahead.
  for (int i = 50; i < 60; ++i)
    live.Arrive(100 + 0.1 * 50 + 1.0 + 0.05 * (i - 50), 5 + 0.1 * i, i == 50);
  EXPECT_FALSE(live.ahead());
  EXPECT_LT(live.lead_s(), 0);

  SensorClock replay;
  int ahead_at = -1;
  for (int i = 0; i < 10; ++i) {
    replay.Arrive(100 + 0.001 * i, 5 + 0.1 * i, false);  // as fast as the queue takes them
    if (replay.ahead() && ahead_at < 0) ahead_at = i;
  }
  EXPECT_EQ(ahead_at, 3);  // 0.3 s of sensor time in 3 ms: more than two periods
  // Then held back: one scan per 300 ms frame, each after the queue refused it, for minutes.
  for (int i = 10; i < 1000; ++i) {
    replay.Arrive(100 + 0.3 * i, 5 + 0.1 * i, true);
    ASSERT_TRUE(replay.ahead()) << i;
  }
  // A pause of the sender's own starts a new run, which keeps to the clock.
  replay.Arrive(1000, 200, false);
  replay.Arrive(1000.1, 200.1, false);
  EXPECT_FALSE(replay.ahead());

  // No timestamps: no clock, never ahead.
  SensorClock none;
  for (int i = 0; i < 20; ++i) none.Arrive(100 + 0.001 * i, 0, false);
  EXPECT_FALSE(none.ahead());
}

// Nothing waits for an upload or a replay but its sender: a full queue pushes the sender back,
// and every frame trains the configured iterations, on the configured batch. A stream that says
// it is real time but sends its scans ahead of their timestamps is a replay too.
TEST(SessionTest, AReplayTrainsTheConfiguredIterationsWhateverItsQueue) {
  for (const bool real_time : {false, true}) {
    SessionOptions options;
    options.queue_length = 4;
    auto session = Session::Create("robot_r", SmallConfig(), options);
    ASSERT_TRUE(session.ok());
    std::mutex mu;
    std::vector<int> iterations, rays;
    int pushed_back = 0;
    for (int i = 0; i < 16; ++i) {
      PosedScan scan = Scan(0.05f * float(i));
      scan.timestamp_s = 0.1 * i;  // a 10 Hz drive, sent as fast as the queue takes it
      absl::Status submitted;
      while (true) {
        submitted = (*session)->Submit(
            uint64_t(i), scan,
            [&](const IntegratedAck& ack) {
              std::lock_guard<std::mutex> lock(mu);
              iterations.push_back(ack.iterations);
              rays.push_back(ack.rays_per_iteration);
            },
            real_time);
        if (!absl::IsResourceExhausted(submitted)) break;
        ++pushed_back;
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
      }
      ASSERT_TRUE(submitted.ok()) << submitted;
    }
    (*session)->Drain();
    EXPECT_GT(pushed_back, 0) << "real_time " << real_time;
    EXPECT_FALSE((*session)->Stats().real_time);
    ASSERT_EQ(iterations.size(), 16u);
    // A stream that says it is real time is found ahead only at its fourth scan (0.3 s of
    // sensor time in a few ms; SensorClockTest): the trainer may take frames 0-2 before that,
    // as a robot's, when the scans come faster than it wakes (a busy host). Frame 3 and later
    // were taken after the fourth scan came.
    const size_t judged_from = real_time ? 3 : 0;
    for (size_t k = 0; k < iterations.size(); ++k) {
      if (k < judged_from) {
        EXPECT_GE(iterations[k], 2) << "frame " << k;  // the floor
        EXPECT_LE(iterations[k], 8) << "frame " << k;
        continue;
      }
      EXPECT_EQ(iterations[k], 8) << "real_time " << real_time << ", frame " << k;
      EXPECT_EQ(rays[k], 128) << "real_time " << real_time << ", frame " << k;
    }
  }
}

}  // namespace
}  // namespace rim::server
