// Pacing over the wire (docs/service.md, "Sharing the cores"): a stream that says it runs at a
// sensor's rate (the `x-rim-real-time: 1` header, which the C++ client sends for a stream with a
// rate) gets frames planned to end before the next scan, so its queue stays short; the same scans
// at the same rate sent as an upload train every frame fully, so the queue fills. Both go through
// the real rim_server and the real client on loopback. A paced frame trains on
// sampler.paced_rays_per_iteration rays an iteration, an upload's on sampler.rays_per_iteration.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <string>
#include <vector>

#include "client/client.h"
#include "support/server_process.h"
#include "support/small_session.h"
#include "support/stream_acks.h"

namespace rim {
namespace {

using testing_support::GroundScan;
using testing_support::SecondHalfMedian;
using testing_support::ServerProcess;
using testing_support::ServerProcessOptions;

constexpr int kQueueLength = 8;
constexpr int kFrames = 40;

// The small map with `iterations` per frame of 512 rays and a floor of 2; a paced frame's
// batches of 128 rays, so four times as many of them: [8, 4 × iterations].
constexpr int kRays = 512, kPacedRays = 128;
std::vector<std::pair<std::string, std::string>> Overrides(int iterations) {
  auto o = testing_support::SmallMapOverrides();
  for (auto& [key, value] : o) {
    if (key == "train.iterations") value = std::to_string(iterations);
    if (key == "train.min_iterations") value = "2";
    if (key == "sampler.rays_per_iteration") value = std::to_string(kRays);
  }
  o.emplace_back("sampler.paced_rays_per_iteration", std::to_string(kPacedRays));
  return o;
}

struct StreamRun : testing_support::StreamAcks {
  // Iterations trained between frames: over consecutive acks, the map versions gained (one an
  // iteration) less the later frame's own iterations.
  int64_t Between() const {
    int64_t between = 0;
    for (size_t i = 1; i < versions.size(); ++i)
      between += int64_t(versions[i] - versions[i - 1]) - iterations[i];
    return between;
  }
};

// Streams kFrames ground scans at `interval` into a new session with `iterations` a frame.
StreamRun StreamAt(Client* client, const std::string& robot, double interval_s, bool real_time,
                   int iterations) {
  StreamRun run;
  EXPECT_TRUE(client->CreateSession(robot, "maicity", Overrides(iterations)).ok());
  std::vector<PosedScan> scans;
  for (int i = 0; i < kFrames; ++i) scans.push_back(GroundScan(0.05 * i));
  StreamOptions options;
  options.rate_hz = 1.0 / interval_s;
  options.real_time = real_time;
  options.on_ack = run.Recorder();
  auto summary = client->Session(robot).Stream(scans, options);
  EXPECT_TRUE(summary.ok()) << summary.status();
  if (summary.ok()) EXPECT_EQ(summary->integrated, uint64_t(kFrames));
  return run;
}

// Seconds a frame over 8 ground scans uploaded into a new session with `iterations` a frame.
double CalibrationFrameSeconds(Client* client, const std::string& robot, int iterations) {
  EXPECT_TRUE(client->CreateSession(robot, "maicity", Overrides(iterations)).ok());
  auto summary = client->Session(robot).Stream(testing_support::GroundScans(8));
  EXPECT_TRUE(summary.ok()) << summary.status();
  return summary.ok() ? summary->seconds / 8 : 0;
}

TEST(ServerPacingTest, ARealTimeStreamKeepsItsQueueShortAndAnUploadAtTheSameRateDoesNot) {
  ServerProcessOptions server_options;
  server_options.args = {"--queue-length", std::to_string(kQueueLength)};
  auto server = ServerProcess::Start(server_options);
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok()) << client.status();

  // The robot's interval: 200 ms (5 Hz), or ten frames at the floor of 2 iterations on a
  // slower build or a busy machine. A frame plans 95 % of its period, so what is left for training
  // between frames grows with the period: at 50 ms a busy 2-core host left none over 40 frames.
  const double frame_s = CalibrationFrameSeconds(&*client, "calibration", 2);
  const double interval_s = std::clamp(10 * frame_s, 0.2, 1.5);
  // Both sessions are configured for full iterations worth twice the interval a frame (at least
  // 300), so that on any host the upload's queue fills and the paced session must cut. An
  // iteration's cost: frames of 100 iterations less frames of 2.
  const double iteration_s =
      (CalibrationFrameSeconds(&*client, "calibration_100", 100) - frame_s) / 98;
  const int iterations =
      iteration_s > 0 ? std::clamp(int(std::ceil(2 * interval_s / iteration_s)), 300, 4000) : 300;

  const StreamRun paced =
      StreamAt(&*client, "paced_robot", interval_s, /*real_time=*/true, iterations);
  const StreamRun upload =
      StreamAt(&*client, "upload_robot", interval_s, /*real_time=*/false, iterations);
  ASSERT_EQ(paced.lag.size(), size_t(kFrames));
  ASSERT_EQ(upload.lag.size(), size_t(kFrames));

  std::printf(
      "interval %.3f s, iteration %.2f ms, %d configured; paced: median lag %d, iterations %d; "
      "upload: median lag %d, iterations %d\n",
      interval_s, 1e3 * iteration_s, iterations, SecondHalfMedian(paced.lag),
      SecondHalfMedian(paced.iterations), SecondHalfMedian(upload.lag),
      SecondHalfMedian(upload.iterations));
  // Paced: each frame trains what fits before the next scan, on the smaller batches, well under
  // the configured iterations (4 × as many at a quarter of the rays) and above the floor of 4 × 2.
  EXPECT_LE(SecondHalfMedian(paced.lag), 2) << "interval " << interval_s << " s";  // of 8
  EXPECT_EQ(SecondHalfMedian(paced.rays), kPacedRays);
  EXPECT_LT(SecondHalfMedian(paced.iterations), 4 * iterations);
  EXPECT_GT(SecondHalfMedian(paced.iterations), 4 * 2);
  // What the period leaves after a frame's planned iterations, the paced session trains on
  // between frames (Mapper::TrainBetweenFrames); the upload, whose queue never empties, does not.
  std::printf("iterations between frames: paced %lld, upload %lld\n", (long long)paced.Between(),
              (long long)upload.Between());
  EXPECT_GT(paced.Between(), 0);
  EXPECT_EQ(upload.Between(), 0);
  // The upload: the configured iterations whatever its queue (docs/service.md, "Replays keep the
  // offline map"), on the configured batch, so its queue fills.
  EXPECT_GE(SecondHalfMedian(upload.lag), kQueueLength / 2) << "interval " << interval_s << " s";
  EXPECT_EQ(SecondHalfMedian(upload.iterations), iterations);
  for (int rays : upload.rays) EXPECT_EQ(rays, kRays);
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

// A robot whose period cannot fit the small batches' floor (8 iterations of 8192 rays here, far
// more than 50 ms on any machine this runs on) keeps the configured batch at its own floor of 2,
// which costs less, trying the small one again only every 20th frame.
TEST(ServerPacingTest, ASessionAtItsFloorKeepsTheConfiguredBatch) {
  auto server = ServerProcess::Start();
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok()) << client.status();
  auto overrides = Overrides(2);
  for (auto& [key, value] : overrides) {
    if (key == "sampler.rays_per_iteration") value = "32768";
    if (key == "sampler.paced_rays_per_iteration") value = "8192";
  }
  ASSERT_TRUE(client->CreateSession("busy_robot", "maicity", overrides).ok());
  std::vector<PosedScan> scans;
  for (int i = 0; i < 16; ++i) scans.push_back(GroundScan(0.05 * i));
  std::mutex mu;
  std::vector<int> rays, iterations;
  StreamOptions options;
  options.rate_hz = 20;
  options.on_ack = [&](const rim::v1::ScanAck& ack) {
    if (ack.state() != rim::v1::ScanAck::INTEGRATED) return;
    std::lock_guard<std::mutex> lock(mu);
    rays.push_back(int(ack.rays_per_iteration()));
    iterations.push_back(int(ack.iterations()));
  };
  auto summary = client->Session("busy_robot").Stream(scans, options);
  ASSERT_TRUE(summary.ok()) << summary.status();
  ASSERT_EQ(rays.size(), scans.size());
  std::printf("rays per iteration:");
  for (int r : rays) std::printf(" %d", r);
  std::printf("\n");
  // Frames 4 to 16 (once three frames measured the costs): the configured batch at its floor.
  for (size_t k = 4; k < rays.size(); ++k) {
    EXPECT_EQ(rays[k], 32768) << "frame " << k;
    EXPECT_EQ(iterations[k], 2) << "frame " << k;
  }
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

}  // namespace
}  // namespace rim
