// Replays keep the offline map (docs/service.md, "Replays keep the offline map"): a recorded drive
// of the synthetic city streamed as fast as the server takes it trains every frame with the
// preset's iterations, as rim_map does, and is pushed back by its full queue instead; so does a
// stream that says it is real time but sends its scans ahead of their timestamps. A stream at its
// sensor's rate still keeps that rate. All through the real rim_server and the real client.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "client/client.h"
#include "rim/config/config.h"
#include "sim/city_frames.h"
#include "support/server_process.h"
#include "support/stream_acks.h"

namespace rim {
namespace {

using testing_support::Median;
using testing_support::ServerProcess;
using testing_support::ServerProcessOptions;
using StreamRun = testing_support::StreamAcks;

constexpr int kQueueLength = 4;

// A small drive of the synthetic city (a quarter of the LiDAR's columns), its timestamps
// `period_s` apart.
std::vector<PosedScan> CityDrive(int frames, double period_s) {
  sim::CityFrameOptions options;
  options.frames = frames;
  options.seed = 601;
  options.columns = 450;
  sim::CityFrames city(options);
  std::vector<PosedScan> scans;
  for (size_t k = 0; k < city.size(); ++k) {
    scans.push_back(city.Frame(k));
    scans.back().timestamp_s = double(k) * period_s;
  }
  return scans;
}

StreamRun Stream(Client* client, const std::string& robot, const std::vector<PosedScan>& scans,
                 double rate_hz, bool real_time) {
  StreamRun run;
  EXPECT_TRUE(client->CreateSession(robot, "maicity").ok());
  StreamOptions options;
  options.rate_hz = rate_hz;
  options.real_time = real_time;
  options.on_ack = run.Recorder();
  auto summary = client->Session(robot).Stream(scans, options);
  EXPECT_TRUE(summary.ok()) << summary.status();
  if (summary.ok()) {
    EXPECT_EQ(summary->integrated, scans.size());
    run.seconds = summary->seconds;
  }
  return run;
}

TEST(ServerReplayTest, AFlatOutReplayTrainsTheOfflineIterationsAndARealTimeStreamKeepsItsRate) {
  ServerProcessOptions server_options;
  server_options.args = {"--queue-length", std::to_string(kQueueLength)};
  auto server = ServerProcess::Start(server_options);
  ASSERT_TRUE(server.ok()) << server.status();
  auto client = Client::Connect((*server)->address());
  ASSERT_TRUE(client.ok()) << client.status();
  auto preset = MakePreset("maicity");
  ASSERT_TRUE(preset.ok());
  const int iterations = preset->train.iterations;
  const int rays = preset->sampler.rays_per_iteration;

  // A 10 Hz drive replayed flat out (no rate, no real-time header): rim_map's iterations on
  // every frame, rim_map's batch, and the queue full most of the way (backpressure).
  const std::vector<PosedScan> drive = CityDrive(12, 0.1);
  const StreamRun replay = Stream(&*client, "replay", drive, 0, /*real_time=*/false);
  ASSERT_EQ(replay.iterations.size(), drive.size());
  for (size_t k = 0; k < drive.size(); ++k) {
    EXPECT_EQ(replay.iterations[k], iterations) << "frame " << k;
    EXPECT_EQ(replay.rays[k], rays) << "frame " << k;
  }
  EXPECT_GE(*std::max_element(replay.lag.begin(), replay.lag.end()), kQueueLength - 1);

  // The same drive with the real-time header, sent at five times its sensor's rate: its
  // timestamps run ahead of their arrival, so it is a replay too.
  const StreamRun ahead = Stream(&*client, "ahead", drive, 50, /*real_time=*/true);
  ASSERT_EQ(ahead.iterations.size(), drive.size());
  for (size_t k = kQueueLength; k < drive.size(); ++k) {
    EXPECT_EQ(ahead.iterations[k], iterations) << "frame " << k;
    EXPECT_EQ(ahead.rays[k], rays) << "frame " << k;
  }

  // A robot at its sensor's rate, slower than a full frame here: it keeps the rate, its queue
  // short, and the session trains what fits its period.
  constexpr int kFrames = 16;
  constexpr double kPeriodS = 0.2;
  const StreamRun live = Stream(&*client, "live", CityDrive(kFrames, kPeriodS), 1 / kPeriodS,
                                /*real_time=*/true);
  ASSERT_EQ(live.lag.size(), size_t(kFrames));
  std::printf(
      "replay: %.2f s, median iterations %d; ahead: median iterations %d; live: %.2f s "
      "for %.2f s of drive, median lag %d, median rays/frame %d\n",
      replay.seconds, Median(replay.iterations), Median(ahead.iterations), live.seconds,
      kFrames * kPeriodS, Median(live.lag), Median(live.iterations) * Median(live.rays));
  EXPECT_LE(Median(std::vector<int>(live.lag.begin() + kFrames / 2, live.lag.end())), 2);  // of 8
  EXPECT_LT(live.seconds, kFrames * kPeriodS + 1.0);
  EXPECT_EQ((*server)->Stop().value_or(-1), 0);
}

}  // namespace
}  // namespace rim
