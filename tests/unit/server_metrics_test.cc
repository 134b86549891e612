// ServerMetrics (server/metrics/metrics.h): the exposition text carries what the hooks were told,
// under the names of docs/metrics.md, with the labels it documents.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/metrics/metrics.h"

namespace rim::server {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

// True when something accepts TCP connections on 127.0.0.1:port.
bool Connects(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return false;
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(uint16_t(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const bool ok = connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) == 0;
  close(fd);
  return ok;
}

TEST(ServerMetricsTest, MethodNamesDropTheRimServicePrefix) {
  EXPECT_EQ(MetricMethodName("/rim.v1.Rim/CreateSession"), "CreateSession");
  EXPECT_EQ(MetricMethodName("/grpc.health.v1.Health/Check"), "grpc.health.v1.Health/Check");
  EXPECT_EQ(GrpcCodeName(0), "OK");
  EXPECT_EQ(GrpcCodeName(3), "INVALID_ARGUMENT");
  EXPECT_EQ(GrpcCodeName(16), "UNAUTHENTICATED");
  EXPECT_EQ(GrpcCodeName(42), "CODE_42");
}

TEST(ServerMetricsTest, EventsShowUpInTheExpositionText) {
  ServerMetrics m(/*host_memory_budget_bytes=*/123456789);
  m.ScanAccepted("r1");
  m.ScanAccepted("r1");
  m.ScanRejected("r1", absl::StatusCode::kInvalidArgument);
  m.ScanRejected("r1", absl::StatusCode::kResourceExhausted);
  m.ScanRejected("r1", absl::StatusCode::kNotFound);
  StageTimings t;
  t.total_s = 0.5;
  // Binary fractions, so that "other" comes out exact.
  t.forward_s = 0.125;
  t.backward_s = 0.25;
  t.distance_s = 0.0625;
  m.FrameIntegrated("r1", t);
  m.DistanceRefreshed("r1", 0.0625);
  m.DistanceRefreshed("r1", 0.25);
  m.QueryAnswered("r2", 1000, 0.002);
  m.TileEncoded("r1", 4096, 0.05, 7);
  m.TilePushed("r1", 1.2);
  m.WatchMeshed("r1", 0.25, 0.5);
  m.WatchMeshed("r1", 0.125, 0.0);
  m.CheckpointWritten("r1", 0.3, 1 << 20);
  m.WalAppended("r1", 0.001);
  m.RpcFinished("/rim.v1.Rim/QuerySdf", 5, 0.01);
  // (The registry writes labels in name order.)
  const std::string text = m.Text();
  EXPECT_THAT(text, HasSubstr("rim_scans_accepted_total{session=\"r1\"} 2"));
  EXPECT_THAT(text,
              HasSubstr("rim_scans_rejected_total{reason=\"invalid_argument\",session=\"r1\"} 1"));
  EXPECT_THAT(
      text, HasSubstr("rim_scans_rejected_total{reason=\"resource_exhausted\",session=\"r1\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_scans_rejected_total{reason=\"other\",session=\"r1\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_scans_integrated_total{session=\"r1\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_frame_integration_seconds_sum{session=\"r1\"} 0.5"));
  EXPECT_THAT(text,
              HasSubstr("rim_training_stage_seconds_sum{session=\"r1\",stage=\"backward\"} 0.25"));
  EXPECT_THAT(
      text, HasSubstr("rim_training_stage_seconds_sum{session=\"r1\",stage=\"distance\"} 0.0625"));
  // The time no stage accounts for is reported as "other": 0.5 - 0.125 - 0.25 - 0.0625.
  EXPECT_THAT(text,
              HasSubstr("rim_training_stage_seconds_sum{session=\"r1\",stage=\"other\"} 0.0625"));
  // Every refresh, after a frame or between frames.
  EXPECT_THAT(text, HasSubstr("rim_distance_refresh_seconds_count{session=\"r1\"} 2"));
  EXPECT_THAT(text, HasSubstr("rim_distance_refresh_seconds_sum{session=\"r1\"} 0.3125"));
  EXPECT_THAT(text, HasSubstr("rim_query_points_total{session=\"r2\"} 1000"));
  EXPECT_THAT(text, HasSubstr("rim_mesh_tile_bytes_total{session=\"r1\"} 4096"));
  EXPECT_THAT(text, HasSubstr("rim_mesh_blocks_remeshed_total{session=\"r1\"} 7"));
  EXPECT_THAT(text, HasSubstr("rim_mesh_tile_push_delay_seconds_count{session=\"r1\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_mesh_tile_push_delay_seconds_sum{session=\"r1\"} 1.2"));
  EXPECT_THAT(text, HasSubstr("rim_meshing_cpu_seconds_total{session=\"r1\"} 0.375"));
  EXPECT_THAT(text, HasSubstr("rim_meshing_budget_wait_seconds_total{session=\"r1\"} 0.5"));
  EXPECT_THAT(text, HasSubstr("rim_checkpoint_seconds_count{session=\"r1\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_wal_append_seconds_count{session=\"r1\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_grpc_requests_total{code=\"NOT_FOUND\",method=\"QuerySdf\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_host_memory_budget_bytes 123456789"));
  EXPECT_THAT(text, HasSubstr("rim_sessions_active 0"));
  EXPECT_THAT(text, HasSubstr("rim_build_info{version="));
  // Query latency buckets: 2 ms falls in le=0.0025 but not in le=0.001.
  EXPECT_THAT(text, HasSubstr("rim_query_latency_seconds_bucket{session=\"r2\",le=\"0.0025\"} 1"));
  EXPECT_THAT(text, HasSubstr("rim_query_latency_seconds_bucket{session=\"r2\",le=\"0.001\"} 0"));
  EXPECT_THAT(text, Not(HasSubstr("session=\"r3\"")));
}

TEST(ServerMetricsTest, ServeRefusesAnAddressItCannotBind) {
  ServerMetrics m(0);
  auto port = m.Serve("256.1.1.1:99999");
  EXPECT_FALSE(port.ok());
  ServerMetrics ok(0);
  auto bound = ok.Serve("127.0.0.1:0");
  ASSERT_TRUE(bound.ok()) << bound.status();
  EXPECT_GT(*bound, 0);
}

// rim_server stops the exposer before the SessionManager that scrapes read is destroyed; after
// StopServing nothing answers on the port.
TEST(ServerMetricsTest, StopServingClosesThePort) {
  ServerMetrics m(0);
  auto port = m.Serve("127.0.0.1:0");
  ASSERT_TRUE(port.ok()) << port.status();
  EXPECT_TRUE(Connects(*port));
  m.StopServing();
  EXPECT_FALSE(Connects(*port));
  m.StopServing();  // a second call does nothing
}

}  // namespace
}  // namespace rim::server
